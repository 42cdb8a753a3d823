//! The batched-policy interface shared by rollouts, actors and planners.

use crate::rng::{uniform_range_f32, Rng};

/// A policy acting on a batch of observations: SAC's actor, a planner, or uniform noise.
pub trait BatchPolicy {
    /// Write actions for `batch` observations (`obs` is `batch x obs_dim`, row-major) into
    /// `actions` (`batch x act_dim`), drawing any noise from `rng`.
    fn act_batch(&mut self, obs: &[f32], batch: usize, actions: &mut [f32], rng: &mut Rng);
}

/// Uniform random actions in a box (MBPO's warm-up policy).
#[derive(Debug, Clone)]
pub struct UniformPolicy {
    /// Lower bound per action dimension.
    pub low: Vec<f32>,
    /// Upper bound per action dimension.
    pub high: Vec<f32>,
}

impl BatchPolicy for UniformPolicy {
    fn act_batch(&mut self, _obs: &[f32], batch: usize, actions: &mut [f32], rng: &mut Rng) {
        let d = self.low.len();
        for row in actions[..batch * d].chunks_exact_mut(d) {
            for (j, a) in row.iter_mut().enumerate() {
                *a = uniform_range_f32(rng, self.low[j], self.high[j]);
            }
        }
    }
}
