//! The machinery shared by all ports: event services, the attach handshake, blocking
//! backpressure that sleeps, and per-producer sequence tracking.
//!
//! # Why an attach handshake
//!
//! With `enable_safe_overflow(false)` and blocking backpressure, iceoryx2 0.10 blocks a publisher
//! on a full subscriber queue *only once the subscriber has attached to the connection*, which it
//! does inside `update_connections()` (called by `receive()`). A subscriber created before the
//! publisher that is busy elsewhere has not attached yet: the publisher fills its queue and then
//! silently drops samples for it (measured: 4 of 50 delivered). So every publisher owns a small
//! event service `<service>/attach/<publisher id>`; a subscriber, after `update_connections()`,
//! notifies the attach service of every publisher it has just connected to. A publisher's
//! [`wait_for_subscribers`](crate::TransitionPublisher::wait_for_subscribers) counts those
//! confirmations, so its first send happens only after the consumers are truly connected.
//! Subscribers created *after* a publisher attach in their constructor, so later consumers are
//! safe too; and every publisher creates a notifier on the channel's event service, which
//! wakes sleeping subscribers (a "publisher created" event) so they connect and confirm.
//!
//! The consequence to keep in mind: a subscriber created *before* a publisher confirms only
//! when its process runs wire code (`receive`, `drain_into`, a [`crate::Waiter`] wake-up, or
//! `update_connections`). A consumer busy for minutes delays the producer's
//! `wait_for_subscribers` by as long — which is the backpressure we want. In a single thread
//! that creates the subscriber first, call `update_connections()` before waiting.
//! `wait_for_subscribers(n)` counts confirmations since the publisher was created (a
//! subscriber that confirmed and then left still counts).
//!
//! # Backpressure without burning a core
//!
//! iceoryx2's `RetryUntilDelivered` spins through 10 000 `sched_yield`s before it sleeps. The
//! publishers here install a backpressure handler that sleeps itself (20 µs doubling to 1 ms)
//! and retries, so a blocked publisher costs almost no CPU. While blocked it also
//! * checks for SIGINT/SIGTERM every ~20 ms and gives up with [`PublishError::Terminated`],
//! * removes the resources of dead nodes every ~1 s, so a crashed subscriber does not block
//!   its publishers for ever,
//! * warns once after 10 s, and gives up after the run's stall timeout if one is set.

use std::cell::{Cell, RefCell};
use std::collections::HashMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use iceoryx2::node::{Node, NodeState};
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::update_connections::ConnectionFailure;
use iceoryx2::port::{BackpressureAction, BackpressureInfo};
use iceoryx2::prelude::{CallbackProgression, EventId, ServiceName};
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use iceoryx2::service::Service;

use crate::error::{
    HeaderMismatch, PortCreateError, PublishError, ReceiveError, SequenceGap,
    WaitForSubscribersError,
};
use crate::names::{attach_service_name, Channel, ProducerId};
use crate::run::{ChannelQos, WireNode};

/// Event id a publisher sends after every sample.
pub(crate) const EV_DATA: usize = 0;
/// Event id iceoryx2 sends when a publisher's notifier is created.
pub(crate) const EV_PUBLISHER_CREATED: usize = 1;
/// Event id iceoryx2 sends when a publisher's notifier is dropped.
pub(crate) const EV_PUBLISHER_DROPPED: usize = 2;
/// Event id iceoryx2 sends when a publisher's node is found dead.
pub(crate) const EV_PUBLISHER_DEAD: usize = 3;
/// Largest event id used on the channel event services.
const EVENT_ID_MAX: usize = 7;
/// How often a subscriber re-lists publishers even when their number did not change.
///
/// The re-list is the one place the steady-state receive path allocates: iceoryx2 0.10's
/// `list_publishers` builds a snapshot of the publisher container (two small blocks per call,
/// measured). At this period that is at most 40 re-lists a second per subscriber, none per
/// sample; `tests/no_alloc.rs` checks that nothing else allocates.
const REFRESH_PERIOD: Duration = Duration::from_millis(50);

pub(crate) fn service_name(name: &str) -> Result<ServiceName, PortCreateError> {
    ServiceName::new(name)
        .map_err(|e| PortCreateError::iceoryx(name, "building the service name", e))
}

/// Open or create the event service paired with a channel's publish-subscribe service.
pub(crate) fn open_channel_events<S: Service>(
    node: &WireNode<S>,
    name: &str,
    qos: ChannelQos,
) -> Result<EventFactory<S>, PortCreateError> {
    let ports = qos.max_publishers + qos.max_subscribers + 4;
    node.node
        .service_builder(&service_name(name)?)
        .event()
        .max_notifiers(ports)
        .max_listeners(ports)
        .max_nodes(qos.max_nodes + 4)
        .event_id_max_value(EVENT_ID_MAX)
        .notifier_created_event(EventId::new(EV_PUBLISHER_CREATED))
        .notifier_dropped_event(EventId::new(EV_PUBLISHER_DROPPED))
        .notifier_dead_event(EventId::new(EV_PUBLISHER_DEAD))
        .open_or_create()
        .map_err(|e| PortCreateError::iceoryx(name, "opening the event service", e))
}

/// Configure a publish-subscribe builder from a [`ChannelQos`] (works for slices and sized types).
macro_rules! pubsub_builder {
    ($node:expr, $name:expr, $payload:ty, $header:ty, $qos:expr, $history:expr, $overflow:expr) => {{
        let q: $crate::run::ChannelQos = $qos;
        $node
            .node
            .service_builder(&$crate::reliable::service_name($name)?)
            .publish_subscribe::<$payload>()
            .user_header::<$header>()
            .max_publishers(q.max_publishers)
            .max_subscribers(q.max_subscribers)
            .max_nodes(q.max_nodes)
            .subscriber_max_buffer_size(q.buffer_size)
            .subscriber_max_borrowed_samples(q.max_borrowed)
            .history_size($history)
            .enable_safe_overflow($overflow)
            .open_or_create()
            .map_err(|e| {
                $crate::error::PortCreateError::iceoryx(
                    $name,
                    "opening the publish-subscribe service",
                    e,
                )
            })?
    }};
}
pub(crate) use pubsub_builder;

/// State shared between a publisher and its backpressure handler.
#[derive(Debug, Default)]
pub(crate) struct BlockState {
    pub terminated: AtomicBool,
    pub stalled: AtomicBool,
    pub episodes: AtomicU64,
    pub blocked_ns: AtomicU64,
    warned: AtomicBool,
    last_probe_ns: AtomicU64,
    last_cleanup_ns: AtomicU64,
}

/// The backpressure handler of reliable publishers (see the module docs).
pub(crate) fn backpressure_handler<S: Service>(
    block: Arc<BlockState>,
    config: iceoryx2::config::Config,
    stall_timeout: Option<Duration>,
    service: String,
) -> impl Fn(&BackpressureInfo) -> BackpressureAction + Send + 'static {
    move |info: &BackpressureInfo| {
        let elapsed = info.elapsed_time;
        let elapsed_ns = elapsed.as_nanos() as u64;
        if info.retries == 0 {
            block.episodes.fetch_add(1, Ordering::Relaxed);
            block.warned.store(false, Ordering::Relaxed);
            block.last_probe_ns.store(0, Ordering::Relaxed);
            block.last_cleanup_ns.store(0, Ordering::Relaxed);
        }
        let nap = Duration::from_micros(20u64 << info.retries.min(6)).min(Duration::from_millis(1));
        std::thread::sleep(nap);
        block
            .blocked_ns
            .fetch_add(nap.as_nanos() as u64, Ordering::Relaxed);

        if elapsed_ns.saturating_sub(block.last_probe_ns.load(Ordering::Relaxed)) >= 20_000_000 {
            block.last_probe_ns.store(elapsed_ns, Ordering::Relaxed);
            if crate::termination_requested() {
                block.terminated.store(true, Ordering::Relaxed);
                return BackpressureAction::DiscardDataAndFail;
            }
        }
        if elapsed_ns.saturating_sub(block.last_cleanup_ns.load(Ordering::Relaxed)) >= 1_000_000_000
        {
            block.last_cleanup_ns.store(elapsed_ns, Ordering::Relaxed);
            remove_dead_nodes::<S>(&config);
        }
        if elapsed >= Duration::from_secs(10) && !block.warned.swap(true, Ordering::Relaxed) {
            tracing::warn!(
                service = %service,
                waited = ?elapsed,
                "publisher blocked: a subscriber has not taken data for 10 s (backpressure); still waiting"
            );
        }
        if let Some(t) = stall_timeout {
            if elapsed >= t {
                block.stalled.store(true, Ordering::Relaxed);
                return BackpressureAction::DiscardDataAndFail;
            }
        }
        BackpressureAction::Retry
    }
}

/// Remove the resources of dead nodes (a crashed subscriber keeps its full queue attached).
fn remove_dead_nodes<S: Service>(config: &iceoryx2::config::Config) {
    let mut dead = Vec::new();
    let _ = Node::<S>::list(config, |state| {
        if let NodeState::Dead(view) = state {
            dead.push(view);
        }
        CallbackProgression::Continue
    });
    for view in dead {
        if let Err(e) = view.try_remove_stale_resources() {
            tracing::debug!(error = ?e, "removing a dead node's resources failed");
        }
    }
}

/// Counters of a publisher.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct PublisherStats {
    /// Samples sent.
    pub sent: u64,
    /// Sends that reached fewer subscribers than were registered (a subscriber was not
    /// connected yet, or left); see [`SendReport::delivered`].
    pub short_deliveries: u64,
    /// Times a send blocked on a full subscriber.
    pub blocked: u64,
    /// Total time spent blocked, nanoseconds.
    pub blocked_ns: u64,
    /// Subscriber connection confirmations received.
    pub attach_confirmations: u64,
}

/// Outcome of one send.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SendReport {
    /// Sequence number stamped on the sample.
    pub seq: u64,
    /// Subscribers the sample was delivered to.
    pub delivered: usize,
    /// Subscribers registered with the service at send time.
    pub subscribers: usize,
}

/// The publisher half shared by all publishers: wake-up notifier, attach listener, counters.
#[derive(Debug)]
pub(crate) struct PublisherSide<S: Service> {
    pub service: String,
    pub producer: ProducerId,
    pub run_hash: u64,
    notifier: Notifier<S>,
    attach_listener: Listener<S>,
    _attach_service: EventFactory<S>,
    acks: Cell<u64>,
    pub next_seq: Cell<u64>,
    pub block: Arc<BlockState>,
    pub stats: Cell<PublisherStats>,
}

impl<S: Service> PublisherSide<S> {
    /// Call right after the iceoryx2 publisher `publisher_id` exists: creates its attach
    /// service, then the notifier (whose creation wakes sleeping subscribers).
    pub fn create(
        node: &WireNode<S>,
        service: &str,
        events: &EventFactory<S>,
        publisher_id: u128,
        qos: ChannelQos,
        block: Arc<BlockState>,
    ) -> Result<Self, PortCreateError> {
        let attach_name = attach_service_name(service, publisher_id);
        let attach_service = node
            .node
            .service_builder(&service_name(&attach_name)?)
            .event()
            .max_notifiers(qos.max_subscribers + 4)
            .max_listeners(2)
            .max_nodes(qos.max_nodes + 4)
            .create()
            .map_err(|e| {
                PortCreateError::iceoryx(&attach_name, "creating the attach service", e)
            })?;
        let attach_listener = attach_service.listener_builder().create().map_err(|e| {
            PortCreateError::iceoryx(&attach_name, "creating the attach listener", e)
        })?;
        let notifier = events
            .notifier_builder()
            .default_event_id(EventId::new(EV_DATA))
            .create()
            .map_err(|e| PortCreateError::iceoryx(service, "creating the notifier", e))?;
        Ok(Self {
            service: service.to_string(),
            producer: node.producer,
            run_hash: node.run.run_hash,
            notifier,
            attach_listener,
            _attach_service: attach_service,
            acks: Cell::new(0),
            next_seq: Cell::new(0),
            block,
            stats: Cell::new(PublisherStats::default()),
        })
    }

    /// The attach listener, for the [`crate::Waiter`].
    pub fn listener(&self) -> &Listener<S> {
        &self.attach_listener
    }

    /// Consume attach confirmations; returns how many arrived.
    pub fn poll_acks(&self) -> u64 {
        let mut n = 0;
        let _ = self.attach_listener.try_wait(|a| n += a.count);
        if n > 0 {
            self.acks.set(self.acks.get() + n);
        }
        n
    }

    /// Confirmations received so far.
    pub fn acks(&self) -> u64 {
        self.poll_acks();
        self.acks.get()
    }

    /// Block (sleeping on the attach listener) until `n` subscribers confirmed.
    pub fn wait_for_acks(
        &self,
        n: usize,
        timeout: Duration,
        registered: impl Fn() -> usize,
    ) -> Result<usize, WaitForSubscribersError> {
        let start = Instant::now();
        loop {
            let confirmed = self.acks() as usize;
            if confirmed >= n {
                return Ok(confirmed);
            }
            if crate::termination_requested() {
                return Err(WaitForSubscribersError::Terminated(self.service.clone()));
            }
            let waited = start.elapsed();
            if waited >= timeout {
                return Err(WaitForSubscribersError::Timeout {
                    service: self.service.clone(),
                    wanted: n,
                    confirmed,
                    registered: registered(),
                    waited,
                });
            }
            // Sleep on the listener; wake at least every 20 ms to check for signals.
            let slice = (timeout - waited).min(Duration::from_millis(20));
            let mut got = 0;
            self.attach_listener
                .timed_wait(|a| got += a.count, slice)
                .map_err(|e| WaitForSubscribersError::Listener {
                    service: self.service.clone(),
                    cause: format!("{e:?}"),
                })?;
            self.acks.set(self.acks.get() + got);
        }
    }

    /// Take the next sequence number.
    pub fn take_seq(&self) -> u64 {
        let s = self.next_seq.get();
        self.next_seq.set(s + 1);
        s
    }

    /// Wake the listeners after a send.
    pub fn notify(&self) -> Result<(), PublishError> {
        self.notifier
            .notify()
            .map(|_| ())
            .map_err(|e| PublishError::Notify {
                service: self.service.clone(),
                cause: format!("{e:?}"),
            })
    }

    /// Map a failed send, telling a termination or stall apart from iceoryx2 errors.
    pub fn send_failed(
        &self,
        seq: u64,
        cause: impl std::fmt::Debug,
        started: Instant,
    ) -> PublishError {
        if self.block.terminated.swap(false, Ordering::Relaxed) {
            PublishError::Terminated {
                service: self.service.clone(),
                seq,
            }
        } else if self.block.stalled.swap(false, Ordering::Relaxed) {
            PublishError::Stalled {
                service: self.service.clone(),
                seq,
                waited: started.elapsed(),
            }
        } else {
            PublishError::Send {
                service: self.service.clone(),
                seq,
                cause: format!("{cause:?}"),
            }
        }
    }

    /// Map a failed loan of `bytes` bytes of shared memory.
    pub fn loan_failed(&self, bytes: usize, cause: impl std::fmt::Debug) -> PublishError {
        let cause = format!("{cause:?}");
        PublishError::Loan {
            service: self.service.clone(),
            bytes,
            hint: crate::error::hint_for(&cause),
            cause,
        }
    }

    /// Record a successful send.
    pub fn record(&self, seq: u64, delivered: usize, subscribers: usize) -> SendReport {
        let mut st = self.stats.get();
        st.sent += 1;
        if delivered < subscribers {
            st.short_deliveries += 1;
            tracing::warn!(
                service = %self.service, seq, delivered, subscribers,
                "sample reached fewer subscribers than are registered (a subscriber is not connected yet or just left)"
            );
        }
        self.stats.set(st);
        SendReport {
            seq,
            delivered,
            subscribers,
        }
    }

    /// Counters, including the backpressure ones.
    pub fn stats(&self) -> PublisherStats {
        let mut st = self.stats.get();
        st.blocked = self.block.episodes.load(Ordering::Relaxed);
        st.blocked_ns = self.block.blocked_ns.load(Ordering::Relaxed);
        st.attach_confirmations = self.acks();
        st
    }
}

/// The subscriber half shared by all subscribers: wake-up listener and attach confirmations.
#[derive(Debug)]
pub(crate) struct SubscriberSide<S: Service> {
    node: Arc<Node<S>>,
    pub service: String,
    listener: Listener<S>,
    /// Publisher ports this subscriber has confirmed to.
    confirmed: RefCell<Vec<u128>>,
    /// Publisher ports whose attach service could not be opened yet.
    pending: Cell<bool>,
    last_count: Cell<usize>,
    next_refresh: Cell<Instant>,
    publisher_created: Cell<bool>,
    /// Reused list of publisher ids (no allocation in steady state).
    ids: RefCell<Vec<u128>>,
    /// Times the publishers were listed (see [`REFRESH_PERIOD`]).
    relists: Cell<u64>,
}

impl<S: Service> SubscriberSide<S> {
    pub fn create(
        node: &WireNode<S>,
        service: &str,
        events: &EventFactory<S>,
    ) -> Result<Self, PortCreateError> {
        let listener = events
            .listener_builder()
            .create()
            .map_err(|e| PortCreateError::iceoryx(service, "creating the listener", e))?;
        Ok(Self {
            node: node.node.clone(),
            service: service.to_string(),
            listener,
            confirmed: RefCell::new(Vec::new()),
            pending: Cell::new(false),
            last_count: Cell::new(usize::MAX),
            next_refresh: Cell::new(Instant::now()),
            publisher_created: Cell::new(false),
            ids: RefCell::new(Vec::new()),
            relists: Cell::new(0),
        })
    }

    /// Times this subscriber listed the registered publishers (the only allocating step of a
    /// receive once connected; see [`REFRESH_PERIOD`]).
    pub fn relists(&self) -> u64 {
        self.relists.get()
    }

    /// The wake-up listener, for the [`crate::Waiter`].
    pub fn listener(&self) -> &Listener<S> {
        &self.listener
    }

    /// Consume pending wake-ups; remembers whether a publisher appeared. `true` when there was
    /// one.
    pub fn consume_events(&self) -> bool {
        let mut created = false;
        let pending = self.listener.try_wait(|a| {
            if a.id.as_value() == EV_PUBLISHER_CREATED {
                created = true;
            }
        });
        if created {
            self.publisher_created.set(true);
        }
        pending.is_ok_and(|n| n > 0)
    }

    /// Connect to new publishers and confirm to them, when anything may have changed.
    /// `list` fills the ids of the registered publishers; `update` is the port's
    /// `update_connections`.
    pub fn refresh(
        &self,
        publishers: usize,
        force: bool,
        list: impl FnOnce(&mut Vec<u128>),
        update: impl FnOnce() -> Result<(), ConnectionFailure>,
    ) {
        let now = Instant::now();
        let due = force
            || publishers != self.last_count.get()
            || self.publisher_created.replace(false)
            || now >= self.next_refresh.get();
        if !due {
            return;
        }
        self.last_count.set(publishers);
        self.next_refresh.set(now + REFRESH_PERIOD);
        // List first, then connect: every listed publisher is connected after `update`.
        let mut ids = self.ids.borrow_mut();
        ids.clear();
        list(&mut ids);
        self.relists.set(self.relists.get() + 1);
        if let Err(e) = update() {
            tracing::warn!(service = %self.service, error = ?e, "connecting to a publisher failed; retrying at the next receive");
            return;
        }
        let mut confirmed = self.confirmed.borrow_mut();
        confirmed.retain(|c| ids.contains(c));
        let mut pending = false;
        for &id in ids.iter() {
            if confirmed.contains(&id) {
                continue;
            }
            if self.confirm(id) {
                confirmed.push(id);
            } else {
                pending = true;
            }
        }
        self.pending.set(pending);
    }

    /// Tell publisher `id` that this subscriber is connected.
    fn confirm(&self, id: u128) -> bool {
        let name = attach_service_name(&self.service, id);
        let Ok(sn) = ServiceName::new(&name) else {
            return false;
        };
        // The attach service appears right after the publisher registers; until then, retry.
        let Ok(svc) = self.node.service_builder(&sn).event().open() else {
            return false;
        };
        // The publisher creates its attach listener right after the attach service: a
        // notification that reached no listener is not a confirmation; retry it.
        match svc.notifier_builder().create() {
            Ok(n) => matches!(n.notify(), Ok(listeners) if listeners > 0),
            Err(_) => false,
        }
    }
}

/// Per-producer sequence tracking of a reliable subscriber.
#[derive(Debug)]
pub(crate) struct SeqTracker {
    channel: Channel,
    /// producer id -> (publisher port, next expected sequence number)
    next: HashMap<u32, (u128, u64)>,
    pub stats: SubscriberStats,
}

/// Counters of a reliable subscriber.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct SubscriberStats {
    /// Samples accepted.
    pub received: u64,
    /// Samples rejected (header mismatch or sequence regression).
    pub rejected: u64,
    /// Gaps seen (each is reported once as a [`SequenceGap`]).
    pub gaps: u64,
    /// Messages missing in those gaps.
    pub missing: u64,
    /// Publisher ports seen for a producer id that already had one (process restarts).
    pub restarts: u64,
}

impl SeqTracker {
    pub fn new(channel: Channel) -> Self {
        Self {
            channel,
            next: HashMap::new(),
            stats: SubscriberStats::default(),
        }
    }

    /// Count and log a sample from `producer` numbered `seq` whose header did not validate;
    /// the error to return for it.
    pub fn reject(&mut self, producer: u32, seq: u64, reason: HeaderMismatch) -> ReceiveError {
        self.stats.rejected += 1;
        let err = ReceiveError::Rejected {
            channel: self.channel,
            producer: ProducerId(producer),
            seq,
            reason,
        };
        tracing::warn!("{err}");
        err
    }

    /// Check `seq` from `producer` via publisher port `origin`.
    pub fn check(
        &mut self,
        producer: u32,
        origin: u128,
        seq: u64,
    ) -> Result<Option<SequenceGap>, ReceiveError> {
        let channel = self.channel;
        let pid = ProducerId(producer);
        let (expected, first_contact) = match self.next.get(&producer) {
            Some(&(o, next)) if o == origin => (next, false),
            Some(_) => {
                self.stats.restarts += 1;
                (0, true)
            }
            None => (0, true),
        };
        if seq < expected {
            self.stats.rejected += 1;
            return Err(ReceiveError::SequenceRegression {
                channel,
                producer: pid,
                expected,
                got: seq,
            });
        }
        self.next.insert(producer, (origin, seq + 1));
        self.stats.received += 1;
        if seq > expected {
            let gap = SequenceGap {
                channel,
                producer: pid,
                expected,
                got: seq,
                missing: seq - expected,
                first_contact,
            };
            self.stats.gaps += 1;
            self.stats.missing += gap.missing;
            tracing::warn!("{gap}");
            return Ok(Some(gap));
        }
        Ok(None)
    }
}
