//! MBPO in one process: the sequential reference (Janner et al. 2019, Algorithm 2).
//!
//! ```text
//! Initialise policy π, model p_θ, env buffer D_env, model buffer D_model
//! D_env ← init_random_steps uniform-random transitions                      warm_up
//! for each env step t (epoch = ⌊t / epoch_length⌋):
//!     every model_train_freq steps:
//!         train p_θ on D_env by maximum likelihood                           train_model
//!         k ← rollout_length(epoch); resize D_model to retain_epochs of rollouts
//!         for M · model_train_freq start states s ~ D_env:                   branch_rollouts
//!             k-step rollout of π in p_θ from s; add to D_model
//!     take an action in the env with π; add to D_env                         env_step
//!     for G gradient updates:                                                policy_updates
//!         update π, Q on a batch of real_ratio D_env + (1 − real_ratio) D_model
//! ```
//!
//! This single-process mode is the oracle the multi-process pipeline is tested against: every
//! random draw comes from the named stream of the role that owns it in the pipeline
//! (`actor.*`, `model.*`, `rollout.*`, `learner.*`, `eval.env`), so a lockstep pipeline draws
//! exactly the same numbers in the same order.

use crate::actor::{Behaviour, EnvActor};
use crate::config::ExperimentConfig;
use crate::eval::Evaluator;
use crate::run_dir::{RunDir, Summary};
use crate::sac_trainer::TrainError;
use mbpo_core::rng::stream;
use mbpo_core::{sample_mixed, Batch, ReplayBuffer, Rng};
use mbpo_envs::{termination_fn, TerminationFn};
use mbpo_model::{rollout_length, ModelPoolSizing, ProbabilisticEnsemble, TrainReport};
use mbpo_sac::{ActorPolicy, Sac, SacStats};
use std::path::Path;
use std::time::Instant;

/// State of one MBPO run.
pub struct Mbpo {
    cfg: ExperimentConfig,
    actor: EnvActor,
    sac: Sac,
    model: ProbabilisticEnsemble,
    termination: TerminationFn,
    d_env: ReplayBuffer,
    d_model: ReplayBuffer,
    pool: ModelPoolSizing,
    batch: Batch,
    starts: Batch,
    model_rng: Rng,
    rollout_rng: Rng,
    sample_rng: Rng,
    update_rng: Rng,
    /// Rollout length k in force.
    pub rollout_length: usize,
    /// Report of the last model training.
    pub last_model_report: Option<TrainReport>,
    /// Statistics of the last SAC update.
    pub last_sac_stats: SacStats,
}

impl Mbpo {
    /// Build every component from `cfg`; nothing is trained yet.
    pub fn new(cfg: &ExperimentConfig) -> Result<Self, TrainError> {
        let seed = cfg.seed;
        let m = &cfg.mbpo;
        let actor = EnvActor::new(&cfg.env, seed, 0)?;
        let (o, a) = (actor.obs_dim(), actor.act_dim());
        let termination = termination_fn(&cfg.env).ok_or_else(|| {
            TrainError::Config(format!("no termination function for {}", cfg.env))
        })?;
        let model =
            ProbabilisticEnsemble::new(o, a, cfg.model.clone(), &mut stream(seed, "model.init", 0))
                .map_err(|e| TrainError::Config(e.to_string()))?;
        let pool = ModelPoolSizing {
            rollout_batch_size: m.rollouts_per_step * m.model_train_freq as usize,
            epoch_length: m.epoch_length as usize,
            model_train_freq: m.model_train_freq as usize,
            retain_epochs: m.retain_epochs,
        };
        let k0 = rollout_length(0, m.rollout_schedule);
        Ok(Self {
            sac: Sac::new(o, a, cfg.sac.clone(), &mut stream(seed, "sac.init", 0)),
            d_env: ReplayBuffer::new(o, a, m.replay_capacity),
            d_model: ReplayBuffer::new(o, a, pool.capacity(k0).max(1)),
            batch: Batch::new(o, a, cfg.sac.batch_size),
            starts: Batch::new(o, a, pool.rollout_batch_size),
            model_rng: stream(seed, "model.train", 0),
            rollout_rng: stream(seed, "rollout", 0),
            sample_rng: stream(seed, "learner.sample", 0),
            update_rng: stream(seed, "learner.update", 0),
            rollout_length: k0,
            last_model_report: None,
            last_sac_stats: SacStats::default(),
            cfg: cfg.clone(),
            actor,
            model,
            termination,
            pool,
        })
    }

    /// Real env steps taken so far.
    pub fn env_steps(&self) -> u64 {
        self.actor.steps
    }

    /// Transitions in the model buffer D_model.
    pub fn model_buffer_len(&self) -> usize {
        self.d_model.len()
    }

    /// The SAC agent (policy parameters, update count).
    pub fn sac(&self) -> &Sac {
        &self.sac
    }

    /// One uniform-random env step into D_env (the warm-up before the loop).
    pub fn warm_up_step(&mut self) {
        self.actor
            .step(Behaviour::Uniform, &mut self.sac.policy(), &mut self.d_env);
    }

    /// Train p_θ on all of D_env (holdout early stopping; elites).
    pub fn train_model(&mut self) -> Result<&TrainReport, TrainError> {
        let data = self.d_env.to_batch();
        let report = self
            .model
            .train(&data, &mut self.model_rng)
            .map_err(|e| TrainError::Config(e.to_string()))?;
        Ok(self.last_model_report.insert(report))
    }

    /// Set k for `epoch`, resize D_model to keep `retain_epochs` of rollouts, and branch
    /// M · model_train_freq k-step rollouts of π from start states drawn uniformly from D_env.
    pub fn branch_rollouts(&mut self, epoch: usize) -> Result<(), TrainError> {
        self.rollout_length = rollout_length(epoch, self.cfg.mbpo.rollout_schedule);
        self.d_model
            .set_capacity(self.pool.capacity(self.rollout_length).max(1));
        self.d_env
            .sample_into(&mut self.rollout_rng, &mut self.starts);
        let mut policy =
            ActorPolicy::new(self.sac.actor.clone(), self.sac.actor_params.clone(), false);
        let termination = self.termination;
        self.model
            .rollout(
                &self.starts.obs,
                self.starts.len,
                &mut policy,
                self.rollout_length,
                &termination,
                &mut self.rollout_rng,
                &mut self.d_model,
            )
            .map_err(|e| TrainError::Config(e.to_string()))?;
        Ok(())
    }

    /// One real env step with a ~ π(·|s) into D_env.
    pub fn env_step(&mut self) {
        self.actor
            .step(Behaviour::Policy, &mut self.sac.policy(), &mut self.d_env);
    }

    /// G SAC updates on batches of `real_ratio` D_env and the rest D_model.
    pub fn policy_updates(&mut self) {
        for _ in 0..self.cfg.mbpo.updates_per_step {
            sample_mixed(
                &self.d_env,
                &self.d_model,
                self.cfg.mbpo.real_ratio,
                &mut self.sample_rng,
                &mut self.batch,
            );
            self.last_sac_stats = self.sac.update(&self.batch, &mut self.update_rng);
        }
    }
}

/// Run MBPO per `cfg`, writing the run directory `out`; returns the summary.
pub fn train_mbpo(cfg: &ExperimentConfig, out: &Path) -> Result<Summary, TrainError> {
    let m = &cfg.mbpo;
    let mut run = RunDir::create(out, cfg)?;
    let mut mbpo = Mbpo::new(cfg)?;
    let mut evaluator = Evaluator::new(cfg)?;
    let mut step_seconds = Vec::with_capacity(cfg.steps as usize);
    for t in 1..=cfg.steps {
        let started = Instant::now();
        if t <= m.init_random_steps {
            mbpo.warm_up_step();
        } else {
            let since = t - m.init_random_steps - 1;
            if since.is_multiple_of(m.model_train_freq) {
                let report = mbpo.train_model()?;
                tracing::debug!(
                    "model trained: {} epochs, elites {:?}, holdout mse {:?}",
                    report.epochs,
                    report.elites,
                    report.final_holdout_mse
                );
                mbpo.branch_rollouts((since / m.epoch_length) as usize)?;
            }
            mbpo.env_step();
            mbpo.policy_updates();
            step_seconds.push(started.elapsed().as_secs_f64());
        }
        if t.is_multiple_of(cfg.eval.every) || t == cfg.steps {
            let mut row = evaluator.evaluate(t, &mut mbpo.sac, &mbpo.last_sac_stats, &mbpo.actor);
            if let Some(r) = &mbpo.last_model_report {
                let elites = &r.elites;
                let mse: f64 = elites
                    .iter()
                    .map(|&e| r.final_holdout_mse[e] as f64)
                    .sum::<f64>()
                    / elites.len() as f64;
                row.model_holdout_mse = Some(mse);
                row.rollout_length = Some(mbpo.rollout_length as f64);
                row.model_buffer = Some(mbpo.d_model.len() as f64);
            }
            run.write_metrics(&row)?;
            evaluator.log("mbpo", &row);
        }
    }
    step_seconds.sort_by(f64::total_cmp);
    let median = step_seconds.get(step_seconds.len() / 2).copied();
    let summary = evaluator.summary("mbpo", &mbpo.sac, median);
    run.write_summary(&summary)?;
    Ok(summary)
}
