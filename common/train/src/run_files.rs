//! The files of a checkpoint directory, one format for `mbpo train` and `mbpo run`.
//!
//! A checkpoint after env step T holds one file per role -- its state ([`crate::roles`]) and
//! the counters its service loop resumes from -- and the run's [`RunBook`] (metrics rows,
//! returns, clock). The sequential trainer writes exactly the files of a one-actor pipeline,
//! so a run checkpointed by `mbpo train` resumes under `mbpo run` and the other way round
//! (`tests/tests/pipeline_resume.rs`, `*_checkpoints_cross_*`). `mbpo run` adds the launcher's
//! own file (`supervisor`: mode, actors, slack); `mbpo train` refuses a checkpoint of more than
//! one actor.

use std::collections::BTreeMap;

use mbpo_core::Rng;
use serde::{Deserialize, Serialize};

use crate::mpc::{PlanningActorState, PlanningEvaluatorState};
use crate::roles::{ActorState, LearnerState, ModelTrainerState, RolloutState};

/// File names in a checkpoint directory (actors: [`actor_file`]).
pub mod file {
    /// The learner's ([`super::LearnerCheckpoint`]).
    pub const LEARNER: &str = "learner";
    /// The model trainer's ([`super::ModelTrainerCheckpoint`]).
    pub const MODEL_TRAINER: &str = "model-trainer";
    /// The rollout generator's ([`super::RolloutCheckpoint`]).
    pub const ROLLOUT: &str = "rollout-generator";
    /// The evaluator's ([`super::EvaluatorCheckpoint`], MPC: [`super::PlanningEvaluatorCheckpoint`]).
    pub const EVALUATOR: &str = "evaluator";
    /// The run's book ([`super::RunBook`]).
    pub const RUN_BOOK: &str = "run-book";
    /// The launcher's (`mbpo run` only: mode, actors, slack).
    pub const SUPERVISOR: &str = "supervisor";
}

/// The file name of actor `index`'s checkpoint.
pub fn actor_file(index: u16) -> String {
    format!("actor-{index}")
}

/// Kinds of the files (the `kind` field of a checkpoint file's header).
pub mod kind {
    /// [`super::ActorCheckpoint`].
    pub const ACTOR: &str = "mbpo.role.actor";
    /// [`super::EvaluatorCheckpoint`].
    pub const EVALUATOR: &str = "mbpo.role.evaluator";
    /// [`super::ModelTrainerCheckpoint`].
    pub const MODEL_TRAINER: &str = "mbpo.role.model-trainer";
    /// [`super::RolloutCheckpoint`].
    pub const ROLLOUT: &str = "mbpo.role.rollout-generator";
    /// [`super::LearnerCheckpoint`].
    pub const LEARNER: &str = "mbpo.role.learner";
    /// [`super::PlanningActorCheckpoint`] (MPC runs).
    pub const PLANNING_ACTOR: &str = "mbpo.role.planning-actor";
    /// [`super::PlanningEvaluatorCheckpoint`] (MPC runs).
    pub const PLANNING_EVALUATOR: &str = "mbpo.role.planning-evaluator";
    /// [`super::RunBook`].
    pub const RUN_BOOK: &str = "mbpo.run-book";
}

/// An actor after T: the role (env episode in progress, streams, policy) and its local steps.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ActorCheckpoint {
    /// The role.
    pub role: ActorState,
    /// Local steps done (its global steps follow from the index).
    pub steps: u64,
}

/// The evaluator after T (every eval point ≤ T evaluated).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct EvaluatorCheckpoint {
    /// The `eval.env` stream.
    pub rng: Rng,
    /// Policy version last evaluated.
    pub version: u64,
    /// Evaluations done.
    pub evals: u64,
    /// The checkpoint's env step T.
    pub env_steps: u64,
}

/// The model trainer after T with K trainings.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ModelTrainerCheckpoint {
    /// The role (D_env, model, optimiser, stream, version = K).
    pub role: ModelTrainerState,
}

/// The rollout generator after T with K branches.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct RolloutCheckpoint {
    /// The role (D_env, model, policy, stream).
    pub role: RolloutState,
    /// Branches done (= K).
    pub branches: u64,
}

/// The learner after T: it consumed and published step T and holds the K imagined batches.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LearnerCheckpoint {
    /// The role (SAC, D_env, D_model, streams).
    pub role: LearnerState,
    /// Env steps consumed and published (= T).
    pub consumed: u64,
    /// SAC updates done.
    pub updates: u64,
    /// Imagined batches received (= K).
    pub model_batches: u64,
    /// Model version of the newest imagined batch.
    pub model_version: u64,
}

/// A planning actor (MPC run) after T.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PlanningActorCheckpoint {
    /// The role (env episode in progress, streams, the controller's warm start; not the
    /// model: the model trainer publishes its version again when the run resumes).
    pub role: PlanningActorState,
    /// Local steps done.
    pub steps: u64,
}

/// The planning evaluator (MPC run) after T.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PlanningEvaluatorCheckpoint {
    /// The `eval.env` and `eval.plan` streams.
    pub role: PlanningEvaluatorState,
    /// Evaluations done.
    pub evals: u64,
    /// The checkpoint's env step T (every eval point ≤ T is done, none after it).
    pub env_steps: u64,
}

/// The run's bookkeeping at a checkpoint: what the metrics rows, the summary and the progress
/// line continue from. `mbpo run`'s coordinator keeps it from the roles' reports, `mbpo train`
/// from its roles directly.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunBook {
    /// Metrics rows written (index of the next eval point to write).
    pub next_row: usize,
    /// Every episode end so far: (env step, return).
    pub episodes: Vec<(u64, f64)>,
    /// Holdout MSE of each model version (mean over the elites).
    pub models: BTreeMap<u64, f64>,
    /// (env steps, SAC updates, model version) last reported.
    pub progress: (u64, u64, u64),
    /// (wall seconds, env steps) of the last row written (its rates start there).
    pub last_row: (f64, u64),
    /// SAC updates at the last row written.
    pub last_row_updates: u64,
    /// Last evaluation return.
    pub final_return: f64,
    /// Best evaluation return.
    pub best_return: f64,
    /// Last evaluation return, once there is one (for the progress line).
    pub last_eval: Option<f64>,
    /// Process restarts.
    pub restarts: u32,
    /// Evaluations at or before the checkpoint's step whose row was not written yet (MPC,
    /// pipelined: an actor behind the others had not reached them), as (eval point, return,
    /// model version). The evaluator's file is after them, so they are not evaluated again.
    pub unwritten_evals: Vec<(u64, f64, u64)>,
    /// Wall seconds of the run so far (the clock continues from here).
    pub elapsed_seconds: f64,
    /// Wall seconds of each env step after the warm-up, for `mbpo train`'s median per step
    /// (the pipeline's learner times its own steps and keeps none here, so a run continued
    /// under the other command reports the median of the steps since then).
    pub step_seconds: Vec<f64>,
}

impl RunBook {
    /// The book of a run that has not started.
    pub fn start() -> Self {
        Self {
            next_row: 0,
            episodes: Vec::new(),
            models: BTreeMap::new(),
            progress: (0, 0, 0),
            last_row: (0.0, 0),
            last_row_updates: 0,
            final_return: f64::NAN,
            best_return: f64::NEG_INFINITY,
            last_eval: None,
            restarts: 0,
            unwritten_evals: Vec::new(),
            elapsed_seconds: 0.0,
            step_seconds: Vec::new(),
        }
    }

    /// The metrics rows a run resumed from this book keeps: those up to the checkpoint's step
    /// `env_steps`, except the ones of its unwritten evaluations (written after the checkpoint
    /// by the attempt being abandoned; the book writes them again).
    pub fn rows_upto(&self, env_steps: u64) -> u64 {
        self.unwritten_evals
            .first()
            .map_or(env_steps, |&(t, _, _)| t - 1)
    }

    /// Take a metrics row of eval point `t` with return `ret` at `wall` seconds after
    /// `updates` SAC updates: the returns, and where the next row's rates start.
    pub fn wrote_row(&mut self, t: u64, ret: f64, wall: f64, updates: u64) {
        self.last_row = (wall, t);
        self.last_row_updates = updates;
        self.final_return = ret;
        self.best_return = self.best_return.max(ret);
        self.last_eval = Some(ret);
        self.next_row += 1;
    }
}
