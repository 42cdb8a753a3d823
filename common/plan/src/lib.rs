//! Planning with a learned model (the other half of model-based RL next to MBPO's policy
//! learning): model predictive control with random shooting, CEM, MPPI/PDDM or gradient-based
//! planners, scored by PETS-style trajectory sampling.
//!
//! * [`PlanningModel`]: what a planner needs from a model (batched one-step predictions with a
//!   member per row; optionally input gradients). [`EnsembleModel`] wraps the learned
//!   `mbpo_model::ProbabilisticEnsemble` (reward from its head or the task's known reward);
//!   toy models with known optima plug in for tests.
//! * [`Planner`]: [`RandomShooting`], [`Cem`], [`Mppi`], [`GradientPlanner`], built from a
//!   [`PlannerConfig`] by [`build`]. Each is written as one function per algorithm step next to
//!   its paper's pseudo-code in the module docs.
//! * [`TrajectorySampler`]: candidates x particles as one batch of rows per model step (TS∞).
//! * [`Mpc`]: closed-loop replanning with warm start, or open-loop execution for comparison.
//! * [`bench`](mod@bench): planning latency.
//!
//! Actions are in the normalised box [−1, 1]^A throughout, as everywhere in the workspace.
#![warn(missing_docs)]

pub mod bench;
mod cem;
mod config;
mod configured;
mod error;
mod grad;
mod model;
mod mpc;
mod mppi;
mod planner;
mod random;
mod sampler;

pub use cem::Cem;
pub use config::{CemConfig, GradConfig, MppiConfig, PlannerConfig, PlannerKind, RandomConfig};
pub use configured::build;
pub use error::PlanError;
pub use grad::GradientPlanner;
pub use model::{EnsembleModel, PlanningModel, RewardSource};
pub use mpc::{Mpc, MpcState};
pub use mppi::Mppi;
pub use planner::Planner;
pub use random::RandomShooting;
pub use sampler::{deal_members, TrajectorySampler};
