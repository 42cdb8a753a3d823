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
//!    counter ([`report_paused`]: an actor its local steps, the others their trainings or
//!    branches). The learner and evaluator keep consuming.
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

use std::marker::PhantomData;
use std::path::Path;

use mbpo_core::TransitionSink;
use mbpo_train::checkpoint;
use mbpo_wire::{BarrierReport, StatsPublisher, TransitionSubscriber, Transport, Waiter};
use serde::{de::DeserializeOwned, Serialize};

use crate::error::ensure_protocol;
use crate::inbox::{wait_for, ControlInbox, RealInbox};
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

/// Report the pause with the process's own counter, then sleep until the cut arrives.
/// `Ok(None)`: stopped instead.
pub fn report_paused<S: Transport>(
    waiter: &Waiter<'_, S>,
    control: &ControlInbox<S>,
    stats: &StatsPublisher<S>,
    counter: u64,
) -> Result<Option<Cut>> {
    if control.cut().is_none() {
        stats.report(BarrierReport::Paused(counter))?;
        tracing::info!("checkpoint barrier: paused at {counter}");
    }
    let arrived = wait_for(waiter, control, &|| "the checkpoint cut".into(), || {
        Ok(control.cut().is_some())
    })?;
    Ok(arrived.then(|| control.cut()).flatten())
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

/// What a producer of trainings or branches (model trainer, rollout generator) may do before
/// its next one, given the barrier.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Gate {
    /// No barrier, or the cut still holds this work (`done < K`): go on.
    Work,
    /// At the cut: take the transitions ≤ T, write the checkpoint, wait for the resume.
    AtCut(Cut),
    /// Stopped.
    Stop,
}

/// True when a barrier holds a producer that has done `done` pieces of work: paused and the
/// cut not yet known, or known and not needing more work. Use it in a wait's wake-up condition.
pub fn holds<S: Transport>(control: &ControlInbox<S>, done: u64) -> bool {
    control.pause_requested() && control.cut().is_none_or(|c| done >= c.model_trainings)
}

/// Look at the barrier before the `done + 1`-th piece of work: report the pause (once) and
/// wait for the cut if a barrier is under way.
pub fn gate<S: Transport>(
    waiter: &Waiter<'_, S>,
    control: &ControlInbox<S>,
    stats: &StatsPublisher<S>,
    done: u64,
) -> Result<Gate> {
    if !control.pause_requested() {
        return Ok(Gate::Work);
    }
    let cut = match control.cut() {
        Some(c) => c,
        None => match report_paused(waiter, control, stats, done)? {
            Some(c) => c,
            None => return Ok(Gate::Stop),
        },
    };
    Ok(if done < cut.model_trainings {
        Gate::Work
    } else {
        Gate::AtCut(cut)
    })
}

/// Wait until the first `env_steps` real transitions of the run arrived and hand out those not
/// yet taken to `sink` (a consumer at the cut holds every transition ≤ T). `Ok(false)`: stopped.
pub fn take_upto<S: Transport>(
    waiter: &Waiter<'_, S>,
    control: &ControlInbox<S>,
    real: &TransitionSubscriber<S>,
    inbox: &mut RealInbox<S>,
    sink: &mut dyn TransitionSink,
    env_steps: u64,
) -> Result<bool> {
    let arrived = wait_for(
        waiter,
        control,
        &|| format!("{env_steps} real transitions for the checkpoint"),
        || {
            inbox.pull(real, env_steps, sink)?;
            Ok(inbox.received() >= env_steps)
        },
    )?;
    if arrived {
        ensure_protocol!(
            inbox.received() == env_steps,
            "checkpoint after step {env_steps}: {} real transitions arrived although the actors are paused",
            inbox.received()
        );
        inbox.take((env_steps - inbox.taken()) as usize, sink);
    }
    Ok(arrived)
}

/// After its work, sleep until the supervisor's Stop while still taking part in checkpoint
/// barriers: `pause_counter` is reported at a pause (`None` for the learner and evaluator,
/// which never pause), `at_cut` writes the file and waits for the resume (`Ok(false)`: stop).
pub fn idle_until_stop<S: Transport>(
    waiter: &Waiter<'_, S>,
    control: &ControlInbox<S>,
    stats: &StatsPublisher<S>,
    pause_counter: Option<u64>,
    mut at_cut: impl FnMut(Cut) -> Result<bool>,
) -> Result<()> {
    loop {
        let what = || "the supervisor's stop".to_string();
        if !wait_for(waiter, control, &what, || Ok(control.pause_requested()))? {
            return Ok(());
        }
        let cut = match pause_counter {
            Some(c) => report_paused(waiter, control, stats, c)?,
            None => wait_for(waiter, control, &what, || Ok(control.cut().is_some()))?
                .then(|| control.cut())
                .flatten(),
        };
        match cut {
            Some(cut) if at_cut(cut)? => {}
            _ => return Ok(()),
        }
    }
}

/// An actor's step `g` failed with `e`, after `done` local steps. An environment failure (a
/// Python exception, a Python process that exited again at once) is reported, and the actor
/// takes part in the checkpoint that stops the run: nothing of step g was sent, so the
/// checkpoint holds every transition accepted. Any other error ends the process at once.
pub fn after_env_failure<S: Transport>(
    waiter: &Waiter<'_, S>,
    control: &ControlInbox<S>,
    stats: &StatsPublisher<S>,
    e: mbpo_train::TrainError,
    g: u64,
    done: u64,
    at_cut: impl FnMut(Cut) -> Result<bool>,
) -> Result<()> {
    let mbpo_train::TrainError::Env(env_error) = e else {
        return Err(e.into());
    };
    tracing::error!("env step {g}: {env_error}");
    stats.report(mbpo_wire::EnvFailed { env_steps: g })?;
    idle_until_stop(waiter, control, stats, Some(done), at_cut)
}

/// How a consumer that keeps its own D_env (model trainer, rollout generator) serves a
/// barrier: its ports, and `at_cut(role, cut)`, called at the cut once every transition ≤ T
/// is in the role, which writes the role's file and waits for the resume (`Ok(false)`:
/// stopped).
pub struct DataGate<'w, 'a, S: Transport, R, F> {
    waiter: &'w Waiter<'a, S>,
    control: &'w ControlInbox<S>,
    stats: &'w StatsPublisher<S>,
    real: &'w TransitionSubscriber<S>,
    at_cut: F,
    pipelined: bool,
    role: PhantomData<fn(&mut R)>,
}

impl<'w, 'a, S: Transport, R: TransitionSink, F> DataGate<'w, 'a, S, R, F>
where
    F: Fn(&mut R, Cut) -> Result<bool>,
{
    /// The gate of a process with these ports, in hand-off `mode` (see [`DataGate::wait_until`]).
    pub fn new(
        waiter: &'w Waiter<'a, S>,
        control: &'w ControlInbox<S>,
        stats: &'w StatsPublisher<S>,
        real: &'w TransitionSubscriber<S>,
        mode: crate::Mode,
        at_cut: F,
    ) -> Self {
        Self {
            waiter,
            control,
            stats,
            real,
            at_cut,
            pipelined: mode == crate::Mode::Pipelined,
            role: PhantomData,
        }
    }

    /// At the cut: take every transition ≤ T out of `inbox` into the role, then `at_cut`.
    /// `Ok(false)`: stopped.
    fn serve_cut(&self, inbox: &mut RealInbox<S>, role: &mut R, cut: Cut) -> Result<bool> {
        let n = cut.env_steps;
        if !take_upto(self.waiter, self.control, self.real, inbox, role, n)? {
            return Ok(false);
        }
        (self.at_cut)(role, cut)
    }

    /// Sleep until `ready(role, inbox)` (evaluated after pulling the real transitions on every
    /// wake-up), serving checkpoint barriers meanwhile (`done`: trainings or branches so far).
    /// `Ok(false)`: stopped.
    ///
    /// The role takes real transitions as they arrive: in lockstep the first `upto` (those its
    /// next training or branch sees), pipelined all of them (it works on whatever has arrived).
    /// It reads its D_env only when it works, so this equals taking them then, and nothing it
    /// may see waits in shared memory.
    pub fn wait_until(
        &self,
        inbox: &mut RealInbox<S>,
        role: &mut R,
        done: u64,
        upto: u64,
        what: &dyn Fn() -> String,
        mut ready: impl FnMut(&mut R, &RealInbox<S>) -> Result<bool>,
    ) -> Result<bool> {
        loop {
            let mut is_ready = false;
            let woke = wait_for(self.waiter, self.control, what, || {
                let upto = if self.pipelined { u64::MAX } else { upto };
                inbox.pull(self.real, upto, role)?;
                is_ready = ready(role, inbox)?;
                Ok(is_ready || holds(self.control, done))
            })?;
            if !woke {
                return Ok(false);
            }
            match gate(self.waiter, self.control, self.stats, done)? {
                Gate::Stop => return Ok(false),
                Gate::Work if is_ready => return Ok(true),
                Gate::Work => {}
                Gate::AtCut(cut) => {
                    if !self.serve_cut(inbox, role, cut)? {
                        return Ok(false);
                    }
                }
            }
        }
    }

    /// [`DataGate::wait_until`] the first `need` real transitions arrived.
    pub fn wait_for_real(
        &self,
        inbox: &mut RealInbox<S>,
        role: &mut R,
        need: u64,
        done: u64,
    ) -> Result<bool> {
        let what = || format!("{need} real transitions");
        self.wait_until(inbox, role, done, need, &what, |_, inbox| {
            Ok(inbox.received() >= need)
        })
    }

    /// [`idle_until_stop`] for such a consumer.
    pub fn idle_until_stop(
        &self,
        inbox: &mut RealInbox<S>,
        role: &mut R,
        pause_counter: Option<u64>,
    ) -> Result<()> {
        idle_until_stop(
            self.waiter,
            self.control,
            self.stats,
            pause_counter,
            |cut| self.serve_cut(inbox, role, cut),
        )
    }
}
