//! Input gradients of the mean prediction: what gradient-based planning backpropagates through.
//!
//! A planner that optimises an action sequence by gradient ascent on the predicted return needs
//! `∂(return)/∂(actions)` through H model steps. One step of the mean model is
//!
//! ```text
//! x          = ([obs, act] − mean) / std                  (the input normaliser)
//! [μ_r, μ_Δ] = first d outputs of member e's MLP on x      (the log-variance half is unused)
//! reward     = μ_r,    next_obs = obs + μ_Δ
//! ```
//!
//! so, given `∂L/∂reward` and `∂L/∂next_obs`, the backward pass is the MLP's input gradient
//! (`mbpo_nn::Mlp::backward`) followed by the normaliser's chain rule:
//!
//! ```text
//! ∂L/∂y   = [∂L/∂reward, ∂L/∂next_obs, 0 … 0]
//! ∂L/∂obs = ∂L/∂next_obs + (∂L/∂x)[..o] / std[..o]         (the identity path obs → next_obs)
//! ∂L/∂act = (∂L/∂x)[o..] / std[o..]
//! ```
//!
//! The prediction is the member's mean (ε = 0): gradient planning optimises the expected
//! trajectory of each particle's member, while the sampling planners propagate sampled states.
//! Every step of a horizon is recorded in its own slot of a [`MeanTape`] (the activations the
//! backward pass needs), so the whole horizon is run forward once and backward once.

use crate::error::PredictError;
use crate::grouped::Grouping;
use crate::model::{check_len, ProbabilisticEnsemble};
use mbpo_nn::MlpCache;

/// Activations of recorded mean predictions, one slot per planning step; reused across calls
/// (buffers only grow, so a planner's steady state allocates nothing).
#[derive(Debug, Clone, Default)]
pub struct MeanTape {
    slots: Vec<TapeSlot>,
    /// `∂L/∂y` rows of one member (`rows x 2d`).
    d_y: Vec<f32>,
    /// `∂L/∂x` rows of one member (`rows x in`).
    d_x: Vec<f32>,
}

/// One recorded step.
#[derive(Debug, Clone, Default)]
struct TapeSlot {
    n: usize,
    group: Grouping,
    /// Standardised inputs in member-grouped order (`n x in`).
    x: Vec<f32>,
    /// One cache per member, holding that member's rows.
    caches: Vec<MlpCache>,
}

impl MeanTape {
    /// An empty tape.
    pub fn new() -> Self {
        Self::default()
    }
}

impl ProbabilisticEnsemble {
    /// Mean one-step predictions (ε = 0) of `n` samples, sample i by member `members[i]`,
    /// recorded in slot `step` of `tape` for [`ProbabilisticEnsemble::mean_step_backward`].
    ///
    /// Writes `reward` (`n`) and `next_obs = obs + μ_Δ` (`n x obs_dim`).
    #[allow(clippy::too_many_arguments)]
    pub fn mean_step_recorded(
        &self,
        tape: &mut MeanTape,
        step: usize,
        obs: &[f32],
        act: &[f32],
        n: usize,
        members: &[usize],
        reward: &mut [f32],
        next_obs: &mut [f32],
    ) -> Result<(), PredictError> {
        let (o, a, d) = (self.obs_dim, self.act_dim, self.net.d());
        let in_dim = o + a;
        check_len("obs", n * o, obs.len())?;
        check_len("act", n * a, act.len())?;
        check_len("members", n, members.len())?;
        check_len("reward", n, reward.len())?;
        check_len("next_obs", n * o, next_obs.len())?;
        if let Some(&member) = members.iter().find(|&&m| m >= self.members()) {
            return Err(PredictError::Member {
                member,
                members: self.members(),
            });
        }
        if tape.slots.len() <= step {
            tape.slots.resize_with(step + 1, TapeSlot::default);
        }
        let slot = &mut tape.slots[step];
        slot.n = n;
        slot.group.build(members, self.members());
        slot.x.resize(n * in_dim, 0.0);
        // Gather the rows member by member, standardised.
        for (pos, &i) in slot.group.order.iter().enumerate() {
            let i = i as usize;
            self.normalizer.transform_into(
                &obs[i * o..(i + 1) * o],
                &act[i * a..(i + 1) * a],
                &mut slot.x[pos * in_dim..(pos + 1) * in_dim],
            );
        }
        if slot.caches.len() != self.members() {
            slot.caches = vec![MlpCache::default(); self.members()];
        }
        let (ens, mlp) = (self.net.ensemble(), self.net.mlp());
        for e in 0..self.members() {
            let (start, end) = (slot.group.starts[e], slot.group.starts[e + 1]);
            if start == end {
                continue;
            }
            let y = mlp.forward(
                &self.theta[ens.member_range(e)],
                &slot.x[start * in_dim..end * in_dim],
                end - start,
                &mut slot.caches[e],
            );
            // Scatter μ back to the samples' own rows.
            for (row, &i) in y.chunks_exact(2 * d).zip(&slot.group.order[start..end]) {
                let i = i as usize;
                reward[i] = row[0];
                for ((v, &dm), &s) in next_obs[i * o..(i + 1) * o]
                    .iter_mut()
                    .zip(&row[1..d])
                    .zip(&obs[i * o..(i + 1) * o])
                {
                    *v = s + dm;
                }
            }
        }
        Ok(())
    }

    /// The backward pass of slot `step` of `tape` (see the module docs): from `∂L/∂reward`
    /// (`n`) and `∂L/∂next_obs` (`n x obs_dim`), **overwrite** `d_obs` (`n x obs_dim`) and
    /// `d_act` (`n x act_dim`). The model's parameters must not have changed since the slot was
    /// recorded.
    pub fn mean_step_backward(
        &self,
        tape: &mut MeanTape,
        step: usize,
        d_reward: &[f32],
        d_next_obs: &[f32],
        d_obs: &mut [f32],
        d_act: &mut [f32],
    ) -> Result<(), PredictError> {
        let (o, a, d) = (self.obs_dim, self.act_dim, self.net.d());
        let in_dim = o + a;
        let MeanTape { slots, d_y, d_x } = tape;
        let Some(slot) = slots.get_mut(step) else {
            return Err(PredictError::Length {
                what: "recorded tape slots",
                expected: step + 1,
                found: slots.len(),
            });
        };
        let n = slot.n;
        check_len("d_reward", n, d_reward.len())?;
        check_len("d_next_obs", n * o, d_next_obs.len())?;
        check_len("d_obs", n * o, d_obs.len())?;
        check_len("d_act", n * a, d_act.len())?;
        let (ens, mlp) = (self.net.ensemble(), self.net.mlp());
        let (std_o, std_a) = self.normalizer.std.split_at(o);
        for e in 0..self.members() {
            let (start, end) = (slot.group.starts[e], slot.group.starts[e + 1]);
            let rows = end - start;
            if rows == 0 {
                continue;
            }
            let idx = &slot.group.order[start..end];
            d_y.resize(rows * 2 * d, 0.0);
            d_x.resize(rows * in_dim, 0.0);
            for (dy, &i) in d_y.chunks_exact_mut(2 * d).zip(idx) {
                let i = i as usize;
                dy[0] = d_reward[i];
                dy[1..d].copy_from_slice(&d_next_obs[i * o..(i + 1) * o]);
                dy[d..].fill(0.0);
            }
            mlp.backward(
                &self.theta[ens.member_range(e)],
                &slot.x[start * in_dim..end * in_dim],
                &mut slot.caches[e],
                d_y,
                None,
                Some(d_x),
            );
            for (dx, &i) in d_x.chunks_exact(in_dim).zip(idx) {
                let i = i as usize;
                for (((g, &dn), &dxi), &s) in d_obs[i * o..(i + 1) * o]
                    .iter_mut()
                    .zip(&d_next_obs[i * o..(i + 1) * o])
                    .zip(&dx[..o])
                    .zip(std_o)
                {
                    *g = dn + dxi / s;
                }
                for ((g, &dxi), &s) in d_act[i * a..(i + 1) * a]
                    .iter_mut()
                    .zip(&dx[o..])
                    .zip(std_a)
                {
                    *g = dxi / s;
                }
            }
        }
        Ok(())
    }
}
