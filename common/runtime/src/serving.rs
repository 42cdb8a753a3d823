//! The one serving loop every role of the pipeline runs on, and the small interface a role
//! implements to run on it ([`Worker`]), in the spirit of Acme's actors and learners: a role
//! says what it consumes and produces (its ports), does one step of work at a time, and says
//! what its checkpoint holds; [`serve`] owns everything else.
//!
//! Per turn the loop reads the control channel, stops when told to, serves a checkpoint barrier
//! (ARCHITECTURE.md, "Checkpoints of the pipeline"; [`crate::barrier`]) and otherwise asks the
//! worker for one step. A worker that waits for data says so ([`Step::Waiting`]) and the loop
//! sleeps on the ports it attached, so nothing polls. After its last step the loop reports the
//! worker's `Done` and serves barriers until the supervisor's stop.
//!
//! At a barrier, a role that pauses (the role table's `pauses`: actors, model trainer, rollout
//! generator) reports its counter ([`Worker::done_so_far`]) and does nothing until the cut
//! arrives; the learner and evaluators work on. Once the cut is known, [`Worker::at_cut`] says
//! whether the worker is at it (its file is written, then the loop waits for the resume), must
//! work on to reach it, or waits for the data the cut holds.

use std::time::{Duration, Instant};

use mbpo_wire::{BarrierReport, StatsPublisher, Transport, Waiter};
use serde::{de::DeserializeOwned, Serialize};

use crate::barrier::{self, Cut, FileTarget};
use crate::inbox::ControlInbox;
use crate::realtime;
use crate::{Process, Result, RoleKind, RuntimeError, ServiceArgs};

/// What one [`Worker::step`] came to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Step {
    /// It did a piece of work (an env step, an update, a training): ask again.
    Worked,
    /// What it needs next has not arrived: sleep until a port it attached wakes it.
    Waiting,
    /// Its work for the run is done: the loop reports [`Worker::finish`] and serves barriers
    /// until the stop.
    Finished,
    /// Its environment failed (it reported that itself): it serves barriers until the stop
    /// (the checkpoint that stops the run holds every transition accepted), without `Done`.
    Failed,
}

/// A worker's state at a checkpoint cut.
#[derive(Debug)]
pub enum AtCut<C> {
    /// It is exactly at the cut: this is its checkpoint file.
    Write(C),
    /// It must work on (more steps, trainings or evaluations) to reach the cut.
    Work,
    /// It is at the cut, but the data the cut holds has not all arrived.
    Wait,
}

/// What a worker's functions are given: its process, the control and stats ports the loop
/// owns, the waiter and the worker's own ports.
pub struct Cx<'a, S: Transport, P> {
    /// Config, schedule, sizes, mode, slack and arguments.
    pub s: &'a Process<S>,
    /// Stops, acknowledgements and barriers addressed to this process.
    pub control: &'a ControlInbox<S>,
    /// Reports to the supervisor.
    pub stats: &'a StatsPublisher<S>,
    /// Sleeps on the control channel and the worker's attached ports (a blocking wait inside
    /// a step, such as MPC's acknowledgements, uses it with [`crate::wait_for`]).
    pub waiter: &'a Waiter<'a, S>,
    /// The worker's ports.
    pub ports: &'a P,
}

/// One role of the pipeline as small functions on the serving loop ([`serve`]). Ports are apart
/// from the state: the waiter borrows the ports while the loop changes the state.
pub trait Worker<S: Transport>: Sized {
    /// The role (its node, its row of the role table, its checkpoint file).
    const KIND: RoleKind;
    /// What it subscribes and publishes besides control and stats.
    type Ports;
    /// Its checkpoint file's contents.
    type Checkpoint: Serialize + DeserializeOwned;

    /// Create its ports (all before anyone waits, so peers see them meanwhile).
    fn ports(s: &Process<S>) -> Result<Self::Ports>;
    /// Wait for the peers its first sends need (after the supervisor's stats subscriber).
    fn connect(_s: &Process<S>, _control: &ControlInbox<S>, _ports: &Self::Ports) -> Result<()> {
        Ok(())
    }
    /// Attach the ports whose arrivals wake it.
    fn attach<'a>(ports: &'a Self::Ports, waiter: &mut Waiter<'a, S>);
    /// Its state at the start of a run.
    fn new(cx: &Cx<'_, S, Self::Ports>) -> Result<Self>;
    /// Continue from its checkpoint file (`--resume-from`).
    fn restore(&mut self, state: Self::Checkpoint, cx: &Cx<'_, S, Self::Ports>) -> Result<()>;
    /// Before the first step, after any restore (e.g. publish the weights it starts with).
    fn start(&mut self, _cx: &Cx<'_, S, Self::Ports>) -> Result<()> {
        Ok(())
    }
    /// One step of work, or the finding that it must wait.
    fn step(&mut self, cx: &Cx<'_, S, Self::Ports>) -> Result<Step>;
    /// What it has done so far in its own unit (steps, trainings, branches, evaluations): the
    /// counter a pausing role reports at a barrier, and the log's word on a stop.
    fn done_so_far(&self) -> u64;
    /// Its state at `cut`.
    fn at_cut(&mut self, cut: Cut, cx: &Cx<'_, S, Self::Ports>) -> Result<AtCut<Self::Checkpoint>>;
    /// After its last step: report `Done` and log what it did.
    fn finish(&mut self, cx: &Cx<'_, S, Self::Ports>) -> Result<()>;
    /// What a [`Step::Waiting`] waits for (said when the wait grows long).
    fn waiting_for(&self) -> String;
}

/// Run worker `W` as the process (or thread) of `args` until the supervisor stops it.
pub fn serve<S: Transport, W: Worker<S>>(args: &ServiceArgs) -> Result<()> {
    let s = Process::<S>::open(args, W::KIND)?;
    schedule(&s, W::KIND);
    let control = ControlInbox::create(&s.node)?;
    let stats = StatsPublisher::<S>::create(&s.node)?;
    let ports = W::ports(&s)?;
    stats.wait_for_subscribers(1, Duration::from_secs(60))?;
    W::connect(&s, &control, &ports)?;
    let mut waiter = Waiter::new()?;
    waiter.attach(&control.sub);
    W::attach(&ports, &mut waiter);
    let cx = Cx {
        s: &s,
        control: &control,
        stats: &stats,
        waiter: &waiter,
        ports: &ports,
    };
    let mut worker = W::new(&cx)?;
    let kind = W::KIND;
    let file = FileTarget::new(&args.run_dir, kind.name(args.index), kind.checkpoint_kind());
    if let Some(dir) = &args.resume_from {
        worker.restore(file.read(dir)?, &cx)?;
    }
    worker.start(&cx)?;
    Serving {
        worker,
        cx,
        file,
        finished: false,
        paused_reported: false,
        waiting: None,
    }
    .run()
}

/// A paced actor's scheduling, before it makes its environment (whose process inherits it):
/// SCHED_FIFO on a core of its own ([`realtime`]); other roles, unpaced runs and
/// `actor.realtime_priority = 0` change nothing.
fn schedule<S: Transport>(s: &Process<S>, kind: RoleKind) {
    if !kind.is_actor() || !realtime::actors_run_real_time(&s.cfg, s.mode) {
        return;
    }
    let priority = s.cfg.actor.realtime_priority;
    let got = realtime::paced_actor(priority, realtime::actor_cpu(s.args.index));
    match &got {
        realtime::Scheduling::Default { why } => tracing::warn!("{why}"),
        _ => tracing::info!("paced run: {} runs with {got}", kind.name(s.args.index)),
    }
}

/// How a barrier turn ended.
enum Barrier {
    /// No barrier, or one the worker works on through: step.
    Step,
    /// Held by the barrier (paused before the cut, or waiting for what the cut holds): sleep.
    Held,
    /// The checkpoint was written and the supervisor said resume.
    Resumed,
    /// The checkpoint was written and the supervisor said stop.
    Stopped,
}

/// The loop's state around one worker.
struct Serving<'a, S: Transport, W: Worker<S>> {
    worker: W,
    cx: Cx<'a, S, W::Ports>,
    file: FileTarget,
    /// Its `Done` (or its env failure) was reported.
    finished: bool,
    /// The pause of the barrier under way was reported.
    paused_reported: bool,
    /// Since when, and until which warning, it has been sleeping without work.
    waiting: Option<(Instant, Duration)>,
}

impl<S: Transport, W: Worker<S>> Serving<'_, S, W> {
    fn run(mut self) -> Result<()> {
        loop {
            self.cx.control.poll()?;
            if self.cx.control.stopped() {
                return self.stopped();
            }
            match self.serve_barrier()? {
                Barrier::Step => {}
                Barrier::Held => {
                    self.sleep()?;
                    continue;
                }
                Barrier::Resumed => continue,
                Barrier::Stopped => return self.stopped(),
            }
            if self.finished {
                self.sleep()?;
                continue;
            }
            match self.worker.step(&self.cx)? {
                Step::Worked => self.waiting = None,
                Step::Waiting => self.sleep()?,
                Step::Finished => {
                    self.worker.finish(&self.cx)?;
                    self.finished = true;
                }
                Step::Failed => self.finished = true,
            }
        }
    }

    /// Serve the barrier under way, if any.
    fn serve_barrier(&mut self) -> Result<Barrier> {
        let control = self.cx.control;
        if !control.pause_requested() {
            self.paused_reported = false;
            return Ok(Barrier::Step);
        }
        let Some(cut) = control.cut() else {
            if !W::KIND.pauses() {
                return Ok(Barrier::Step);
            }
            if !self.paused_reported {
                let counter = self.worker.done_so_far();
                self.cx.stats.report(BarrierReport::Paused(counter))?;
                tracing::info!("checkpoint barrier: paused at {counter}");
                self.paused_reported = true;
            }
            return Ok(Barrier::Held);
        };
        match self.worker.at_cut(cut, &self.cx)? {
            AtCut::Work if self.finished => Err(RuntimeError::protocol(format!(
                "checkpoint after step {} with {} model trainings, but {} is done at {}",
                cut.env_steps,
                cut.model_trainings,
                W::KIND.name(self.cx.s.args.index),
                self.worker.done_so_far()
            ))),
            AtCut::Work => Ok(Barrier::Step),
            AtCut::Wait => Ok(Barrier::Held),
            AtCut::Write(state) => {
                let (w, c, st) = (self.cx.waiter, control, self.cx.stats);
                let resumed = barrier::write_and_await_resume(w, c, st, &self.file, cut, &state)?;
                self.paused_reported = false;
                self.waiting = None;
                Ok(if resumed {
                    Barrier::Resumed
                } else {
                    Barrier::Stopped
                })
            }
        }
    }

    /// Sleep until a port wakes the process (at most a second), saying every minute what it
    /// still waits for. A termination signal ends the sleep; the next turn sees it.
    fn sleep(&mut self) -> Result<()> {
        let (since, next_warning) = self
            .waiting
            .get_or_insert((Instant::now(), Duration::from_secs(60)));
        self.cx.waiter.wait(Duration::from_secs(1))?;
        if since.elapsed() >= *next_warning {
            let what = match (self.finished, self.cx.control.pause_requested()) {
                (true, false) => "the supervisor's stop".to_string(),
                (_, true) => "the checkpoint barrier's cut and data".to_string(),
                (false, false) => self.worker.waiting_for(),
            };
            tracing::warn!("still waiting after {:?} for {what}", since.elapsed());
            *next_warning += Duration::from_secs(60);
        }
        Ok(())
    }

    /// The end of a run the supervisor stopped: say where the worker was.
    fn stopped(&self) -> Result<()> {
        let what = if self.finished { "done" } else { "stopped" };
        let at = self.worker.done_so_far();
        tracing::info!("{what} at {at}: stopped by the supervisor");
        Ok(())
    }
}
