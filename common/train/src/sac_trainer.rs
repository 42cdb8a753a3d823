//! Model-free SAC on a real environment: the baseline MBPO is measured against.
//!
//! Per env step: act (uniform random for the first `random_steps`, then a ~ π(·|s)), store
//! (s, a, r, s', terminated), then `updates_per_step` SAC updates on uniform replay batches.
//! Every random draw comes from a named stream of the run seed, so a seed reproduces a run bit
//! for bit.

use crate::actor::{Behaviour, EnvActor};
use crate::checkpoint;
use crate::config::ExperimentConfig;
use crate::error::TrainError;
use crate::eval::Evaluator;
use crate::progress::{Display, Progress};
use crate::run_control::{checkpoint_due, log_stopped, open_run, RunOptions};
use crate::run_dir::Summary;
use crate::sac_checkpoint::{SacRunState, SAC_CHECKPOINT_FILE, SAC_CHECKPOINT_KIND};
use mbpo_core::rng::stream;
use mbpo_core::{Batch, ReplayBuffer};
use mbpo_sac::{Sac, SacStats};
use std::path::Path;

/// Run SAC per `cfg`, writing the run directory `out`; returns the summary.
pub fn train_sac(cfg: &ExperimentConfig, out: &Path) -> Result<Summary, TrainError> {
    train_sac_with(cfg, out, RunOptions::default())
}

/// [`train_sac`] with resume and stop control.
pub fn train_sac_with(
    cfg: &ExperimentConfig,
    out: &Path,
    opts: RunOptions,
) -> Result<Summary, TrainError> {
    let seed = cfg.seed;
    let mut actor = EnvActor::new(cfg.make_env()?, seed, 0)?;
    let (obs_dim, act_dim) = (actor.obs_dim(), actor.act_dim());
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
    let schedule = crate::Schedule::of(cfg);
    let mut stats = SacStats::default();
    let (mut run, done) = open_run(cfg, out, opts, |dir, _| {
        let path = dir.join(SAC_CHECKPOINT_FILE);
        let state: SacRunState = checkpoint::read(&path, SAC_CHECKPOINT_KIND)?;
        let bad = |e: String| TrainError::Config(format!("{}: {e}", path.display()));
        actor.restore(state.actor)?;
        sac.restore(state.sac).map_err(bad)?;
        replay = ReplayBuffer::from_snapshot(&state.replay, obs_dim, act_dim)
            .map_err(|e| bad(e.to_string()))?;
        (sample_rng, update_rng, stats) = (state.sample_rng, state.update_rng, state.stats);
        evaluator.restore(state.evaluator);
        Ok(())
    })?;
    let label = format!("sac {} s{seed}", cfg.env);
    let mut progress = Progress::new(label, cfg.steps, Display::auto());

    let mut status = "completed";
    for t in done + 1..=cfg.steps {
        // Act: uniform over the action box during warm-up, then the stochastic policy.
        let behaviour = if t <= cfg.sac_loop.random_steps {
            Behaviour::Uniform
        } else {
            Behaviour::Policy
        };
        actor.step(behaviour, &mut sac.policy(), &mut replay)?;

        // Learn.
        if t >= cfg.sac_loop.random_steps && replay.len() >= cfg.sac.batch_size {
            for _ in 0..cfg.sac_loop.updates_per_step {
                replay.sample_into(&mut sample_rng, &mut batch);
                stats = sac.update(&batch, &mut update_rng);
            }
        }

        // Evaluate and record.
        if schedule.is_eval_point(t) {
            let row = evaluator.evaluate(t, &sac, &stats, &actor)?;
            run.write_metrics(&row)?;
            evaluator.log("sac", &row);
            progress.set_eval(row.eval_return);
        }
        progress.update(t, sac.updates());

        // Checkpoint.
        let stopping = opts.stopping_at(t, cfg.steps);
        if checkpoint_due(cfg, t, stopping) {
            let dir = checkpoint::dir_for(out, t);
            std::fs::create_dir_all(&dir)?;
            let state = SacRunState {
                actor: actor.checkpoint(),
                sac: sac.checkpoint(),
                replay: replay.snapshot(),
                sample_rng: sample_rng.clone(),
                update_rng: update_rng.clone(),
                stats,
                evaluator: evaluator.checkpoint(),
            };
            checkpoint::write(&dir.join(SAC_CHECKPOINT_FILE), SAC_CHECKPOINT_KIND, &state)?;
            checkpoint::mark_complete(&dir, t, &[SAC_CHECKPOINT_FILE])?;
            checkpoint::prune(out, cfg.checkpoint.keep, cfg.checkpoint.keep_every)?;
        }
        if stopping {
            log_stopped(t, out);
            status = "stopped";
            break;
        }
    }
    progress.finish();

    let target = cfg.target_return();
    let target = (target, run.env_steps_to_target(target)?);
    let mut summary = evaluator.summary("sac", &sac, None, target);
    summary.env_steps = actor.steps;
    summary.status = status.into();
    summary.episodes_cut_by_resume = actor.episodes_cut;
    summary.episodes_lost_to_env_exit = actor.episodes_lost;
    if status == "completed" {
        crate::policy_file::write_final_policy(out, summary.env_steps, &sac.actor_params)?;
    }
    run.write_summary(&summary)?;
    Ok(summary)
}
