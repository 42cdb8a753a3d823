//! Twin Q critics Q₁, Q₂(s, a): two ReLU MLPs (their hidden layers LayerNormed as an option)
//! on the concatenated [s, a] with one scalar output, stored one after the other in one flat
//! vector (`q1.*`, then `q2.*`) so one Adam and one Polyak call cover both.

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
}

impl TwinCritic {
    /// Twin critics with ReLU hidden layers of widths `hidden`, each LayerNormed before its
    /// ReLU when `layer_norm` (`sac.critic_layer_norm`).
    pub fn new(obs_dim: usize, act_dim: usize, hidden: &[usize], layer_norm: bool) -> Self {
        let mut dims = vec![obs_dim + act_dim];
        dims.extend_from_slice(hidden);
        dims.push(1);
        let mlp = match layer_norm {
            false => Mlp::new(&dims, Activation::Relu, Activation::Identity),
            true => Mlp::with_hidden_layer_norm(&dims, Activation::Relu, Activation::Identity),
        };
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
}
