//! The extension points, proven: a task the project does not ship, added with one
//! `mbpo_envs::register` call and one `Env` impl (this file only), runs under the sequential
//! trainer and under the in-process pipeline, and lockstep equals sequential on it too.

use std::time::Duration;

use mbpo_core::rng::{uniform_range_f32, Rng};
use mbpo_envs::{register, BoxSpace, Env, EnvError, Step, TaskSpec};
use mbpo_integration_tests::*;
use mbpo_runtime::in_process::{run_in_process, InProcessRun};
use mbpo_runtime::{Mode, Slack};
use mbpo_train::train_mbpo;

/// A point on a line pushed by the action; reward −x² − 0.1·a²; 50-step episodes.
struct Toy {
    x: f64,
    steps: usize,
    obs_space: BoxSpace,
    act_space: BoxSpace,
}

const TOY_ID: &str = "ToyLine-v0";

impl Env for Toy {
    fn id(&self) -> &'static str {
        TOY_ID
    }
    fn observation_space(&self) -> &BoxSpace {
        &self.obs_space
    }
    fn action_space(&self) -> &BoxSpace {
        &self.act_space
    }
    fn state_dim(&self) -> usize {
        1
    }
    fn state_layout(&self) -> &'static str {
        "x"
    }
    fn max_episode_steps(&self) -> usize {
        50
    }
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) {
        self.x = uniform_range_f32(rng, -1.0, 1.0) as f64;
        self.steps = 0;
        obs[0] = self.x as f32;
    }
    fn reset_to(&mut self, state: &[f64], obs: &mut [f32]) -> Result<(), EnvError> {
        self.x = state[0];
        self.steps = 0;
        obs[0] = self.x as f32;
        Ok(())
    }
    fn state(&self) -> Vec<f64> {
        vec![self.x]
    }
    fn elapsed_steps(&self) -> usize {
        self.steps
    }
    fn set_elapsed_steps(&mut self, steps: usize) {
        self.steps = steps;
    }
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Step {
        let a = action[0].clamp(-1.0, 1.0) as f64;
        self.x = (self.x + 0.1 * a).clamp(-2.0, 2.0);
        self.steps += 1;
        obs[0] = self.x as f32;
        Step {
            reward: -self.x * self.x - 0.1 * a * a,
            terminated: false,
            truncated: self.steps >= 50,
        }
    }
}

fn make_toy() -> Result<Box<dyn Env>, EnvError> {
    Ok(Box::new(Toy {
        x: 0.0,
        steps: 0,
        obs_space: BoxSpace::new(vec![-2.0], vec![2.0]),
        act_space: BoxSpace::new(vec![-1.0], vec![1.0]),
    }))
}

#[test]
fn a_registered_task_runs_sequentially_and_in_the_pipeline_with_equal_results() {
    register(TaskSpec {
        id: TOY_ID,
        make: make_toy,
        termination: mbpo_envs::termination::never,
        reward: None,
        target_return: Some(-5.0),
        mujoco: false,
    })
    .unwrap();
    let mut cfg = tiny_config(300);
    cfg.env = TOY_ID.into();
    cfg.eval.every = 100;
    let dir = scratch("extension-toy-env");
    let seq = train_mbpo(&cfg, &dir.join("sequential")).unwrap();
    let run = InProcessRun {
        out: dir.join("lockstep"),
        ipc_root: ipc_root("ext-toy"),
        mode: Mode::Lockstep,
        actors: 1,
        slack: Slack::ZERO,
        timeout: Duration::from_secs(240),
    };
    let s = run_in_process(&cfg, &run).unwrap();
    assert_eq!(s.summary.env, TOY_ID);
    assert_eq!(s.summary.policy_sha256, seq.policy_sha256);
    assert_eq!(
        metrics_without_timing(&run.out),
        metrics_without_timing(&dir.join("sequential"))
    );
}
