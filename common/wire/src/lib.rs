//! Everything that crosses shared memory between MBPO processes, and the only crate that
//! imports iceoryx2.
//!
//! * [`names`]: the services of a run (`mbpo/<run>/real`, `.../imagined`, `.../policy`,
//!   `.../model`, `.../stats`, `.../control`), roles, producer ids, [`SCHEMA_VERSION`].
//! * [`stats`]: what the services report to the coordinator ([`Stats`], named fields) and the
//!   one place that maps it onto the fixed-size [`StatsRecord`].
//! * [`model_layout`]: a model snapshot as one flat `[f32]` ([`ModelWireLayout`]).
//! * [`schema`]: the `#[repr(C)]` headers and payloads ([`TransitionHeader`], [`WeightsHeader`],
//!   [`MsgHeader`], [`StatsRecord`], [`ControlMsg`]) and the transition [`RowLayout`]
//!   (`[obs, act, reward, next_obs, terminated]`) with allocation-free conversions to and from
//!   [`mbpo_core::Batch`] / [`mbpo_core::ReplayBuffer`].
//! * [`run`]: [`RunIpc`], one iceoryx2 configuration per run (own `global.prefix` and root path),
//!   nodes, stale-resource cleanup and full removal at the end.
//! * Ports, one error enum per operation ([`error`]):
//!   - [`TransitionPublisher`] / [`TransitionSubscriber`]: reliable; a full subscriber blocks the
//!     publisher (sleeping, not spinning); every header validated; per-producer sequence numbers
//!     checked and gaps reported as [`SequenceGap`] values and counters.
//!   - [`WeightsPublisher`] / [`WeightsSubscriber`]: latest-value snapshots; late subscribers get
//!     the current one.
//!   - [`StatsPublisher`] / [`StatsSubscriber`], [`ControlPublisher`] / [`ControlSubscriber`]:
//!     reliable fixed-size messages.
//! * [`Waiter`]: sleep until any attached port has news, a deadline passes or SIGINT/SIGTERM.
//! * [`bench`](mod@bench): throughput and latency measurements (`cargo run --release -p mbpo-wire --example ipc_bench`).
//!
//! All ports are generic over the iceoryx2 service type: [`ipc::Service`] between processes
//! (the default), [`local::Service`] for single-process tests. Ports are not `Send`: create them
//! on the thread that uses them. Their methods take `&self`, so a port can stay attached to a
//! [`Waiter`] while it is used.
//!
//! ```no_run
//! use std::time::Duration;
//! use mbpo_wire::*;
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let run = RunIpc::new("pendulum-s1", "/tmp/mbpo-ipc")?;
//! run.remove_stale_nodes::<ipc::Service>()?;            // a crashed predecessor's leftovers
//! let node = run.node::<ipc::Service>(Role::Learner, 0)?;
//! let layout = RowLayout::new(3, 1);
//! let real = TransitionSubscriber::create(&node, Channel::Real, layout)?;
//! let policy = WeightsPublisher::create(&node, WeightsKind::Policy, 0xfeed, 1234)?;
//! let mut d_env = mbpo_core::ReplayBuffer::new(3, 1, 1_000_000);
//! let mut waiter = Waiter::new()?;
//! waiter.attach(&real).attach(&policy);
//! while waiter.wait(Duration::from_secs(1))? != WaitOutcome::Terminate {
//!     real.drain_into(&mut d_env)?;
//!     // ... SAC updates, then policy.publish(&params, version, counters)?
//! }
//! # Ok(()) }
//! ```
#![warn(missing_docs)]

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

pub mod bench;
pub mod error;
pub mod messages;
pub mod model_layout;
pub mod names;
mod ports;
pub mod reliable;
pub mod run;
pub mod schema;
pub mod stats;
pub mod transitions;
pub mod waiter;
pub mod weights;

pub use error::{
    CleanupError, DecodeError, HeaderMismatch, NodeCreateError, PortCreateError, PublishError,
    ReceiveError, RunIpcError, SequenceGap, WaitError, WaitForSubscribersError, WaiterCreateError,
    WeightsReceiveError,
};
pub use messages::{
    ControlPublisher, ControlSubscriber, MsgPublisher, MsgSubscriber, Received, StatsPublisher,
    StatsSubscriber, WireMessage,
};
pub use model_layout::ModelWireLayout;
pub use names::{Channel, ProducerId, Role, SCHEMA_VERSION};
pub use reliable::{PublisherStats, SendReport, SubscriberStats};
pub use run::{run_hash, ChannelQos, RunIpc, StaleCleanup, WireNode};
pub use schema::{
    ControlCommand, ControlMsg, MsgHeader, RowLayout, RowRef, StatsKind, StatsRecord, StopReason,
    TransitionHeader, WeightsCounters, WeightsHeader, WeightsKind, CONTROL_TARGET_ALL,
};
pub use stats::{
    BarrierReport, Done, EnvFailed, EpisodeEnd, EvalResult, LearnerRow, ModelTrained,
    ModelTraining, PacingPart, Progress, RolloutBranch, SlackTracker, Stats, PACING_PART_BINS,
};
pub use transitions::{
    DrainReport, RowLoan, TransitionBatch, TransitionMeta, TransitionPublisher,
    TransitionSubscriber,
};
pub use waiter::{Transport, WaitOutcome, Waiter, Wakeable};
pub use weights::{
    policy_version_of, policy_wire_version, WeightsPublisher, WeightsSnapshot, WeightsSubscriber,
};

/// The iceoryx2 service types, so services can name them without importing iceoryx2.
pub use iceoryx2::service::{ipc, ipc_threadsafe, local, Service};

static TERMINATION: AtomicBool = AtomicBool::new(false);

/// True once SIGINT or SIGTERM has been received by this process.
///
/// iceoryx2 captures both signals once a node exists ([`RunIpc::node`]), so they no longer kill
/// the process: services must check this (or sleep in a [`Waiter`], which returns
/// [`WaitOutcome::Terminate`]) and exit. iceoryx2 reports a signal only once; this function
/// remembers it, so every caller sees it.
pub fn termination_requested() -> bool {
    if termination_latched() {
        return true;
    }
    // An empty WaitSet reports a pending termination request before anything else.
    let seen = iceoryx2::prelude::WaitSetBuilder::new()
        .create::<local::Service>()
        .map(|ws| {
            matches!(
                ws.wait_and_process_once_with_timeout(
                    |_| iceoryx2::prelude::CallbackProgression::Continue,
                    Duration::ZERO
                ),
                Ok(iceoryx2::waitset::WaitSetRunResult::TerminationRequest)
            )
        })
        .unwrap_or(false);
    if seen {
        latch_termination();
    }
    seen
}

/// Forget a SIGINT/SIGTERM seen so far (returns whether there was one), so that [`Waiter`]s
/// sleep again and the next signal is reported anew: the supervisor answers the first signal
/// with a checkpoint and a clean stop, which takes a while, and a second one with a hard stop.
pub fn take_termination_request() -> bool {
    TERMINATION.swap(false, Ordering::Relaxed)
}

pub(crate) fn termination_latched() -> bool {
    TERMINATION.load(Ordering::Relaxed)
}

pub(crate) fn latch_termination() {
    TERMINATION.store(true, Ordering::Relaxed);
}
