//! Weight snapshots (`Policy` and `Model` channels) with "latest value" semantics.
//!
//! The service keeps a history of 1 and each subscriber a buffer of 1 with safe overflow, so a
//! publisher never blocks and a subscriber only ever sees the newest snapshot. A subscriber that
//! starts late gets the current snapshot as soon as the publisher updates its connections:
//! on its next publish, on [`WeightsPublisher::update_connections`], or at once when the
//! publisher sleeps in a [`crate::Waiter`] (the new subscriber's attach confirmation wakes it).

use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::AllocationStrategy;
use iceoryx2::sample::Sample;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::service::Service;

use crate::error::{HeaderMismatch, PortCreateError, PublishError, WeightsReceiveError};
use crate::names::{ProducerId, SCHEMA_VERSION};
use crate::ports::{PublisherPort, SubscriberPort};
use crate::reliable::{
    open_channel_events, pubsub_builder, PublisherSide, PublisherStats, SubscriberSide,
};
use crate::run::WireNode;
use crate::schema::{now_ns, WeightsCounters, WeightsHeader, WeightsKind};

type Factory<S> = PortFactory<S, [f32], WeightsHeader>;

fn open_service<S: Service>(
    node: &WireNode<S>,
    kind: WeightsKind,
) -> Result<(String, Factory<S>), PortCreateError> {
    let channel = kind.channel();
    let name = channel.service_name(&node.run.run_id);
    let mut qos = node.run.qos(channel);
    qos.buffer_size = qos.buffer_size.max(1);
    let svc = pubsub_builder!(node, &name, [f32], WeightsHeader, qos, 1, true);
    Ok((name, svc))
}

/// Publishes weight snapshots of one network.
#[derive(Debug)]
pub struct WeightsPublisher<S: Service = iceoryx2::service::ipc::Service> {
    port: PublisherPort<S, [f32], WeightsHeader>,
    kind: WeightsKind,
    layout_hash: u64,
    n_values: usize,
    version: std::cell::Cell<u64>,
}

impl<S: Service> WeightsPublisher<S> {
    /// A publisher of `kind` snapshots of `n_values` floats with parameter layout hash
    /// `layout_hash` (`mbpo_nn::ParamLayout::hash`).
    pub fn create(
        node: &WireNode<S>,
        kind: WeightsKind,
        layout_hash: u64,
        n_values: usize,
    ) -> Result<Self, PortCreateError> {
        if n_values == 0 {
            return Err(PortCreateError::InvalidArgument {
                what: "n_values",
                value: 0,
                hint: "a weight snapshot needs at least one value",
            });
        }
        let (name, svc) = open_service(node, kind)?;
        let qos = node.run.qos(kind.channel());
        let events = open_channel_events(node, &name, qos)?;
        let publisher = svc
            .publisher_builder()
            .initial_max_slice_len(n_values)
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
            .max_loaned_samples(qos.max_loaned)
            .create()
            .map_err(|e| PortCreateError::iceoryx(&name, "creating the publisher", e))?;
        Ok(Self {
            port: PublisherPort::new(
                node,
                &name,
                &events,
                qos,
                Default::default(),
                svc,
                publisher,
            )?,
            kind,
            layout_hash,
            n_values,
            version: std::cell::Cell::new(0),
        })
    }

    /// Publish `params` as `version` (must be greater than the previous one).
    pub fn publish(
        &self,
        params: &[f32],
        version: u64,
        counters: WeightsCounters,
    ) -> Result<(), PublishError> {
        if params.len() != self.n_values {
            return Err(PublishError::Invalid(format!(
                "{:?} snapshot has {} values, this publisher was created for {}",
                self.kind,
                params.len(),
                self.n_values
            )));
        }
        if version <= self.version.get() {
            return Err(PublishError::Invalid(format!(
                "{:?} version {version} is not greater than the last published version {}",
                self.kind,
                self.version.get()
            )));
        }
        let side = &self.port.side;
        let sample = self
            .port
            .publisher
            .loan_slice_uninit(params.len())
            .map_err(|e| side.loan_failed(params.len() * 4, e))?;
        let mut sample = sample.write_from_slice(params);
        *sample.user_header_mut() = WeightsHeader {
            run_hash: side.run_hash,
            version,
            layout_hash: self.layout_hash,
            n_values: params.len() as u64,
            env_steps: counters.env_steps,
            sac_updates: counters.sac_updates,
            model_trainings: counters.model_trainings,
            send_time_ns: now_ns(),
            schema_version: SCHEMA_VERSION,
            kind: self.kind as u32,
            producer_id: side.producer.0,
            reserved: 0,
        };
        self.port.deliver(sample, version)?;
        self.version.set(version);
        side.notify()
    }

    /// Deliver the current snapshot to subscribers that connected since the last publish.
    /// Call it from an idle loop if the publisher does not sleep in a [`crate::Waiter`].
    pub fn update_connections(&self) -> Result<(), PublishError> {
        self.port.side.poll_acks();
        self.port
            .publisher
            .update_connections()
            .map_err(|e| PublishError::Send {
                service: self.port.side.service.clone(),
                seq: self.version.get(),
                cause: format!("{e:?}"),
            })?;
        if self.version.get() > 0 {
            self.port.side.notify()?;
        }
        Ok(())
    }

    /// The last published version (0 before the first).
    pub fn version(&self) -> u64 {
        self.version.get()
    }
    /// Subscribers currently registered.
    pub fn subscribers(&self) -> usize {
        self.port.subscribers()
    }
    /// Block until `n` subscribers confirmed their connection.
    pub fn wait_for_subscribers(
        &self,
        n: usize,
        timeout: std::time::Duration,
    ) -> Result<usize, crate::WaitForSubscribersError> {
        self.port.wait_for_subscribers(n, timeout)
    }
    /// Counters.
    pub fn stats(&self) -> PublisherStats {
        self.port.side.stats()
    }
    pub(crate) fn side(&self) -> &PublisherSide<S> {
        &self.port.side
    }
    /// Take the confirmations that woke the port (connecting to the new subscribers); `true`
    /// when there were any.
    pub(crate) fn on_wake(&self) -> bool {
        let woken = self.port.side.poll_acks() > 0;
        if woken {
            if let Err(e) = self.update_connections() {
                tracing::warn!("{e}");
            }
        }
        woken
    }
}

/// A received snapshot: a zero-copy view of the parameters in shared memory.
#[derive(Debug)]
pub struct WeightsSnapshot<S: Service = iceoryx2::service::ipc::Service> {
    sample: Sample<S, [f32], WeightsHeader>,
}

impl<S: Service> WeightsSnapshot<S> {
    /// The validated header.
    pub fn header(&self) -> &WeightsHeader {
        self.sample.user_header()
    }
    /// The parameters.
    pub fn params(&self) -> &[f32] {
        self.sample.payload()
    }
    /// The version.
    pub fn version(&self) -> u64 {
        self.header().version
    }
}

/// Receives the newest weight snapshot of one network, validating kind, layout hash and length.
#[derive(Debug)]
pub struct WeightsSubscriber<S: Service = iceoryx2::service::ipc::Service> {
    port: SubscriberPort<S, [f32], WeightsHeader>,
    kind: WeightsKind,
    layout_hash: u64,
    n_values: usize,
    run_hash: u64,
    /// (publisher port, version) of the last snapshot returned.
    last: std::cell::Cell<Option<(u128, u64)>>,
}

impl<S: Service> WeightsSubscriber<S> {
    /// A subscriber of `kind` snapshots that must have `layout_hash` and `n_values` floats.
    pub fn create(
        node: &WireNode<S>,
        kind: WeightsKind,
        layout_hash: u64,
        n_values: usize,
    ) -> Result<Self, PortCreateError> {
        let (name, svc) = open_service(node, kind)?;
        let events = open_channel_events(node, &name, node.run.qos(kind.channel()))?;
        let subscriber = svc
            .subscriber_builder()
            .buffer_size(1)
            .history_request(1)
            .create()
            .map_err(|e| PortCreateError::iceoryx(&name, "creating the subscriber", e))?;
        Ok(Self {
            port: SubscriberPort::new(node, &name, &events, svc, subscriber)?,
            kind,
            layout_hash,
            n_values,
            run_hash: node.run.run_hash,
            last: std::cell::Cell::new(None),
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

    fn validate(&self, h: &WeightsHeader, payload: usize) -> Result<(), HeaderMismatch> {
        check_weights_header(
            h,
            payload,
            self.run_hash,
            self.kind,
            self.layout_hash,
            self.n_values,
        )
    }

    /// The newest snapshot if it is newer than the last one returned, else `None`. A
    /// restarted publisher (new port) may start again from any version.
    pub fn receive_latest(&self) -> Result<Option<WeightsSnapshot<S>>, WeightsReceiveError> {
        let mut newest = None;
        while let Some(sample) = self.port.receive()? {
            let h = *sample.user_header();
            if let Err(reason) = self.validate(&h, sample.payload().len()) {
                let err = WeightsReceiveError::Rejected {
                    kind: self.kind,
                    version: h.version,
                    reason,
                };
                tracing::warn!(producer = %ProducerId(h.producer_id), "{err}");
                return Err(err);
            }
            let origin = sample.origin().value();
            let newer = match self.last.get() {
                Some((o, v)) if o == origin => h.version > v,
                _ => true,
            };
            if newer {
                newest = Some(sample);
            }
        }
        Ok(newest.map(|sample| {
            self.last.set(Some((
                sample.origin().value(),
                sample.user_header().version,
            )));
            WeightsSnapshot { sample }
        }))
    }

    /// Like [`WeightsSubscriber::receive_latest`], copying the parameters into `dst`.
    pub fn receive_latest_into(
        &self,
        dst: &mut [f32],
    ) -> Result<Option<WeightsHeader>, WeightsReceiveError> {
        if dst.len() != self.n_values {
            return Err(WeightsReceiveError::Destination {
                dst: dst.len(),
                len: self.n_values,
            });
        }
        Ok(self.receive_latest()?.map(|s| {
            dst.copy_from_slice(s.params());
            *s.header()
        }))
    }

    /// Times this port listed the registered publishers: the only step of a receive that
    /// allocates once connected (inside iceoryx2; at most every 50 ms, none per sample).
    pub fn publisher_relists(&self) -> u64 {
        self.port.side.relists()
    }
    /// Version of the last snapshot returned (0 before the first).
    pub fn last_version(&self) -> u64 {
        self.last.get().map_or(0, |(_, v)| v)
    }
    pub(crate) fn side(&self) -> &SubscriberSide<S> {
        &self.port.side
    }
}

/// Validate a weights header (and its payload length, in floats) against what a subscriber
/// expects.
pub fn check_weights_header(
    h: &WeightsHeader,
    payload: usize,
    run_hash: u64,
    kind: WeightsKind,
    layout_hash: u64,
    n_values: usize,
) -> Result<(), HeaderMismatch> {
    HeaderMismatch::check_schema_and_run(h.schema_version, h.run_hash, run_hash)?;
    if h.kind != kind as u32 {
        return Err(HeaderMismatch::Kind {
            expected: kind as u32,
            found: h.kind,
        });
    }
    if h.layout_hash != layout_hash {
        return Err(HeaderMismatch::Layout {
            expected: layout_hash,
            found: h.layout_hash,
        });
    }
    if h.n_values != n_values as u64 || payload != n_values {
        return Err(HeaderMismatch::Length {
            announced: h.n_values,
            payload: payload as u64,
        });
    }
    Ok(())
}

/// Policy versions cross the wire shifted by one ([`WeightsPublisher`] versions start at 1,
/// policy versions at 0 = the initial parameters).
pub fn policy_wire_version(version: u64) -> u64 {
    version + 1
}

/// The policy version of a wire version (see [`policy_wire_version`]).
pub fn policy_version_of(wire_version: u64) -> u64 {
    wire_version.saturating_sub(1)
}
