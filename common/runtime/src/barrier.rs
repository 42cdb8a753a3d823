//! Checkpoints of the running pipeline: a barrier that brings every process to one consistent
//! cut, and the file each service writes there.
//!
//! A checkpoint of a pipeline must hold, for every process, the state after the *same* real env
//! step T, with no transition in flight that one process has and another lacks. The supervisor
//! gets there in four messages on the control channel (ARCHITECTURE.md, "Checkpoints of the
//! pipeline"):
//!
//! 1. **Pause** (to all): actors finish their current step and produce nothing more; the model
//!    trainer and rollout generator start no new training / branch. Each of those reports its
//!    counter (an actor its local steps, the others their trainings or branches; the serving
//!    loop does it, `crate::serving`). The learner and evaluator keep consuming.
//! 2. **Checkpoint(T, K)** (the cut, to all): T = the actors' steps summed (every real
//!    transition that exists), K = the model trainings the cut holds: those done (lockstep: at
//!    least those of the train points ≤ T; more if the trainer had already trained for T + 1).
//!    A pipelined MBPO trainer abandons a training under way when the run stops after the
//!    barrier ([`PAUSE_TO_STOP`]), so K can miss a train point ≤ T there. Every process goes
//!    on until its state is exactly "after T with K trainings" -- the learner consumed T steps,
//!    published version T and holds K imagined batches; the model trainer and rollout generator
//!    did K trainings / branches and hold all T transitions; the evaluator evaluated every eval
//!    point ≤ T -- then writes its file into `checkpoints/<T>/` and reports it
//!    ([`write_and_await_resume`]).
//! 3. The supervisor writes its own file and the `COMPLETE` marker when all files are in.
//! 4. **Resume** (go on) or **Stop** (a clean stop: SIGINT/SIGTERM).
//!
//! An MPC run has no learner or rollout generator: its planning actors and model trainer pause,
//! and its planning evaluator writes the state it had before its first eval point after T (a
//! model can exist before the actors reach the step that uses it, so the evaluator may be ahead).
//!
//! Lockstep runs are deterministic whatever the cut's timing, so a resumed lockstep run ends
//! with the same weights as an uninterrupted one (`tests/tests/pipeline_resume.rs`).

use std::path::Path;

use mbpo_train::checkpoint;
use mbpo_wire::{BarrierReport, StatsPublisher, Transport, Waiter};
use serde::{de::DeserializeOwned, Serialize};

use crate::inbox::{wait_for, ControlInbox};
use crate::{Result, RuntimeError};

pub use crate::inbox::{Cut, PAUSE_TO_STOP};

/// The checkpoint files' names, kinds and contents: one format for `mbpo train` and `mbpo run`
/// (`mbpo_train::run_files`), plus the launcher's own file.
pub use mbpo_train::run_files::{
    actor_file, ActorCheckpoint, EvaluatorCheckpoint, LearnerCheckpoint, ModelTrainerCheckpoint,
    PlanningActorCheckpoint, PlanningEvaluatorCheckpoint, RolloutCheckpoint, RunBook,
};

/// File kinds of a pipeline checkpoint: the roles' and the run book's
/// (`mbpo_train::run_files::kind`) and the launcher's.
pub mod kind {
    pub use mbpo_train::run_files::kind::*;
    /// The launcher's file (`SupervisorCheckpoint`: mode, actors, slack). Version 3 holds only
    /// those (the run book has a file of its own); older files are refused by their kind.
    pub const SUPERVISOR: &str = "mbpo.pipeline.supervisor.3";
}

/// File names of a pipeline checkpoint (actors: [`actor_file`]).
pub mod file {
    pub use mbpo_train::run_files::file::*;
}

/// Where a service's checkpoint file goes: `<run_dir>/checkpoints/<T>/<file>`, of its kind.
#[derive(Debug, Clone)]
pub struct FileTarget {
    /// The run directory.
    pub run_dir: std::path::PathBuf,
    /// File name inside the checkpoint directory.
    pub file: String,
    /// Checkpoint kind (see [`kind`]).
    pub kind: &'static str,
}

impl FileTarget {
    /// The file `file` (see [`mod@file`], [`actor_file`]) of kind `kind` in checkpoints of `run_dir`.
    pub fn new(run_dir: &Path, file: impl Into<String>, kind: &'static str) -> Self {
        Self {
            run_dir: run_dir.to_path_buf(),
            file: file.into(),
            kind,
        }
    }
    /// Read this file of the checkpoint directory `dir` (`--resume-from`).
    pub fn read<T: DeserializeOwned>(&self, dir: &Path) -> Result<T> {
        let path = dir.join(&self.file);
        let state = checkpoint::read(&path, self.kind)?;
        tracing::info!("resuming from {}", path.display());
        Ok(state)
    }
}

/// Write `state` into checkpoint `cut` at `target`, report it, then sleep until the supervisor
/// says resume (`Ok(true)`) or stop (`Ok(false)`).
pub fn write_and_await_resume<S: Transport, T: Serialize>(
    waiter: &Waiter<'_, S>,
    control: &ControlInbox<S>,
    stats: &StatsPublisher<S>,
    target: &FileTarget,
    cut: Cut,
    state: &T,
) -> Result<bool> {
    let dir = checkpoint::dir_for(&target.run_dir, cut.env_steps);
    std::fs::create_dir_all(&dir).map_err(|source| RuntimeError::Io {
        path: dir.clone(),
        source,
    })?;
    checkpoint::write(&dir.join(&target.file), target.kind, state)?;
    stats.report(BarrierReport::Written(cut.env_steps))?;
    tracing::info!(
        "checkpoint after step {} ({} model trainings): wrote {}",
        cut.env_steps,
        cut.model_trainings,
        target.file
    );
    let resumed = wait_for(
        waiter,
        control,
        &|| "the supervisor's resume after the checkpoint".into(),
        || Ok(control.take_resume()),
    )?;
    Ok(resumed)
}

/// True when a barrier holds a producer that has done `done` pieces of work: paused and the
/// cut not yet known, or known and not needing more work. Use it in a wait's wake-up condition.
pub fn holds<S: Transport>(control: &ControlInbox<S>, done: u64) -> bool {
    control.pause_requested() && control.cut().is_none_or(|c| done >= c.model_trainings)
}
