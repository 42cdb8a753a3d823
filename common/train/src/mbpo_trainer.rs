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

use crate::actor::Behaviour;
use crate::checkpoint::{self, CheckpointError};
use crate::checkpoint_writer::{BackgroundWriter, CheckpointFiles};
use crate::config::ExperimentConfig;
use crate::driver::{drive, SequentialRun};
use crate::error::TrainError;
use crate::eval::Evaluator;
use crate::phase_times::PhaseTimes;
use crate::roles::{
    ActorRole, LearnerRole, ModelSnapshot, ModelTrainerRole, RolloutRole, Schedule,
};
use crate::run_control::RunOptions;
use crate::run_dir::{MetricsRow, RunDir, Summary};
use crate::run_files::{
    actor_file, check_one_actor_cut, file, kind, ActorCheckpoint, EvaluatorCheckpoint,
    LearnerCheckpoint, ModelTrainerCheckpoint, RolloutCheckpoint, RunBook,
};
use mbpo_core::Rng;
use mbpo_envs::EnvError;
use mbpo_model::EpochProgress;
use mbpo_model::TrainReport;
use mbpo_sac::Sac;
use std::path::Path;
use std::time::Instant;

/// Every role of one MBPO run in one process, called in Algorithm 2's order.
pub struct Mbpo {
    schedule: Schedule,
    updates_per_step: usize,
    actor: ActorRole,
    model_trainer: ModelTrainerRole,
    rollout: RolloutRole,
    learner: LearnerRole,
    /// Report of the last model training.
    pub last_model_report: Option<TrainReport>,
    /// The run's book (episode ends, model MSEs, step times, rows): what a checkpoint keeps of
    /// the run besides the roles, the same as `mbpo run`'s coordinator keeps.
    pub book: RunBook,
    /// Seconds per phase so far (this process's steps only; not checkpointed).
    pub phases: PhaseTimes,
}

impl Mbpo {
    /// Build every role from `cfg`; nothing is trained yet.
    pub fn new(cfg: &ExperimentConfig) -> Result<Self, TrainError> {
        let actor = ActorRole::new(cfg, 0)?;
        let (o, a) = (actor.env_actor().obs_dim(), actor.env_actor().act_dim());
        let learner = LearnerRole::new(cfg, o, a);
        let mut mbpo = Self {
            schedule: Schedule::of(cfg),
            updates_per_step: cfg.mbpo.updates_per_step,
            model_trainer: ModelTrainerRole::new(cfg, o, a)?,
            rollout: RolloutRole::new(cfg, o, a)?,
            actor,
            learner,
            last_model_report: None,
            book: RunBook::start(),
            phases: PhaseTimes::default(),
        };
        mbpo.actor.set_policy(&mbpo.learner.policy());
        Ok(mbpo)
    }

    /// Real env steps taken so far.
    pub fn env_steps(&self) -> u64 {
        self.actor.env_actor().steps
    }

    /// Transitions in the model buffer D_model.
    pub fn model_buffer_len(&self) -> usize {
        self.learner.model_buffer_len()
    }

    /// The SAC agent (policy parameters, update count).
    pub fn sac(&self) -> &Sac {
        self.learner.sac()
    }

    /// The learner role (SAC with D_env and D_model), for diagnostics.
    pub fn learner_mut(&mut self) -> &mut LearnerRole {
        &mut self.learner
    }

    /// The rollout role (the model and the termination rule), for diagnostics.
    pub fn rollout_mut(&mut self) -> &mut RolloutRole {
        &mut self.rollout
    }

    /// One env step with `behaviour`, its transition handed to every role that keeps real data.
    fn act_and_distribute(&mut self, behaviour: Behaviour) -> Result<(), TrainError> {
        let episodes = self.actor.env_actor().episodes;
        let rows = self.actor.act(behaviour)?;
        self.model_trainer.add_real(rows);
        self.rollout.add_real(rows);
        self.learner.add_real(rows);
        self.book.note_episode_end(self.actor.env_actor(), episodes);
        Ok(())
    }

    /// One uniform-random env step into D_env (the warm-up before the loop).
    pub fn warm_up_step(&mut self) -> Result<(), TrainError> {
        self.act_and_distribute(Behaviour::Uniform)?;
        self.learner.finish_step();
        Ok(())
    }

    /// Train p_θ on all of D_env (holdout early stopping; elites) and hand it to the rollouts.
    pub fn train_model(&mut self) -> Result<&TrainReport, TrainError> {
        let (snapshot, report) = self.model_trainer.train()?;
        self.use_model(snapshot, report)
    }

    /// [`Self::train_model`], abandoned (nothing changed) when `stop` says so after an epoch.
    fn train_model_unless(
        &mut self,
        stop: impl FnMut(&EpochProgress) -> bool,
    ) -> Result<Option<&TrainReport>, TrainError> {
        match self.model_trainer.train_watched(stop)? {
            Some((snapshot, report)) => self.use_model(snapshot, report).map(Some),
            None => Ok(None),
        }
    }

    /// Hand a newly trained model to the roles that use it.
    fn use_model(
        &mut self,
        snapshot: ModelSnapshot,
        report: TrainReport,
    ) -> Result<&TrainReport, TrainError> {
        self.phases.add_training(&report);
        self.rollout.set_model(&snapshot)?;
        let mse = report.elite_holdout_mse();
        self.book.models.insert(snapshot.version, mse);
        Ok(self.last_model_report.insert(report))
    }

    /// Set k for `epoch`, resize D_model to keep `retain_epochs` of rollouts, and branch
    /// M · model_train_freq k-step rollouts of the current π from start states drawn uniformly
    /// from D_env.
    pub fn branch_rollouts(&mut self, epoch: usize) -> Result<(), TrainError> {
        self.rollout.set_policy(&self.learner.policy());
        let started = Instant::now();
        // What the branch starts from, so a checkpoint can store it instead of D_model's rows.
        let inputs = self.rollout.inputs_of_branch(epoch);
        let imagined = self.rollout.branch(epoch)?;
        self.learner.add_imagined_from(&imagined, inputs);
        self.phases.rollout_seconds += started.elapsed().as_secs_f64();
        self.phases.imagined += imagined.rows.len as u64;
        Ok(())
    }

    /// One real env step with a ~ π(·|s) into D_env.
    pub fn env_step(&mut self) -> Result<(), TrainError> {
        let started = Instant::now();
        self.actor.set_policy(&self.learner.policy());
        self.act_and_distribute(Behaviour::Policy)?;
        self.phases.act_seconds += started.elapsed().as_secs_f64();
        self.phases.steps += 1;
        Ok(())
    }

    /// G SAC updates on batches of `real_ratio` D_env and the rest D_model.
    pub fn policy_updates(&mut self) -> Result<(), TrainError> {
        let started = Instant::now();
        for _ in 0..self.updates_per_step {
            self.learner.update()?;
        }
        self.learner.finish_step();
        self.phases.sac_seconds += started.elapsed().as_secs_f64();
        self.phases.sac_updates += self.updates_per_step as u64;
        Ok(())
    }

    /// One env step `t` of Algorithm 2 (1-based), warm-up included; `true` when done. When
    /// `stop()` says so during its model training (checked after every epoch), the training is
    /// undone and `false` returned, so the run is exactly as after step t − 1: a stop need not
    /// wait for a training that can take minutes.
    pub fn step_unless(
        &mut self,
        t: u64,
        stop: impl FnMut(&EpochProgress) -> bool,
    ) -> Result<bool, TrainError> {
        if self.schedule.is_warm_up(t) {
            self.warm_up_step()?;
            return Ok(true);
        }
        // A checkpoint of a lockstep pipeline can hold the training of step t already.
        let trained = self.model_trainer.version() >= self.schedule.train_points_upto(t);
        if let Some(epoch) = self.schedule.train_point(t).filter(|_| !trained) {
            let Some(report) = self.train_model_unless(stop)? else {
                return Ok(false);
            };
            // The same line as the pipeline's model trainer, so runs can be compared.
            tracing::info!(
                "model trained for step {t} on {} transitions: {} epochs, elites {:?}, {:.2} s{}",
                report.n_train + report.n_holdout,
                report.epochs,
                report.elites,
                report.seconds,
                report
                    .termination
                    .map(|t| format!("; {t}"))
                    .unwrap_or_default()
            );
            self.branch_rollouts(epoch)?;
        }
        self.env_step()?;
        self.policy_updates()?;
        Ok(true)
    }
}

impl Mbpo {
    /// Encode the checkpoint after env step `t`, to go into `dir`: the files of a one-actor
    /// pipeline ([`crate::run_files`]), so `mbpo run --resume` continues it too. `book` is the
    /// run's (the caller copies the evaluator's part into it). Writing them
    /// ([`CheckpointFiles::write`]) does not need the trainer, so it can run while it trains.
    pub fn encode_checkpoint(
        &self,
        dir: &Path,
        t: u64,
        evaluator: &Evaluator,
        book: &RunBook,
    ) -> Result<CheckpointFiles, CheckpointError> {
        // In the order of `role_files`, as `mbpo run` lists them in `COMPLETE`.
        let mut files = CheckpointFiles::new(dir, t);
        let k = self.model_trainer.version();
        let (role, d_model_branches) = self.learner.checkpoint();
        let learner = LearnerCheckpoint {
            role,
            consumed: t,
            updates: self.sac().updates(),
            model_batches: k,
            model_version: k,
            d_model_branches,
        };
        files.add(file::LEARNER, kind::LEARNER, &learner)?;
        let trainer = ModelTrainerCheckpoint {
            role: self.model_trainer.checkpoint(),
        };
        files.add(file::MODEL_TRAINER, kind::MODEL_TRAINER, &trainer)?;
        let rollout = RolloutCheckpoint {
            role: self.rollout.checkpoint(),
            branches: k,
        };
        files.add(file::ROLLOUT, kind::ROLLOUT, &rollout)?;
        let eval = EvaluatorCheckpoint {
            rng: evaluator.rng().clone(),
            version: t,
            evals: self.schedule.eval_points_upto(t),
            env_steps: t,
        };
        files.add(file::EVALUATOR, kind::EVALUATOR, &eval)?;
        let actor = ActorCheckpoint {
            role: self.actor.checkpoint(),
            steps: t,
        };
        files.add(&actor_file(0), kind::ACTOR, &actor)?;
        files.add(file::RUN_BOOK, kind::RUN_BOOK, book)?;
        Ok(files)
    }

    /// The run `run` (config `cfg`) as it was at its complete checkpoint after `at` env steps,
    /// and its run book, for tools that continue or inspect it (`mbpo bench breakdown`,
    /// `mbpo bench diagnose`). Nothing is written to the run. No such checkpoint is an error
    /// naming the kept ones and how to keep more.
    pub fn from_kept_checkpoint(
        cfg: &ExperimentConfig,
        run: &Path,
        at: u64,
    ) -> Result<(Self, RunBook), TrainError> {
        let dir = checkpoint::dir_for(run, at);
        if !dir.join(checkpoint::COMPLETE).is_file() {
            let kept = checkpoint::complete_steps(run);
            let kept = match kept.is_empty() {
                true => "none".to_string(),
                false => kept
                    .iter()
                    .map(u64::to_string)
                    .collect::<Vec<_>>()
                    .join(", "),
            };
            return Err(TrainError::Config(format!(
                "{}: no complete checkpoint at {at} env steps (kept: {kept}). Run with \
                 `--set checkpoint.keep_every=N` to keep one every N env steps",
                run.display()
            )));
        }
        let mut mbpo = Self::new(cfg)?;
        let (_, book) = mbpo.restore_checkpoint(&dir, at)?;
        Ok((mbpo, book))
    }

    /// Restore every role from the checkpoint directory `dir` (after `t` env steps), written
    /// by this trainer or by a one-actor `mbpo run`; returns the evaluator's stream and the
    /// run book.
    ///
    /// A lockstep pipeline's cut can hold the model training (and rollouts) of step t + 1
    /// already, which [`Mbpo::step_unless`] then does not repeat; a pipelined one stopped
    /// during a training may lack one, which only `mbpo run` can continue.
    pub fn restore_checkpoint(&mut self, dir: &Path, t: u64) -> Result<(Rng, RunBook), TrainError> {
        let read = |name: &str| dir.join(name);
        let actor: ActorCheckpoint = checkpoint::read(&read(&actor_file(0)), kind::ACTOR)?;
        let trainer: ModelTrainerCheckpoint =
            checkpoint::read(&read(file::MODEL_TRAINER), kind::MODEL_TRAINER)?;
        let rollout: RolloutCheckpoint = checkpoint::read(&read(file::ROLLOUT), kind::ROLLOUT)?;
        let learner: LearnerCheckpoint = checkpoint::read(&read(file::LEARNER), kind::LEARNER)?;
        let eval: EvaluatorCheckpoint = checkpoint::read(&read(file::EVALUATOR), kind::EVALUATOR)?;
        let book: RunBook = checkpoint::read(&read(file::RUN_BOOK), kind::RUN_BOOK)?;
        let k = trainer.role.version;
        check_one_actor_cut(
            dir,
            &self.schedule,
            t,
            k,
            &[("actor", actor.steps), ("learner", learner.consumed)],
            &[
                ("rollout branches", rollout.branches),
                ("imagined batches", learner.model_batches),
            ],
        )?;
        self.actor.restore(actor.role)?;
        self.model_trainer.restore(trainer.role)?;
        self.rollout.restore(rollout.role)?;
        let rollout = Some(&mut self.rollout);
        self.learner
            .restore(learner.role, learner.d_model_branches, rollout)?;
        Ok((eval.rng, book))
    }
}

/// The role files of an MBPO checkpoint with one actor (besides the run book), in the order
/// of `mbpo run`'s role list.
pub fn role_files() -> Vec<String> {
    vec![
        file::LEARNER.into(),
        file::MODEL_TRAINER.into(),
        file::ROLLOUT.into(),
        file::EVALUATOR.into(),
        actor_file(0),
    ]
}

/// Run MBPO per `cfg`, writing the run directory `out`; returns the summary.
pub fn train_mbpo(cfg: &ExperimentConfig, out: &Path) -> Result<Summary, TrainError> {
    train_mbpo_with(cfg, out, RunOptions::default())
}

/// [`train_mbpo`] with resume and stop control.
pub fn train_mbpo_with(
    cfg: &ExperimentConfig,
    out: &Path,
    opts: RunOptions,
) -> Result<Summary, TrainError> {
    let mut run = MbpoRun {
        cfg,
        out,
        mbpo: Mbpo::new(cfg)?,
        evaluator: Evaluator::new(cfg)?,
        writer: BackgroundWriter::default(),
        phases_at_last_row: PhaseTimes::default(),
    };
    drive(&mut run, cfg, out, opts)
}

/// MBPO under the shared driver: the roles, the evaluator, and the checkpoint writer.
struct MbpoRun<'a> {
    cfg: &'a ExperimentConfig,
    out: &'a Path,
    mbpo: Mbpo,
    evaluator: Evaluator,
    /// Checkpoints are written on the writer's thread while the run goes on
    /// (crate::checkpoint_writer); pruning follows each one there.
    writer: BackgroundWriter,
    phases_at_last_row: PhaseTimes,
}

impl SequentialRun for MbpoRun<'_> {
    fn restore(&mut self, dir: &Path, t: u64) -> Result<(), TrainError> {
        let (rng, book) = self.mbpo.restore_checkpoint(dir, t)?;
        self.evaluator.restore_book(rng, &book);
        self.mbpo.book = book;
        Ok(())
    }

    fn begin(&mut self) {
        self.phases_at_last_row = self.mbpo.phases;
    }

    fn step(
        &mut self,
        t: u64,
        stop: &mut dyn FnMut(&EpochProgress) -> bool,
    ) -> Result<bool, TrainError> {
        let started = Instant::now();
        let stepped = match self.mbpo.step_unless(t, stop) {
            // Step t failed at its env step before anything else of it happened (no model
            // training at t): steps 1..t-1 are whole, keep them.
            Err(TrainError::Env(error)) if self.mbpo.schedule.train_point(t).is_none() => {
                let kept = match t - 1 {
                    0 => "nothing was kept (it failed at the first step)".to_string(),
                    done => {
                        self.save(done, true)?;
                        format!("the run stopped with a checkpoint after step {done}")
                    }
                };
                return Err(TrainError::EnvFailed {
                    step: t,
                    kept,
                    error,
                });
            }
            other => other?,
        };
        if stepped && !self.mbpo.schedule.is_warm_up(t) {
            let seconds = started.elapsed().as_secs_f64();
            self.mbpo.book.step_seconds.push(seconds);
        }
        Ok(stepped)
    }

    fn evaluate(&mut self, t: u64) -> Result<MetricsRow, TrainError> {
        let row = metrics_row(&self.mbpo, &mut self.evaluator, t)?;
        self.mbpo.book.next_row += 1;
        self.evaluator.log(self.cfg.algo.name(), &row);
        let phases = self.mbpo.phases.since(&self.phases_at_last_row);
        if phases.steps > 0 {
            tracing::info!("{}", phases.per_step_line());
        }
        self.phases_at_last_row = self.mbpo.phases;
        Ok(row)
    }

    fn progress(&self) -> (u64, Option<u64>) {
        let version = self.mbpo.model_trainer.version();
        (self.mbpo.sac().updates(), (version > 0).then_some(version))
    }

    fn save(&mut self, t: u64, wait: bool) -> Result<(), TrainError> {
        let mut book = self.mbpo.book.clone();
        self.evaluator.write_book(&mut book);
        book.progress = (
            t,
            self.mbpo.sac().updates(),
            self.mbpo.model_trainer.version(),
        );
        let dir = checkpoint::dir_for(self.out, t);
        let files = self
            .mbpo
            .encode_checkpoint(&dir, t, &self.evaluator, &book)?;
        let (run, keep) = (self.out.to_path_buf(), &self.cfg.checkpoint);
        let (keep, keep_every) = (keep.keep, keep.keep_every);
        self.writer
            .submit(files, move || checkpoint::prune(&run, keep, keep_every))?;
        if wait {
            self.writer.wait()?;
        }
        Ok(())
    }

    fn finish(&mut self, status: &str, run: &mut RunDir) -> Result<Summary, TrainError> {
        let mbpo = &self.mbpo;
        let median = mbpo_core::stats::median(&mut mbpo.book.step_seconds.clone());
        let target = self.cfg.target_return();
        let target = (target, run.env_steps_to_target(target)?);
        let sac = mbpo.learner.sac();
        let mut summary = self
            .evaluator
            .summary(self.cfg.algo.name(), sac, median, target);
        summary.env_steps = mbpo.env_steps();
        summary.status = status.into();
        summary.episodes_cut_by_resume = mbpo.actor.env_actor().episodes_cut;
        summary.episodes_lost_to_env_exit = mbpo.actor.env_actor().episodes_lost;
        if status == "completed" {
            let actor = &sac.actor_params;
            crate::policy_file::write_final_policy(self.out, summary.env_steps, actor)?;
        }
        Ok(summary)
    }
}

/// The metrics row of eval point `t`: evaluation, SAC statistics and the model's (that of the
/// newest training, as the pipeline's rows show the learner's newest imagined batch's).
fn metrics_row(mbpo: &Mbpo, evaluator: &mut Evaluator, t: u64) -> Result<MetricsRow, EnvError> {
    let learner = &mbpo.learner;
    let mut row = evaluator.evaluate(
        t,
        learner.sac(),
        &learner.last_stats,
        mbpo.actor.env_actor(),
    )?;
    let version = mbpo.model_trainer.version();
    if let Some(&mse) = mbpo.book.models.get(&version).filter(|_| version > 0) {
        row.model_holdout_mse = Some(mse);
        row.rollout_length = Some(learner.rollout_length as f64);
        row.model_buffer = Some(learner.model_buffer_len() as f64);
    }
    Ok(row)
}
