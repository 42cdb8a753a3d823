//! TD-MPC2 under `mbpo train` at a scale CI affords: the run reproduces itself, a run resumed
//! from any checkpoint (in the seed steps, right after the burst of updates, mid-episode) ends
//! with the uninterrupted run's parameters and metrics, and bad settings are named.

use mbpo_train::tdmpc::{train_tdmpc, train_tdmpc_with};
use mbpo_train::TdmpcSize;
use mbpo_train::{Algo, ExperimentConfig, RunOptions};

mod support;
use support::{crash_copy_after, metrics_without_timings, temp_dir};

/// TD-MPC on Pendulum with small networks and planner: 100 seed steps, then one update per
/// step; checkpoints every 75 steps (75: seed steps; 150: after the burst, mid-episode; 225,
/// 300: mid-episode).
fn small_tdmpc(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        algo: Algo::TDMPC,
        steps,
        ..Default::default()
    };
    let t = &mut cfg.tdmpc;
    (t.latent, t.encoder_hidden, t.hidden) = (Some(16), Some(32), Some(32));
    (t.seed_steps, t.batch_size) = (100, 16);
    let p = &mut t.planner;
    (p.samples, p.policy_samples, p.elites, p.iterations) = (32, 4, 8, 2);
    cfg.eval.every = 100;
    cfg.eval.episodes = 1;
    cfg.checkpoint.every = 75;
    cfg.checkpoint.keep = 10;
    cfg
}

#[test]
fn a_tdmpc_run_resumed_from_any_checkpoint_equals_the_uninterrupted_run() {
    let cfg = small_tdmpc(320);
    let full = temp_dir("tdmpc-full");
    let reference = train_tdmpc(&cfg, &full).unwrap();
    assert_eq!(
        reference.sac_updates,
        100 + 220,
        "the burst, then one per step"
    );
    // Every row (the first after the burst of updates at 100) has the world model's losses.
    let text = std::fs::read_to_string(full.join("metrics.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 4, "100, 200, 300 and the last step: {text}");
    for column in [
        "critic_loss",
        "actor_loss",
        "consistency_loss",
        "reward_loss",
    ] {
        let c = header.iter().position(|h| *h == column).unwrap();
        for row in &rows {
            let v: f64 = row[c]
                .parse()
                .unwrap_or_else(|_| panic!("{column}: {text}"));
            assert!(v.is_finite(), "{column}: {text}");
        }
    }
    let again = temp_dir("tdmpc-again");
    let repeat = train_tdmpc(&cfg, &again).unwrap();
    assert_eq!(
        repeat.policy_sha256, reference.policy_sha256,
        "reproducible"
    );
    let resume = RunOptions {
        resume: true,
        ..Default::default()
    };
    for at in [75, 150, 225, 300] {
        let crashed = crash_copy_after(&full, at, &format!("tdmpc-crash-{at}"));
        let resumed = train_tdmpc_with(&cfg, &crashed, resume).unwrap();
        assert_eq!(
            resumed.policy_sha256, reference.policy_sha256,
            "resumed after {at}"
        );
        assert_eq!(resumed.sac_updates, reference.sac_updates);
        assert_eq!(
            metrics_without_timings(&crashed),
            metrics_without_timings(&full),
            "resumed after {at}"
        );
        std::fs::remove_dir_all(crashed).unwrap();
    }
    for dir in [full, again] {
        std::fs::remove_dir_all(dir).unwrap();
    }
}

#[test]
fn tdmpc_settings_out_of_range_are_named_with_their_key() {
    let mut cfg = small_tdmpc(100);
    cfg.tdmpc.latent = Some(20);
    let err = cfg.validate("tdmpc.toml").unwrap_err().to_string();
    assert!(err.contains("tdmpc.latent"), "{err}");
    assert!(err.contains("multiple of 8"), "{err}");
    cfg.tdmpc.latent = None;
    cfg.tdmpc.size = TdmpcSize::FiveM;
    cfg.tdmpc.planner.elites = 1000;
    let err = cfg.validate("tdmpc.toml").unwrap_err().to_string();
    assert!(err.contains("tdmpc.planner"), "{err}");
    // Another algorithm's run does not read the table.
    cfg.algo = Algo::SAC;
    cfg.validate("sac.toml").unwrap();
}

/// A run extended past its planned steps (`--resume --steps N`) goes on: its buffer grows
/// to the new length and draws as it did; a checkpoint of another model size is refused.
#[test]
fn an_extended_run_continues_and_a_checkpoint_of_another_model_size_is_refused() {
    let cfg = small_tdmpc(120);
    let run = temp_dir("tdmpc-size");
    train_tdmpc(&cfg, &run).unwrap();
    let resume = RunOptions {
        resume: true,
        ..Default::default()
    };
    let mut longer = cfg.clone();
    longer.steps = 160;
    let extended = train_tdmpc_with(&longer, &run, resume).unwrap();
    assert_eq!((extended.env_steps, extended.sac_updates), (160, 100 + 60));
    let mut bigger = longer.clone();
    bigger.steps = 240;
    bigger.tdmpc.hidden = Some(64);
    let err = train_tdmpc_with(&bigger, &run, resume)
        .unwrap_err()
        .to_string();
    assert!(err.contains("another model size"), "{err}");
    std::fs::remove_dir_all(run).unwrap();
}
