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
//! The roles are those of the pipeline: [`PlanningActorRole`] is what a planning actor process
//! runs, `ModelTrainerRole` (shared with MBPO) what the model trainer runs, and
//! [`PlanningEvaluator`] what the evaluation actor runs. Random draws come from the same named
//! streams in both: `actor.env` / `actor.policy` (planning noise) of the actor, `model.*` of
//! the trainer, `eval.env` / `eval.plan` of the evaluator.

use crate::actor::{Behaviour, EnvActor, EnvActorState};
use crate::checkpoint::{self, CheckpointError};
use crate::config::{ExperimentConfig, PlanReward};
use crate::progress::{Display, Progress};
use crate::roles::{ModelSnapshot, ModelTrainerRole, Schedule};
use crate::run_control::{checkpoint_due, log_stopped, open_run, stop_before, RunOptions};
use crate::run_dir::{policy_sha256, MetricsRow, Summary};
use crate::run_files::{
    actor_file, check_one_actor_cut, file, kind, ModelTrainerCheckpoint, PlanningActorCheckpoint,
    PlanningEvaluatorCheckpoint, RunBook,
};
use crate::sac_trainer::TrainError;
use mbpo_core::rng::stream;
use mbpo_core::{Batch, BatchPolicy, LastTransition, Rng, TransitionSink};
use mbpo_envs::Env;
use mbpo_model::{ProbabilisticEnsemble, TrainReport};
use mbpo_plan::{build, EnsembleModel, Mpc, MpcState, PlanError, RewardSource};
use mbpo_sac::ActionScale;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::{Duration, Instant};

fn plan_err(e: PlanError) -> TrainError {
    TrainError::Config(format!("planning: {e}"))
}

/// A planning model of `cfg`'s architecture (weights arrive as snapshots) with the configured
/// reward source, the task's termination rule and action box.
pub fn planning_model(cfg: &ExperimentConfig, env: &dyn Env) -> Result<EnsembleModel, TrainError> {
    let (o, a) = (env.obs_dim(), env.act_dim());
    let ensemble = ProbabilisticEnsemble::new(
        o,
        a,
        cfg.model_config(),
        &mut stream(cfg.seed, "plan.model-shape", 0),
    )
    .map_err(|e| TrainError::Config(e.to_string()))?;
    let reward = match cfg.mpc.reward {
        PlanReward::Model => RewardSource::Model,
        PlanReward::Known => {
            RewardSource::Known(mbpo_envs::reward_fn(&cfg.env).ok_or_else(|| {
                TrainError::Config(format!("no known reward function for {}", cfg.env))
            })?)
        }
    };
    let space = env.action_space();
    EnsembleModel::new(
        ensemble,
        reward,
        Some(cfg.rollout_termination(o, a)?),
        &space.low,
        &space.high,
    )
    .map_err(plan_err)
}

/// The configured planner run as a controller (closed or open loop).
pub fn controller(cfg: &ExperimentConfig, act_dim: usize) -> Result<Mpc, TrainError> {
    let planner = build(&cfg.mpc.planner, act_dim).map_err(plan_err)?;
    Ok(Mpc::new(planner, cfg.mpc.open_loop))
}

/// MPC seen as a one-observation [`BatchPolicy`], so the shared [`EnvActor`] can act with it
/// (same streams, same transition bookkeeping as the SAC actors). A planning error is kept and
/// reported after the step.
struct MpcPolicy<'a> {
    mpc: &'a mut Mpc,
    model: &'a mut EnsembleModel,
    error: Option<PlanError>,
    seconds: f64,
}

impl BatchPolicy for MpcPolicy<'_> {
    fn act_batch(&mut self, obs: &[f32], batch: usize, actions: &mut [f32], rng: &mut Rng) {
        debug_assert_eq!(batch, 1, "MPC plans for one observation at a time");
        let start = Instant::now();
        if let Err(e) = self.mpc.act(self.model, obs, rng, actions) {
            self.error = Some(e);
            actions.fill(0.0);
        }
        self.seconds = start.elapsed().as_secs_f64();
    }
}

/// The ensemble a planner plans with, and the version of the weights it holds.
struct VersionedModel {
    model: EnsembleModel,
    version: u64,
}

impl VersionedModel {
    fn new(cfg: &ExperimentConfig, env: &dyn Env) -> Result<Self, TrainError> {
        Ok(Self {
            model: planning_model(cfg, env)?,
            version: 0,
        })
    }
    /// Take a newer model.
    fn set(&mut self, snapshot: &ModelSnapshot) -> Result<(), TrainError> {
        self.model
            .ensemble_mut()
            .load_weights(&snapshot.weights)
            .map_err(|e| TrainError::Config(e.to_string()))?;
        self.version = snapshot.version;
        Ok(())
    }
    fn load<E: std::fmt::Display>(
        &mut self,
        version: u64,
        load: impl FnOnce(&mut ProbabilisticEnsemble) -> Result<(), E>,
    ) -> Result<(), TrainError> {
        load(self.model.ensemble_mut()).map_err(|e| TrainError::Config(e.to_string()))?;
        self.version = version;
        Ok(())
    }
}

/// A checkpointed [`PlanningActorRole`] (its model is the model trainer's current one).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanningActorState {
    /// The env actor (episode in progress, `actor.env` / `actor.policy` streams, counters).
    pub actor: EnvActorState,
    /// The controller's warm start and open-loop plan.
    pub mpc: MpcState,
}

/// Acting in the real environment with MPC on the newest model it was given.
pub struct PlanningActorRole {
    actor: EnvActor,
    mpc: Mpc,
    model: VersionedModel,
    staged: LastTransition,
    /// Wall seconds of the last plan (0 for a warm-up step).
    pub last_plan_seconds: f64,
}

impl PlanningActorRole {
    /// Planning actor `index` of the run (streams `actor.env` / `actor.policy`, index `index`).
    pub fn new(cfg: &ExperimentConfig, index: u64) -> Result<Self, TrainError> {
        let actor = EnvActor::new(cfg.make_env()?, cfg.seed, index)?;
        let env = cfg.make_env()?;
        Ok(Self {
            model: VersionedModel::new(cfg, env.as_ref())?,
            mpc: controller(cfg, env.act_dim())?,
            staged: LastTransition::new(env.obs_dim(), env.act_dim()),
            actor,
            last_plan_seconds: 0.0,
        })
    }
    /// Take a newer model.
    pub fn set_model(&mut self, snapshot: &ModelSnapshot) -> Result<(), TrainError> {
        self.model.set(snapshot)
    }
    /// Take model `version`, loaded in place by `load` (a receiver's one copy out of shared
    /// memory; `load` checks the snapshot before it writes anything).
    pub fn load_model<E: std::fmt::Display>(
        &mut self,
        version: u64,
        load: impl FnOnce(&mut ProbabilisticEnsemble) -> Result<(), E>,
    ) -> Result<(), TrainError> {
        self.model.load(version, load)
    }
    /// Version of the model planned with (0: none yet).
    pub fn model_version(&self) -> u64 {
        self.model.version
    }
    /// The env actor (episode counters).
    pub fn env_actor(&self) -> &EnvActor {
        &self.actor
    }
    /// Plans made so far.
    pub fn plans(&self) -> u64 {
        self.mpc.plans()
    }
    /// The role's state (for checkpoints; the model is not in it).
    pub fn checkpoint(&self) -> PlanningActorState {
        PlanningActorState {
            actor: self.actor.checkpoint(),
            mpc: self.mpc.state(),
        }
    }
    /// Continue from [`PlanningActorRole::checkpoint`] (then give it the model with
    /// [`PlanningActorRole::set_model`]).
    pub fn restore(&mut self, s: PlanningActorState) -> Result<(), TrainError> {
        self.actor.restore(s.actor)?;
        self.mpc.restore(s.mpc).map_err(plan_err)
    }
    /// One real env step (uniform, or the planner's action); returns the transition. The
    /// planner's warm start is dropped at every episode end.
    pub fn act(&mut self, behaviour: Behaviour) -> Result<&Batch, TrainError> {
        let (actor, mpc, model) = (&mut self.actor, &mut self.mpc, &mut self.model);
        self.last_plan_seconds = plan_step(actor, mpc, model, behaviour, &mut self.staged)?;
        Ok(self.staged.batch())
    }
    /// One real env step whose transition goes straight into `sink` (a pipeline actor's
    /// loaned shared-memory sample). On an error `sink` may hold a partial row: drop it.
    pub fn act_into(
        &mut self,
        behaviour: Behaviour,
        sink: &mut dyn TransitionSink,
    ) -> Result<(), TrainError> {
        let (actor, mpc, model) = (&mut self.actor, &mut self.mpc, &mut self.model);
        self.last_plan_seconds = plan_step(actor, mpc, model, behaviour, sink)?;
        Ok(())
    }
}

/// One env step of a planning actor into `sink`; returns the plan's wall seconds (0 for a
/// warm-up step). A new episode starts with a reset planner.
fn plan_step(
    actor: &mut EnvActor,
    mpc: &mut Mpc,
    model: &mut VersionedModel,
    behaviour: Behaviour,
    sink: &mut dyn TransitionSink,
) -> Result<f64, TrainError> {
    let episodes = actor.episodes;
    let mut policy = MpcPolicy {
        mpc,
        model: &mut model.model,
        error: None,
        seconds: 0.0,
    };
    actor.step(behaviour, &mut policy, sink)?;
    let seconds = policy.seconds;
    if let Some(e) = policy.error {
        return Err(plan_err(e));
    }
    if actor.episodes > episodes {
        mpc.reset();
    }
    Ok(seconds)
}

/// A checkpointed [`PlanningEvaluator`]: its streams (each evaluation episode starts with a
/// reset planner, and the model is the trainer's).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PlanningEvaluatorState {
    /// The `eval.env` stream.
    pub env_rng: Rng,
    /// The `eval.plan` stream.
    pub plan_rng: Rng,
}

/// Evaluation episodes with the planner: own environment (`eval.env`), own planning noise
/// (`eval.plan`), own copy of the model.
pub struct PlanningEvaluator {
    env: Box<dyn Env>,
    scale: ActionScale,
    env_rng: Rng,
    plan_rng: Rng,
    mpc: Mpc,
    model: VersionedModel,
}

impl PlanningEvaluator {
    /// The evaluator of the run.
    pub fn new(cfg: &ExperimentConfig) -> Result<Self, TrainError> {
        let env = cfg.make_env()?;
        Ok(Self {
            scale: ActionScale::new(&env.action_space().low, &env.action_space().high),
            model: VersionedModel::new(cfg, env.as_ref())?,
            mpc: controller(cfg, env.act_dim())?,
            env,
            env_rng: stream(cfg.seed, "eval.env", 0),
            plan_rng: stream(cfg.seed, "eval.plan", 0),
        })
    }
    /// Take a newer model.
    pub fn set_model(&mut self, snapshot: &ModelSnapshot) -> Result<(), TrainError> {
        self.model.set(snapshot)
    }
    /// Take model `version`, loaded in place by `load` (a receiver's one copy out of shared
    /// memory; `load` checks the snapshot before it writes anything).
    pub fn load_model<E: std::fmt::Display>(
        &mut self,
        version: u64,
        load: impl FnOnce(&mut ProbabilisticEnsemble) -> Result<(), E>,
    ) -> Result<(), TrainError> {
        self.model.load(version, load)
    }
    /// Version of the model evaluated.
    pub fn model_version(&self) -> u64 {
        self.model.version
    }
    /// The evaluator's state (for checkpoints).
    pub fn checkpoint(&self) -> PlanningEvaluatorState {
        PlanningEvaluatorState {
            env_rng: self.env_rng.clone(),
            plan_rng: self.plan_rng.clone(),
        }
    }
    /// Continue from [`PlanningEvaluator::checkpoint`].
    pub fn restore(&mut self, s: PlanningEvaluatorState) {
        self.env_rng = s.env_rng;
        self.plan_rng = s.plan_rng;
    }
    /// Mean undiscounted return of `episodes` MPC episodes (the warm start reset per episode).
    pub fn evaluate(&mut self, episodes: usize) -> Result<f64, TrainError> {
        let ret = self.evaluate_unless(episodes, || false)?;
        Ok(ret.expect("an evaluation nobody abandons completes"))
    }

    /// [`PlanningEvaluator::evaluate`], abandoned (`Ok(None)`) as soon as `abandon()` says so;
    /// it is asked before every planning step (an MPC evaluation can take minutes, a checkpoint
    /// barrier should not wait for one it will discard). An abandoned evaluation has moved the
    /// streams on: [`PlanningEvaluator::restore`] the state from before it to evaluate again.
    pub fn evaluate_unless(
        &mut self,
        episodes: usize,
        mut abandon: impl FnMut() -> bool,
    ) -> Result<Option<f64>, TrainError> {
        let (o, a) = (self.env.obs_dim(), self.env.act_dim());
        let (mut obs, mut action, mut env_action) =
            (vec![0.0f32; o], vec![0.0f32; a], vec![0.0f32; a]);
        let mut total = 0.0;
        for _ in 0..episodes {
            self.env.reset(&mut self.env_rng, &mut obs)?;
            self.mpc.reset();
            loop {
                if abandon() {
                    return Ok(None);
                }
                self.mpc
                    .act(&mut self.model.model, &obs, &mut self.plan_rng, &mut action)
                    .map_err(plan_err)?;
                self.scale.to_env(&action, &mut env_action);
                let step = self.env.step(&env_action, &mut obs)?;
                total += step.reward;
                if step.terminated || step.truncated {
                    break;
                }
            }
        }
        Ok(Some(total / episodes.max(1) as f64))
    }
}

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

    /// [`Self::train_model`], abandoned (nothing changed) when `stop()` says so.
    fn train_model_unless(
        &mut self,
        stop: impl FnMut() -> bool,
    ) -> Result<Option<&TrainReport>, TrainError> {
        match self.model_trainer.train_unless(stop)? {
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
    pub fn step_unless(&mut self, t: u64, stop: impl FnMut() -> bool) -> Result<bool, TrainError> {
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
    let mut mpc = MpcRun::new(cfg)?;
    let mut book = RunBook::start();
    let (mut run, done) = open_run(cfg, out, opts, |dir, t| {
        book = mpc.restore_checkpoint(dir, t)?;
        Ok(())
    })?;
    // The clock continues from the checkpoint's.
    let started = Instant::now()
        .checked_sub(Duration::from_secs_f64(book.elapsed_seconds.max(0.0)))
        .unwrap_or_else(Instant::now);
    let save = |mpc: &MpcRun, book: &mut RunBook, t: u64| -> Result<(), TrainError> {
        book.elapsed_seconds = started.elapsed().as_secs_f64();
        book.progress = (t, 0, mpc.model_trainer.version());
        mpc.write_checkpoint(&checkpoint::dir_for(out, t), t, book)?;
        Ok(checkpoint::prune(
            out,
            cfg.checkpoint.keep,
            cfg.checkpoint.keep_every,
        )?)
    };
    let mut status = "completed";
    let label = format!("mpc {} s{}", cfg.env, cfg.seed);
    let mut progress = Progress::new(label, cfg.steps, Display::auto()).counting("plans");
    for t in done + 1..=cfg.steps {
        let (version, episodes) = (mpc.model_trainer.version(), mpc.actor.env_actor().episodes);
        if !mpc.step_unless(t, || opts.stopping_at(t, cfg.steps))? {
            // Stopped during the model training of step t, which was undone.
            stop_before(t, |at| save(&mpc, &mut book, at), out)?;
            status = "stopped";
            break;
        }
        record_step(&mpc, &mut book, version, episodes);
        if !mpc.schedule.is_warm_up(t) {
            book.step_seconds.push(mpc.actor.last_plan_seconds);
        }
        if mpc.schedule.is_eval_point(t) {
            // (Not while warming up: there is no model to plan with.)
            let row = evaluate_at(&mut mpc, &mut book, t, started, cfg.eval.episodes)?;
            run.write_metrics(&row)?;
            progress.set_eval(row.eval_return);
            tracing::info!(
                "mpc {} seed {}: step {t} eval {:.1} best {:.1} train episode {:.1} model v{} ({:.2} steps/s)",
                cfg.env,
                cfg.seed,
                row.eval_return,
                book.best_return,
                row.train_return.unwrap_or(f64::NAN),
                mpc.actor.model_version(),
                row.env_steps_per_sec
            );
        }
        progress.set_model_version(mpc.actor.model_version());
        progress.update(t, mpc.actor.plans());
        let stopping = opts.stopping_at(t, cfg.steps);
        if checkpoint_due(cfg, t, stopping) {
            save(&mpc, &mut book, t)?;
        }
        if stopping {
            log_stopped(t, out);
            status = "stopped";
            break;
        }
    }
    progress.finish();
    let target_return = cfg.target_return();
    let summary = Summary {
        algo: "mpc".into(),
        env: cfg.env.clone(),
        seed: cfg.seed,
        env_steps: mpc.actor.env_actor().steps,
        sac_updates: 0,
        final_eval_return: book.final_return,
        best_eval_return: book.best_return,
        target_return,
        env_steps_to_target: run.env_steps_to_target(target_return)?,
        policy_sha256: policy_sha256(&mpc.model_params),
        wall_seconds: started.elapsed().as_secs_f64(),
        median_seconds_per_env_step: mbpo_core::stats::median(&mut book.step_seconds.clone()),
        status: status.into(),
        episodes_cut_by_resume: mpc.actor.env_actor().episodes_cut,
        episodes_lost_to_env_exit: mpc.actor.env_actor().episodes_lost,
    };
    run.write_summary(&summary)?;
    Ok(summary)
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
