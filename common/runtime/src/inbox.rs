//! What a service receives and holds back: control messages addressed to it ([`ControlInbox`]:
//! stops, acknowledgements, checkpoint barriers), real transitions a role may not see yet
//! ([`RealInbox`]), and the one way a service sleeps until something it needs arrives
//! ([`wait_for`]).

use std::cell::{Cell, RefCell};
use std::collections::BTreeSet;
use std::time::{Duration, Instant};

use mbpo_core::Batch;
use mbpo_wire::{
    ControlCommand, ControlMsg, ControlPublisher, ControlSubscriber, ProducerId, RowLayout,
    TransitionSubscriber, Transport, WaitOutcome, Waiter, WireNode,
};

use crate::Result;

/// Stop requests and acknowledgements addressed to this process.
pub struct ControlInbox<S: Transport> {
    /// The subscriber (attach it to the process's [`Waiter`]).
    pub sub: ControlSubscriber<S>,
    me: ProducerId,
    stop: Cell<bool>,
    acked: RefCell<BTreeSet<u64>>,
    pause: Cell<bool>,
    /// The barrier under way ends in a stop (SIGINT/SIGTERM).
    pause_to_stop: Cell<bool>,
    cut: Cell<Option<crate::barrier::Cut>>,
    resume: Cell<bool>,
}

impl<S: Transport> ControlInbox<S> {
    /// Subscribe to the run's control channel as `node`.
    pub fn create(node: &WireNode<S>) -> Result<Self> {
        Ok(Self {
            sub: ControlSubscriber::create(node)?,
            me: node.producer(),
            stop: Cell::new(false),
            acked: RefCell::new(BTreeSet::new()),
            pause: Cell::new(false),
            pause_to_stop: Cell::new(false),
            cut: Cell::new(None),
            resume: Cell::new(false),
        })
    }
    /// Read pending control messages.
    pub fn poll(&self) -> Result<()> {
        while let Some(m) = self.sub.receive()? {
            if !m.msg.is_for(self.me) {
                continue;
            }
            match m.msg.control_command() {
                Some(ControlCommand::Stop) => self.stop.set(true),
                Some(ControlCommand::Ack) => {
                    self.acked.borrow_mut().insert(m.msg.step);
                }
                Some(ControlCommand::Pause) => {
                    self.pause.set(true);
                    if m.msg.request_id == crate::barrier::PAUSE_TO_STOP {
                        self.pause_to_stop.set(true);
                    }
                }
                Some(ControlCommand::Checkpoint) => {
                    self.pause.set(true);
                    self.cut.set(Some(crate::barrier::Cut {
                        env_steps: m.msg.step,
                        model_trainings: m.msg.request_id,
                    }));
                }
                Some(ControlCommand::Resume) => {
                    self.pause.set(false);
                    self.pause_to_stop.set(false);
                    self.cut.set(None);
                    self.resume.set(true);
                }
                None => {}
            }
        }
        Ok(())
    }
    /// True once a Stop for this process arrived, or SIGINT/SIGTERM.
    pub fn stopped(&self) -> bool {
        self.stop.get() || mbpo_wire::termination_requested()
    }
    /// True when an acknowledgement for `step` arrived (consumes it).
    pub fn take_ack(&self, step: u64) -> bool {
        self.acked.borrow_mut().remove(&step)
    }
    /// Count `step` as acknowledged (a resumed learner: the evaluator acknowledged the eval
    /// point of the checkpoint before it was written).
    pub fn assume_ack(&self, step: u64) {
        self.acked.borrow_mut().insert(step);
    }
    /// True while a checkpoint barrier is under way (from its Pause to its Resume).
    pub fn pause_requested(&self) -> bool {
        self.pause.get()
    }
    /// True while the checkpoint barrier under way is one the run stops after: work the
    /// cut does not need may then be abandoned rather than finished (a periodic checkpoint
    /// lets it finish, as the run goes on with it).
    pub fn pause_to_stop(&self) -> bool {
        self.pause_to_stop.get()
    }
    /// The cut of the checkpoint barrier under way, once the supervisor sent it.
    pub fn cut(&self) -> Option<crate::barrier::Cut> {
        self.cut.get()
    }
    /// True when the supervisor said "resume" after a checkpoint (consumes it).
    pub fn take_resume(&self) -> bool {
        self.resume.replace(false)
    }
}

/// Tell `target` that step `step` was handled (the evaluator's "I copied policy version t").
pub fn send_ack<S: Transport>(
    control: &ControlPublisher<S>,
    target: ProducerId,
    step: u64,
) -> Result<()> {
    let msg = ControlMsg {
        request_id: step,
        step,
        command: ControlCommand::Ack as u32,
        target: target.0,
        status: 0,
        acked_command: 0,
    };
    control.send(&msg)?;
    Ok(())
}

/// Sleep in `waiter` until `ready` returns true (`Ok(true)`), or a stop/termination arrives
/// (`Ok(false)`). `ready` is evaluated after every wake-up; it drains the subscribers it needs.
pub fn wait_for<S: Transport>(
    waiter: &Waiter<'_, S>,
    control: &ControlInbox<S>,
    what: &dyn Fn() -> String,
    mut ready: impl FnMut() -> Result<bool>,
) -> Result<bool> {
    let start = Instant::now();
    let mut next_warn = Duration::from_secs(60);
    loop {
        control.poll()?;
        if control.stopped() {
            return Ok(false);
        }
        if ready()? {
            return Ok(true);
        }
        if waiter.wait(Duration::from_secs(1))? == WaitOutcome::Terminate {
            return Ok(false);
        }
        if start.elapsed() >= next_warn {
            tracing::warn!("still waiting after {:?} for {}", start.elapsed(), what());
            next_warn += Duration::from_secs(60);
        }
    }
}

/// Real transitions received but not yet handed to the role: lockstep roles must see exactly
/// the first t − 1 transitions at a train point although transition t may already be here.
pub struct RealInbox {
    layout: RowLayout,
    rows: Vec<f32>,
    start: usize,
    received: u64,
    taken: u64,
}

impl RealInbox {
    /// An empty inbox for rows of `layout`.
    pub fn new(layout: RowLayout) -> Self {
        Self {
            layout,
            rows: Vec::new(),
            start: 0,
            received: 0,
            taken: 0,
        }
    }
    /// Move every pending batch of `sub` into the inbox; returns the rows added.
    pub fn pull<S: Transport>(&mut self, sub: &TransitionSubscriber<S>) -> Result<usize> {
        let mut n = 0;
        while let Some(b) = sub.receive()? {
            if self.start > 0 && self.start * 2 >= self.rows.len() {
                self.rows.drain(..self.start);
                self.start = 0;
            }
            self.rows.extend_from_slice(b.rows());
            n += b.n_rows();
        }
        self.received += n as u64;
        Ok(n)
    }
    /// A resumed consumer: the first `n` rows of the run were received and taken before the
    /// checkpoint it continues from.
    pub fn resume_at(&mut self, n: u64) {
        self.received = n;
        self.taken = n;
    }
    /// Rows received so far (taken or not).
    pub fn received(&self) -> u64 {
        self.received
    }
    /// Rows handed out so far.
    pub fn taken(&self) -> u64 {
        self.taken
    }
    /// Rows waiting.
    pub fn pending(&self) -> usize {
        (self.rows.len() - self.start) / self.layout.width()
    }
    /// Hand out the next `n` rows (at most [`RealInbox::pending`]) into `out`.
    pub fn take(&mut self, n: usize, out: &mut Batch) {
        let n = n.min(self.pending());
        let w = self.layout.width();
        self.layout
            .unpack_into(&self.rows[self.start..self.start + n * w], out);
        self.start += n * w;
        self.taken += n as u64;
    }
}
