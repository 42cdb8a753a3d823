//! Soft actor-critic (Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and Applications").
//!
//! * [`actor::TanhGaussianActor`]: π(a|s) = tanh(N(μ(s), σ(s)²)), log σ clamped to [−20, 2].
//! * [`critic::TwinCritic`]: Q₁, Q₂ with the clipped double-Q minimum.
//! * [`agent::Sac`]: one update = critic step, actor step, temperature step, Polyak targets,
//!   written as [`agent::Sac::update`] reads next to the paper.
//!
//! Actions live in the normalised box [−1, 1]^A everywhere inside the agent (replay data, model
//! inputs, critics); [`ActionScale`] maps them to an environment's bounds at the very edge.
#![warn(missing_docs)]
// Numeric kernels index several parallel arrays by row; iterator chains would hide the math.
#![allow(clippy::needless_range_loop)]

pub mod actor;
pub mod agent;
pub mod bench;
pub mod config;
pub mod critic;
mod shard;

pub use actor::{ActorCache, ActorPolicy, TanhGaussianActor};
pub use agent::{Sac, SacPolicy, SacState, SacStats};
pub use config::SacConfig;
pub use critic::{CriticCache, TwinCritic};

/// Affine map between the agent's [−1, 1] actions and an environment's box.
#[derive(Debug, Clone, PartialEq)]
pub struct ActionScale {
    low: Vec<f32>,
    high: Vec<f32>,
}

impl ActionScale {
    /// The map onto `[low, high]`.
    pub fn new(low: &[f32], high: &[f32]) -> Self {
        assert_eq!(low.len(), high.len());
        Self {
            low: low.to_vec(),
            high: high.to_vec(),
        }
    }
    /// Environment action for a normalised action: `low + (a + 1)/2 · (high − low)`.
    pub fn to_env(&self, normalized: &[f32], env_action: &mut [f32]) {
        for j in 0..self.low.len() {
            env_action[j] =
                self.low[j] + (normalized[j] + 1.0) * 0.5 * (self.high[j] - self.low[j]);
        }
    }
}
