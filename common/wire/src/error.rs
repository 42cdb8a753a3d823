//! One error enum per operation. Messages say what went wrong and what to do about it.

use std::time::Duration;

use crate::names::{Channel, ProducerId};

/// Why a [`crate::RunIpc`] could not be set up.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RunIpcError {
    /// The run id cannot be used in service names and paths.
    #[error("run id {0:?} is not usable: use 1 to 64 characters from [A-Za-z0-9_.-], not starting with '.'")]
    InvalidRunId(String),
    /// The root path would make iceoryx2's unix-socket paths too long (Linux allows 107 bytes).
    #[error("iceoryx2 root path {path:?} is {len} bytes; event sockets under it need at most {max}: choose a shorter base directory (e.g. /tmp/mbpo-ipc)")]
    RootPathTooLong {
        /// The root path.
        path: String,
        /// Its length.
        len: usize,
        /// The longest root path accepted.
        max: usize,
    },
    /// The root directory could not be created.
    #[error("cannot create the iceoryx2 root directory {path:?}: {source}")]
    Io {
        /// The directory.
        path: String,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// The prefix or root path was refused by iceoryx2.
    #[error(
        "iceoryx2 refused the {what} {value:?} ({cause}); use plain ASCII paths without spaces"
    )]
    Config {
        /// `prefix` or `root path`.
        what: &'static str,
        /// The value.
        value: String,
        /// iceoryx2's reason.
        cause: String,
    },
}

/// Why a node could not be created.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum NodeCreateError {
    /// The node name is not valid for iceoryx2.
    #[error("invalid node name {name:?} ({cause})")]
    InvalidName {
        /// The name.
        name: String,
        /// iceoryx2's reason.
        cause: String,
    },
    /// iceoryx2 could not create the node.
    #[error("cannot create iceoryx2 node {name:?} under {root:?}: {source}; check that the root path is writable and /dev/shm is mounted")]
    Iceoryx {
        /// The node name.
        name: String,
        /// The run's root path.
        root: String,
        /// The cause.
        #[source]
        source: iceoryx2::node::NodeCreationFailure,
    },
}

/// Why cleaning up a run's resources failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum CleanupError {
    /// Listing the run's nodes failed.
    #[error("cannot list the nodes of the run ({0}); check permissions on the root path")]
    List(#[from] iceoryx2::node::NodeListFailure),
    /// Processes of the run are still alive.
    #[error("{} node(s) of the run are still alive ({}); stop those processes (and reap them with waitpid) before removing the run's resources", .0.len(), .0.join(", "))]
    NodesStillAlive(Vec<String>),
    /// Removing files failed.
    #[error("cannot remove {path:?}: {source}")]
    Io {
        /// The file or directory.
        path: String,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

/// Why a port (publisher, subscriber, or their event ports) could not be created.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum PortCreateError {
    /// The channel cannot be used with this port type.
    #[error("channel {channel} cannot carry {what}; use {expected}")]
    WrongChannel {
        /// The channel given.
        channel: Channel,
        /// What the port carries.
        what: &'static str,
        /// The channels that can.
        expected: &'static str,
    },
    /// A size argument is out of range.
    #[error("invalid {what}: {value} ({hint})")]
    InvalidArgument {
        /// The argument.
        what: &'static str,
        /// Its value.
        value: u64,
        /// What would be valid.
        hint: &'static str,
    },
    /// An iceoryx2 step failed.
    #[error("{step} for service {service:?} failed: {cause}; {hint}")]
    Iceoryx {
        /// The service name.
        service: String,
        /// What was being done.
        step: &'static str,
        /// iceoryx2's error, e.g. `PublishSubscribeOpenError::IncompatibleTypes`.
        cause: String,
        /// What usually fixes it.
        hint: &'static str,
    },
}

impl PortCreateError {
    pub(crate) fn iceoryx(service: &str, step: &'static str, cause: impl std::fmt::Debug) -> Self {
        let cause = format!("{cause:?}");
        let hint = hint_for(&cause);
        PortCreateError::Iceoryx {
            service: service.to_string(),
            step,
            cause,
            hint,
        }
    }
}

/// A fix for a known iceoryx2 error, from its debug name.
pub(crate) fn hint_for(cause: &str) -> &'static str {
    if cause.contains("IncompatibleTypes") {
        "another process uses different header/payload types on this service: every process of a run must be built from the same mbpo-wire (same SCHEMA_VERSION)"
    } else if cause.contains("VersionMismatch") {
        "every process must link exactly iceoryx2 =0.10.0 (the workspace pins it): rebuild all binaries"
    } else if cause.contains("DoesNotSupport")
        || cause.contains("IncompatibleOverflow")
        || cause.contains("IncompatibleNotifier")
        || cause.contains("IncompatibleDeadline")
        || cause.contains("IncompatibleAttributes")
        || cause.contains("IncompatibleMessagingPattern")
    {
        "the service exists with other limits: every process of a run must use the same ChannelQos; if it is left over from a crashed run, call RunIpc::remove_stale_nodes first"
    } else if cause.contains("ExceedsMax") {
        "the service's port/node limit is reached: raise the ChannelQos limit for this channel (all processes), or clean up dead processes (reap children with waitpid; RunIpc::remove_stale_nodes)"
    } else if cause.contains("InsufficientPermissions") {
        "the resources belong to another user: run every process of a run as the same user"
    } else if cause.contains("HangsInCreation")
        || cause.contains("ServiceInCorruptedState")
        || cause.contains("IsMarkedForDestruction")
    {
        "a crashed process left the service half-created or half-removed: call RunIpc::remove_stale_nodes, or remove the run's resources with RunIpc::remove_all when nothing runs"
    } else if cause.contains("OutOfMemory") || cause.contains("UnableToCreateDataSegment") {
        "shared memory is exhausted: check free space in /dev/shm (containers: --shm-size) and lower ChannelQos buffer sizes"
    } else {
        "see the iceoryx2 0.10 documentation of this error; IOX2_LOG_LEVEL=debug shows details"
    }
}

/// Why a publisher stopped waiting for its subscribers.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum WaitForSubscribersError {
    /// Not enough subscribers confirmed their connection in time.
    #[error("{confirmed} of {wanted} subscriber(s) of {service:?} confirmed their connection after {waited:?} ({registered} registered); start the consuming processes, or check that they call receive()/drain or wait in a Waiter")]
    Timeout {
        /// The service.
        service: String,
        /// Subscribers asked for.
        wanted: usize,
        /// Subscribers that confirmed.
        confirmed: usize,
        /// Subscribers registered with the service (connected or not).
        registered: usize,
        /// Time waited.
        waited: Duration,
    },
    /// SIGINT or SIGTERM arrived while waiting.
    #[error("termination requested (SIGINT/SIGTERM) while waiting for subscribers of {0:?}")]
    Terminated(String),
    /// The attach listener failed.
    #[error("waiting on the attach listener of {service:?} failed: {cause}")]
    Listener {
        /// The service.
        service: String,
        /// iceoryx2's error.
        cause: String,
    },
}

/// Why a publish (transitions, weights, stats or control) failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum PublishError {
    /// The data do not match the port (dimensions, length, version order).
    #[error("{0}")]
    Invalid(String),
    /// Shared memory for the sample could not be loaned.
    #[error("cannot loan {bytes} bytes on {service:?}: {cause}; {hint}")]
    Loan {
        /// The service.
        service: String,
        /// Requested payload size.
        bytes: usize,
        /// iceoryx2's error.
        cause: String,
        /// What usually fixes it.
        hint: &'static str,
    },
    /// SIGINT or SIGTERM arrived while blocked on a full subscriber; the sample was not
    /// delivered to that subscriber.
    #[error("termination requested (SIGINT/SIGTERM) while {service:?} was blocked on a full subscriber; sample {seq} was not delivered to it")]
    Terminated {
        /// The service.
        service: String,
        /// Sequence number of the undelivered sample.
        seq: u64,
    },
    /// A subscriber did not make room within the configured stall timeout.
    #[error("a subscriber of {service:?} did not take sample {seq} within {waited:?}: the consumer is stuck or too slow; raise the stall timeout or fix the consumer")]
    Stalled {
        /// The service.
        service: String,
        /// Sequence number of the undelivered sample.
        seq: u64,
        /// Time blocked.
        waited: Duration,
    },
    /// iceoryx2 failed to send.
    #[error("sending sample {seq} on {service:?} failed: {cause}")]
    Send {
        /// The service.
        service: String,
        /// Sequence number.
        seq: u64,
        /// iceoryx2's error.
        cause: String,
    },
    /// The wake-up notification after a send failed (the data were delivered).
    #[error("notifying listeners of {service:?} failed: {cause}; the data were delivered but consumers may sleep until their timeout")]
    Notify {
        /// The service.
        service: String,
        /// iceoryx2's error.
        cause: String,
    },
}

/// Why a received header was rejected.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum HeaderMismatch {
    /// Written by another schema version.
    #[error("schema version {found}, this build reads {expected}: rebuild every process from the same commit")]
    Schema {
        /// This build's [`crate::SCHEMA_VERSION`].
        expected: u32,
        /// The writer's.
        found: u32,
    },
    /// Written by another run.
    #[error("run hash {found:#018x}, this run is {expected:#018x}: two runs share an iceoryx2 prefix; give each run its own RunIpc")]
    Run {
        /// This run's hash.
        expected: u64,
        /// The writer's.
        found: u64,
    },
    /// Written for another channel.
    #[error("stream tag {found}, this port reads {expected} ({channel})")]
    Stream {
        /// This port's channel tag.
        expected: u32,
        /// The writer's.
        found: u32,
        /// This port's channel.
        channel: Channel,
    },
    /// Transition rows of other dimensions.
    #[error("rows have obs_dim {found_obs} / act_dim {found_act}, this port expects {expected_obs} / {expected_act}: the producer runs another environment")]
    Dims {
        /// Expected observation width.
        expected_obs: u32,
        /// Expected action width.
        expected_act: u32,
        /// Received observation width.
        found_obs: u32,
        /// Received action width.
        found_act: u32,
    },
    /// Another layout hash (row layout or parameter layout).
    #[error("layout hash {found:#018x}, this port expects {expected:#018x}: the producer's network/row layout differs (architecture or field order)")]
    Layout {
        /// Expected hash.
        expected: u64,
        /// Received hash.
        found: u64,
    },
    /// The payload length does not agree with the header.
    #[error("payload holds {payload} floats, the header announces {announced}")]
    Length {
        /// Floats announced by the header.
        announced: u64,
        /// Floats in the payload.
        payload: u64,
    },
    /// Weights of another kind.
    #[error("weights kind {found}, this port reads {expected}")]
    Kind {
        /// Expected [`crate::WeightsKind`] value.
        expected: u32,
        /// Received value.
        found: u32,
    },
}

impl HeaderMismatch {
    /// Every header starts with the writer's schema version and run hash: both must be ours.
    pub(crate) fn check_schema_and_run(
        schema_version: u32,
        found_run: u64,
        run_hash: u64,
    ) -> Result<(), Self> {
        if schema_version != crate::names::SCHEMA_VERSION {
            return Err(HeaderMismatch::Schema {
                expected: crate::names::SCHEMA_VERSION,
                found: schema_version,
            });
        }
        if found_run != run_hash {
            return Err(HeaderMismatch::Run {
                expected: run_hash,
                found: found_run,
            });
        }
        Ok(())
    }
}

/// A hole in a producer's sequence numbers: `got - expected` messages never arrived.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("{missing} message(s) from {producer} on {channel} lost: expected sequence number {expected}, got {got}{}", if *.first_contact { " (first message seen from this publisher)" } else { "" })]
pub struct SequenceGap {
    /// The channel.
    pub channel: Channel,
    /// The producer.
    pub producer: ProducerId,
    /// The sequence number that should have come next.
    pub expected: u64,
    /// The one that came.
    pub got: u64,
    /// `got - expected`.
    pub missing: u64,
    /// True when this is the first message seen from this publisher port (the subscriber
    /// joined late, or the producer restarted and sent before this subscriber connected).
    pub first_contact: bool,
}

/// Why a reliable receive (transitions, stats, control) failed. The offending sample has been
/// released; the next call continues with the next one.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum ReceiveError {
    /// The header did not validate.
    #[error("rejected sample {seq} from {producer} on {channel}: {reason}")]
    Rejected {
        /// The channel.
        channel: Channel,
        /// The producer claimed by the header.
        producer: ProducerId,
        /// The sequence number claimed by the header.
        seq: u64,
        /// What did not match.
        reason: HeaderMismatch,
    },
    /// A sequence number went backwards for one publisher port (a duplicate or reordering: a bug).
    #[error("sequence number of {producer} on {channel} went back from {expected} to {got}: two live publishers use the same producer id?")]
    SequenceRegression {
        /// The channel.
        channel: Channel,
        /// The producer.
        producer: ProducerId,
        /// The sequence number expected.
        expected: u64,
        /// The one received.
        got: u64,
    },
    /// iceoryx2 failed to receive.
    #[error("receiving on {service:?} failed: {cause}; if it is ExceedsMaxBorrows, drop received batches before receiving more")]
    Iceoryx {
        /// The service.
        service: String,
        /// iceoryx2's error.
        cause: String,
    },
}

/// iceoryx2 failed under a port: the service and iceoryx2's error, which the typed receive
/// errors ([`ReceiveError::Iceoryx`], [`WeightsReceiveError::Iceoryx`]) carry.
#[derive(Debug)]
pub(crate) struct IceoryxFailure {
    pub service: String,
    pub cause: String,
}

impl From<IceoryxFailure> for ReceiveError {
    fn from(f: IceoryxFailure) -> Self {
        ReceiveError::Iceoryx {
            service: f.service,
            cause: f.cause,
        }
    }
}

impl From<IceoryxFailure> for WeightsReceiveError {
    fn from(f: IceoryxFailure) -> Self {
        WeightsReceiveError::Iceoryx {
            service: f.service,
            cause: f.cause,
        }
    }
}

/// Why receiving weights failed. The offending sample has been released.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum WeightsReceiveError {
    /// The header did not validate.
    #[error("rejected {kind:?} weights version {version}: {reason}")]
    Rejected {
        /// The kind this port reads.
        kind: crate::WeightsKind,
        /// The version claimed by the header.
        version: u64,
        /// What did not match.
        reason: HeaderMismatch,
    },
    /// The destination slice has the wrong length.
    #[error("destination holds {dst} floats, the weights have {len}")]
    Destination {
        /// Destination length.
        dst: usize,
        /// Weights length.
        len: usize,
    },
    /// iceoryx2 failed to receive.
    #[error("receiving on {service:?} failed: {cause}")]
    Iceoryx {
        /// The service.
        service: String,
        /// iceoryx2's error.
        cause: String,
    },
}

/// Why a [`crate::Waiter`] could not be created.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("cannot create the WaitSet ({0}); the process may be out of file descriptors (ulimit -n)")]
pub struct WaiterCreateError(pub String);

/// Why waiting failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum WaitError {
    /// Nothing is attached, so the wait could only end by timeout.
    #[error("the Waiter has no attached ports; attach at least one subscriber or publisher")]
    NothingAttached,
    /// Attaching a listener to the WaitSet failed.
    #[error(
        "attaching a listener to the WaitSet failed ({0}); the WaitSet capacity may be exhausted"
    )]
    Attach(String),
    /// The WaitSet failed.
    #[error("the WaitSet failed ({0})")]
    WaitSet(String),
}

/// A message that arrived intact but does not decode into what its kind promises.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DecodeError {
    /// A stats record of a kind this build does not know (a newer peer?).
    #[error("stats record of unknown kind {0}: every process of a run must be the same build")]
    UnknownStatsKind(u32),
    /// A model snapshot whose length does not match the run's model layout.
    #[error("model snapshot has {found} floats, the run's model layout needs {expected}: every process of a run must use the same config")]
    ModelLength {
        /// Floats the layout needs.
        expected: usize,
        /// Floats that arrived.
        found: usize,
    },
    /// Model weights that do not fit the run's wire layout (sender side).
    #[error("model weights do not match the wire layout: {0}")]
    ModelWeights(String),
}
