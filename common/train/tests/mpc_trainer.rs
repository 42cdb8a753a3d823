//! The single-process MPC run at a scale CI affords: reproducible, data aggregation into the
//! model trainer, and planning on the learned model beating random behaviour.

use mbpo_plan::PlannerKind;
use mbpo_train::run_dir::read_eval_curve;
use mbpo_train::{
    checkpoint, train_mpc, train_mpc_with, Algo, ExperimentConfig, PlanReward, RunOptions,
};
use std::path::Path;
use std::sync::atomic::AtomicBool;

mod support;
use support::{crash_copy_after, metrics_without_timings, temp_dir};

/// MPC-CEM on Pendulum with a small model and planner.
fn small_config(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        algo: Algo::MPC,
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
    let header: Vec<&str> = metrics.lines().next().unwrap().split(',').collect();
    let last: Vec<&str> = metrics.lines().last().unwrap().split(',').collect();
    let mse = header
        .iter()
        .position(|h| *h == "model_holdout_mse")
        .unwrap();
    assert!(
        last[mse].parse::<f64>().unwrap() > 0.0,
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

/// metrics.csv without the timing columns (wall_seconds onwards).
/// An MPC run resumed from a checkpoint -- mid-episode, where the planner's warm start carries
/// over; at the end of the warm-up; mid warm-up; after a clean stop -- ends with the final
/// model and the metrics of the uninterrupted run.
#[test]
fn mpc_resumed_from_a_checkpoint_equals_the_uninterrupted_run() {
    let mut cfg = small_config(500);
    cfg.eval.every = 250;
    cfg.checkpoint.every = 100;
    cfg.checkpoint.keep = 10;
    let full = temp_dir("mpc-resume-full");
    let _ = std::fs::remove_dir_all(&full);
    let reference = train_mpc(&cfg, &full).unwrap();
    assert_eq!(reference.status, "completed");
    let resume = RunOptions {
        resume: true,
        ..Default::default()
    };
    // 300: mid-episode (Pendulum episodes are 200 steps), planning with a warm start;
    // 200: the last warm-up step (the next one trains the first model); 100: mid warm-up.
    for at in [300, 200, 100] {
        let crashed = crash_copy_after(&full, at, &format!("mpc-crash-{at}"));
        let resumed = train_mpc_with(&cfg, &crashed, resume).unwrap();
        assert_eq!(
            resumed.policy_sha256, reference.policy_sha256,
            "crash at {at}"
        );
        assert_eq!(resumed.env_steps, 500);
        assert_eq!(
            metrics_without_timings(&crashed),
            metrics_without_timings(&full),
            "crash at {at}"
        );
        std::fs::remove_dir_all(crashed).unwrap();
    }
    // Ctrl-C during the model training of step 201 undoes it and checkpoints step 200 (the
    // actor's and model trainer's files byte for byte the uninterrupted run's); the resume
    // trains again.
    let crashed = crash_copy_after(&full, 200, "mpc-stop-in-training");
    let stop = AtomicBool::new(true);
    let opts = RunOptions {
        resume: true,
        stop: Some(&stop),
    };
    let stopped = train_mpc_with(&cfg, &crashed, opts).unwrap();
    assert_eq!(
        (stopped.status.as_str(), stopped.env_steps),
        ("stopped", 200)
    );
    let (_, newest) = checkpoint::latest(&crashed).unwrap().unwrap();
    assert_eq!(newest.env_steps, 200);
    // Every role's file (not the run's book: it holds the wall clock).
    for f in ["actor-0", "model-trainer", "evaluator"] {
        let read = |run: &Path| std::fs::read(checkpoint::dir_for(run, 200).join(f)).unwrap();
        assert!(
            read(&full) == read(&crashed),
            "{f} of checkpoint 200 differs"
        );
    }
    let resumed = train_mpc_with(&cfg, &crashed, resume).unwrap();
    assert_eq!(resumed.policy_sha256, reference.policy_sha256);
    assert_eq!(
        metrics_without_timings(&crashed),
        metrics_without_timings(&full)
    );
    std::fs::remove_dir_all(crashed).unwrap();
    // A clean stop checkpoints off the periodic schedule and resumes from there.
    let run = temp_dir("mpc-stop");
    let _ = std::fs::remove_dir_all(&run);
    let stop = AtomicBool::new(true);
    let opts = RunOptions {
        resume: false,
        stop: Some(&stop),
    };
    let stopped = train_mpc_with(&cfg, &run, opts).unwrap();
    assert_eq!((stopped.status.as_str(), stopped.env_steps), ("stopped", 1));
    let done = train_mpc_with(&cfg, &run, resume).unwrap();
    assert_eq!(done.status, "completed");
    assert_eq!(done.policy_sha256, reference.policy_sha256);
    assert_eq!(
        metrics_without_timings(&run),
        metrics_without_timings(&full)
    );
    for d in [full, run] {
        std::fs::remove_dir_all(d).unwrap();
    }
}
