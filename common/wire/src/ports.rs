//! The iceoryx2 publish-subscribe port under each typed port of this crate (messages,
//! transition batches, weight snapshots), joined with its half of the attach handshake
//! ([`crate::reliable`]). Connecting to new publishers and confirming to them, receiving,
//! counting peers and delivering a loaned sample are written here once; the typed ports add
//! only their headers, their checks and their sequence or version rules.

use std::fmt::Debug;
use std::sync::Arc;
use std::time::{Duration, Instant};

use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::{CallbackProgression, IceoryxSend, ZeroCopySend};
use iceoryx2::sample::Sample;
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::service::port_factory::event::PortFactory as EventFactory;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::Service;

use crate::error::{IceoryxFailure, PortCreateError, PublishError, WaitForSubscribersError};
use crate::reliable::{BlockState, PublisherSide, SendReport, SubscriberSide};
use crate::run::{ChannelQos, WireNode};

/// A subscriber with its service (to list the publishers) and its half of the handshake.
#[derive(Debug)]
pub(crate) struct SubscriberPort<
    S: Service,
    P: IceoryxSend + Debug + ?Sized + 'static,
    H: Debug + ZeroCopySend,
> {
    pub side: SubscriberSide<S>,
    subscriber: Subscriber<S, P, H>,
    svc: PortFactory<S, P, H>,
}

impl<S: Service, P: IceoryxSend + Debug + ?Sized + 'static, H: Debug + ZeroCopySend>
    SubscriberPort<S, P, H>
{
    /// Wrap `subscriber`, just created on `svc` (the service `name`, whose event service is
    /// `events`), and connect to the publishers already registered, confirming to them.
    pub fn new(
        node: &WireNode<S>,
        name: &str,
        events: &EventFactory<S>,
        svc: PortFactory<S, P, H>,
        subscriber: Subscriber<S, P, H>,
    ) -> Result<Self, PortCreateError> {
        let side = SubscriberSide::create(node, name, events)?;
        let port = Self {
            side,
            subscriber,
            svc,
        };
        port.refresh(true);
        Ok(port)
    }

    /// Connect to publishers that appeared and confirm to them: always when `force`, else
    /// when anything may have changed ([`SubscriberSide::refresh`]).
    pub fn refresh(&self, force: bool) {
        let dc = self.svc.dynamic_config();
        self.side.refresh(
            dc.number_of_publishers(),
            force,
            |ids| {
                dc.list_publishers(|p| {
                    ids.push(p.publisher_id.value());
                    CallbackProgression::Continue
                })
            },
            || self.subscriber.update_connections(),
        );
    }

    /// The next sample, or `None`; connects to new publishers first.
    pub fn receive(&self) -> Result<Option<Sample<S, P, H>>, IceoryxFailure>
    where
        Subscriber<S, P, H>: ReceiveSample<S, P, H>,
    {
        self.refresh(false);
        self.subscriber
            .receive_sample()
            .map_err(|e| self.failure(e))
    }

    /// Whether a sample is waiting.
    pub fn has_samples(&self) -> Result<bool, IceoryxFailure> {
        self.subscriber.has_samples().map_err(|e| self.failure(e))
    }

    /// Publishers currently registered with the service.
    pub fn publishers(&self) -> usize {
        self.svc.dynamic_config().number_of_publishers()
    }

    fn failure(&self, cause: impl Debug) -> IceoryxFailure {
        IceoryxFailure {
            service: self.side.service.clone(),
            cause: format!("{cause:?}"),
        }
    }
}

/// iceoryx2 receives a value and a slice through two inherent methods of one name
/// (`Subscriber::receive`); this trait lets [`SubscriberPort::receive`] call either.
pub(crate) trait ReceiveSample<
    S: Service,
    P: IceoryxSend + Debug + ?Sized + 'static,
    H: Debug + ZeroCopySend,
>
{
    fn receive_sample(&self) -> Result<Option<Sample<S, P, H>>, iceoryx2::port::ReceiveError>;
}

impl<S: Service, T: IceoryxSend + Debug, H: Debug + ZeroCopySend> ReceiveSample<S, T, H>
    for Subscriber<S, T, H>
{
    fn receive_sample(&self) -> Result<Option<Sample<S, T, H>>, iceoryx2::port::ReceiveError> {
        self.receive()
    }
}

impl<S: Service, T: ZeroCopySend + Debug, H: Debug + ZeroCopySend> ReceiveSample<S, [T], H>
    for Subscriber<S, [T], H>
{
    fn receive_sample(&self) -> Result<Option<Sample<S, [T], H>>, iceoryx2::port::ReceiveError> {
        self.receive()
    }
}

/// A publisher with its service (to count the subscribers) and its half of the handshake.
#[derive(Debug)]
pub(crate) struct PublisherPort<
    S: Service,
    P: IceoryxSend + Debug + ?Sized + 'static,
    H: Debug + ZeroCopySend,
> {
    pub side: PublisherSide<S>,
    pub publisher: Publisher<S, P, H>,
    svc: PortFactory<S, P, H>,
}

impl<S: Service, P: IceoryxSend + Debug + ?Sized + 'static, H: Debug + ZeroCopySend>
    PublisherPort<S, P, H>
{
    /// Wrap `publisher`, just created on `svc` (the service `name`, whose event service is
    /// `events`; `block` is its backpressure handler's state): creates the attach service and
    /// the notifier that wakes sleeping subscribers ([`PublisherSide::create`]).
    pub fn new(
        node: &WireNode<S>,
        name: &str,
        events: &EventFactory<S>,
        qos: ChannelQos,
        block: Arc<BlockState>,
        svc: PortFactory<S, P, H>,
        publisher: Publisher<S, P, H>,
    ) -> Result<Self, PortCreateError> {
        let side = PublisherSide::create(node, name, events, publisher.id().value(), qos, block)?;
        Ok(Self {
            side,
            publisher,
            svc,
        })
    }

    /// Subscribers currently registered with the service.
    pub fn subscribers(&self) -> usize {
        self.svc.dynamic_config().number_of_subscribers()
    }

    /// Block until `n` subscribers have confirmed that they are connected, sleeping on the
    /// attach listener; returns the confirmations seen.
    pub fn wait_for_subscribers(
        &self,
        n: usize,
        timeout: Duration,
    ) -> Result<usize, WaitForSubscribersError> {
        self.side.wait_for_acks(n, timeout, || self.subscribers())
    }

    /// Send `sample`, numbered `seq`, and count its delivery (blocking while a subscriber's
    /// queue is full, as the service's backpressure says). The subscribers are not woken yet:
    /// call [`PublisherSide::notify`] once the port's own state is updated.
    pub fn deliver(
        &self,
        sample: SampleMut<S, P, H>,
        seq: u64,
    ) -> Result<SendReport, PublishError> {
        let subscribers = self.subscribers();
        let started = Instant::now();
        let delivered = sample
            .send()
            .map_err(|e| self.side.send_failed(seq, e, started))?;
        Ok(self.side.record(seq, delivered, subscribers))
    }
}
