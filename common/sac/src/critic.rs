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
    /// ∂L/∂[s, a] of one critic (`batch x (O + A)`).
    d_input: Vec<f32>,
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
            d_input: vec![0.0; batch * width],
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
        for r in 0..batch {
            let row = &mut cache.input[r * (o + a)..(r + 1) * (o + a)];
            row[..o].copy_from_slice(&obs[r * o..(r + 1) * o]);
            row[o..].copy_from_slice(&act[r * a..(r + 1) * a]);
        }
        for e in 0..2 {
            self.mlp.forward(
                &params[self.member_range(e)],
                &cache.input,
                batch,
                &mut cache.members[e],
            );
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

    /// ∂L/∂a summed over both critics for `d_q[e]` = ∂L/∂Q_e per row (`d_act` is `batch x A`,
    /// overwritten). No parameter gradients are formed.
    pub fn backward_action(
        &self,
        params: &[f32],
        cache: &mut CriticCache,
        d_q: [&[f32]; 2],
        d_act: &mut [f32],
    ) {
        let (o, a, batch) = (self.obs_dim, self.act_dim, cache.batch);
        d_act[..batch * a].fill(0.0);
        for (e, d) in d_q.iter().enumerate() {
            let mut d_input = std::mem::take(&mut cache.d_input);
            self.mlp.backward(
                &params[self.member_range(e)],
                &cache.input,
                &mut cache.members[e],
                d,
                None,
                Some(&mut d_input),
            );
            for r in 0..batch {
                let src = &d_input[r * (o + a) + o..(r + 1) * (o + a)];
                d_act[r * a..(r + 1) * a]
                    .iter_mut()
                    .zip(src)
                    .for_each(|(x, &g)| *x += g);
            }
            cache.d_input = d_input;
        }
    }
}
