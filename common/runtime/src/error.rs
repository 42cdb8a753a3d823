//! The one error type of the runtime: every way a service can fail, each naming what went
//! wrong and, where there is one, the fix. Binaries print it with [`crate::error_chain`].

use std::path::PathBuf;

use mbpo_wire::{
    CleanupError, NodeCreateError, PortCreateError, PublishError, ReceiveError, RunIpcError,
    WaitError, WaitForSubscribersError, WaiterCreateError, WeightsReceiveError,
};

/// Why a service (or the coordinator) stopped with an error.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RuntimeError {
    /// The run's `config.toml` could not be read or is invalid.
    #[error("loading {path}: {source}")]
    Config {
        /// The file.
        path: PathBuf,
        /// What was wrong.
        #[source]
        source: mbpo_train::ConfigError,
    },
    /// A role (environment, model, SAC, planner) failed or refused its input.
    #[error(transparent)]
    Train(#[from] mbpo_train::TrainError),
    /// The environment could not be built.
    #[error(transparent)]
    Env(#[from] mbpo_envs::EnvError),
    /// A checkpoint file could not be written or read.
    #[error(transparent)]
    Checkpoint(#[from] mbpo_train::checkpoint::CheckpointError),
    /// A file or directory of the run could not be written.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// The model configuration gives no valid ensemble (so no wire layout).
    #[error("model config: {0}")]
    Model(String),
    /// A peer broke the pipeline's protocol (a version or count it must never send): a bug or
    /// processes of different builds in one run.
    #[error("{0}")]
    Protocol(String),
    /// Roles of an in-process run did not stop after the Stop (their threads are left running).
    #[error("roles {0:?} did not stop within 30 s of the stop")]
    RolesStuck(Vec<String>),
    /// A run cannot be resumed from its checkpoints.
    #[error("{0}")]
    Resume(String),
    /// The run's iceoryx2 environment could not be set up.
    #[error(transparent)]
    RunIpc(#[from] RunIpcError),
    /// A node could not be created.
    #[error(transparent)]
    Node(#[from] NodeCreateError),
    /// A port could not be created.
    #[error(transparent)]
    Port(#[from] PortCreateError),
    /// A sample could not be sent.
    #[error(transparent)]
    Publish(#[from] PublishError),
    /// A sample could not be received.
    #[error(transparent)]
    Receive(#[from] ReceiveError),
    /// A weight snapshot could not be received.
    #[error(transparent)]
    WeightsReceive(#[from] WeightsReceiveError),
    /// The peers a port needs did not connect in time.
    #[error(transparent)]
    WaitForSubscribers(#[from] WaitForSubscribersError),
    /// A waiter could not be created.
    #[error(transparent)]
    WaiterCreate(#[from] WaiterCreateError),
    /// Sleeping in a waiter failed.
    #[error(transparent)]
    Wait(#[from] WaitError),
    /// The run's shared-memory resources could not be removed.
    #[error(transparent)]
    Cleanup(#[from] CleanupError),
    /// A message on the wire did not decode.
    #[error(transparent)]
    Decode(#[from] mbpo_wire::DecodeError),
}

impl RuntimeError {
    /// A protocol violation described by `what`.
    pub fn protocol(what: impl Into<String>) -> Self {
        RuntimeError::Protocol(what.into())
    }
}

/// Results of the runtime.
pub type Result<T, E = RuntimeError> = std::result::Result<T, E>;

/// Fail with a [`RuntimeError::Protocol`] unless `cond` holds.
macro_rules! ensure_protocol {
    ($cond:expr, $($fmt:tt)+) => {
        if !$cond {
            return Err($crate::RuntimeError::Protocol(format!($($fmt)+)));
        }
    };
}
pub(crate) use ensure_protocol;
