//! Transition batches (`Real` and `Imagined` channels): reliable, validated, sequence-checked.
//!
//! ```no_run
//! use mbpo_wire::{Channel, RowLayout, RunIpc, Role, TransitionMeta};
//! use mbpo_wire::ipc::Service as Ipc;
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let run = RunIpc::new("pendulum-s1", "/tmp/mbpo-ipc")?;
//! let node = run.node::<Ipc>(Role::Actor, 0)?;
//! let layout = RowLayout::new(3, 1);
//! let tx = mbpo_wire::TransitionPublisher::create(&node, Channel::Real, layout, 1000)?;
//! tx.wait_for_subscribers(3, std::time::Duration::from_secs(30))?;
//! let batch = mbpo_core::Batch::new(3, 1, 1000);
//! tx.send_batch(&batch, TransitionMeta { policy_version: 7, model_version: 0, env_steps: 1000 })?;
//! # Ok(()) }
//! ```

use std::mem::MaybeUninit;
use std::time::Duration;

use iceoryx2::prelude::AllocationStrategy;
use iceoryx2::sample::Sample;
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::sample_mut_uninit::SampleMutUninit;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use iceoryx2::service::Service;
use mbpo_core::{Batch, ReplayBuffer, TransitionSink};

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
use crate::schema::{now_ns, RowLayout, RowRef, TransitionHeader};

type Factory<S> = PortFactory<S, [f32], TransitionHeader>;

fn check_channel(channel: Channel) -> Result<(), PortCreateError> {
    match channel {
        Channel::Real | Channel::Imagined => Ok(()),
        _ => Err(PortCreateError::WrongChannel {
            channel,
            what: "transition batches",
            expected: "Channel::Real or Channel::Imagined",
        }),
    }
}

fn open_service<S: Service>(
    node: &WireNode<S>,
    channel: Channel,
) -> Result<(String, Factory<S>), PortCreateError> {
    check_channel(channel)?;
    let name = channel.service_name(&node.run.run_id);
    let qos = node.run.qos(channel);
    let svc = pubsub_builder!(node, &name, [f32], TransitionHeader, qos, 0, false);
    Ok((name, svc))
}

/// Versions and counters stamped on a batch.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct TransitionMeta {
    /// Policy version that chose the actions (0: uniform warm-up).
    pub policy_version: u64,
    /// Model version that produced the rows (0: real environment).
    pub model_version: u64,
    /// Producer's env-step counter after the last row.
    pub env_steps: u64,
}

/// Publishes transition batches; never drops them (blocks while a subscriber's queue is full).
#[derive(Debug)]
pub struct TransitionPublisher<S: Service = iceoryx2::service::ipc::Service> {
    port: PublisherPort<S, [f32], TransitionHeader>,
    channel: Channel,
    layout: RowLayout,
    layout_hash: u64,
}

impl<S: Service> TransitionPublisher<S> {
    /// A publisher of rows with `layout` on `channel` (`Real` or `Imagined`). `typical_rows`
    /// sizes the first shared-memory segment; larger batches grow it (power-of-two segments).
    pub fn create(
        node: &WireNode<S>,
        channel: Channel,
        layout: RowLayout,
        typical_rows: usize,
    ) -> Result<Self, PortCreateError> {
        if layout.obs_dim == 0 || layout.act_dim == 0 || layout.obs_dim > u32::MAX as usize / 4 {
            return Err(PortCreateError::InvalidArgument {
                what: "row layout",
                value: layout.obs_dim as u64,
                hint: "obs_dim and act_dim must be positive",
            });
        }
        let (name, svc) = open_service(node, channel)?;
        let qos = node.run.qos(channel);
        let events = open_channel_events(node, &name, qos)?;
        let block = std::sync::Arc::new(crate::reliable::BlockState::default());
        let publisher = svc
            .publisher_builder()
            .initial_max_slice_len(typical_rows.max(1) * layout.width())
            .allocation_strategy(AllocationStrategy::PowerOfTwo)
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
        Ok(Self {
            port: PublisherPort::new(node, &name, &events, qos, block, svc, publisher)?,
            channel,
            layout,
            layout_hash: layout.hash(),
        })
    }

    /// Block until `n` subscribers have confirmed that they are connected (so nothing sent
    /// afterwards can be lost for them), sleeping on an event; returns the confirmations seen.
    pub fn wait_for_subscribers(
        &self,
        n: usize,
        timeout: Duration,
    ) -> Result<usize, WaitForSubscribersError> {
        self.port.wait_for_subscribers(n, timeout)
    }

    /// Subscribers currently registered with the service.
    pub fn subscribers(&self) -> usize {
        self.port.subscribers()
    }

    /// Send every row of `batch`.
    pub fn send_batch(
        &self,
        batch: &Batch,
        meta: TransitionMeta,
    ) -> Result<SendReport, PublishError> {
        self.send_batch_rows(batch, 0, batch.len, meta)
    }

    /// Send rows `start..start + n` of `batch` (no allocation: rows are written straight into
    /// shared memory).
    pub fn send_batch_rows(
        &self,
        batch: &Batch,
        start: usize,
        n: usize,
        meta: TransitionMeta,
    ) -> Result<SendReport, PublishError> {
        if (batch.obs_dim, batch.act_dim) != (self.layout.obs_dim, self.layout.act_dim) {
            return Err(PublishError::Invalid(format!(
                "batch has obs_dim {} / act_dim {}, this publisher sends {} / {}",
                batch.obs_dim, batch.act_dim, self.layout.obs_dim, self.layout.act_dim
            )));
        }
        if start + n > batch.len {
            return Err(PublishError::Invalid(format!(
                "rows {start}..{} out of a batch of {}",
                start + n,
                batch.len
            )));
        }
        let layout = self.layout;
        self.send_with_uninit(n, meta, |dst| pack_uninit(&layout, batch, start, dst))
    }

    /// Send rows already laid out as `[obs, act, reward, next_obs, terminated]`.
    pub fn send_rows(
        &self,
        rows: &[f32],
        meta: TransitionMeta,
    ) -> Result<SendReport, PublishError> {
        let Some(n) = self.layout.rows_in(rows.len()) else {
            return Err(PublishError::Invalid(format!(
                "{} floats are not a whole number of {}-float rows",
                rows.len(),
                self.layout.width()
            )));
        };
        self.send_with_uninit(n, meta, |dst| {
            for (d, s) in dst.iter_mut().zip(rows) {
                d.write(*s);
            }
        })
    }

    /// Send `n_rows` rows written in place by `fill` (the slice is zeroed first; use
    /// [`RowLayout::write_row`] on `chunks_exact_mut(width)`).
    pub fn send_with(
        &self,
        n_rows: usize,
        meta: TransitionMeta,
        fill: impl FnOnce(&mut [f32]),
    ) -> Result<SendReport, PublishError> {
        let mut sample = self.loan_zeroed(n_rows)?;
        fill(sample.payload_mut());
        self.send_sample(sample, n_rows, meta)
    }

    fn send_with_uninit(
        &self,
        n_rows: usize,
        meta: TransitionMeta,
        fill: impl FnOnce(&mut [MaybeUninit<f32>]),
    ) -> Result<SendReport, PublishError> {
        let mut sample = self.loan_uninit(n_rows)?;
        fill(sample.payload_mut());
        // SAFETY: `fill` initialised every element (all helpers above write the whole slice).
        let sample = unsafe { sample.assume_init() };
        self.send_sample(sample, n_rows, meta)
    }

    /// Room for `n_rows` rows in shared memory, uninitialised.
    fn loan_uninit(
        &self,
        n_rows: usize,
    ) -> Result<SampleMutUninit<S, [MaybeUninit<f32>], TransitionHeader>, PublishError> {
        if n_rows > u32::MAX as usize {
            return Err(PublishError::Invalid(format!(
                "{n_rows} rows exceed u32::MAX"
            )));
        }
        let len = n_rows * self.layout.width();
        self.port
            .publisher
            .loan_slice_uninit(len)
            .map_err(|e| self.port.side.loan_failed(len * 4, e))
    }

    /// Loan room for `n_rows` rows in shared memory, to be written in place through
    /// [`TransitionSink`] and then [`RowLoan::send`]: an actor's env step writes its transition
    /// straight into the sample it publishes (no staging copy). A loan dropped unsent sends
    /// nothing and takes no sequence number.
    pub fn loan_rows(&self, n_rows: usize) -> Result<RowLoan<'_, S>, PublishError> {
        Ok(RowLoan {
            publisher: self,
            sample: self.loan_zeroed(n_rows)?,
            n_rows,
            written: 0,
        })
    }

    /// Room for `n_rows` rows in shared memory, zeroed.
    fn loan_zeroed(
        &self,
        n_rows: usize,
    ) -> Result<SampleMut<S, [f32], TransitionHeader>, PublishError> {
        let mut sample = self.loan_uninit(n_rows)?;
        for d in sample.payload_mut().iter_mut() {
            d.write(0.0);
        }
        // SAFETY: every element was just initialised.
        Ok(unsafe { sample.assume_init() })
    }

    fn send_sample(
        &self,
        mut sample: SampleMut<S, [f32], TransitionHeader>,
        n_rows: usize,
        meta: TransitionMeta,
    ) -> Result<SendReport, PublishError> {
        let side = &self.port.side;
        let seq = side.take_seq();
        *sample.user_header_mut() = TransitionHeader {
            run_hash: side.run_hash,
            seq,
            policy_version: meta.policy_version,
            model_version: meta.model_version,
            env_steps: meta.env_steps,
            layout_hash: self.layout_hash,
            send_time_ns: now_ns(),
            schema_version: SCHEMA_VERSION,
            producer_id: side.producer.0,
            stream: self.channel.tag(),
            n_rows: n_rows as u32,
            obs_dim: self.layout.obs_dim as u32,
            act_dim: self.layout.act_dim as u32,
        };
        let report = self.port.deliver(sample, seq)?;
        side.notify()?;
        Ok(report)
    }

    /// The sequence number the next batch will carry.
    pub fn next_seq(&self) -> u64 {
        self.port.side.next_seq.get()
    }
    /// The row layout.
    pub fn layout(&self) -> RowLayout {
        self.layout
    }
    /// The channel.
    pub fn channel(&self) -> Channel {
        self.channel
    }
    /// Counters.
    pub fn stats(&self) -> PublisherStats {
        self.port.side.stats()
    }
    pub(crate) fn side(&self) -> &PublisherSide<S> {
        &self.port.side
    }
}

fn pack_uninit(layout: &RowLayout, batch: &Batch, start: usize, dst: &mut [MaybeUninit<f32>]) {
    let (o, a, w) = (layout.obs_dim, layout.act_dim, layout.width());
    #[inline(always)]
    fn put(dst: &mut [MaybeUninit<f32>], src: &[f32]) {
        for (d, s) in dst.iter_mut().zip(src) {
            d.write(*s);
        }
    }
    for (i, row) in dst.chunks_exact_mut(w).enumerate() {
        let r = start + i;
        put(&mut row[..o], &batch.obs[r * o..(r + 1) * o]);
        put(&mut row[o..o + a], &batch.act[r * a..(r + 1) * a]);
        row[o + a].write(batch.reward[r]);
        put(
            &mut row[o + a + 1..2 * o + a + 1],
            &batch.next_obs[r * o..(r + 1) * o],
        );
        row[2 * o + a + 1].write(if batch.terminated[r] != 0.0 { 1.0 } else { 0.0 });
    }
}

/// Receives transition batches, validating every header and tracking sequence numbers.
#[derive(Debug)]
pub struct TransitionSubscriber<S: Service = iceoryx2::service::ipc::Service> {
    max_borrowed: usize,
    port: SubscriberPort<S, [f32], TransitionHeader>,
    channel: Channel,
    layout: RowLayout,
    layout_hash: u64,
    run_hash: u64,
    tracker: std::cell::RefCell<SeqTracker>,
}

/// Rows loaned from a [`TransitionPublisher`] ([`TransitionPublisher::loan_rows`]), filled
/// in place one [`TransitionSink::push`] per row.
pub struct RowLoan<'p, S: Service> {
    publisher: &'p TransitionPublisher<S>,
    sample: SampleMut<S, [f32], TransitionHeader>,
    n_rows: usize,
    written: usize,
}

impl<S: Service> TransitionSink for RowLoan<'_, S> {
    /// Write the next row; rows past the loaned number are ignored ([`RowLoan::send`] then
    /// refuses, as it does with rows missing).
    fn push(&mut self, obs: &[f32], act: &[f32], reward: f32, next_obs: &[f32], terminated: bool) {
        let layout = self.publisher.layout;
        let w = layout.width();
        let i = self.written;
        self.written += 1;
        if i < self.n_rows {
            let row = &mut self.sample.payload_mut()[i * w..(i + 1) * w];
            layout.write_row(row, obs, act, reward, next_obs, terminated);
        }
    }
}

impl<S: Service> RowLoan<'_, S> {
    /// Publish the rows, once exactly the loaned number was written.
    pub fn send(self, meta: TransitionMeta) -> Result<SendReport, PublishError> {
        if self.written != self.n_rows {
            return Err(PublishError::Invalid(format!(
                "{} rows written into a loan of {}",
                self.written, self.n_rows
            )));
        }
        self.publisher.send_sample(self.sample, self.n_rows, meta)
    }
}

/// A received batch: a zero-copy view of the rows in shared memory. Drop it (or let it go out
/// of scope) promptly: a subscriber may hold only `max_borrowed` batches at once.
#[derive(Debug)]
pub struct TransitionBatch<S: Service = iceoryx2::service::ipc::Service> {
    sample: Sample<S, [f32], TransitionHeader>,
    layout: RowLayout,
    gap: Option<SequenceGap>,
}

impl<S: Service> TransitionBatch<S> {
    /// The validated header.
    pub fn header(&self) -> &TransitionHeader {
        self.sample.user_header()
    }
    /// The rows, `n_rows * width` floats.
    pub fn rows(&self) -> &[f32] {
        self.sample.payload()
    }
    /// Number of rows.
    pub fn n_rows(&self) -> usize {
        self.header().n_rows as usize
    }
    /// Row `i` as fields.
    pub fn row(&self, i: usize) -> RowRef<'_> {
        let w = self.layout.width();
        self.layout.split_row(&self.rows()[i * w..(i + 1) * w])
    }
    /// The producer.
    pub fn producer(&self) -> ProducerId {
        ProducerId(self.header().producer_id)
    }
    /// Messages from this producer that were lost right before this one, if any (also counted
    /// in [`TransitionSubscriber::stats`]).
    pub fn gap(&self) -> Option<SequenceGap> {
        self.gap
    }
    /// Push rows `from..` into `sink` in order (no allocation).
    pub fn push_rows_from(&self, from: usize, n: usize, sink: &mut dyn TransitionSink) {
        let w = self.layout.width();
        self.layout
            .push_rows(&self.rows()[from * w..(from + n) * w], sink)
    }
    /// Copy the rows into `out` (no allocation once `out` is large enough).
    pub fn to_batch(&self, out: &mut Batch) {
        self.layout.unpack_into(self.rows(), out)
    }
    /// Append the rows to `buf` in order.
    pub fn push_into(&self, buf: &mut ReplayBuffer) {
        self.layout.push_into(self.rows(), buf)
    }
}

/// What [`TransitionSubscriber::drain_into`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct DrainReport {
    /// Batches pushed.
    pub batches: usize,
    /// Rows pushed.
    pub rows: usize,
    /// Gaps seen among them.
    pub gaps: usize,
    /// Largest env-step counter seen.
    pub max_env_steps: u64,
    /// Largest policy version seen.
    pub max_policy_version: u64,
}

impl<S: Service> TransitionSubscriber<S> {
    /// A subscriber of rows with `layout` on `channel`. Connects to existing publishers and
    /// confirms to them before returning.
    pub fn create(
        node: &WireNode<S>,
        channel: Channel,
        layout: RowLayout,
    ) -> Result<Self, PortCreateError> {
        let (name, svc) = open_service(node, channel)?;
        let qos = node.run.qos(channel);
        let events = open_channel_events(node, &name, qos)?;
        let subscriber = svc
            .subscriber_builder()
            .buffer_size(qos.buffer_size)
            .create()
            .map_err(|e| PortCreateError::iceoryx(&name, "creating the subscriber", e))?;
        Ok(Self {
            max_borrowed: qos.max_borrowed,
            port: SubscriberPort::new(node, &name, &events, svc, subscriber)?,
            channel,
            layout,
            layout_hash: layout.hash(),
            run_hash: node.run.run_hash,
            tracker: std::cell::RefCell::new(SeqTracker::new(channel)),
        })
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
        self.port.refresh(force)
    }

    /// The next batch, or `None` when nothing is pending. A batch whose header does not match
    /// this port is released and reported as [`ReceiveError::Rejected`]; keep calling to get
    /// the following ones.
    pub fn receive(&self) -> Result<Option<TransitionBatch<S>>, ReceiveError> {
        let Some(sample) = self.port.receive()? else {
            return Ok(None);
        };
        let h = *sample.user_header();
        if let Err(reason) = check_header(
            &h,
            sample.payload().len(),
            self.run_hash,
            self.channel,
            self.layout,
            self.layout_hash,
        ) {
            return Err(self
                .tracker
                .borrow_mut()
                .reject(h.producer_id, h.seq, reason));
        }
        let gap = self
            .tracker
            .borrow_mut()
            .check(h.producer_id, sample.origin().value(), h.seq)?;
        Ok(Some(TransitionBatch {
            sample,
            layout: self.layout,
            gap,
        }))
    }

    /// Push every pending batch into `buf` (no allocation). Stops at the first error; batches
    /// before it have been pushed, the offending one is dropped.
    pub fn drain_into(&self, buf: &mut ReplayBuffer) -> Result<DrainReport, ReceiveError> {
        let mut r = DrainReport::default();
        while let Some(b) = self.receive()? {
            b.push_into(buf);
            r.batches += 1;
            r.rows += b.n_rows();
            r.gaps += b.gap().is_some() as usize;
            r.max_env_steps = r.max_env_steps.max(b.header().env_steps);
            r.max_policy_version = r.max_policy_version.max(b.header().policy_version);
        }
        Ok(r)
    }

    /// Publishers currently registered with the service.
    pub fn publishers(&self) -> usize {
        self.port.publishers()
    }
    /// Batches this port may hold at once (received and not yet dropped).
    pub fn max_borrowed(&self) -> usize {
        self.max_borrowed
    }
    /// Whether a batch is waiting to be received.
    pub fn has_pending(&self) -> Result<bool, ReceiveError> {
        Ok(self.port.has_samples()?)
    }
    /// Times this port listed the registered publishers: the only step of a receive that
    /// allocates once connected (inside iceoryx2; at most every 50 ms, none per sample).
    pub fn publisher_relists(&self) -> u64 {
        self.port.side.relists()
    }
    /// Counters: received, rejected, gaps, missing, restarts.
    pub fn stats(&self) -> SubscriberStats {
        self.tracker.borrow().stats
    }
    /// The row layout.
    pub fn layout(&self) -> RowLayout {
        self.layout
    }
    pub(crate) fn side(&self) -> &SubscriberSide<S> {
        &self.port.side
    }
}

/// Validate a transition header against what a subscriber expects.
pub fn check_header(
    h: &TransitionHeader,
    payload: usize,
    run_hash: u64,
    channel: Channel,
    layout: RowLayout,
    layout_hash: u64,
) -> Result<(), HeaderMismatch> {
    HeaderMismatch::check_schema_and_run(h.schema_version, h.run_hash, run_hash)?;
    if h.stream != channel.tag() {
        return Err(HeaderMismatch::Stream {
            expected: channel.tag(),
            found: h.stream,
            channel,
        });
    }
    if (h.obs_dim as usize, h.act_dim as usize) != (layout.obs_dim, layout.act_dim) {
        return Err(HeaderMismatch::Dims {
            expected_obs: layout.obs_dim as u32,
            expected_act: layout.act_dim as u32,
            found_obs: h.obs_dim,
            found_act: h.act_dim,
        });
    }
    if h.layout_hash != layout_hash {
        return Err(HeaderMismatch::Layout {
            expected: layout_hash,
            found: h.layout_hash,
        });
    }
    let announced = h.n_rows as u64 * layout.width() as u64;
    if announced != payload as u64 {
        return Err(HeaderMismatch::Length {
            announced,
            payload: payload as u64,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn good() -> TransitionHeader {
        let l = RowLayout::new(3, 1);
        TransitionHeader {
            run_hash: 7,
            layout_hash: l.hash(),
            schema_version: SCHEMA_VERSION,
            stream: Channel::Real.tag(),
            n_rows: 2,
            obs_dim: 3,
            act_dim: 1,
            ..Default::default()
        }
    }

    fn check(h: TransitionHeader, payload: usize) -> Result<(), HeaderMismatch> {
        check_header(
            &h,
            payload,
            7,
            Channel::Real,
            RowLayout::new(3, 1),
            RowLayout::new(3, 1).hash(),
        )
    }

    #[test]
    fn every_header_field_is_checked() {
        assert_eq!(check(good(), 18), Ok(()));
        let e = check(
            TransitionHeader {
                schema_version: 99,
                ..good()
            },
            18,
        );
        assert!(matches!(
            e,
            Err(HeaderMismatch::Schema {
                expected: SCHEMA_VERSION,
                found: 99
            })
        ));
        let e = check(
            TransitionHeader {
                run_hash: 8,
                ..good()
            },
            18,
        );
        assert!(matches!(
            e,
            Err(HeaderMismatch::Run {
                expected: 7,
                found: 8
            })
        ));
        let e = check(
            TransitionHeader {
                stream: Channel::Imagined.tag(),
                ..good()
            },
            18,
        );
        assert!(matches!(e, Err(HeaderMismatch::Stream { .. })));
        let e = check(
            TransitionHeader {
                act_dim: 2,
                ..good()
            },
            18,
        );
        assert!(matches!(e, Err(HeaderMismatch::Dims { found_act: 2, .. })));
        let e = check(
            TransitionHeader {
                layout_hash: 1,
                ..good()
            },
            18,
        );
        assert!(matches!(e, Err(HeaderMismatch::Layout { found: 1, .. })));
        let e = check(good(), 17);
        assert!(matches!(
            e,
            Err(HeaderMismatch::Length {
                announced: 18,
                payload: 17
            })
        ));
        // The messages name the problem.
        let msg = check(
            TransitionHeader {
                schema_version: 2,
                ..good()
            },
            18,
        )
        .unwrap_err()
        .to_string();
        assert!(
            msg.contains("schema version 2") && msg.contains("rebuild"),
            "{msg}"
        );
    }
}
