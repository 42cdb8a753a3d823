//! Model-free SAC on a real environment: the baseline MBPO is measured against.
//!
//! Per env step: act (uniform random for the first `random_steps`, then a ~ π(·|s)), store
//! (s, a, r, s', terminated), then `updates_per_step` SAC updates on uniform replay batches.
//! Every random draw comes from a named stream of the run seed, so a seed reproduces a run bit
//! for bit.

use crate::actor::{Behaviour, EnvActor};
use crate::checkpoint;
use crate::config::ExperimentConfig;
use crate::driver::{drive, SequentialRun};
use crate::error::TrainError;
use crate::eval::Evaluator;
use crate::run_control::RunOptions;
use crate::run_dir::{MetricsRow, RunDir, Summary};
use crate::sac_checkpoint::{SacRunState, SAC_CHECKPOINT_FILE, SAC_CHECKPOINT_KIND};
use mbpo_core::rng::stream;
use mbpo_core::{Batch, ReplayBuffer, Rng};
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
    drive(&mut SacRun::new(cfg, out)?, cfg, out, opts)
}

/// A SAC run's state: the actor, the agent, its replay buffer and streams, the evaluator.
struct SacRun<'a> {
    cfg: &'a ExperimentConfig,
    out: &'a Path,
    actor: EnvActor,
    sac: Sac,
    replay: ReplayBuffer,
    batch: Batch,
    sample_rng: Rng,
    update_rng: Rng,
    evaluator: Evaluator,
    stats: SacStats,
}

impl<'a> SacRun<'a> {
    fn new(cfg: &'a ExperimentConfig, out: &'a Path) -> Result<Self, TrainError> {
        let seed = cfg.seed;
        let actor = EnvActor::new(cfg.make_env()?, seed, 0)?;
        let (obs_dim, act_dim) = (actor.obs_dim(), actor.act_dim());
        let sac = Sac::new(
            obs_dim,
            act_dim,
            cfg.sac.clone(),
            &mut stream(seed, "sac.init", 0),
        );
        Ok(Self {
            cfg,
            out,
            actor,
            sac,
            replay: ReplayBuffer::new(obs_dim, act_dim, cfg.sac_loop.replay_capacity),
            batch: Batch::new(obs_dim, act_dim, cfg.sac.batch_size),
            sample_rng: stream(seed, "learner.sample", 0),
            update_rng: stream(seed, "learner.update", 0),
            evaluator: Evaluator::new(cfg)?,
            stats: SacStats::default(),
        })
    }
}

impl SequentialRun for SacRun<'_> {
    fn restore(&mut self, dir: &Path, _t: u64) -> Result<(), TrainError> {
        let path = dir.join(SAC_CHECKPOINT_FILE);
        let state: SacRunState = checkpoint::read(&path, SAC_CHECKPOINT_KIND)?;
        let bad = |e: String| TrainError::Config(format!("{}: {e}", path.display()));
        let (obs_dim, act_dim) = (self.actor.obs_dim(), self.actor.act_dim());
        self.actor.restore(state.actor)?;
        self.sac.restore(state.sac).map_err(bad)?;
        self.replay = ReplayBuffer::from_snapshot(&state.replay, obs_dim, act_dim)
            .map_err(|e| bad(e.to_string()))?;
        (self.sample_rng, self.update_rng) = (state.sample_rng, state.update_rng);
        self.stats = state.stats;
        self.evaluator.restore(state.evaluator);
        Ok(())
    }

    /// Act (uniform over the action box during warm-up, then the stochastic policy), store,
    /// then `updates_per_step` SAC updates.
    fn step(
        &mut self,
        t: u64,
        _stop: &mut dyn FnMut(&mbpo_model::EpochProgress) -> bool,
    ) -> Result<bool, TrainError> {
        let warm_up = self.cfg.sac_loop.random_steps;
        let behaviour = match t <= warm_up {
            true => Behaviour::Uniform,
            false => Behaviour::Policy,
        };
        self.actor
            .step(behaviour, &mut self.sac.policy(), &mut self.replay)?;
        if t >= warm_up && self.replay.len() >= self.cfg.sac.batch_size {
            for _ in 0..self.cfg.sac_loop.updates_per_step {
                self.replay
                    .sample_into(&mut self.sample_rng, &mut self.batch);
                self.stats = self.sac.update(&self.batch, &mut self.update_rng);
            }
        }
        Ok(true)
    }

    fn evaluate(&mut self, t: u64) -> Result<MetricsRow, TrainError> {
        let row = self
            .evaluator
            .evaluate(t, &self.sac, &self.stats, &self.actor)?;
        self.evaluator.log(self.cfg.algo.name(), &row);
        Ok(row)
    }

    fn progress(&self) -> (u64, Option<u64>) {
        (self.sac.updates(), None)
    }

    fn save(&mut self, t: u64, _wait: bool) -> Result<(), TrainError> {
        let dir = checkpoint::dir_for(self.out, t);
        std::fs::create_dir_all(&dir)?;
        let state = SacRunState {
            actor: self.actor.checkpoint(),
            sac: self.sac.checkpoint(),
            replay: self.replay.snapshot(),
            sample_rng: self.sample_rng.clone(),
            update_rng: self.update_rng.clone(),
            stats: self.stats,
            evaluator: self.evaluator.checkpoint(),
        };
        checkpoint::write(&dir.join(SAC_CHECKPOINT_FILE), SAC_CHECKPOINT_KIND, &state)?;
        checkpoint::mark_complete(&dir, t, &[SAC_CHECKPOINT_FILE])?;
        let keep = &self.cfg.checkpoint;
        Ok(checkpoint::prune(self.out, keep.keep, keep.keep_every)?)
    }

    fn finish(&mut self, status: &str, run: &mut RunDir) -> Result<Summary, TrainError> {
        let target = self.cfg.target_return();
        let target = (target, run.env_steps_to_target(target)?);
        let mut summary = self
            .evaluator
            .summary(self.cfg.algo.name(), &self.sac, None, target);
        summary.env_steps = self.actor.steps;
        summary.status = status.into();
        summary.episodes_cut_by_resume = self.actor.episodes_cut;
        summary.episodes_lost_to_env_exit = self.actor.episodes_lost;
        if status == "completed" {
            let actor = &self.sac.actor_params;
            crate::policy_file::write_final_policy(self.out, summary.env_steps, actor)?;
        }
        Ok(summary)
    }
}
