//! Small fixed-size messages: statistics ([`StatsRecord`], everyone -> supervisor) and control
//! ([`ControlMsg`], supervisor <-> everyone). Reliable like transitions: never dropped,
//! sequence-checked, validated.

use std::fmt::Debug;
use std::time::Duration;

use iceoryx2::prelude::ZeroCopySend;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::service::Service;

use crate::error::{
    HeaderMismatch, PortCreateError, PublishError, ReceiveError, SequenceGap,
    WaitForSubscribersError,
};
use crate::names::{Channel, ProducerId, SCHEMA_VERSION};
use crate::ports::{PublisherPort, SubscriberPort};
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
    port: PublisherPort<S, T, MsgHeader>,
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
        let port = PublisherPort::new(node, &name, &events, qos, block, svc, publisher)?;
        Ok(Self { port })
    }

    /// Send `msg` (blocks while a subscriber's queue is full).
    pub fn send(&self, msg: &T) -> Result<SendReport, PublishError> {
        let side = &self.port.side;
        let seq = side.take_seq();
        let mut sample = self
            .port
            .publisher
            .loan_uninit()
            .map_err(|e| side.loan_failed(std::mem::size_of::<T>(), e))?;
        *sample.user_header_mut() = MsgHeader {
            run_hash: side.run_hash,
            seq,
            send_time_ns: now_ns(),
            schema_version: SCHEMA_VERSION,
            producer_id: side.producer.0,
        };
        let report = self.port.deliver(sample.write_payload(*msg), seq)?;
        side.notify()?;
        Ok(report)
    }

    /// Block until `n` subscribers confirmed their connection.
    pub fn wait_for_subscribers(
        &self,
        n: usize,
        timeout: Duration,
    ) -> Result<usize, WaitForSubscribersError> {
        self.port.wait_for_subscribers(n, timeout)
    }
    /// Subscribers currently registered.
    pub fn subscribers(&self) -> usize {
        self.port.subscribers()
    }
    /// Counters.
    pub fn stats(&self) -> PublisherStats {
        self.port.side.stats()
    }
    pub(crate) fn side(&self) -> &PublisherSide<S> {
        &self.port.side
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
    port: SubscriberPort<S, T, MsgHeader>,
    run_hash: u64,
    tracker: std::cell::RefCell<SeqTracker>,
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
        Ok(Self {
            port: SubscriberPort::new(node, &name, &events, svc, subscriber)?,
            run_hash: node.run.run_hash,
            tracker: std::cell::RefCell::new(SeqTracker::new(T::CHANNEL)),
        })
    }

    /// Connect to new publishers and confirm to them now, as
    /// [`crate::TransitionSubscriber::update_connections`] does.
    pub fn update_connections(&self) {
        self.refresh(true)
    }

    pub(crate) fn refresh(&self, force: bool) {
        self.port.refresh(force)
    }

    /// The next message, or `None`.
    pub fn receive(&self) -> Result<Option<Received<T>>, ReceiveError> {
        let Some(sample) = self.port.receive()? else {
            return Ok(None);
        };
        let h = *sample.user_header();
        if let Err(reason) =
            HeaderMismatch::check_schema_and_run(h.schema_version, h.run_hash, self.run_hash)
        {
            return Err(self
                .tracker
                .borrow_mut()
                .reject(h.producer_id, h.seq, reason));
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
        self.port.publishers()
    }
    /// Counters.
    pub fn stats(&self) -> SubscriberStats {
        self.tracker.borrow().stats
    }
    pub(crate) fn side(&self) -> &SubscriberSide<S> {
        &self.port.side
    }
}
