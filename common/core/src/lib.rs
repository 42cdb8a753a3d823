//! Shared foundations of the MBPO workspace.
//!
//! * [`rng`]: every random draw in the system comes from a named stream derived from
//!   `(run seed, role, index)`, never from time or process ids. The sequential reference and the
//!   multi-process pipeline derive the same streams, which is what makes lockstep runs equal bit
//!   for bit.
//! * [`replay`]: the FIFO transition buffer used for real data and for MBPO's model buffer.
//! * [`policy`]: the batched-policy interface (SAC actor, planners, uniform warm-up).
//! * [`rate_limit`]: Reverb-style limiters that hold the algorithm's ratios in a pipeline.
//! * [`state_box`]: the box of the real states seen, which imagined states can be clipped to.
//! * [`roles`]: the one table of roles (names, binaries, checkpoint kinds, channels).
//! * [`stats`]: the median every report uses.
//! * [`budget`]: a plan's wall-clock budget (how many iterations fit).
//! * [`alloc_count`]: the counting allocator of the no-allocation tests.
#![warn(missing_docs)]

pub mod alloc_count;
pub mod budget;
pub mod policy;
pub mod rate_limit;
pub mod replay;
pub mod rng;
pub mod roles;
pub mod state_box;
pub mod stats;

pub use policy::{BatchPolicy, UniformPolicy};
pub use replay::{
    sample_mixed, Batch, FillFromNewest, LastTransition, ReplayBuffer, ReplaySnapshot,
    SnapshotMismatch, TransitionSink,
};
pub use rng::{stream, Rng};
pub use state_box::StateBox;
