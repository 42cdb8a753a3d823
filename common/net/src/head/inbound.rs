//! The head's main thread: everything that arrives from workers. It admits them, publishes
//! their roles' transitions, reports and control messages on the head's iceoryx2 under each
//! slot's own producer id (the head's roles cannot tell a remote role from a local one), writes
//! their checkpoint files into the run directory and their logs under `logs/<worker>/`, and
//! acknowledges. It blocks when the consumers' queues are full, and then acknowledges nothing,
//! so the worker's window fills and its roles wait: the rate limits hold across hosts.

use std::time::{Duration, Instant};

use mbpo_runtime::run_plan::Slot;
use mbpo_runtime::{configure_run, Dims, PipelineSpec, RuntimeError};
use mbpo_train::checkpoint;
use mbpo_wire::*;

use super::account::{Batches, HostsAccount, ACCOUNT_CHECK, HOSTS_REWRITE};
use super::admission::{admit, refuse, Offer};
use super::state::Gate;
use super::HeadOptions;
use crate::files::{append, sanitize, write_atomically};
use crate::link::Accept;
use crate::peer::lock;
use crate::protocol::{decode, Body, Envelope, Item};
use crate::GatewayError;
use zenoh::Wait;

/// The ports of one remote slot that carry its worker's data to the head's roles: what the
/// slot's role publishes.
struct SlotOut {
    slot: Slot,
    real: Option<TransitionPublisher<ipc::Service>>,
    stats: StatsPublisher<ipc::Service>,
    control: Option<ControlPublisher<ipc::Service>>,
    /// The actor's next batch number (checked end to end).
    next_actor_seq: u64,
    consumers_ready: bool,
    control_ready: bool,
    transitions: u64,
}

/// The main thread's own: the slots' ports and the counts their first sends wait for.
pub(crate) struct Inbound<'a> {
    gate: &'a Gate,
    session: &'a zenoh::Session,
    opts: &'a HeadOptions,
    outs: Vec<SlotOut>,
    real_consumers: usize,
    control_subscribers: usize,
    _nodes: Vec<WireNode<ipc::Service>>,
}

impl<'a> Inbound<'a> {
    /// Create the publishers of `slots` on the head's iceoryx2.
    pub fn open(
        gate: &'a Gate,
        session: &'a zenoh::Session,
        opts: &'a HeadOptions,
        pipeline: &'static PipelineSpec,
        dims: Dims,
        slots: &[Slot],
    ) -> Result<Self, GatewayError> {
        let args = &opts.service;
        let mut run = RunIpc::new(&args.run_id, &args.ipc_root)?;
        configure_run(&mut run);
        let (mut outs, mut nodes) = (Vec::new(), Vec::new());
        for &slot in slots {
            let node = run.node::<ipc::Service>(slot.kind.wire_role(), slot.index)?;
            let real = match slot.kind.publishes(Channel::Real) {
                true => Some(TransitionPublisher::create(
                    &node,
                    Channel::Real,
                    dims.rows(),
                    1,
                )?),
                false => None,
            };
            let control = match slot.kind.publishes(Channel::Control) {
                true => Some(ControlPublisher::create(&node)?),
                false => None,
            };
            outs.push(SlotOut {
                slot,
                real,
                stats: StatsPublisher::create(&node)?,
                control,
                next_actor_seq: 0,
                consumers_ready: false,
                control_ready: false,
                transitions: 0,
            });
            nodes.push(node);
        }
        Ok(Self {
            gate,
            session,
            opts,
            outs,
            real_consumers: pipeline.real_consumers(),
            control_subscribers: pipeline.subscribers(Channel::Control, args.actors),
            _nodes: nodes,
        })
    }

    /// Transition batches delivered per slot so far.
    pub fn batches(&self) -> Batches {
        self.outs.iter().map(|o| (o.slot, o.transitions)).collect()
    }

    /// Receive until the run is over, the attempt is rolled back, a signal, or a failure.
    pub fn run(&mut self, account: &HostsAccount) -> Result<(), GatewayError> {
        let sub = self
            .session
            .declare_subscriber(crate::session::FROM_ANY_WORKER)
            .wait()
            .map_err(|e| GatewayError::Zenoh(format!("subscribing to workers: {e}")))?;
        let mut ends = Ends::default();
        let mut account_checked = Instant::now();
        loop {
            if account_checked.elapsed() >= ACCOUNT_CHECK {
                account_checked = Instant::now();
                ends.write_account_if_due(&lock(&self.gate.state), account, &self.batches());
            }
            if termination_requested() {
                tracing::info!("stopped by a signal");
                return Ok(());
            }
            if self.gate.stopping() || ends.reached(self.gate)? {
                return Ok(());
            }
            let sample = match sub.recv_timeout(Duration::from_millis(100)) {
                Ok(Some(s)) => s,
                Ok(None) => continue,
                Err(e) => return Err(GatewayError::Zenoh(format!("receiving: {e}"))),
            };
            match decode(&sample.payload().to_bytes()) {
                Ok(env) => self.handle(env)?,
                Err(e) => tracing::warn!("dropped a message from {}: {e}", sample.key_expr()),
            }
        }
    }

    fn handle(&mut self, env: Envelope) -> Result<(), GatewayError> {
        let (gate, from) = (self.gate, env.session);
        match env.body {
            Body::Hello {
                worker,
                actors,
                roles,
            } => {
                let offer = Offer {
                    worker,
                    actors,
                    roles,
                };
                admit(gate, self.session, self.opts, from, offer)
            }
            Body::Data { seq, item } => {
                let accept = {
                    let mut st = lock(&gate.state);
                    let Some(w) = st.workers.get_mut(&from) else {
                        return Ok(()); // a worker of an earlier attempt: its heartbeat tells it
                    };
                    w.last_heard = Instant::now();
                    w.accept(seq)
                };
                if accept == Accept::Deliver {
                    self.deliver(from, item)?;
                }
                let mut st = lock(&gate.state);
                match st.workers.get_mut(&from) {
                    Some(w) => w.acknowledge(accept),
                    None => Ok(()),
                }
            }
            Body::Ack { next } => {
                heard(gate, from, next, None);
                Ok(())
            }
            Body::Heartbeat { next, weights } => match heard(gate, from, next, Some(weights)) {
                true => Ok(()),
                // Not (or no longer) a member: say so, so it joins again.
                false => refuse(
                    self.session,
                    gate,
                    from,
                    "this worker is not a member of the run's current attempt: join again",
                ),
            },
            other => {
                tracing::warn!("a worker sent a head's message: {other:?}");
                Ok(())
            }
        }
    }

    /// One message of a worker's stream, in order.
    fn deliver(&mut self, from: u64, item: Item) -> Result<(), GatewayError> {
        let slot = match &item {
            Item::Transitions { slot, .. }
            | Item::Stats { slot, .. }
            | Item::CheckpointFile { slot, .. }
            | Item::SlotFailed { slot, .. }
            | Item::Log { slot, .. }
            | Item::ControlFrom { slot, .. } => *slot,
            Item::Bye => {
                let mut st = lock(&self.gate.state);
                st.said_bye.insert(from);
                let name = st.workers.get(&from).map(|w| w.name.clone());
                tracing::info!(
                    "worker {}: every role exited, goodbye",
                    name.unwrap_or_default()
                );
                return Ok(());
            }
            Item::Control { .. } | Item::Finished => {
                tracing::warn!("a worker sent a head's item");
                return Ok(());
            }
        };
        let Some((name, i)) = self.holder(from, slot) else {
            return Ok(());
        };
        self.deliver_to(i, &name, item)
    }

    /// The worker's name and the slot's position when worker `from` holds `slot`; otherwise
    /// the gateway fails.
    fn holder(&self, from: u64, slot: Slot) -> Option<(String, usize)> {
        let mut st = lock(&self.gate.state);
        let name = st
            .workers
            .get(&from)
            .map(|w| w.name.clone())
            .unwrap_or_default();
        match st.slot_index(slot) {
            Some(i) if st.owner[i] == Some(from) => Some((name, i)),
            _ => {
                st.fail(format!(
                    "worker {name} sent data of {slot}, which it does not hold"
                ));
                None
            }
        }
    }

    fn deliver_to(&mut self, i: usize, name: &str, item: Item) -> Result<(), GatewayError> {
        let out = &mut self.outs[i];
        let slot = out.slot;
        match item {
            Item::Transitions {
                actor_seq,
                meta,
                rows,
                ..
            } => {
                if actor_seq != out.next_actor_seq {
                    lock(&self.gate.state).fail(format!(
                        "{slot} on {name}: batch {actor_seq} arrived, {} expected (a transition was lost or doubled)",
                        out.next_actor_seq
                    ));
                    return Ok(());
                }
                publish_rows(out, self.real_consumers, &rows, meta)?;
            }
            Item::Stats { record, .. } => {
                if out.stats.subscribers() == 0 {
                    let wait = out.stats.wait_for_subscribers(1, Duration::from_secs(60));
                    wait.map_err(RuntimeError::from)?;
                }
                out.stats.send(&record).map_err(RuntimeError::from)?;
            }
            Item::ControlFrom { msg, .. } => {
                publish_control(out, self.control_subscribers, &msg)?;
            }
            Item::CheckpointFile {
                env_steps, bytes, ..
            } => {
                let dir = checkpoint::dir_for(&self.opts.service.run_dir, env_steps);
                write_atomically(&dir.join(slot.name()), &bytes)?;
                tracing::info!(
                    "checkpoint after step {env_steps}: wrote {slot}'s file from {name}"
                );
            }
            Item::SlotFailed { reason, .. } => {
                lock(&self.gate.state).fail(format!("{slot} on {name} failed: {reason}"));
            }
            Item::Log { text, .. } => {
                let dir = self.opts.service.run_dir.join("logs").join(sanitize(name));
                append(&dir, &format!("{slot}.log"), &text)?;
            }
            Item::Control { .. } | Item::Finished | Item::Bye => unreachable!("handled before"),
        }
        Ok(())
    }
}

/// Publish one batch of an actor's rows (the first waits for every consumer of real
/// transitions, so nothing is lost).
fn publish_rows(
    out: &mut SlotOut,
    consumers: usize,
    rows: &[f32],
    meta: TransitionMeta,
) -> Result<(), GatewayError> {
    let Some(real) = &out.real else {
        return Err(GatewayError::Failed(format!(
            "{} sent real transitions, which its role does not publish",
            out.slot
        )));
    };
    if !out.consumers_ready {
        let wait = real.wait_for_subscribers(consumers, Duration::from_secs(120));
        wait.map_err(RuntimeError::from)?;
        out.consumers_ready = true;
    }
    real.send_rows(rows, meta).map_err(RuntimeError::from)?;
    out.next_actor_seq += 1;
    out.transitions += 1;
    Ok(())
}

/// Publish a control message of the slot's role (the first waits for every role's control
/// subscriber, as the role itself does on a single host).
fn publish_control(
    out: &mut SlotOut,
    subscribers: usize,
    msg: &ControlMsg,
) -> Result<(), GatewayError> {
    let Some(control) = &out.control else {
        return Err(GatewayError::Failed(format!(
            "{} sent a control message, which its role does not publish",
            out.slot
        )));
    };
    if !out.control_ready {
        let wait = control.wait_for_subscribers(subscribers, Duration::from_secs(120));
        wait.map_err(RuntimeError::from)?;
        out.control_ready = true;
    }
    control.send(msg).map_err(RuntimeError::from)?;
    Ok(())
}

/// Worker `from` acknowledged up to `next` (and, in a heartbeat, has weights up to
/// `weights`); false when it is not a member.
fn heard(gate: &Gate, from: u64, next: u64, weights: Option<u64>) -> bool {
    let mut st = lock(&gate.state);
    let Some(w) = st.workers.get_mut(&from) else {
        return false;
    };
    w.last_heard = Instant::now();
    if w.acked(next) > 0 {
        gate.space.notify_all();
    }
    if let (Some(v), Some(seen)) = (weights, st.weights_seen.get_mut(&from)) {
        seen.0 = seen.0.max(v);
    }
    true
}

/// How the gateway's attempt ends, and when `hosts.json` was last written.
#[derive(Default)]
struct Ends {
    finished_at: Option<Instant>,
    rolled_back_at: Option<Instant>,
    /// (workers when last written, when).
    account_written: Option<(usize, Instant)>,
}

impl Ends {
    /// Write `hosts.json` on a change of the workers and every [`HOSTS_REWRITE`].
    fn write_account_if_due(
        &mut self,
        st: &super::state::Shared,
        account: &HostsAccount,
        batches: &Batches,
    ) {
        let due = self.account_written.is_none_or(|(workers, at)| {
            workers != st.workers.len() || at.elapsed() >= HOSTS_REWRITE
        });
        if due && !st.workers.is_empty() {
            account.write_or_warn(st, batches);
            self.account_written = Some((st.workers.len(), Instant::now()));
        }
    }

    /// The run is over once every remote slot was told to stop: tell the workers, and end
    /// when each said Bye (its roles exited, its last data and logs are in; or after 10 s).
    /// A rollback: end once every worker has the Stop (they join the next attempt).
    fn reached(&mut self, gate: &Gate) -> Result<bool, GatewayError> {
        let mut st = lock(&gate.state);
        if st.all_stopped(StopReason::RunOver) && !st.finished_sent {
            for w in st.workers.values_mut() {
                w.send_item(Item::Finished)?;
            }
            st.finished_sent = true;
            self.finished_at = Some(Instant::now());
        }
        if st.all_stopped(StopReason::RollBack) {
            let t = *self.rolled_back_at.get_or_insert_with(Instant::now);
            let delivered = st.workers.values().all(|w| w.outstanding() == 0);
            if delivered || t.elapsed() > Duration::from_secs(5) {
                tracing::info!(
                    "the pipeline rolls back to its newest checkpoint: the gateway ends, the workers join the next attempt"
                );
                return Ok(true);
            }
        }
        let Some(t) = self.finished_at else {
            return Ok(false);
        };
        let all_bye = st.workers.keys().all(|w| st.said_bye.contains(w));
        if all_bye || t.elapsed() > Duration::from_secs(10) {
            if !all_bye {
                tracing::warn!("a worker did not say goodbye within 10 s");
            }
            tracing::info!("every remote role stopped: the gateway ends");
            return Ok(true);
        }
        Ok(false)
    }
}
