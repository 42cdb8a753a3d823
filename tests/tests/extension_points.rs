//! The extension points, proven from this file alone:
//! - a task the project does not ship (one `Env` impl, one `mbpo_envs::register` call) runs
//!   under the sequential trainer and under the in-process pipeline, and lockstep equals
//!   sequential on it too. The toy does not offer the optional saved-state capability
//!   (`RestorableEnv`), as a Python env or a robot would not: checkpoints still resume, starting
//!   a new episode;
//! - an algorithm the project does not ship (a uniform-random baseline: one function, one
//!   `mbpo_train::algorithm::register` call) is a config's `algo`, runs where `mbpo train`
//!   runs algorithms, and is refused by the pipeline by name.

use std::path::Path;
use std::time::Duration;

use mbpo_core::rng::{stream, uniform_range_f32, Rng};
use mbpo_core::{BatchPolicy, UniformPolicy};
use mbpo_envs::{register, BoxSpace, Env, EnvError, Step, TaskSpec};
use mbpo_integration_tests::*;
use mbpo_runtime::in_process::{run_in_process, InProcessRun};
use mbpo_runtime::{Mode, Slack};
use mbpo_train::algorithm::{self, AlgorithmSpec};
use mbpo_train::run_dir::MetricsRow;
use mbpo_train::{
    train_mbpo, train_mbpo_with, ExperimentConfig, RunDir, RunOptions, Schedule, Summary,
    TrainError,
};

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
        let a = action[0].clamp(-1.0, 1.0) as f64;
        self.x = (self.x + 0.1 * a).clamp(-2.0, 2.0);
        self.steps += 1;
        obs[0] = self.x as f32;
        Ok(Step {
            reward: -self.x * self.x - 0.1 * a * a,
            terminated: false,
            truncated: self.steps >= 50,
        })
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
    std::fs::remove_dir_all(&dir).unwrap();
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
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The toy algorithm: a uniform-random policy, evaluated at the config's eval points.
fn train_random(
    cfg: &ExperimentConfig,
    out: &Path,
    opts: RunOptions,
) -> Result<Summary, TrainError> {
    if opts.resume {
        return Err(TrainError::Config(
            "the random baseline keeps no checkpoints".into(),
        ));
    }
    let mut run = RunDir::create(out, cfg)?;
    let mut env = mbpo_envs::make(&cfg.env)?;
    let space = env.action_space().clone();
    let mut policy = UniformPolicy {
        low: space.low.clone(),
        high: space.high.clone(),
    };
    let mut rng = stream(cfg.seed, "random.eval", 0);
    let schedule = Schedule::of(cfg);
    let (mut last, mut best) = (f64::NAN, f64::NEG_INFINITY);
    for t in (1..=cfg.steps).filter(|&t| schedule.is_eval_point(t)) {
        // Actions are [-1, 1] inside learners; this one acts in the env's own box.
        let ret = evaluate_in_box(&mut policy, env.as_mut(), cfg.eval.episodes, &mut rng);
        run.write_metrics(&MetricsRow {
            env_steps: t,
            eval_return: ret,
            ..Default::default()
        })?;
        (last, best) = (ret, best.max(ret));
    }
    let summary = Summary {
        algo: cfg.algo.name().into(),
        env: cfg.env.clone(),
        seed: cfg.seed,
        env_steps: cfg.steps,
        sac_updates: 0,
        final_eval_return: last,
        best_eval_return: best,
        target_return: cfg.target_return(),
        env_steps_to_target: run.env_steps_to_target(cfg.target_return())?,
        policy_sha256: String::new(),
        wall_seconds: 0.0,
        median_seconds_per_env_step: None,
        status: "completed".into(),
        episodes_cut_by_resume: 0,
        episodes_lost_to_env_exit: 0,
    };
    run.write_summary(&summary)?;
    Ok(summary)
}

/// Mean return of `episodes` episodes of `policy` acting directly in the env's action box.
fn evaluate_in_box(
    policy: &mut UniformPolicy,
    env: &mut dyn Env,
    episodes: usize,
    rng: &mut Rng,
) -> f64 {
    let (mut obs, mut action) = (vec![0.0f32; env.obs_dim()], vec![0.0f32; env.act_dim()]);
    let mut total = 0.0;
    for _ in 0..episodes {
        env.reset(rng, &mut obs).unwrap();
        loop {
            policy.act_batch(&obs, 1, &mut action, rng);
            let step = env.step(&action, &mut obs).unwrap();
            total += step.reward;
            if step.terminated || step.truncated {
                break;
            }
        }
    }
    total / episodes as f64
}

#[test]
fn a_registered_algorithm_runs_as_a_configs_algo_and_the_pipeline_refuses_it() {
    let unknown = toml::from_str::<ExperimentConfig>("algo = \"random-policy\"").unwrap_err();
    assert!(
        unknown
            .to_string()
            .contains("unknown algorithm 'random-policy'"),
        "{unknown}"
    );
    let algo = algorithm::register(AlgorithmSpec {
        name: "random-policy",
        train: train_random,
    })
    .unwrap();
    let mut cfg: ExperimentConfig =
        toml::from_str("algo = \"random-policy\"\nenv = \"Pendulum-v1\"\nsteps = 400").unwrap();
    assert_eq!(cfg.algo, algo);
    cfg.eval.every = 200;
    cfg.eval.episodes = 2;
    cfg.validate("test").unwrap();
    let dir = scratch("extension-random-algo");
    let s = algorithm::train(&cfg, &dir.join("train"), RunOptions::default()).unwrap();
    assert_eq!((s.algo.as_str(), s.env_steps), ("random-policy", 400));
    // Pendulum under random actions: about -1200 per episode.
    assert!((-1800.0..-800.0).contains(&s.final_eval_return), "{s:?}");
    let rows: Vec<String> = metrics_without_timing(&dir.join("train"))
        .iter()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().to_string())
        .collect();
    assert_eq!(rows, ["200", "400"]);
    let run = InProcessRun {
        out: dir.join("pipeline"),
        ipc_root: ipc_root("ext-algo"),
        mode: Mode::Lockstep,
        actors: 1,
        slack: Slack::ZERO,
        timeout: Duration::from_secs(30),
    };
    let err = run_in_process(&cfg, &run).unwrap_err().to_string();
    assert!(err.contains("runs mbpo or mpc, not random-policy"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}
