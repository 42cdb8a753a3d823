//! The extension points, proven: a task the project does not ship, added with one
//! `mbpo_envs::register` call and one `Env` impl (this file only), runs under the sequential
//! trainer and under the in-process pipeline, and lockstep equals sequential on it too. The toy
//! does not offer the optional saved-state capability (`RestorableEnv`), as a Python env or a
//! robot would not: checkpoints still resume, starting a new episode.

use std::time::Duration;

use mbpo_core::rng::{uniform_range_f32, Rng};
use mbpo_envs::{register, BoxSpace, Env, EnvError, Step, TaskSpec};
use mbpo_integration_tests::*;
use mbpo_runtime::in_process::{run_in_process, InProcessRun};
use mbpo_runtime::{Mode, Slack};
use mbpo_train::{train_mbpo, train_mbpo_with, RunOptions};

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
    fn max_episode_steps(&self) -> usize {
        50
    }
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) {
        self.x = uniform_range_f32(rng, -1.0, 1.0) as f64;
        self.steps = 0;
        obs[0] = self.x as f32;
    }
    fn elapsed_steps(&self) -> usize {
        self.steps
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

/// Register the toy once per test binary (tests run on threads of one process).
fn register_toy() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        register(TaskSpec {
            id: TOY_ID,
            make: make_toy,
            termination: mbpo_envs::termination::never,
            reward: None,
            target_return: Some(-5.0),
            mujoco: false,
        })
        .unwrap()
    });
}

#[test]
fn a_registered_task_runs_sequentially_and_in_the_pipeline_with_equal_results() {
    register_toy();
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

#[test]
fn an_env_that_cannot_save_its_state_resumes_with_a_new_episode() {
    register_toy();
    assert!(make_toy().unwrap().restorable().is_none());
    let dir = scratch("extension-toy-resume");
    let mut cfg = tiny_config(125);
    cfg.env = TOY_ID.into();
    cfg.eval.every = 100;
    // 125 steps end 25 steps into the third 50-step episode: the checkpoint cannot hold it.
    let first = train_mbpo(&cfg, &dir).unwrap();
    assert_eq!((first.env_steps, first.episodes_cut_by_resume), (125, 0));
    cfg.steps = 300;
    let resume = RunOptions {
        resume: true,
        ..Default::default()
    };
    let resumed = train_mbpo_with(&cfg, &dir, resume).unwrap();
    assert_eq!(resumed.status, "completed");
    assert_eq!(resumed.env_steps, 300);
    assert_eq!(resumed.episodes_cut_by_resume, 1);
    let rows: Vec<String> = metrics_without_timing(&dir)
        .iter()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().to_string())
        .collect();
    // Eval points 100, 200, 300 and the first run's last step.
    assert_eq!(rows, ["100", "125", "200", "300"]);
}
