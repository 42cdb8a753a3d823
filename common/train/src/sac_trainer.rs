//! Model-free SAC on a real environment: the baseline MBPO is measured against.
//!
//! Per env step: act (uniform random for the first `random_steps`, then a ~ π(·|s)), store
//! (s, a, r, s', terminated), then `updates_per_step` SAC updates on uniform replay batches.
//! Every random draw comes from a named stream of the run seed, so a seed reproduces a run bit
//! for bit.

use crate::actor::{Behaviour, EnvActor};
use crate::config::ExperimentConfig;
use crate::eval::Evaluator;
use crate::progress::{Display, Progress};
use crate::run_dir::{RunDir, Summary};
use mbpo_core::rng::stream;
use mbpo_core::{Batch, ReplayBuffer};
use mbpo_sac::{Sac, SacStats};
use std::path::Path;

/// Errors of a training run.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// The environment could not be built.
    #[error(transparent)]
    Env(#[from] mbpo_envs::EnvError),
    /// The run directory could not be written.
    #[error("run directory: {0}")]
    Io(#[from] std::io::Error),
    /// A component rejected its configuration or input.
    #[error("{0}")]
    Config(String),
    /// A results file could not be encoded.
    #[error("results file: {0}")]
    Json(#[from] serde_json::Error),
}

/// Run SAC per `cfg`, writing the run directory `out`; returns the summary.
pub fn train_sac(cfg: &ExperimentConfig, out: &Path) -> Result<Summary, TrainError> {
    let seed = cfg.seed;
    let mut actor = EnvActor::new(&cfg.env, seed, 0)?;
    let (obs_dim, act_dim) = (actor.obs_dim(), actor.act_dim());
    let mut run = RunDir::create(out, cfg)?;
    let mut sac = Sac::new(
        obs_dim,
        act_dim,
        cfg.sac.clone(),
        &mut stream(seed, "sac.init", 0),
    );
    let mut replay = ReplayBuffer::new(obs_dim, act_dim, cfg.sac_loop.replay_capacity);
    let mut batch = Batch::new(obs_dim, act_dim, cfg.sac.batch_size);
    let mut sample_rng = stream(seed, "learner.sample", 0);
    let mut update_rng = stream(seed, "learner.update", 0);
    let mut evaluator = Evaluator::new(cfg)?;
    let mut stats = SacStats::default();
    let label = format!("sac {} s{seed}", cfg.env);
    let mut progress = Progress::new(label, cfg.steps, Display::auto());

    for t in 1..=cfg.steps {
        // Act: uniform over the action box during warm-up, then the stochastic policy.
        let behaviour = if t <= cfg.sac_loop.random_steps {
            Behaviour::Uniform
        } else {
            Behaviour::Policy
        };
        actor.step(behaviour, &mut sac.policy(), &mut replay);

        // Learn.
        if t >= cfg.sac_loop.random_steps && replay.len() >= cfg.sac.batch_size {
            for _ in 0..cfg.sac_loop.updates_per_step {
                replay.sample_into(&mut sample_rng, &mut batch);
                stats = sac.update(&batch, &mut update_rng);
            }
        }

        // Evaluate and record.
        if t.is_multiple_of(cfg.eval.every) || t == cfg.steps {
            let row = evaluator.evaluate(t, &sac, &stats, &actor);
            run.write_metrics(&row)?;
            evaluator.log("sac", &row);
            progress.set_eval(row.eval_return);
        }
        progress.update(t, sac.updates());
    }
    progress.finish();

    let summary = evaluator.summary("sac", &sac, None);
    run.write_summary(&summary)?;
    Ok(summary)
}
