//! Twin Q critics Q₁, Q₂(s, a): two ReLU MLPs on the concatenated [s, a] with one scalar output,
//! stored one after the other in one flat vector (`q1.*`, then `q2.*`) so one Adam and one
//! Polyak call cover both.

use mbpo_core::Rng;
use mbpo_nn::{Activation, Init, Mlp, MlpCache, ParamLayout};
use std::ops::Range;

/// Architecture of the twin critics (owns no parameters).
#[derive(Debug, Clone, PartialEq)]
pub struct TwinCritic {
    mlp: Mlp,
    obs_dim: usize,
    act_dim: usize,
    layout: ParamLayout,
}

/// Inputs and activations of one twin-critic pass.
#[derive(Debug, Clone, Default)]
pub struct CriticCache {
    batch: usize,
    /// [s, a] rows (`batch x (O + A)`).
    input: Vec<f32>,
    members: [MlpCache; 2],
    /// Rows whose min(Q₁, Q₂) is Q_e, per critic e.
    min_rows: [Vec<usize>; 2],
    /// ∂L/∂Q_e of those rows, compact.
    min_grad: [Vec<f32>; 2],
    /// ∂L/∂a of those rows, compact (`rows x A`).
    min_d_act: Vec<f32>,
}

impl TwinCritic {
    /// Twin critics with ReLU hidden layers of widths `hidden`.
    pub fn new(obs_dim: usize, act_dim: usize, hidden: &[usize]) -> Self {
        let mut dims = vec![obs_dim + act_dim];
        dims.extend_from_slice(hidden);
        dims.push(1);
        let mlp = Mlp::new(&dims, Activation::Relu, Activation::Identity);
        let mut layout = ParamLayout::new();
        layout.extend_prefixed("q1", mlp.layout());
        layout.extend_prefixed("q2", mlp.layout());
        Self {
            mlp,
            obs_dim,
            act_dim,
            layout,
        }
    }

    /// One critic's architecture.
    pub fn mlp(&self) -> &Mlp {
        &self.mlp
    }
    /// Action width A.
    pub fn act_dim(&self) -> usize {
        self.act_dim
    }
    /// Parameter count of both critics.
    pub fn num_params(&self) -> usize {
        self.layout.len()
    }
    /// Names and shapes of both critics' parameters.
    pub fn layout(&self) -> &ParamLayout {
        &self.layout
    }
    /// Range of critic `e` (0 or 1) in the flat vector.
    pub fn member_range(&self, e: usize) -> Range<usize> {
        let p = self.mlp.num_params();
        e * p..(e + 1) * p
    }
    /// PyTorch-default initial parameters for both critics.
    pub fn init(&self, params: &mut [f32], rng: &mut Rng) {
        for e in 0..2 {
            self.mlp
                .init(&mut params[self.member_range(e)], Init::TorchDefault, rng);
        }
    }

    /// A cache sized for `batch` rows.
    pub fn cache(&self, batch: usize) -> CriticCache {
        let width = self.obs_dim + self.act_dim;
        CriticCache {
            batch,
            input: vec![0.0; batch * width],
            members: [
                MlpCache::new(&self.mlp, batch),
                MlpCache::new(&self.mlp, batch),
            ],
            min_rows: [Vec::with_capacity(batch), Vec::with_capacity(batch)],
            min_grad: [vec![0.0; batch], vec![0.0; batch]],
            min_d_act: vec![0.0; batch * self.act_dim],
        }
    }

    /// Q₁ and Q₂ on `batch` rows of (s, a); read them with [`TwinCritic::q`].
    pub fn forward(
        &self,
        params: &[f32],
        obs: &[f32],
        act: &[f32],
        batch: usize,
        cache: &mut CriticCache,
    ) {
        let (o, a) = (self.obs_dim, self.act_dim);
        if cache.input.len() < batch * (o + a) {
            *cache = self.cache(batch);
        }
        cache.batch = batch;
        self.join_inputs(obs, act, batch, &mut cache.input);
        for e in 0..2 {
            self.mlp.forward(
                &params[self.member_range(e)],
                &cache.input,
                batch,
                &mut cache.members[e],
            );
        }
    }

    /// The critics' input rows [s, a] of `batch` rows into `input` (`batch x (O + A)`).
    pub fn join_inputs(&self, obs: &[f32], act: &[f32], batch: usize, input: &mut [f32]) {
        let (o, a) = (self.obs_dim, self.act_dim);
        for ((row, s), u) in input[..batch * (o + a)]
            .chunks_exact_mut(o + a)
            .zip(obs.chunks_exact(o))
            .zip(act.chunks_exact(a))
        {
            row[..o].copy_from_slice(s);
            row[o..].copy_from_slice(u);
        }
    }

    /// Which critic's value is min(Q₁, Q₂) of a row, the one its gradient flows through:
    /// 0 for Q₁ (also on ties), 1 for Q₂.
    pub fn min_critic(q1: f32, q2: f32) -> usize {
        if q1 <= q2 {
            0
        } else {
            1
        }
    }

    /// Q_e values of the last forward pass (one per row).
    pub fn q<'c>(&self, cache: &'c CriticCache, e: usize) -> &'c [f32] {
        cache.members[e].output(&self.mlp)
    }

    /// ∂L/∂θ of both critics for `d_q[e]` = ∂L/∂Q_e per row (overwrites `grads`).
    pub fn backward_params(
        &self,
        params: &[f32],
        cache: &mut CriticCache,
        d_q: [&[f32]; 2],
        grads: &mut [f32],
    ) {
        for (e, d) in d_q.iter().enumerate() {
            let r = self.member_range(e);
            self.mlp.backward(
                &params[r.clone()],
                &cache.input,
                &mut cache.members[e],
                d,
                Some(&mut grads[r]),
                None,
            );
        }
    }

    /// ∂L/∂a for L = Σ_r `d_min[r]` · min(Q₁, Q₂)(s_r, a_r) on the last forward pass
    /// (`d_act` is `batch x A`, overwritten). No parameter gradients are formed.
    ///
    /// The minimum passes each row's gradient to one critic (Q₁ on ties), so each critic runs
    /// its backward pass on its own rows only ([`Mlp::input_grad_rows`]): half the work of
    /// back-propagating both critics on every row with zeros for the other half.
    pub fn backward_action_min(
        &self,
        params: &[f32],
        cache: &mut CriticCache,
        d_min: &[f32],
        d_act: &mut [f32],
    ) {
        let (o, a, batch) = (self.obs_dim, self.act_dim, cache.batch);
        {
            let CriticCache {
                members,
                min_rows,
                min_grad,
                ..
            } = &mut *cache;
            let q1 = members[0].output(&self.mlp);
            let q2 = members[1].output(&self.mlp);
            min_rows.iter_mut().for_each(Vec::clear);
            for r in 0..batch {
                let e = Self::min_critic(q1[r], q2[r]);
                min_grad[e][min_rows[e].len()] = d_min[r];
                min_rows[e].push(r);
            }
        }
        for e in 0..2 {
            let rows = std::mem::take(&mut cache.min_rows[e]);
            let mut compact = std::mem::take(&mut cache.min_d_act);
            self.mlp.input_grad_rows(
                &params[self.member_range(e)],
                &mut cache.members[e],
                &rows,
                &cache.min_grad[e],
                o..o + a,
                &mut compact,
            );
            for (i, &r) in rows.iter().enumerate() {
                d_act[r * a..(r + 1) * a].copy_from_slice(&compact[i * a..(i + 1) * a]);
            }
            cache.min_d_act = compact;
            cache.min_rows[e] = rows;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::rng::{normal_f32, stream};

    #[test]
    fn action_gradient_of_the_clipped_double_q_matches_finite_differences() {
        let (o, a, batch) = (3, 2, 32);
        let critic = TwinCritic::new(o, a, &[16, 16]);
        let mut params = vec![0.0; critic.num_params()];
        critic.init(&mut params, &mut stream(5, "q", 0));
        let mut g = stream(4, "q.data", 0);
        let obs: Vec<f32> = (0..batch * o).map(|_| normal_f32(&mut g)).collect();
        let act: Vec<f32> = (0..batch * a).map(|_| normal_f32(&mut g).tanh()).collect();
        let d_min: Vec<f32> = (0..batch).map(|_| normal_f32(&mut g)).collect();
        let loss = |act: &[f32]| {
            let mut cache = critic.cache(batch);
            critic.forward(&params, &obs, act, batch, &mut cache);
            let (q1, q2) = (critic.q(&cache, 0), critic.q(&cache, 1));
            (0..batch)
                .map(|r| d_min[r] as f64 * q1[r].min(q2[r]) as f64)
                .sum::<f64>()
        };
        let mut cache = critic.cache(batch);
        critic.forward(&params, &obs, &act, batch, &mut cache);
        let picks_q2 = (0..batch).any(|r| critic.q(&cache, 1)[r] < critic.q(&cache, 0)[r]);
        let picks_q1 = (0..batch).any(|r| critic.q(&cache, 0)[r] <= critic.q(&cache, 1)[r]);
        assert!(picks_q1 && picks_q2, "both critics must own some rows");
        let mut d_act = vec![f32::NAN; batch * a];
        critic.backward_action_min(&params, &mut cache, &d_min, &mut d_act);
        // Small steps: with 32 rows x 2 x 16 ReLUs, a step of 1e-3 already crosses a kink.
        let eps = 2e-4f32;
        let scale = d_act.iter().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
        for i in 0..batch * a {
            let mut x = act.clone();
            x[i] += eps;
            let up = loss(&x);
            x[i] -= 2.0 * eps;
            let numeric = (up - loss(&x)) / (2.0 * eps as f64);
            let err = (d_act[i] as f64 - numeric).abs() / (0.05 * scale + numeric.abs());
            assert!(err < 2e-2, "d_act[{i}]: {} vs {numeric}", d_act[i]);
        }
    }
}
