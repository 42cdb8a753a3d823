//! A run's trained policy: where it is and how to read it.
//!
//! Every run that completes writes its final actor to `<run>/policy.ckpt`, whichever command
//! ran it (`mbpo train` for SAC or MBPO, `mbpo run` for the pipeline): the pipeline's periodic
//! checkpoints rarely fall on the last step, so without this file the policy a completed run
//! ended with would be lost. A run that was stopped, crashed or is still running has its
//! policy only in its newest checkpoint: the learner's file of an MBPO run (either command) or
//! the SAC trainer's ([`newest_policy`] reads both and takes whichever of the two is newer).
//! [`evaluate_run`] plays that policy (`mbpo eval`).

use crate::checkpoint::{self, CheckpointError};
use crate::config::ExperimentConfig;
use crate::error::TrainError;
use crate::eval::evaluate;
use crate::run_files::{self, LearnerCheckpoint};
use crate::sac_checkpoint::{checkpointed_actor_params, SAC_CHECKPOINT_FILE};
use mbpo_core::rng::stream;
use mbpo_sac::ActorPolicy;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

pub use crate::run_dir::FINAL_POLICY_FILE;

/// Checkpoint kind of [`FinalPolicy`].
const FINAL_POLICY_KIND: &str = "mbpo.policy";

/// The actor a run ended with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FinalPolicy {
    /// Real env steps the run had taken.
    pub env_steps: u64,
    /// The SAC actor's parameters θ_π (architecture: the run's `config.toml`, `[sac] hidden`).
    pub actor_params: Vec<f32>,
}

/// Write `<run>/policy.ckpt` (atomically, in the checkpoint file format).
pub fn write_final_policy(
    run: &Path,
    env_steps: u64,
    actor_params: &[f32],
) -> Result<(), CheckpointError> {
    let policy = FinalPolicy {
        env_steps,
        actor_params: actor_params.to_vec(),
    };
    checkpoint::write(&run.join(FINAL_POLICY_FILE), FINAL_POLICY_KIND, &policy)
}

/// A policy found in a run directory, and the file it came from.
#[derive(Debug, Clone, PartialEq)]
pub struct FoundPolicy {
    /// The policy.
    pub policy: FinalPolicy,
    /// The file it was read from.
    pub file: PathBuf,
}

/// The newest policy of `run`: its final policy or the actor of its newest complete
/// checkpoint, whichever is after more env steps (the final policy on a tie). A run with
/// neither is an error that says when each is written.
pub fn newest_policy(run: &Path) -> Result<FoundPolicy, TrainError> {
    let final_path = run.join(FINAL_POLICY_FILE);
    let final_policy = if final_path.exists() {
        let policy: FinalPolicy = checkpoint::read(&final_path, FINAL_POLICY_KIND)?;
        Some(FoundPolicy {
            policy,
            file: final_path,
        })
    } else {
        None
    };
    // A checkpoint is read only when it is newer than the final policy: its learner file
    // holds the replay buffers too, and a damaged older one must not hide a good final policy.
    let final_steps = final_policy.as_ref().map(|f| f.policy.env_steps);
    let from_checkpoint = match checkpoint::latest(run)? {
        Some((dir, manifest)) if final_steps.is_none_or(|s| manifest.env_steps > s) => {
            Some(checkpointed_policy(&dir, &manifest)?)
        }
        _ => None,
    };
    match (final_policy, from_checkpoint) {
        (_, Some(c)) => Ok(c),
        (Some(f), None) => Ok(f),
        (None, None) => Err(TrainError::Config(format!(
            "{} has no policy yet: {FINAL_POLICY_FILE} is written when a run completes, and \
             checkpoints (in {}) every `[checkpoint] every` env steps",
            run.display(),
            checkpoint::root(run).display()
        ))),
    }
}

/// The actor of the checkpoint in `dir`, from whichever trainer's layout it is.
fn checkpointed_policy(
    dir: &Path,
    manifest: &checkpoint::Manifest,
) -> Result<FoundPolicy, TrainError> {
    let has = |name: &str| manifest.files.iter().any(|f| f == name);
    let (file, actor_params) = if has(run_files::file::LEARNER) {
        let path = dir.join(run_files::file::LEARNER);
        let learner: LearnerCheckpoint = checkpoint::read(&path, run_files::kind::LEARNER)?;
        (path, learner.role.sac.actor_params)
    } else if has(SAC_CHECKPOINT_FILE) {
        (
            dir.join(SAC_CHECKPOINT_FILE),
            checkpointed_actor_params(dir)?,
        )
    } else {
        return Err(TrainError::Config(format!(
            "checkpoint {} holds no policy (files: {}); MPC runs plan with the model and have none",
            dir.display(),
            manifest.files.join(", ")
        )));
    };
    Ok(FoundPolicy {
        policy: FinalPolicy {
            env_steps: manifest.env_steps,
            actor_params,
        },
        file,
    })
}

/// What `mbpo eval` reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalReport {
    /// The run directory.
    pub run: String,
    /// Environment id.
    pub env: String,
    /// Env steps of the policy evaluated (the run's final policy or its newest checkpoint's).
    pub policy_env_steps: u64,
    /// The file the policy was read from.
    pub policy_file: String,
    /// Episodes run.
    pub episodes: usize,
    /// Mean return.
    pub mean_return: f64,
    /// Standard deviation of the returns (population).
    pub std_return: f64,
    /// Each episode's return.
    pub returns: Vec<f64>,
}

/// Evaluate the newest policy of `run` (its final policy, or its newest complete checkpoint's
/// while it has not completed: [`newest_policy`]; architecture from its
/// `config.toml`) over `episodes` deterministic episodes with start states from stream
/// `eval.cli` of `seed`.
pub fn evaluate_run(
    run: &std::path::Path,
    episodes: usize,
    seed: u64,
) -> Result<EvalReport, TrainError> {
    if episodes == 0 {
        return Err(TrainError::Config("--episodes must be at least 1".into()));
    }
    let cfg = ExperimentConfig::load(&run.join("config.toml")).map_err(|e| {
        TrainError::Config(format!("{} is not a run directory: {e}", run.display()))
    })?;
    if cfg.algo == crate::Algo::MPC {
        return Err(TrainError::Config(format!(
            "{} is an MPC run: it plans with its model and has no policy network to evaluate \
             (its evaluations are in metrics.csv)",
            run.display()
        )));
    }
    let found = newest_policy(run)?;
    let params = found.policy.actor_params;
    let mut env = cfg.make_env()?;
    let net = mbpo_sac::TanhGaussianActor::new(
        env.obs_dim(),
        env.act_dim(),
        &cfg.sac.hidden,
        cfg.sac.log_std_min,
        cfg.sac.log_std_max,
    );
    if params.len() != net.num_params() {
        return Err(TrainError::Config(format!(
            "{}: the policy has {} parameters, the config's actor needs {}",
            found.file.display(),
            params.len(),
            net.num_params()
        )));
    }
    let mut policy = ActorPolicy::new(net, params, true);
    let mut rng = stream(seed, "eval.cli", 0);
    let returns: Vec<f64> = (0..episodes)
        .map(|_| evaluate(&mut policy, env.as_mut(), 1, &mut rng))
        .collect::<Result<_, _>>()?;
    let mean = returns.iter().sum::<f64>() / episodes as f64;
    let var = returns.iter().map(|r| (r - mean).powi(2)).sum::<f64>() / episodes as f64;
    Ok(EvalReport {
        run: run.display().to_string(),
        env: cfg.env.clone(),
        policy_env_steps: found.policy.env_steps,
        policy_file: found.file.display().to_string(),
        episodes,
        mean_return: mean,
        std_return: var.sqrt(),
        returns,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn temp_run(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("mbpo-policy-file-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        dir
    }

    #[test]
    fn the_final_policy_reads_back_and_an_empty_run_says_what_is_missing() {
        let run = temp_run("roundtrip");
        let err = newest_policy(&run).unwrap_err().to_string();
        assert!(err.contains("has no policy yet"), "{err}");
        assert!(err.contains(FINAL_POLICY_FILE), "{err}");
        write_final_policy(&run, 500, &[1.0, -2.5, 3.25]).unwrap();
        let found = newest_policy(&run).unwrap();
        assert_eq!(found.file, run.join(FINAL_POLICY_FILE));
        assert_eq!(found.policy.env_steps, 500);
        assert_eq!(found.policy.actor_params, vec![1.0, -2.5, 3.25]);
        // An older checkpoint is not even read: a damaged one cannot hide the final policy.
        let older = checkpoint::dir_for(&run, 400);
        std::fs::create_dir_all(&older).unwrap();
        std::fs::write(older.join("learner"), b"damaged").unwrap();
        checkpoint::mark_complete(&older, 400, &["learner"]).unwrap();
        assert_eq!(newest_policy(&run).unwrap().policy.env_steps, 500);
        // A newer one is, and its damage is reported.
        let newer = checkpoint::dir_for(&run, 600);
        std::fs::create_dir_all(&newer).unwrap();
        std::fs::write(newer.join("learner"), b"damaged").unwrap();
        checkpoint::mark_complete(&newer, 600, &["learner"]).unwrap();
        let err = newest_policy(&run).unwrap_err().to_string();
        assert!(err.contains("learner"), "{err}");
        let _ = std::fs::remove_dir_all(&run);
    }
}
