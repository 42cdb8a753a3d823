//! Model predictive control on the learned model (PETS-style model-based RL, Chua et al. 2018),
//! in one process: the sequential reference of the planning pipeline.
//!
//! ```text
//! D_env ← init_random_steps uniform-random transitions                          warm-up
//! for each env step t:
//!     every model_train_freq steps: train p_θ on all of D_env; hand it to the planners
//!     plan on p_θ from the real observation, execute the first action            act
//!     add the transition to D_env (data aggregation: the model learns where the planner goes)
//! ```
//!
//! The roles are those of the pipeline ([`crate::mpc_roles`]): [`PlanningActorRole`] is what a
//! planning actor process runs, `ModelTrainerRole` (shared with MBPO) what the model trainer
//! runs, and [`PlanningEvaluator`] what the evaluation actor runs. Random draws come from the
//! same named streams in both: `actor.env` / `actor.policy` (planning noise) of the actor,
//! `model.*` of the trainer, `eval.env` / `eval.plan` of the evaluator.

use crate::actor::Behaviour;
use crate::checkpoint::{self, CheckpointError};
use crate::config::ExperimentConfig;
use crate::driver::{drive, SequentialRun};
use crate::error::TrainError;
use crate::mpc_roles::{PlanningActorRole, PlanningEvaluator};
use crate::roles::{ModelSnapshot, ModelTrainerRole, Schedule};
use crate::run_control::RunOptions;
use crate::run_dir::{MetricsRow, RunDir, Summary};
use crate::run_files::{
    actor_file, check_one_actor_cut, file, kind, ModelTrainerCheckpoint, PlanningActorCheckpoint,
    PlanningEvaluatorCheckpoint, RunBook,
};
use mbpo_model::EpochProgress;
use mbpo_model::TrainReport;
use std::path::Path;
use std::time::Instant;

/// Every role of one MPC run in one process.
pub struct MpcRun {
    schedule: Schedule,
    actor: PlanningActorRole,
    model_trainer: ModelTrainerRole,
    evaluator: PlanningEvaluator,
    /// Report of the last model training.
    pub last_model_report: Option<TrainReport>,
    /// Parameters of the newest model (the "policy" of MPC is planner + model).
    pub model_params: Vec<f32>,
}

impl MpcRun {
    /// Build every role from `cfg`; no model is trained yet.
    pub fn new(cfg: &ExperimentConfig) -> Result<Self, TrainError> {
        let actor = PlanningActorRole::new(cfg, 0)?;
        let (o, a) = (actor.env_actor().obs_dim(), actor.env_actor().act_dim());
        Ok(Self {
            schedule: Schedule::of(cfg),
            model_trainer: ModelTrainerRole::new(cfg, o, a)?,
            evaluator: PlanningEvaluator::new(cfg)?,
            actor,
            last_model_report: None,
            model_params: Vec::new(),
        })
    }

    /// The planning actor.
    pub fn actor(&self) -> &PlanningActorRole {
        &self.actor
    }

    /// Train p_θ on all of D_env and hand the new model to the actor and the evaluator.
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
        self.actor.set_model(&snapshot)?;
        self.evaluator.set_model(&snapshot)?;
        self.model_params = snapshot.weights.params;
        Ok(self.last_model_report.insert(report))
    }

    /// One env step `t` (1-based): warm-up, or (re)train at a train point and act by planning;
    /// `true` when done. When `stop()` says so during its model training (checked after every
    /// epoch), the training is undone and `false` returned, so the run is exactly as after
    /// step t − 1.
    pub fn step_unless(
        &mut self,
        t: u64,
        stop: impl FnMut(&EpochProgress) -> bool,
    ) -> Result<bool, TrainError> {
        let behaviour = if self.schedule.is_warm_up(t) {
            Behaviour::Uniform
        } else {
            // A checkpoint of a lockstep pipeline can hold the training of step t already.
            let trained = self.model_trainer.version() >= self.schedule.train_points_upto(t);
            if self.schedule.train_point(t).is_some() && !trained {
                let Some(r) = self.train_model_unless(stop)? else {
                    return Ok(false);
                };
                tracing::debug!(
                    "model trained before step {t}: {} epochs, elites {:?}",
                    r.epochs,
                    r.elites
                );
            }
            Behaviour::Policy
        };
        let rows = self.actor.act(behaviour)?;
        self.model_trainer.add_real(rows);
        Ok(true)
    }

    /// Evaluation episodes with the current model.
    pub fn evaluate(&mut self, episodes: usize) -> Result<f64, TrainError> {
        self.evaluator.evaluate(episodes)
    }
}

impl MpcRun {
    /// Write the checkpoint after env step `t` into `dir`: the files of a one-actor MPC
    /// pipeline ([`crate::run_files`]), so `mbpo run --resume` continues it too.
    fn write_checkpoint(&self, dir: &Path, t: u64, book: &RunBook) -> Result<(), CheckpointError> {
        std::fs::create_dir_all(dir).map_err(|source| CheckpointError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let actor = PlanningActorCheckpoint {
            role: self.actor.checkpoint(),
            steps: t,
        };
        checkpoint::write(&dir.join(actor_file(0)), kind::PLANNING_ACTOR, &actor)?;
        let trainer = ModelTrainerCheckpoint {
            role: self.model_trainer.checkpoint(),
        };
        checkpoint::write(
            &dir.join(file::MODEL_TRAINER),
            kind::MODEL_TRAINER,
            &trainer,
        )?;
        let evaluator = PlanningEvaluatorCheckpoint {
            role: self.evaluator.checkpoint(),
            evals: self.schedule.eval_points_upto(t),
            env_steps: t,
        };
        checkpoint::write(
            &dir.join(file::EVALUATOR),
            kind::PLANNING_EVALUATOR,
            &evaluator,
        )?;
        checkpoint::write(&dir.join(file::RUN_BOOK), kind::RUN_BOOK, book)?;
        let files = [
            file::MODEL_TRAINER.to_string(),
            file::EVALUATOR.into(),
            actor_file(0),
            file::RUN_BOOK.into(),
        ];
        let names: Vec<&str> = files.iter().map(String::as_str).collect();
        checkpoint::mark_complete(dir, t, &names)
    }

    /// Restore every role from the checkpoint directory `dir` (after `t` env steps), written
    /// by this trainer or by a one-actor `mbpo run`; returns the run's book. The actor and the
    /// evaluator get the trainer's current model, the one they had. (A lockstep pipeline's cut
    /// can hold the model training of step t + 1 already, which [`MpcRun::step_unless`] then
    /// does not repeat.)
    fn restore_checkpoint(&mut self, dir: &Path, t: u64) -> Result<RunBook, TrainError> {
        let trainer: ModelTrainerCheckpoint =
            checkpoint::read(&dir.join(file::MODEL_TRAINER), kind::MODEL_TRAINER)?;
        let actor: PlanningActorCheckpoint =
            checkpoint::read(&dir.join(actor_file(0)), kind::PLANNING_ACTOR)?;
        let evaluator: PlanningEvaluatorCheckpoint =
            checkpoint::read(&dir.join(file::EVALUATOR), kind::PLANNING_EVALUATOR)?;
        let book: RunBook = checkpoint::read(&dir.join(file::RUN_BOOK), kind::RUN_BOOK)?;
        let k = trainer.role.version;
        check_one_actor_cut(dir, &self.schedule, t, k, &[("actor", actor.steps)], &[])?;
        self.model_trainer.restore(trainer.role)?;
        self.actor.restore(actor.role)?;
        self.evaluator.restore(evaluator.role);
        if self.model_trainer.version() > 0 {
            let snapshot = self.model_trainer.snapshot();
            self.actor.set_model(&snapshot)?;
            self.evaluator.set_model(&snapshot)?;
            self.model_params = snapshot.weights.params;
        }
        Ok(book)
    }
}

/// Run MPC per `cfg`, writing the run directory `out`; returns the summary.
pub fn train_mpc(cfg: &ExperimentConfig, out: &Path) -> Result<Summary, TrainError> {
    train_mpc_with(cfg, out, RunOptions::default())
}

/// [`train_mpc`] with resume and stop control, as [`crate::train_mbpo_with`]: checkpoints every
/// `checkpoint.every` env steps, at the end and when stopped; a resumed run plans exactly as
/// an uninterrupted one (the controller's warm start is in the checkpoint).
///
/// `metrics.csv` has the usual columns (SAC's empty); `summary.json`'s `policy_sha256` is the
/// SHA-256 of the final model's parameters and `median_seconds_per_env_step` the median wall
/// time of a planning step.
pub fn train_mpc_with(
    cfg: &ExperimentConfig,
    out: &Path,
    opts: RunOptions,
) -> Result<Summary, TrainError> {
    let mut run = MpcDriven {
        cfg,
        out,
        mpc: MpcRun::new(cfg)?,
        book: RunBook::start(),
        started: Instant::now(),
    };
    drive(&mut run, cfg, out, opts)
}

/// MPC under the shared driver: the roles, the run's book and its clock.
struct MpcDriven<'a> {
    cfg: &'a ExperimentConfig,
    out: &'a Path,
    mpc: MpcRun,
    book: RunBook,
    started: Instant,
}

impl SequentialRun for MpcDriven<'_> {
    const COUNTING: Option<&'static str> = Some("plans");

    fn restore(&mut self, dir: &Path, t: u64) -> Result<(), TrainError> {
        self.book = self.mpc.restore_checkpoint(dir, t)?;
        Ok(())
    }

    /// The clock continues from the checkpoint's.
    fn begin(&mut self) {
        self.started = self.book.clock();
    }

    fn step(
        &mut self,
        t: u64,
        stop: &mut dyn FnMut(&EpochProgress) -> bool,
    ) -> Result<bool, TrainError> {
        let mpc = &mut self.mpc;
        let (version, episodes) = (mpc.model_trainer.version(), mpc.actor.env_actor().episodes);
        if !mpc.step_unless(t, stop)? {
            return Ok(false);
        }
        record_step(mpc, &mut self.book, version, episodes);
        if !mpc.schedule.is_warm_up(t) {
            self.book.step_seconds.push(mpc.actor.last_plan_seconds);
        }
        Ok(true)
    }

    fn evaluate(&mut self, t: u64) -> Result<MetricsRow, TrainError> {
        // (Not while warming up: there is no model to plan with.)
        let episodes = self.cfg.eval.episodes;
        let row = evaluate_at(&mut self.mpc, &mut self.book, t, self.started, episodes)?;
        tracing::info!(
            "mpc {} seed {}: step {t} eval {:.1} best {:.1} train episode {:.1} model v{} ({:.2} steps/s)",
            self.cfg.env,
            self.cfg.seed,
            row.eval_return,
            self.book.best_return,
            row.train_return.unwrap_or(f64::NAN),
            self.mpc.actor.model_version(),
            row.env_steps_per_sec
        );
        Ok(row)
    }

    fn progress(&self) -> (u64, Option<u64>) {
        (self.mpc.actor.plans(), Some(self.mpc.actor.model_version()))
    }

    fn save(&mut self, t: u64, _wait: bool) -> Result<(), TrainError> {
        self.book.elapsed_seconds = self.started.elapsed().as_secs_f64();
        self.book.progress = (t, 0, self.mpc.model_trainer.version());
        let dir = checkpoint::dir_for(self.out, t);
        self.mpc.write_checkpoint(&dir, t, &self.book)?;
        let keep = &self.cfg.checkpoint;
        Ok(checkpoint::prune(self.out, keep.keep, keep.keep_every)?)
    }

    fn finish(&mut self, status: &str, run: &mut RunDir) -> Result<Summary, TrainError> {
        let actor = self.mpc.actor.env_actor();
        let model = (0, &self.mpc.model_params[..]);
        self.book
            .one_actor_summary(self.cfg, actor, model, self.started, status, run)
    }
}

/// Keep what step t added in the run's book: its model's holdout MSE (when it trained one
/// since `version`) and the episode it ended (when the actor had `episodes` before).
fn record_step(mpc: &MpcRun, book: &mut RunBook, version: u64, episodes: u64) {
    let v = mpc.model_trainer.version();
    if let Some(r) = mpc.last_model_report.as_ref().filter(|_| v > version) {
        book.models.insert(v, r.elite_holdout_mse());
    }
    book.note_episode_end(mpc.actor.env_actor(), episodes);
}

/// Evaluate the planner on the current model at env step `t` and build the metrics row.
fn evaluate_at(
    mpc: &mut MpcRun,
    book: &mut RunBook,
    t: u64,
    started: Instant,
    episodes: usize,
) -> Result<MetricsRow, TrainError> {
    let ret = mpc.evaluate(episodes)?;
    let now = started.elapsed().as_secs_f64();
    let (last_time, last_steps) = book.last_row;
    let actor = mpc.actor.env_actor();
    let version = mpc.model_trainer.version();
    let row = MetricsRow {
        env_steps: t,
        episodes: actor.episodes,
        eval_return: ret,
        train_return: actor.last_return,
        model_holdout_mse: book.models.get(&version).copied().filter(|_| version > 0),
        wall_seconds: now,
        env_steps_per_sec: (t - last_steps) as f64 / (now - last_time).max(1e-9),
        ..Default::default()
    };
    book.wrote_row(t, ret, now, 0);
    Ok(row)
}
