//! The error of a training run: one type for every trainer and role in this crate, so that
//! a run's failure reads the same whichever algorithm met it.

/// Errors of a training run.
#[derive(Debug, thiserror::Error)]
pub enum TrainError {
    /// The environment could not be built.
    #[error(transparent)]
    Env(#[from] mbpo_envs::EnvError),
    /// The run directory could not be written.
    #[error("run directory: {0}")]
    Io(#[from] std::io::Error),
    /// A component rejected its configuration or input.
    #[error("{0}")]
    Config(String),
    /// A checkpoint could not be written or read.
    #[error(transparent)]
    Checkpoint(#[from] crate::checkpoint::CheckpointError),
    /// A results file could not be encoded.
    #[error("results file: {0}")]
    Json(#[from] serde_json::Error),
    /// The environment failed at a step (an exception in a Python env); what the run had before
    /// it is kept in a checkpoint.
    #[error(
        "the environment failed at env step {step}: {error}\n{kept}. Fix the environment, then \
         continue the run with --resume"
    )]
    EnvFailed {
        /// The env step that failed.
        step: u64,
        /// What was kept (`the run stopped with a checkpoint after step N`).
        kept: String,
        /// The environment's error (with the Python traceback).
        error: mbpo_envs::EnvError,
    },
    /// NaN or infinity where a number must be finite: the run stops where it appeared (its
    /// last complete checkpoint stays as it was).
    #[error(
        "{role}: {quantity} is {value} at {at}; the run stops here (its last complete checkpoint \
         is kept). Check the environment's observations and rewards, or lower the learning rates"
    )]
    NonFinite {
        /// The role that met it (`actor`, `learner`, `model trainer`).
        role: &'static str,
        /// What was not finite.
        quantity: String,
        /// Its value.
        value: f64,
        /// Where: env step, update or training.
        at: String,
    },
}

impl From<mbpo_config::RolloutTerminationError> for TrainError {
    /// The same variants as before the config had a crate of its own.
    fn from(e: mbpo_config::RolloutTerminationError) -> Self {
        match e {
            mbpo_config::RolloutTerminationError::Config(m) => TrainError::Config(m),
            mbpo_config::RolloutTerminationError::Env(e) => TrainError::Env(e),
        }
    }
}
