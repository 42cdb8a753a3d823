//! What the trainer's integration tests share: scratch directories and the small MBPO run.
#![allow(dead_code)] // each test binary uses some of it

use mbpo_train::checkpoint;
use mbpo_train::{Algo, ExperimentConfig};
use std::path::{Path, PathBuf};

/// A fresh scratch directory `name` for this test process (a leftover of an earlier run with
/// the same process id is removed).
pub fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("mbpo-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// MBPO on Pendulum, small: train points at t = 201, 301, 401; checkpoints every 100 steps.
pub fn small_mbpo(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        algo: Algo::MBPO,
        steps,
        ..Default::default()
    };
    cfg.eval.every = 50;
    cfg.eval.episodes = 1;
    cfg.sac.hidden = vec![32, 32];
    cfg.sac.batch_size = 32;
    cfg.mbpo.init_random_steps = 200;
    cfg.mbpo.epoch_length = 100;
    cfg.mbpo.model_train_freq = 100;
    cfg.mbpo.rollouts_per_step = 10;
    cfg.mbpo.rollout_schedule = [1, 3, 1, 3];
    cfg.mbpo.updates_per_step = 2;
    cfg.model.members = 3;
    cfg.model.elites = 2;
    cfg.model.hidden = vec![16, 16];
    cfg.model.weight_decay = vec![2.5e-5, 5e-5, 1e-4];
    cfg.model.batch_size = 32;
    cfg.model.max_epochs = Some(5);
    cfg.checkpoint.every = 100;
    cfg.checkpoint.keep = 10;
    cfg
}

/// metrics.csv without its timing columns (the first 13 columns: no wall seconds or rates).
pub fn metrics_without_timings(run: &Path) -> Vec<String> {
    std::fs::read_to_string(run.join("metrics.csv"))
        .unwrap()
        .lines()
        .map(|l| l.split(',').take(13).collect::<Vec<_>>().join(","))
        .collect()
}

/// A crash right after the checkpoint of `at`: later checkpoints and the summary are gone.
pub fn crash_copy_after(full: &Path, at: u64, name: &str) -> PathBuf {
    let crashed = temp_dir(name);
    let _ = std::fs::remove_dir_all(&crashed);
    let status = std::process::Command::new("cp")
        .arg("-r")
        .arg(full)
        .arg(&crashed)
        .status()
        .unwrap();
    assert!(status.success());
    for entry in std::fs::read_dir(checkpoint::root(&crashed)).unwrap() {
        let dir = entry.unwrap().path();
        let steps: u64 = dir.file_name().unwrap().to_str().unwrap().parse().unwrap();
        if steps > at {
            std::fs::remove_dir_all(dir).unwrap();
        }
    }
    std::fs::remove_file(crashed.join("summary.json")).unwrap();
    crashed
}
