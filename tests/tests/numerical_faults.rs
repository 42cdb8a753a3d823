//! NaN where a number must be finite stops the run where it appears, naming the role, the
//! step and the quantity, and keeps the last good checkpoint: here an environment whose
//! observation turns NaN at env step 60, under `mbpo train` and under the in-process
//! pipeline.

use std::time::Duration;

use mbpo_core::rng::{uniform_range_f32, Rng};
use mbpo_envs::{register, BoxSpace, Env, EnvError, Step, TaskSpec};
use mbpo_integration_tests::*;
use mbpo_runtime::in_process::{run_in_process, InProcessRun};
use mbpo_runtime::{Mode, Slack};
use mbpo_train::{checkpoint, train_mbpo};

const ID: &str = "NanAt60-v0";

/// A point on a line; its observation is NaN from the run's 60th env step on.
struct NanAt60 {
    x: f64,
    steps: usize,
    total: u64,
    space: BoxSpace,
}

impl Env for NanAt60 {
    fn id(&self) -> &'static str {
        ID
    }
    fn observation_space(&self) -> &BoxSpace {
        &self.space
    }
    fn action_space(&self) -> &BoxSpace {
        &self.space
    }
    fn max_episode_steps(&self) -> usize {
        20
    }
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) -> Result<(), EnvError> {
        self.x = uniform_range_f32(rng, -1.0, 1.0) as f64;
        self.steps = 0;
        obs[0] = self.x as f32;
        Ok(())
    }
    fn elapsed_steps(&self) -> usize {
        self.steps
    }
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<Step, EnvError> {
        self.x = (self.x + 0.1 * action[0] as f64).clamp(-1.0, 1.0);
        self.steps += 1;
        self.total += 1;
        obs[0] = if self.total >= 60 {
            f32::NAN
        } else {
            self.x as f32
        };
        Ok(Step {
            reward: -self.x * self.x,
            terminated: false,
            truncated: self.steps >= 20,
        })
    }
}

fn make() -> Result<Box<dyn Env>, EnvError> {
    Ok(Box::new(NanAt60 {
        x: 0.0,
        steps: 0,
        total: 0,
        space: BoxSpace::new(vec![-1.0], vec![1.0]),
    }))
}

fn register_once() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        register(TaskSpec {
            id: ID,
            make,
            termination: mbpo_envs::termination::never,
            reward: None,
            target_return: None,
            mujoco: false,
        })
        .unwrap()
    });
}

fn config() -> mbpo_train::ExperimentConfig {
    let mut cfg = tiny_config(200);
    cfg.env = ID.into();
    cfg.mbpo.init_random_steps = 40;
    cfg.mbpo.epoch_length = 40;
    cfg.mbpo.model_train_freq = 40;
    cfg.eval.every = 100;
    cfg.checkpoint.every = 25;
    cfg
}

#[test]
fn a_nan_observation_stops_the_sequential_run_naming_it_and_keeps_the_last_checkpoint() {
    register_once();
    let dir = scratch("nan-sequential");
    let err = train_mbpo(&config(), &dir).unwrap_err().to_string();
    assert!(
        err.contains("actor: observation[0] is NaN at env step 60 of NanAt60-v0"),
        "{err}"
    );
    assert!(err.contains("last complete checkpoint is kept"), "{err}");
    let (_, manifest) = checkpoint::latest(&dir).unwrap().unwrap();
    assert_eq!(manifest.env_steps, 50);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_nan_observation_fails_the_pipeline_naming_the_actor() {
    register_once();
    let dir = scratch("nan-pipeline");
    let run = InProcessRun {
        out: dir.join("run"),
        ipc_root: ipc_root("nan"),
        mode: Mode::Lockstep,
        actors: 1,
        slack: Slack::ZERO,
        timeout: Duration::from_secs(120),
    };
    let err = run_in_process(&config(), &run).unwrap_err().to_string();
    assert!(
        err.contains("actor-0") && err.contains("observation[0] is NaN at env step 60"),
        "{err}"
    );
    let _ = std::fs::remove_dir_all(dir);
}
