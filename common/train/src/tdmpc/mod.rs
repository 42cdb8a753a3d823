//! TD-MPC2 (Hansen, Su, Wang, ICLR 2024) in one process: planning in a learned latent space
//! with a value at the horizon (`algo = "tdmpc"`, settings in `[tdmpc]`).
//!
//! ```text
//! for each env step t:
//!     t ≤ seed_steps: a uniform-random action                                     seed
//!     else: encode the observation, MPPI over H-step latent plans (policy-prior samples,
//!           warm start from the last plan), act with exploration noise σ              act
//!     keep the transition in its episode
//!     t = seed_steps: seed_steps updates; t > seed_steps: updates_per_step updates   learn
//!         each on subsequences of H steps: consistency, reward and value losses over the
//!         horizon, then the policy prior, then the target Q heads by Polyak averaging
//!     hand the new parameters to the planner
//! ```
//!
//! The networks and the update are `mbpo-latent`'s; this module holds the run's parts with
//! their checkpoint states ([`roles`]) and the run under the shared driver ([`run`]).

pub mod roles;
pub mod run;

pub use run::{train_tdmpc, train_tdmpc_with};
