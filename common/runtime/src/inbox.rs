//! What a service receives and holds back: control messages addressed to it ([`ControlInbox`]:
//! stops, acknowledgements, checkpoint barriers), real transitions a role may not see yet
//! ([`RealInbox`]), and the one way a service sleeps until something it needs arrives
//! ([`wait_for`]).

use std::cell::{Cell, RefCell};
use std::collections::{BTreeSet, VecDeque};
use std::time::{Duration, Instant};

use mbpo_core::TransitionSink;
use mbpo_wire::{
    ControlCommand, ControlMsg, ControlPublisher, ControlSubscriber, ProducerId, RowLayout,
    TransitionBatch, TransitionSubscriber, Transport, WaitOutcome, Waiter, WireNode,
};

use crate::Result;

/// The Pause's `request_id` of a barrier the run stops after (SIGINT/SIGTERM); 0 for a
/// periodic one. (Sent again when a stop is requested during a periodic barrier.)
pub const PAUSE_TO_STOP: u64 = 1;

/// The cut of a checkpoint barrier.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Cut {
    /// Real env steps T every process holds.
    pub env_steps: u64,
    /// Model trainings K (= imagined batches) the cut holds.
    pub model_trainings: u64,
}

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
    cut: Cell<Option<Cut>>,
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
                    if m.msg.request_id == PAUSE_TO_STOP {
                        self.pause_to_stop.set(true);
                    }
                }
                Some(ControlCommand::Checkpoint) => {
                    self.pause.set(true);
                    self.cut.set(Some(Cut {
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
    pub fn cut(&self) -> Option<Cut> {
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
/// the first t − 1 transitions at a train point although transition t may already be here, and
/// the learner consumes one step at a time.
///
/// The rows stay in shared memory until taken: [`RealInbox::take`] pushes them from there
/// straight into the role's D_env, so a real transition is copied twice on its way (the
/// actor's env step into shared memory, shared memory into D_env). Only when more batches wait
/// than the subscriber may hold at once (`max_borrowed`) is the oldest copied out (counted in
/// [`RealInbox::spilled`]), which frees its shared-memory chunk for the actors.
pub struct RealInbox<S: Transport> {
    layout: RowLayout,
    /// Batches in shared memory, oldest first; `front_taken` rows of the first are taken.
    held: VecDeque<TransitionBatch<S>>,
    front_taken: usize,
    /// Rows copied out of shared memory, all older than every held batch; `spilled_start`
    /// floats of them are taken.
    spilled_rows: Vec<f32>,
    spilled_start: usize,
    pending: usize,
    received: u64,
    taken: u64,
    spilled: u64,
}

impl<S: Transport> RealInbox<S> {
    /// An empty inbox for rows of `layout`.
    pub fn new(layout: RowLayout) -> Self {
        Self {
            layout,
            held: VecDeque::new(),
            front_taken: 0,
            spilled_rows: Vec::new(),
            spilled_start: 0,
            pending: 0,
            received: 0,
            taken: 0,
            spilled: 0,
        }
    }
    /// Receive every pending batch of `sub`, handing `sink` each row as it arrives while
    /// fewer than `take_upto` rows were taken in all (the rows the role may see now); returns
    /// the rows received.
    pub fn pull(
        &mut self,
        sub: &TransitionSubscriber<S>,
        take_upto: u64,
        sink: &mut dyn TransitionSink,
    ) -> Result<usize> {
        // Rows received earlier that the role may see by now.
        self.take_upto(take_upto, sink);
        let mut n = 0;
        while let Some(rows) = self.receive_batch(sub)? {
            n += rows;
            self.take_upto(take_upto, sink);
        }
        Ok(n)
    }
    /// Receive one pending batch of `sub` (its rows), spilling the oldest held one first when
    /// the subscriber holds all it may (one borrow is kept free for the receive itself).
    fn receive_batch(&mut self, sub: &TransitionSubscriber<S>) -> Result<Option<usize>> {
        if !sub.has_pending()? {
            return Ok(None);
        }
        if self.held.len() >= sub.max_borrowed().saturating_sub(1).max(1) {
            self.spill_front();
        }
        let Some(b) = sub.receive()? else {
            return Ok(None);
        };
        let rows = b.n_rows();
        self.pending += rows;
        self.received += rows as u64;
        self.held.push_back(b);
        Ok(Some(rows))
    }
    /// Receive every pending batch of `sub` and hand none out: a role busy with its data (a
    /// model training) keeps what arrives meanwhile, copied out of shared memory beyond
    /// `max_borrowed`, so an actor never blocks on it however long the work takes (a paced
    /// actor must not). Returns the rows received.
    pub fn receive(&mut self, sub: &TransitionSubscriber<S>) -> Result<usize> {
        let mut n = 0;
        while let Some(rows) = self.receive_batch(sub)? {
            n += rows;
        }
        Ok(n)
    }
    /// Take rows until `upto` rows were taken in all (or none is pending).
    fn take_upto(&mut self, upto: u64, sink: &mut dyn TransitionSink) {
        let may = upto.min(self.received);
        self.take(may.saturating_sub(self.taken) as usize, sink);
    }
    /// Copy the oldest held batch's untaken rows out of shared memory.
    fn spill_front(&mut self) {
        let Some(b) = self.held.pop_front() else {
            return;
        };
        if self.spilled_start > 0 && self.spilled_start * 2 >= self.spilled_rows.len() {
            self.spilled_rows.drain(..self.spilled_start);
            self.spilled_start = 0;
        }
        let w = self.layout.width();
        self.spilled_rows
            .extend_from_slice(&b.rows()[self.front_taken * w..]);
        self.spilled += (b.n_rows() - self.front_taken) as u64;
        self.front_taken = 0;
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
        self.pending
    }
    /// Rows copied out of shared memory before they were taken (a third copy).
    pub fn spilled(&self) -> u64 {
        self.spilled
    }
    /// Hand the next `n` rows (at most [`RealInbox::pending`]) to `sink`, in arrival order.
    pub fn take(&mut self, n: usize, sink: &mut dyn TransitionSink) {
        let mut left = n.min(self.pending);
        self.pending -= left;
        self.taken += left as u64;
        let w = self.layout.width();
        let spilled = (self.spilled_rows.len() - self.spilled_start) / w;
        let k = left.min(spilled);
        let rows = &self.spilled_rows[self.spilled_start..self.spilled_start + k * w];
        self.layout.push_rows(rows, sink);
        self.spilled_start += k * w;
        left -= k;
        while left > 0 {
            // Every pending row is spilled or held.
            let Some(front) = self.held.front() else {
                break;
            };
            let k = left.min(front.n_rows() - self.front_taken);
            front.push_rows_from(self.front_taken, k, sink);
            self.front_taken += k;
            left -= k;
            if self.front_taken == front.n_rows() {
                // Dropping the batch gives its chunk back to the actor.
                self.held.pop_front();
                self.front_taken = 0;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::ReplayBuffer;
    use mbpo_wire::{
        local, Channel, ChannelQos, Role, RunIpc, TransitionMeta, TransitionPublisher,
    };

    /// Row `k`: every field holds `k` (terminated: k odd).
    fn send_row(tx: &TransitionPublisher<local::Service>, layout: RowLayout, k: usize) {
        let v = k as f32;
        tx.send_with(1, TransitionMeta::default(), |row| {
            layout.write_row(row, &[v; 3], &[v], v, &[v; 3], k % 2 == 1)
        })
        .unwrap();
    }

    /// Rows stay in shared memory until taken and reach the sink in arrival order, also across
    /// a spill (more waiting than the subscriber may hold), which is counted.
    #[test]
    fn rows_go_from_shared_memory_to_the_sink_in_order() {
        let id = format!("inbox-{}", std::process::id());
        let root = std::env::temp_dir().join("mbpo-runtime-tests");
        let mut run = RunIpc::new(&id, &root).unwrap();
        let mut q = ChannelQos::default_for(Channel::Real);
        (q.buffer_size, q.max_borrowed) = (64, 4);
        run.set_qos(Channel::Real, q);
        let layout = RowLayout::new(3, 1);
        {
            let a = run.node::<local::Service>(Role::Actor, 0).unwrap();
            let l = run.node::<local::Service>(Role::Learner, 0).unwrap();
            let rx = TransitionSubscriber::create(&l, Channel::Real, layout).unwrap();
            let tx = TransitionPublisher::create(&a, Channel::Real, layout, 1).unwrap();
            rx.update_connections();
            tx.wait_for_subscribers(1, Duration::from_secs(2)).unwrap();
            let mut inbox = RealInbox::new(layout);
            let mut d_env = ReplayBuffer::new(3, 1, 100);
            // Three rows: held (the subscriber may hold 4, one is kept for the receive).
            (0..3).for_each(|k| send_row(&tx, layout, k));
            assert_eq!(inbox.pull(&rx, 0, &mut d_env).unwrap(), 3);
            inbox.take(2, &mut d_env);
            assert_eq!((inbox.pending(), inbox.spilled()), (1, 0));
            // Ten more: the oldest held ones are copied out to make room.
            (3..13).for_each(|k| send_row(&tx, layout, k));
            assert_eq!(inbox.pull(&rx, 0, &mut d_env).unwrap(), 10);
            assert_eq!((inbox.pending(), inbox.received()), (11, 13));
            assert_eq!(inbox.spilled(), 8, "11 waiting, 3 held");
            inbox.take(100, &mut d_env);
            assert_eq!((inbox.pending(), inbox.taken()), (0, 13));
            // A consumer busy with its data (a model training) only receives: nothing is
            // handed out, and what arrived is kept in order, out of the actors' way.
            (13..53).for_each(|k| send_row(&tx, layout, k));
            assert_eq!(inbox.receive(&rx).unwrap(), 40);
            assert_eq!(
                (inbox.pending(), inbox.taken(), inbox.spilled()),
                (40, 13, 45)
            );
            inbox.take(100, &mut d_env);
            let snap = d_env.snapshot();
            let want: Vec<f32> = (0..53).map(|k| k as f32).collect();
            assert_eq!(snap.slots.reward, want);
            assert_eq!(snap.slots.act, want);
            let odd: Vec<f32> = (0..53).map(|k| (k % 2) as f32).collect();
            assert_eq!(snap.slots.terminated, odd);
        }
        let _ = run.remove_all::<local::Service>();
    }
}
