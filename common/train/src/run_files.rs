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

use std::path::Path;
use std::time::{Duration, Instant};

use crate::actor::EnvActor;
use crate::config::ExperimentConfig;
use crate::d_model_branches::DModelBranches;
use crate::error::TrainError;
use crate::mpc_roles::{PlanningActorState, PlanningEvaluatorState};
use crate::roles::{ActorState, LearnerState, ModelTrainerState, RolloutState};
use crate::run_dir::{policy_sha256, RunDir, Summary};
use crate::schedule::Schedule;
use crate::tdmpc::roles::{
    TdmpcActorState, TdmpcEvaluatorState, WorldModelLearner, WorldModelLearnerState,
};
use mbpo_latent::EpisodeLinks;

/// File names in a checkpoint directory (actors: [`actor_file`]), the role table's names.
pub mod file {
    use mbpo_core::roles::RoleKind;
    /// The learner's ([`super::LearnerCheckpoint`]).
    pub const LEARNER: &str = RoleKind::Learner.file_name();
    /// The model trainer's ([`super::ModelTrainerCheckpoint`]).
    pub const MODEL_TRAINER: &str = RoleKind::ModelTrainer.file_name();
    /// The rollout generator's ([`super::RolloutCheckpoint`]).
    pub const ROLLOUT: &str = RoleKind::RolloutGenerator.file_name();
    /// The evaluator's ([`super::EvaluatorCheckpoint`], MPC: [`super::PlanningEvaluatorCheckpoint`]).
    pub const EVALUATOR: &str = RoleKind::Evaluator.file_name();
    /// The run's book ([`super::RunBook`]).
    pub const RUN_BOOK: &str = "run-book";
    /// The launcher's (`mbpo run` only: mode, actors, slack).
    pub const SUPERVISOR: &str = "supervisor";
}

/// The file name of actor `index`'s checkpoint.
pub fn actor_file(index: u16) -> String {
    mbpo_core::roles::RoleKind::Actor.name(index)
}

pub use crate::checkpoint::kind;

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
    /// D_model as the branches that made it, when `role`'s D_model holds only its positions
    /// ([`crate::d_model_branches`]). Last, so a format-4 file is this one without it.
    pub d_model_branches: Option<DModelBranches>,
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

/// TD-MPC2's world-model learner after T: it consumed and published step T.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct WorldModelLearnerCheckpoint {
    /// The role (networks, optimisers, real episodes, stream, updates).
    pub role: WorldModelLearnerState,
    /// Env steps consumed and published (= T).
    pub consumed: u64,
    /// How the buffer's rows join into episodes (format 6, last so that a format-5 file reads
    /// as `None`: one actor's rows in order, `checkpoint::upgraded_payload`).
    pub episode_links: Option<EpisodeLinks>,
}

impl WorldModelLearnerCheckpoint {
    /// `learner` after it consumed and published step `consumed`.
    pub fn of(learner: &WorldModelLearner, consumed: u64) -> Self {
        Self {
            role: learner.checkpoint(),
            consumed,
            episode_links: Some(learner.episode_links()),
        }
    }
    /// Give `learner` the state of this checkpoint.
    pub fn restore_into(self, learner: &mut WorldModelLearner) -> Result<(), TrainError> {
        learner.restore(self.role, self.episode_links)
    }
}

/// A TD-MPC2 actor after T.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LatentActorCheckpoint {
    /// The role (env episode in progress, streams, the planner's warm start; not the
    /// parameters: the learner publishes its version again when the run resumes).
    pub role: TdmpcActorState,
    /// Local steps done.
    pub steps: u64,
}

/// TD-MPC2's evaluator after T.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LatentEvaluatorCheckpoint {
    /// The `eval.env` and `eval.plan` streams.
    pub role: TdmpcEvaluatorState,
    /// Parameters version last evaluated.
    pub version: u64,
    /// Evaluations done.
    pub evals: u64,
    /// The checkpoint's env step T.
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

/// A clock started `seconds` ago: a resumed run's wall clock continues from its checkpoint's.
pub fn started_ago(seconds: f64) -> Instant {
    let elapsed = Duration::from_secs_f64(seconds.max(0.0));
    Instant::now()
        .checked_sub(elapsed)
        .unwrap_or_else(Instant::now)
}

impl RunBook {
    /// The run's clock, continuing from the book's elapsed seconds.
    pub fn clock(&self) -> Instant {
        started_ago(self.elapsed_seconds)
    }

    /// The summary of a one-actor `mbpo train` run that kept this book (MPC, TD-MPC2):
    /// `actor`'s counters, `updates`, the SHA-256 of `params`, the clock `started`.
    pub fn one_actor_summary(
        &self,
        cfg: &ExperimentConfig,
        actor: &EnvActor,
        (updates, params): (u64, &[f32]),
        started: Instant,
        status: &str,
        run: &mut RunDir,
    ) -> Result<Summary, TrainError> {
        let target_return = cfg.target_return();
        Ok(Summary {
            algo: cfg.algo.name().into(),
            env: cfg.env.clone(),
            seed: cfg.seed,
            env_steps: actor.steps,
            sac_updates: updates,
            final_eval_return: self.final_return,
            best_eval_return: self.best_return,
            target_return,
            env_steps_to_target: run.env_steps_to_target(target_return)?,
            policy_sha256: policy_sha256(params),
            wall_seconds: started.elapsed().as_secs_f64(),
            median_seconds_per_env_step: mbpo_core::stats::median(&mut self.step_seconds.clone()),
            status: status.into(),
            episodes_cut_by_resume: actor.episodes_cut,
            episodes_lost_to_env_exit: actor.episodes_lost,
        })
    }

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
            // A book read from a damaged or forged file may hold t = 0: no rows then.
            .map_or(env_steps, |&(t, _, _)| t.saturating_sub(1))
    }

    /// Keep the episode `actor` ended in its last step, if it had `episodes_before` before.
    pub fn note_episode_end(&mut self, actor: &EnvActor, episodes_before: u64) {
        if actor.episodes > episodes_before {
            let ret = actor.last_return.unwrap_or(f64::NAN);
            self.episodes.push((actor.steps, ret));
        }
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

/// Check that the checkpoint in `dir`, after env step `t` with `k` model trainings, is one
/// `mbpo train` can continue: one actor, each of `steps` (role, env steps) at `t`, each of
/// `trainings` (role, trainings or imagined batches) at `k`, and `k` the trainings of the train
/// points ≤ t -- or one more, a lockstep cut that already holds the training of step t + 1. A
/// pipelined stop may have abandoned a training; only `mbpo run` continues that.
pub fn check_one_actor_cut(
    dir: &Path,
    schedule: &Schedule,
    t: u64,
    k: u64,
    steps: &[(&str, u64)],
    trainings: &[(&str, u64)],
) -> Result<(), TrainError> {
    if dir.join(actor_file(1)).exists() {
        return Err(TrainError::Config(format!(
            "{} is a checkpoint of `mbpo run` with several actors; `mbpo train` runs one: \
             resume it with `mbpo run --resume`",
            dir.display()
        )));
    }
    let lo = schedule.train_points_upto(t);
    let consistent = steps.iter().all(|&(_, s)| s == t)
        && trainings.iter().all(|&(_, n)| n == k)
        && (lo..=schedule.train_points_upto(t + 1)).contains(&k);
    if consistent {
        return Ok(());
    }
    let found: Vec<String> = steps
        .iter()
        .chain(trainings)
        .map(|(role, n)| format!("{role} {n}"))
        .collect();
    Err(TrainError::Config(format!(
        "{}: the roles are not all after step {t} with {lo} model trainings (trainings {k}, {}); \
         a pipelined run stopped during a model training continues only under `mbpo run --resume`",
        dir.display(),
        found.join(", ")
    )))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::ExperimentConfig;

    #[test]
    fn only_a_one_actor_cut_after_t_with_its_trainings_is_continued_by_mbpo_train() {
        let mut cfg = ExperimentConfig {
            steps: 1000,
            ..Default::default()
        };
        cfg.mbpo.init_random_steps = 200;
        cfg.mbpo.model_train_freq = 100;
        let schedule = Schedule::of(&cfg);
        let dir = std::env::temp_dir().join(format!("mbpo-cut-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // After 300 the train point 201 is done (K = 1); a lockstep cut may also hold the
        // training of 301 (K = 2).
        let check = |t, k, actor, batches| {
            check_one_actor_cut(
                &dir,
                &schedule,
                t,
                k,
                &[("actor", actor)],
                &[("batches", batches)],
            )
        };
        assert!(check(300, 1, 300, 1).is_ok());
        assert!(check(300, 2, 300, 2).is_ok());
        let err = check(300, 0, 300, 0).unwrap_err().to_string();
        assert!(err.contains("with 1 model trainings (trainings 0"), "{err}");
        let err = check(300, 1, 299, 1).unwrap_err().to_string();
        assert!(err.contains("actor 299"), "{err}");
        assert!(check(300, 1, 300, 2).is_err());
        std::fs::create_dir_all(dir.join(actor_file(1))).unwrap();
        let err = check(300, 1, 300, 1).unwrap_err().to_string();
        assert!(err.contains("several actors"), "{err}");
        std::fs::remove_dir_all(dir).unwrap();
    }
}
