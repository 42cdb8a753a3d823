//! A run's directory, the files every command writes alike: the metrics rows, the summary and
//! the resolved config ([`run_dir`]), TensorBoard scalars ([`tensorboard`]), checkpoints
//! ([`checkpoint`]: the layout, checksums and `COMPLETE` marker) and their writer on its own
//! thread ([`checkpoint_writer`]), and what a user watches a run with ([`progress`]).
//!
//! Must not hold what is in a role's checkpoint file or how a run trains (`mbpo-train`, above
//! this crate, re-exports these modules under its own paths).
#![warn(missing_docs)]

pub mod checkpoint;
pub mod checkpoint_writer;
pub mod progress;
pub mod run_dir;
pub mod tensorboard;
