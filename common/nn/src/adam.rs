//! Adam (Kingma & Ba 2015) on a flat parameter vector, written as PyTorch's `torch.optim.Adam`
//! computes it, with weight decay chosen per parameter range.
//!
//! For step t with gradient g:
//! ```text
//! g   ← g + λ·θ                       (L2 decay: the gradient of λ/2·‖θ‖², as MBPO's model loss)
//! θ   ← θ·(1 − lr·λ)                  (decoupled decay instead: AdamW)
//! m   ← β1·m + (1 − β1)·g
//! v   ← β2·v + (1 − β2)·g²
//! θ   ← θ − (lr / (1 − β1^t)) · m / (√v / √(1 − β2^t) + ε)
//! ```

use serde::{Deserialize, Serialize};
use std::ops::Range;

/// Weight decay applied to a range of parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
pub enum WeightDecay {
    /// No decay.
    #[default]
    None,
    /// Coupled L2: adds `λ·θ` to the gradient (PyTorch `Adam(weight_decay=λ)`).
    L2(f32),
    /// Decoupled: multiplies θ by `1 − lr·λ` before the update (PyTorch `AdamW`).
    Decoupled(f32),
}

/// Adam's hyper-parameters.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AdamConfig {
    /// Learning rate.
    pub lr: f32,
    /// First-moment decay β1.
    pub beta1: f32,
    /// Second-moment decay β2.
    pub beta2: f32,
    /// ε added to the denominator.
    pub eps: f32,
}

impl Default for AdamConfig {
    /// PyTorch's defaults: lr 1e-3, β = (0.9, 0.999), ε = 1e-8.
    fn default() -> Self {
        Self {
            lr: 1e-3,
            beta1: 0.9,
            beta2: 0.999,
            eps: 1e-8,
        }
    }
}

impl AdamConfig {
    /// The defaults with learning rate `lr`.
    pub fn with_lr(lr: f32) -> Self {
        Self {
            lr,
            ..Self::default()
        }
    }
}

/// Adam's moments and step count: what a checkpoint must keep.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AdamState {
    /// First moments.
    pub m: Vec<f32>,
    /// Second moments.
    pub v: Vec<f32>,
    /// Steps taken.
    pub t: u64,
}

/// Adam over one flat parameter vector.
#[derive(Debug, Clone, PartialEq)]
pub struct Adam {
    /// Hyper-parameters (may be changed between steps).
    pub config: AdamConfig,
    state: AdamState,
    /// Disjoint, sorted ranges with their decay; the rest has none.
    decay: Vec<(Range<usize>, WeightDecay)>,
}

impl Adam {
    /// Adam for `n` parameters with zero moments.
    pub fn new(n: usize, config: AdamConfig) -> Self {
        Self {
            config,
            state: AdamState {
                m: vec![0.0; n],
                v: vec![0.0; n],
                t: 0,
            },
            decay: Vec::new(),
        }
    }

    /// Apply `decay` to the parameters in `range` (ranges must not overlap).
    pub fn set_decay(&mut self, range: Range<usize>, decay: WeightDecay) {
        assert!(
            range.end <= self.state.m.len(),
            "decay range outside the parameters"
        );
        assert!(
            self.decay
                .iter()
                .all(|(r, _)| r.end <= range.start || range.end <= r.start),
            "decay ranges overlap"
        );
        self.decay.push((range, decay));
        self.decay.sort_by_key(|(r, _)| r.start);
    }

    /// Moments and step count.
    pub fn state(&self) -> &AdamState {
        &self.state
    }

    /// Replace moments and step count (checkpoint restore).
    pub fn set_state(&mut self, state: AdamState) {
        assert_eq!(
            state.m.len(),
            self.state.m.len(),
            "Adam state size mismatch"
        );
        assert_eq!(
            state.v.len(),
            self.state.v.len(),
            "Adam state size mismatch"
        );
        self.state = state;
    }

    /// One update of `params` with `grads`.
    pub fn step(&mut self, params: &mut [f32], grads: &[f32]) {
        assert_eq!(params.len(), self.state.m.len());
        assert_eq!(grads.len(), params.len());
        self.state.t += 1;
        let c = self.config;
        let t = self.state.t as i32;
        let bc1 = 1.0 - c.beta1.powi(t);
        let bc2_sqrt = (1.0 - c.beta2.powi(t)).sqrt();
        let step_size = c.lr / bc1;
        let mut start = 0;
        let decay = std::mem::take(&mut self.decay);
        for (range, wd) in decay.iter().cloned().chain(std::iter::once((
            params.len()..params.len(),
            WeightDecay::None,
        ))) {
            self.update(
                params,
                grads,
                start..range.start,
                WeightDecay::None,
                step_size,
                bc2_sqrt,
            );
            self.update(params, grads, range.clone(), wd, step_size, bc2_sqrt);
            start = range.end;
        }
        self.decay = decay;
    }

    fn update(
        &mut self,
        params: &mut [f32],
        grads: &[f32],
        r: Range<usize>,
        wd: WeightDecay,
        step_size: f32,
        bc2_sqrt: f32,
    ) {
        let c = self.config;
        let (p, g) = (&mut params[r.clone()], &grads[r.clone()]);
        let (m, v) = (&mut self.state.m[r.clone()], &mut self.state.v[r]);
        let (l2, decoupled) = match wd {
            WeightDecay::None => (0.0, 1.0),
            WeightDecay::L2(l) => (l, 1.0),
            WeightDecay::Decoupled(l) => (0.0, 1.0 - c.lr * l),
        };
        let k = AdamKernel {
            c,
            l2,
            decoupled,
            step_size,
            bc2_sqrt,
        };
        crate::simd::dispatch!(adam_kernel(&k, p, g, m, v));
    }
}

/// The per-element constants of one Adam step.
struct AdamKernel {
    c: AdamConfig,
    l2: f32,
    decoupled: f32,
    step_size: f32,
    bc2_sqrt: f32,
}

#[inline(always)]
fn adam_kernel(k: &AdamKernel, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
    let c = k.c;
    let n = p.len();
    let (g, m, v) = (&g[..n], &mut m[..n], &mut v[..n]);
    for i in 0..n {
        let gi = g[i] + k.l2 * p[i];
        m[i] = c.beta1 * m[i] + (1.0 - c.beta1) * gi;
        v[i] = c.beta2 * v[i] + (1.0 - c.beta2) * gi * gi;
        let denom = v[i].sqrt() / k.bc2_sqrt + c.eps;
        p[i] = p[i] * k.decoupled - k.step_size * m[i] / denom;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Adam by the textbook formula in f64, for comparison.
    fn reference(p0: f64, grads: &[f64], lr: f64, l2: f64, decoupled: f64) -> f64 {
        let (b1, b2, eps) = (0.9f64, 0.999f64, 1e-8f64);
        let (mut p, mut m, mut v) = (p0, 0.0, 0.0);
        for (i, &g) in grads.iter().enumerate() {
            let t = (i + 1) as i32;
            let g = g + l2 * p;
            p *= 1.0 - lr * decoupled;
            m = b1 * m + (1.0 - b1) * g;
            v = b2 * v + (1.0 - b2) * g * g;
            let mhat = m / (1.0 - b1.powi(t));
            let vhat = v / (1.0 - b2.powi(t));
            p -= lr * mhat / (vhat.sqrt() + eps);
        }
        p
    }

    #[test]
    fn first_step_moves_each_parameter_by_lr_against_the_gradient_sign() {
        // Hand-computed: m̂ = g and v̂ = g², so step 1 is exactly lr·sign(g) (ε aside).
        let mut adam = Adam::new(3, AdamConfig::with_lr(0.1));
        let mut p = [1.0f32, -2.0, 0.5];
        adam.step(&mut p, &[0.3, -4.0, 1e-3]);
        assert!((p[0] - 0.9).abs() < 1e-6);
        assert!((p[1] + 1.9).abs() < 1e-6);
        assert!((p[2] - (0.5 - 0.1 * 1e-3 / (1e-3 + 1e-8))).abs() < 1e-6);
    }

    #[test]
    fn several_steps_match_the_textbook_formula() {
        let grads = [0.5f64, -0.25, 0.75, 0.1, -1.0];
        let mut adam = Adam::new(1, AdamConfig::with_lr(0.01));
        let mut p = [0.3f32];
        for &g in &grads {
            adam.step(&mut p, &[g as f32]);
        }
        let want = reference(0.3, &grads, 0.01, 0.0, 0.0);
        assert!((p[0] as f64 - want).abs() < 1e-6, "{} vs {want}", p[0]);
        assert_eq!(adam.state().t, 5);
    }

    #[test]
    fn decay_applies_only_to_its_range() {
        // Zero loss gradient: only the decay moves a parameter.
        let mut adam = Adam::new(3, AdamConfig::with_lr(0.01));
        adam.set_decay(1..2, WeightDecay::L2(0.5));
        adam.set_decay(2..3, WeightDecay::Decoupled(0.5));
        let mut p = [1.0f32, 1.0, 1.0];
        let grads = [0.0f64; 3];
        for _ in 0..3 {
            adam.step(&mut p, &[0.0; 3]);
        }
        let l2 = reference(1.0, &grads, 0.01, 0.5, 0.0);
        let dec = reference(1.0, &grads, 0.01, 0.0, 0.5);
        assert_eq!(p[0], 1.0);
        assert!((p[1] as f64 - l2).abs() < 1e-6, "{} vs {l2}", p[1]);
        assert!((p[2] as f64 - dec).abs() < 1e-6, "{} vs {dec}", p[2]);
        assert!(
            (p[1] - 0.97).abs() < 1e-4,
            "L2 under Adam moves ~lr per step: {}",
            p[1]
        );
        assert!((p[2] - 0.995f32.powi(3)).abs() < 1e-6);
    }
}
