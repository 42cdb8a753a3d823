//! `mbpo bench diagnose` on small runs: it reads a kept checkpoint without touching the run,
//! is reproducible, and its figures agree with what the run itself recorded.

use mbpo_bench::diagnose::{diagnose_at, known_tail, BUFFER_ROWS, OPEN_LOOP_HORIZON};
use mbpo_train::{train_mbpo, ExperimentConfig};
use std::path::{Path, PathBuf};

// The train crate's test helpers (a small MBPO config, temporary directories).
#[path = "../../train/tests/support/mod.rs"]
mod support;
use support::{small_mbpo, temp_dir};

/// The small MBPO run on `env` with γ = 0.9, so that Pendulum's 200-step truncated episodes
/// have states with a known soft return.
fn small_mbpo_on(env: &str, steps: u64) -> ExperimentConfig {
    let mut cfg = small_mbpo(steps);
    cfg.env = env.into();
    cfg.sac.gamma = 0.9;
    cfg
}

/// Every file of `dir` with its bytes, sorted by path.
fn files(dir: &Path) -> Vec<(PathBuf, Vec<u8>)> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            out.extend(files(&path));
        } else {
            let bytes = std::fs::read(&path).unwrap();
            out.push((path, bytes));
        }
    }
    out.sort();
    out
}

/// The metrics row at `step`, by column name.
fn metrics_value(run: &Path, step: u64, column: &str) -> f64 {
    let text = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = header.iter().position(|c| *c == column).unwrap();
    let row = lines
        .map(|l| l.split(',').collect::<Vec<_>>())
        .find(|r| r[0] == step.to_string())
        .unwrap();
    row[col].parse().unwrap()
}

#[test]
fn a_kept_checkpoint_is_diagnosed_reproducibly_without_touching_the_run() {
    let cfg = small_mbpo_on("Pendulum-v1", 400);
    let dir = temp_dir("pendulum");
    train_mbpo(&cfg, &dir).unwrap();
    let before = files(&dir);

    let d = diagnose_at(&cfg, &dir, 300, 2).unwrap();
    assert_eq!(files(&dir), before, "the diagnosis wrote to the run");
    let again = diagnose_at(&cfg, &dir, 300, 2).unwrap();
    assert_eq!(
        serde_json::to_string(&d).unwrap(),
        serde_json::to_string(&again).unwrap(),
        "the diagnosis draws from its own stream: the same every time"
    );

    // Pendulum: 200-step episodes, never terminated; a state's soft return is known when
    // known_tail(0.9) = 44 steps follow it.
    let v = &d.value;
    assert_eq!((v.episodes, v.terminated), (2, 0));
    assert_eq!(v.mean_length, 200.0);
    assert_eq!(v.states, 2 * (200 - known_tail(0.9) + 1));
    assert!(v.q_mean.is_finite() && v.soft_return_mean < 0.0, "{v:?}");
    assert!((v.bias - (v.q_mean - v.soft_return_mean)).abs() < 1e-9);

    // The newest training's holdout error is the one the run's metrics row recorded.
    let m = &d.model;
    let recorded = metrics_value(&dir, 300, "model_holdout_mse");
    let holdout = m.holdout_mse.expect("a model was trained by step 300");
    assert!(
        (holdout - recorded).abs() <= 1e-6 * recorded,
        "{holdout} vs {recorded}"
    );
    assert!(m.on_policy_mse.is_finite() && m.on_policy_mse > 0.0);
    // One step open loop is the on-policy error without the reward: MSE over the 3 state
    // dimensions is at most (1 + 3) / 3 of the MSE over [reward, Δobs].
    assert_eq!(m.open_loop_obs_mse.len(), OPEN_LOOP_HORIZON);
    assert!(m
        .open_loop_obs_mse
        .iter()
        .all(|e| e.is_finite() && *e > 0.0));
    assert!(
        m.open_loop_obs_mse[0] * 3.0 <= m.on_policy_mse * 4.0 * (1.0 + 1e-4),
        "{m:?}"
    );
    assert_eq!((m.transitions, m.termination_disagreements), (400, 0));

    // D_env's rows lie in the box of D_env's next states by construction; D_model's rows
    // are the model's and are compared with it.
    assert_eq!(d.real.rows, BUFFER_ROWS / 32 * 32);
    assert_eq!(d.imagined.rows, d.real.rows);
    assert_eq!(d.real.outside_real_box, 0.0);
    assert_eq!(
        d.real.outside_real_box_by_dim,
        vec![0.0; 3],
        "Pendulum's 3 dimensions"
    );
    // A row outside in some dimension is outside overall: the overall share is at least each
    // dimension's and at most their sum.
    let by_dim = &d.imagined.outside_real_box_by_dim;
    assert_eq!(by_dim.len(), 3);
    let (most, sum) = (
        by_dim.iter().cloned().fold(0.0, f64::max),
        by_dim.iter().sum::<f64>(),
    );
    assert!(
        most <= d.imagined.outside_real_box && d.imagined.outside_real_box <= sum + 1e-12,
        "{:?}",
        d.imagined
    );
    assert_eq!((d.real.terminal_rate, d.imagined.terminal_rate), (0.0, 0.0));
    assert!(d.imagined.td_error_rms.is_finite() && d.imagined.td_error_rms > 0.0);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn a_step_without_a_kept_checkpoint_is_a_clear_error() {
    let cfg = small_mbpo_on("Pendulum-v1", 200);
    let dir = temp_dir("missing");
    train_mbpo(&cfg, &dir).unwrap();
    let e = diagnose_at(&cfg, &dir, 150, 1).unwrap_err().to_string();
    assert!(
        e.contains("no complete checkpoint at 150") && e.contains("kept: 100, 200"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// Hopper falls: real terminations, which the rollouts' rule (the task's own) must call the
/// same way on every real transition, and imagined rows that end too.
#[cfg(feature = "mujoco")]
#[test]
fn hoppers_terminations_agree_with_the_rollout_rule() {
    let mut cfg = small_mbpo_on("Hopper-v5", 300);
    cfg.sac.gamma = 0.99;
    let dir = temp_dir("hopper");
    train_mbpo(&cfg, &dir).unwrap();
    let d = diagnose_at(&cfg, &dir, 300, 5).unwrap();
    assert_eq!(d.value.terminated, 5, "{:?}", d.value);
    assert_eq!(d.value.states as f64, 5.0 * d.value.mean_length);
    assert!(d.model.transitions > 0);
    assert_eq!(d.model.termination_disagreements, 0, "{:?}", d.model);
    assert!(d.real.terminal_rate > 0.0, "{:?}", d.real);
    let _ = std::fs::remove_dir_all(dir);
}
