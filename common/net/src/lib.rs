//! Between hosts: roles on worker hosts (actors, the evaluator) join a run on the head host
//! over Zenoh.
//!
//! Within a host everything stays on iceoryx2 shared memory. Between hosts, one gateway process
//! per host carries the remote roles' channels over one Zenoh session: on the head it stands in
//! for the remote roles' ports ([`head`]), on a worker it stands in for the head's side
//! ([`worker`]). Which channels cross, and so which roles can be remote, is
//! `mbpo_runtime::remote`'s one rule. The roles themselves are the ordinary processes, and the
//! coordinator and the other roles cannot tell a remote role from a local one.
//!
//! * [`protocol`]: the messages, their encoding and its limits;
//! * [`link`]: sequence numbers, cumulative acknowledgements and resending (go-back-N), so
//!   nothing accepted is lost or doubled when a link drops;
//! * [`session`]: Zenoh configuration: endpoints, TLS with mutual authentication,
//!   user/password, and the rule that a head beyond loopback needs credentials;
//! * [`peer`]: one side's view of the other end (publisher, outbox, inbox, liveness).
#![warn(missing_docs)]

pub mod certs;
mod files;
pub mod head;
pub mod link;
pub mod peer;
pub mod protocol;
pub mod session;
pub mod worker;

pub use head::{run_head, HeadOptions};
pub use session::{NetOptions, SessionError, DEFAULT_PORT};
pub use worker::{run_worker, WorkerOptions, WorkerReport};

use mbpo_runtime::{Dims, PipelineSpec, RuntimeError};
use mbpo_wire::WeightsKind;

/// Why a gateway stopped.
#[derive(Debug, thiserror::Error)]
pub enum GatewayError {
    /// The Zenoh session could not be opened (endpoint, credentials).
    #[error(transparent)]
    Session(#[from] SessionError),
    /// Zenoh failed while running.
    #[error("zenoh: {0}")]
    Zenoh(String),
    /// The local side: config, iceoryx2 ports.
    #[error(transparent)]
    Runtime(#[from] RuntimeError),
    /// A file of the run.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The error.
        #[source]
        source: std::io::Error,
    },
    /// A remote actor's state is lost, or the peers disagree.
    #[error("{0}")]
    Failed(String),
}

macro_rules! via_runtime {
    ($($t:ty),*) => {$(
        impl From<$t> for GatewayError {
            fn from(e: $t) -> Self {
                GatewayError::Runtime(RuntimeError::from(e))
            }
        }
    )*};
}
via_runtime!(
    mbpo_wire::RunIpcError,
    mbpo_wire::NodeCreateError,
    mbpo_wire::PortCreateError,
    mbpo_wire::PublishError,
    mbpo_wire::ReceiveError,
    mbpo_wire::WeightsReceiveError,
    mbpo_wire::WaitError,
    mbpo_wire::WaiterCreateError,
    mbpo_wire::WaitForSubscribersError,
    mbpo_wire::CleanupError,
    mbpo_train::checkpoint::CheckpointError
);

/// The weights a run's actors act with (policy for MBPO, model for MPC): kind, layout hash
/// and length.
pub fn actor_weights(pipeline: &PipelineSpec, dims: &Dims) -> (WeightsKind, u64, usize) {
    let kind = pipeline.actor_weights();
    let (hash, len) = dims.weights_layout(kind);
    (kind, hash, len)
}
