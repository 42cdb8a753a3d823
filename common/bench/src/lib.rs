//! Benchmarks and diagnoses of runs (`mbpo bench ...`): what a user measures a run or a build
//! with, on top of the experiments of `mbpo-train`.
//!
//! Holds: [`learning_bench`] (seeds of a config to a budget, against the paper's curves and
//! peers' ones, [`published`]),
//! [`breakdown`] (where an MBPO run's time goes, from a kept checkpoint), [`diagnose`] (a run's
//! critic and model held against the real environment, from a kept checkpoint),
//! [`checkpoint_bench`] (what checkpointing costs the training loop), [`termination_bench`]
//! (the learned termination rule against a task's exact one) and [`chaos`] (`mbpo run` under
//! random SIGKILLs: what a user must be able to trust after them); [`command`] is `mbpo
//! bench`'s commands (their arguments and the micro-benchmarks' glue), [`stdout`] how every
//! `mbpo` command prints.
//!
//! Must not hold what a run needs to train, resume or be read: nothing below depends on this
//! crate, so a trainer never links a benchmark.
#![warn(missing_docs)]
#![allow(clippy::needless_range_loop)]

pub mod breakdown;
pub mod chaos;
pub mod checkpoint_bench;
pub mod command;
pub mod diagnose;
pub mod learning_bench;
pub mod published;
pub mod stdout;
pub mod termination_bench;
