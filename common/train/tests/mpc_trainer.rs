//! The single-process MPC run at a scale CI affords: reproducible, data aggregation into the
//! model trainer, and planning on the learned model beating random behaviour.

use mbpo_plan::PlannerKind;
use mbpo_train::run_dir::read_eval_curve;
use mbpo_train::{train_mpc, Algo, ExperimentConfig, PlanReward};
use std::path::PathBuf;

/// MPC-CEM on Pendulum with a small model and planner.
fn small_config(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        algo: Algo::Mpc,
        steps,
        ..Default::default()
    };
    cfg.eval.every = 200;
    cfg.eval.episodes = 1;
    cfg.mpc.init_random_steps = 200;
    cfg.mpc.model_train_freq = 200;
    cfg.mpc.reward = PlanReward::Known;
    let p = &mut cfg.mpc.planner;
    p.kind = PlannerKind::Cem;
    p.horizon = 15;
    p.particles = 3;
    p.cem.candidates = 60;
    p.cem.elites = 6;
    p.cem.iterations = 3;
    cfg.model.members = 3;
    cfg.model.elites = 3;
    cfg.model.hidden = vec![48, 48];
    cfg.model.weight_decay = vec![2.5e-5, 5e-5, 1e-4];
    cfg.model.batch_size = 32;
    cfg.model.max_epochs_since_update = 50;
    cfg
}

fn temp_dir(name: &str) -> PathBuf {
    std::env::temp_dir().join(format!("mbpo-test-{name}-{}", std::process::id()))
}

#[test]
fn mpc_run_reproduces_and_plans_better_than_random_actions() {
    let cfg = small_config(600);
    let (a, b) = (temp_dir("mpc-det-a"), temp_dir("mpc-det-b"));
    let sa = train_mpc(&cfg, &a).unwrap();
    let sb = train_mpc(&cfg, &b).unwrap();
    assert_eq!(sa.algo, "mpc");
    assert_eq!(
        sa.policy_sha256, sb.policy_sha256,
        "same seed, same final model"
    );
    let (ca, cb) = (
        read_eval_curve(&a.join("metrics.csv")).unwrap(),
        read_eval_curve(&b.join("metrics.csv")).unwrap(),
    );
    assert_eq!(ca, cb, "same seed, same evaluation returns");
    // No evaluation before the first model (step 200 is still warm-up); then 400 and 600.
    assert_eq!(ca.iter().map(|p| p.0).collect::<Vec<_>>(), vec![400, 600]);
    let metrics = std::fs::read_to_string(a.join("metrics.csv")).unwrap();
    let last: Vec<&str> = metrics.lines().last().unwrap().split(',').collect();
    assert!(
        last[10].parse::<f64>().unwrap() > 0.0,
        "model holdout mse: {metrics}"
    );
    assert!(sa.median_seconds_per_env_step.unwrap() > 0.0);
    // Uniform random torques score about −1200 per Pendulum episode; planning on a model of
    // 200-400 real transitions must swing the pendulum up and hold it (this config: −133).
    eprintln!("eval curve {ca:?}");
    assert!(
        sa.best_eval_return > -400.0,
        "best MPC evaluation {} (random ≈ −1200)",
        sa.best_eval_return
    );
    for d in [a, b] {
        std::fs::remove_dir_all(d).unwrap();
    }
}

#[test]
fn mpc_config_errors_name_the_key() {
    let mut cfg = small_config(300);
    cfg.env = "MountainCarContinuous-v0".into();
    cfg.validate("test").unwrap(); // MountainCar has a known reward too
    cfg.mpc.model_train_freq = 0;
    let err = cfg.validate("test").unwrap_err().to_string();
    assert!(err.contains("mpc.model_train_freq"), "{err}");
    let mut cfg = small_config(300);
    cfg.mpc.planner.horizon = 0;
    let err = cfg.validate("test").unwrap_err().to_string();
    assert!(err.contains("mpc.planner.horizon"), "{err}");
}
