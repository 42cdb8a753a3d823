//! `mbpo bench checkpoint`: what checkpointing a real run costs its training loop.
//!
//! The run's kept checkpoint is restored and written again into a scratch directory on the
//! same file system, timed in its two parts: encoding, which holds the training loop, and
//! checksum + write + `fsync`, which [`mbpo_train::checkpoint_writer`] runs on its own thread (before
//! it, the loop waited for both).

use mbpo_train::checkpoint;
use mbpo_train::config::ExperimentConfig;
use mbpo_train::error::TrainError;
use mbpo_train::eval::Evaluator;
use mbpo_train::Mbpo;
use serde::Serialize;
use std::path::Path;
use std::time::Instant;

/// Seconds per repetition of each part of one checkpoint.
#[derive(Debug, Serialize)]
pub struct CheckpointCost {
    /// Env steps of the checkpoint.
    pub env_steps: u64,
    /// Bytes of its files.
    pub bytes: usize,
    /// Encoding (the training loop waits for it).
    pub encode_seconds: Vec<f64>,
    /// Checksum, write, `fsync`, `COMPLETE` (on the writer's thread).
    pub write_seconds: Vec<f64>,
}

impl CheckpointCost {
    /// One line for people: the medians.
    pub fn summary_line(&self) -> String {
        let median = |v: &[f64]| mbpo_core::stats::median(&mut v.to_vec()).unwrap_or(f64::NAN);
        format!(
            "checkpoint at {}: {:.0} MB; encode {:.3} s (the training loop waits), checksum + \
             write + fsync {:.3} s (on the writer's thread); medians of {}",
            self.env_steps,
            self.bytes as f64 / 1e6,
            median(&self.encode_seconds),
            median(&self.write_seconds),
            self.encode_seconds.len()
        )
    }
}

/// Restore `run`'s checkpoint after `at` env steps and write it `repeats` times under
/// `scratch` (a run directory of its own, removed after each write).
pub fn checkpoint_cost(
    cfg: &ExperimentConfig,
    run: &Path,
    at: u64,
    repeats: usize,
    scratch: &Path,
) -> Result<CheckpointCost, TrainError> {
    let (mbpo, book) = Mbpo::from_kept_checkpoint(cfg, run, at)?;
    let evaluator = Evaluator::new(cfg)?;
    let dir = checkpoint::dir_for(scratch, at);
    let mut cost = CheckpointCost {
        env_steps: at,
        bytes: 0,
        encode_seconds: Vec::new(),
        write_seconds: Vec::new(),
    };
    for _ in 0..repeats {
        let started = Instant::now();
        let files = mbpo.encode_checkpoint(&dir, at, &evaluator, &book)?;
        cost.encode_seconds.push(started.elapsed().as_secs_f64());
        cost.bytes = files.bytes();
        let started = Instant::now();
        files.write()?;
        cost.write_seconds.push(started.elapsed().as_secs_f64());
        std::fs::remove_dir_all(scratch).map_err(|source| checkpoint::CheckpointError::Io {
            path: scratch.to_path_buf(),
            source,
        })?;
    }
    Ok(cost)
}
