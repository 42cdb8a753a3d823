//! Small fixed-size messages: statistics ([`StatsRecord`], everyone -> supervisor) and control
//! ([`ControlMsg`], supervisor <-> everyone). Reliable like transitions: never dropped,
//! sequence-checked, validated.

use std::fmt::Debug;
use std::marker::PhantomData;
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::ZeroCopySend;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::Service;

use crate::error::{
    HeaderMismatch, PortCreateError, PublishError, ReceiveError, SequenceGap,
    WaitForSubscribersError,
};
use crate::names::{Channel, ProducerId, SCHEMA_VERSION};
use crate::reliable::{
    backpressure_handler, open_channel_events, pubsub_builder, PublisherSide, PublisherStats,
    SendReport, SeqTracker, SubscriberSide, SubscriberStats,
};
use crate::run::WireNode;
use crate::schema::{now_ns, ControlMsg, MsgHeader, StatsRecord};

mod sealed {
    pub trait Sealed {}
    impl Sealed for crate::schema::StatsRecord {}
    impl Sealed for crate::schema::ControlMsg {}
}

/// A fixed-size message type and the channel that carries it.
pub trait WireMessage: sealed::Sealed + Debug + Default + Copy + ZeroCopySend + 'static {
    /// The channel.
    const CHANNEL: Channel;
}

impl WireMessage for StatsRecord {
    const CHANNEL: Channel = Channel::Stats;
}
impl WireMessage for ControlMsg {
    const CHANNEL: Channel = Channel::Control;
}

type Factory<S, T> = PortFactory<S, T, MsgHeader>;

fn open_service<S: Service, T: WireMessage>(
    node: &WireNode<S>,
) -> Result<(String, Factory<S, T>), PortCreateError> {
    let name = T::CHANNEL.service_name(&node.run.run_id);
    let svc = pubsub_builder!(
        node,
        &name,
        T,
        MsgHeader,
        node.run.qos(T::CHANNEL),
        0,
        false
    );
    Ok((name, svc))
}

/// Publishes messages of type `T`.
#[derive(Debug)]
pub struct MsgPublisher<T: WireMessage, S: Service = iceoryx2::service::ipc::Service> {
    side: PublisherSide<S>,
    publisher: Publisher<S, T, MsgHeader>,
    svc: Factory<S, T>,
}

/// Publishes [`StatsRecord`]s.
pub type StatsPublisher<S = iceoryx2::service::ipc::Service> = MsgPublisher<StatsRecord, S>;
/// Publishes [`ControlMsg`]s.
pub type ControlPublisher<S = iceoryx2::service::ipc::Service> = MsgPublisher<ControlMsg, S>;
/// Receives [`StatsRecord`]s.
pub type StatsSubscriber<S = iceoryx2::service::ipc::Service> = MsgSubscriber<StatsRecord, S>;
/// Receives [`ControlMsg`]s.
pub type ControlSubscriber<S = iceoryx2::service::ipc::Service> = MsgSubscriber<ControlMsg, S>;

impl<T: WireMessage, S: Service> MsgPublisher<T, S> {
    /// A publisher on `T`'s channel.
    pub fn create(node: &WireNode<S>) -> Result<Self, PortCreateError> {
        let (name, svc) = open_service::<S, T>(node)?;
        let qos = node.run.qos(T::CHANNEL);
        let events = open_channel_events(node, &name, qos)?;
        let block = std::sync::Arc::new(crate::reliable::BlockState::default());
        let publisher = svc
            .publisher_builder()
            .max_loaned_samples(qos.max_loaned)
            .backpressure_strategy(iceoryx2::prelude::BackpressureStrategy::RetryUntilDelivered)
            .set_backpressure_handler(backpressure_handler::<S>(
                block.clone(),
                node.run.config.clone(),
                node.run.stall_timeout,
                name.clone(),
            ))
            .create()
            .map_err(|e| PortCreateError::iceoryx(&name, "creating the publisher", e))?;
        let side = PublisherSide::create(node, &name, &events, publisher.id().value(), qos, block)?;
        Ok(Self {
            side,
            publisher,
            svc,
        })
    }

    /// Send `msg` (blocks while a subscriber's queue is full).
    pub fn send(&self, msg: &T) -> Result<SendReport, PublishError> {
        let seq = self.side.take_seq();
        let mut sample = self
            .publisher
            .loan_uninit()
            .map_err(|e| PublishError::Loan {
                service: self.side.service.clone(),
                bytes: std::mem::size_of::<T>(),
                cause: format!("{e:?}"),
                hint: crate::error::hint_for(&format!("{e:?}")),
            })?;
        *sample.user_header_mut() = MsgHeader {
            run_hash: self.side.run_hash,
            seq,
            send_time_ns: now_ns(),
            schema_version: SCHEMA_VERSION,
            producer_id: self.side.producer.0,
        };
        let sample = sample.write_payload(*msg);
        let subscribers = self.svc.dynamic_config().number_of_subscribers();
        let started = Instant::now();
        let delivered = sample
            .send()
            .map_err(|e| self.side.send_failed(seq, e, started))?;
        let report = self.side.record(seq, delivered, subscribers);
        self.side.notify()?;
        Ok(report)
    }

    /// Block until `n` subscribers confirmed their connection.
    pub fn wait_for_subscribers(
        &self,
        n: usize,
        timeout: Duration,
    ) -> Result<usize, WaitForSubscribersError> {
        self.side.wait_for_acks(n, timeout, || {
            self.svc.dynamic_config().number_of_subscribers()
        })
    }
    /// Subscribers currently registered.
    pub fn subscribers(&self) -> usize {
        self.svc.dynamic_config().number_of_subscribers()
    }
    /// Counters.
    pub fn stats(&self) -> PublisherStats {
        self.side.stats()
    }
    pub(crate) fn side(&self) -> &PublisherSide<S> {
        &self.side
    }
}

impl<S: Service> MsgPublisher<StatsRecord, S> {
    /// Send one report ([`crate::stats::Stats`]) as its record.
    pub fn report(
        &self,
        stats: impl Into<crate::stats::Stats>,
    ) -> Result<SendReport, PublishError> {
        self.send(&stats.into().record())
    }
}

/// A received message with its header.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Received<T> {
    /// The validated header.
    pub header: MsgHeader,
    /// The message.
    pub msg: T,
    /// Messages from this producer lost right before this one, if any.
    pub gap: Option<SequenceGap>,
}

impl<T> Received<T> {
    /// The producer.
    pub fn producer(&self) -> ProducerId {
        ProducerId(self.header.producer_id)
    }
}

/// Receives messages of type `T`.
#[derive(Debug)]
pub struct MsgSubscriber<T: WireMessage, S: Service = iceoryx2::service::ipc::Service> {
    side: SubscriberSide<S>,
    subscriber: Subscriber<S, T, MsgHeader>,
    svc: Factory<S, T>,
    run_hash: u64,
    tracker: std::cell::RefCell<SeqTracker>,
    _t: PhantomData<T>,
}

impl<T: WireMessage, S: Service> MsgSubscriber<T, S> {
    /// A subscriber on `T`'s channel.
    pub fn create(node: &WireNode<S>) -> Result<Self, PortCreateError> {
        let (name, svc) = open_service::<S, T>(node)?;
        let qos = node.run.qos(T::CHANNEL);
        let events = open_channel_events(node, &name, qos)?;
        let subscriber = svc
            .subscriber_builder()
            .buffer_size(qos.buffer_size)
            .create()
            .map_err(|e| PortCreateError::iceoryx(&name, "creating the subscriber", e))?;
        let side = SubscriberSide::create(node, &name, &events)?;
        let me = Self {
            side,
            subscriber,
            svc,
            run_hash: node.run.run_hash,
            tracker: std::cell::RefCell::new(SeqTracker::new(T::CHANNEL)),
            _t: PhantomData,
        };
        me.refresh(true);
        Ok(me)
    }

    /// Connect to publishers that appeared since the last call and confirm to them (see
    /// [`crate::reliable`]). `receive` does this by itself (re-listing at most every 50 ms
    /// unless the number of publishers changed), and so does a [`crate::Waiter`] on wake-up;
    /// call it when the subscriber was created before a publisher that now waits for it in the
    /// same thread.
    pub fn update_connections(&self) {
        self.refresh(true)
    }

    pub(crate) fn refresh(&self, force: bool) {
        let dc = self.svc.dynamic_config();
        self.side.refresh(
            dc.number_of_publishers(),
            force,
            |ids| {
                dc.list_publishers(|p| {
                    ids.push(p.publisher_id.value());
                    iceoryx2::prelude::CallbackProgression::Continue
                })
            },
            || self.subscriber.update_connections(),
        );
    }

    /// The next message, or `None`.
    pub fn receive(&self) -> Result<Option<Received<T>>, ReceiveError> {
        self.refresh(false);
        let Some(sample) = self
            .subscriber
            .receive()
            .map_err(|e| ReceiveError::Iceoryx {
                service: self.side.service.clone(),
                cause: format!("{e:?}"),
            })?
        else {
            return Ok(None);
        };
        let h = *sample.user_header();
        let reason = if h.schema_version != SCHEMA_VERSION {
            Some(HeaderMismatch::Schema {
                expected: SCHEMA_VERSION,
                found: h.schema_version,
            })
        } else if h.run_hash != self.run_hash {
            Some(HeaderMismatch::Run {
                expected: self.run_hash,
                found: h.run_hash,
            })
        } else {
            None
        };
        if let Some(reason) = reason {
            self.tracker.borrow_mut().stats.rejected += 1;
            let err = ReceiveError::Rejected {
                channel: T::CHANNEL,
                producer: ProducerId(h.producer_id),
                seq: h.seq,
                reason,
            };
            tracing::warn!("{err}");
            return Err(err);
        }
        let gap = self
            .tracker
            .borrow_mut()
            .check(h.producer_id, sample.origin().value(), h.seq)?;
        Ok(Some(Received {
            header: h,
            msg: *sample.payload(),
            gap,
        }))
    }

    /// Publishers currently registered.
    pub fn publishers(&self) -> usize {
        self.svc.dynamic_config().number_of_publishers()
    }
    /// Counters.
    pub fn stats(&self) -> SubscriberStats {
        self.tracker.borrow().stats
    }
    pub(crate) fn side(&self) -> &SubscriberSide<S> {
        &self.side
    }
}
