//! Shared foundations of the MBPO workspace.
//!
//! * [`rng`]: every random draw in the system comes from a named stream derived from
//!   `(run seed, role, index)`, never from time or process ids. The sequential reference and the
//!   multi-process pipeline derive the same streams, which is what makes lockstep runs equal bit
//!   for bit.
#![warn(missing_docs)]

pub mod rng;

pub use rng::{stream, Rng};
