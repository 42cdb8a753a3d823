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
        assert_eq!(grads.len(), params.len());
        for part in self.step_parts(params, 1) {
            let range = part.range();
            part.apply(&grads[range]);
        }
    }

    /// One update cut into pieces that can run on different threads: advances the step count
    /// and returns disjoint pieces of `params` (consecutive ranges of
    /// [`part_len`]`(len, parts)` parameters, the last one shorter), each to be finished with
    /// [`AdamPart::apply`] on its range of the gradient. The result does not depend on the cut.
    pub fn step_parts<'a>(
        &'a mut self,
        params: &'a mut [f32],
        parts: usize,
    ) -> impl Iterator<Item = AdamPart<'a>> + 'a {
        assert_eq!(params.len(), self.state.m.len());
        self.state.t += 1;
        let c = self.config;
        let t = self.state.t as i32;
        let step = StepConstants {
            c,
            step_size: c.lr / (1.0 - c.beta1.powi(t)),
            bc2_sqrt: (1.0 - c.beta2.powi(t)).sqrt(),
        };
        let len = part_len(params.len(), parts);
        let decay = &self.decay;
        params
            .chunks_mut(len)
            .zip(self.state.m.chunks_mut(len))
            .zip(self.state.v.chunks_mut(len))
            .enumerate()
            .map(move |(i, ((params, m), v))| AdamPart {
                offset: i * len,
                params,
                m,
                v,
                decay,
                step,
            })
    }
}

/// Length of each piece when `len` items are cut into `parts` consecutive pieces (all but the
/// last have this length). Everything cut alongside an [`Adam::step_parts`] uses it.
pub fn part_len(len: usize, parts: usize) -> usize {
    len.div_ceil(parts.max(1)).max(1)
}

/// The constants of one Adam step.
#[derive(Debug, Clone, Copy)]
struct StepConstants {
    c: AdamConfig,
    /// lr / (1 − β1^t).
    step_size: f32,
    /// √(1 − β2^t).
    bc2_sqrt: f32,
}

/// One piece of an Adam step ([`Adam::step_parts`]): the parameters and moments of
/// `range()`, updated by [`AdamPart::apply`].
#[derive(Debug)]
pub struct AdamPart<'a> {
    offset: usize,
    params: &'a mut [f32],
    m: &'a mut [f32],
    v: &'a mut [f32],
    decay: &'a [(Range<usize>, WeightDecay)],
    step: StepConstants,
}

impl<'a> AdamPart<'a> {
    /// The piece's range in the whole parameter vector.
    pub fn range(&self) -> Range<usize> {
        self.offset..self.offset + self.params.len()
    }

    /// The piece's parameters before the update.
    pub fn params(&self) -> &[f32] {
        self.params
    }

    /// Update the piece with `grads`, the gradient of its range; returns the new parameters.
    pub fn apply(mut self, grads: &[f32]) -> &'a mut [f32] {
        assert_eq!(grads.len(), self.params.len());
        let (lo, hi) = (self.offset, self.offset + self.params.len());
        // Walk the decay ranges that meet [lo, hi), with no decay in the gaps between them.
        let mut at = lo;
        let decays = self
            .decay
            .iter()
            .filter(|(r, _)| r.end > lo && r.start < hi)
            .map(|(r, wd)| (r.start.max(lo)..r.end.min(hi), *wd))
            .chain(std::iter::once((hi..hi, WeightDecay::None)));
        for (r, wd) in decays {
            self.update(at..r.start, WeightDecay::None, grads);
            self.update(r.clone(), wd, grads);
            at = r.end;
        }
        self.params
    }

    /// Adam on the absolute range `r` (inside the piece) with decay `wd`.
    fn update(&mut self, r: Range<usize>, wd: WeightDecay, grads: &[f32]) {
        if r.is_empty() {
            return;
        }
        let local = r.start - self.offset..r.end - self.offset;
        let p = &mut self.params[local.clone()];
        let m = &mut self.m[local.clone()];
        let v = &mut self.v[local.clone()];
        let c = self.step.c;
        let (l2, decoupled) = match wd {
            WeightDecay::None => (0.0, 1.0),
            WeightDecay::L2(l) => (l, 1.0),
            WeightDecay::Decoupled(l) => (0.0, 1.0 - c.lr * l),
        };
        let k = AdamKernel {
            c,
            l2,
            decoupled,
            step_size: self.step.step_size,
            bc2_sqrt: self.step.bc2_sqrt,
        };
        crate::simd::dispatch!(adam_kernel(&k, p, &grads[local], m, v));
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

    #[test]
    fn a_step_cut_into_parts_equals_the_whole_step_bit_for_bit() {
        let n = 23;
        let make = || {
            let mut adam = Adam::new(n, AdamConfig::with_lr(0.01));
            // Decay ranges that straddle the cuts.
            adam.set_decay(3..9, WeightDecay::L2(0.3));
            adam.set_decay(14..20, WeightDecay::Decoupled(0.2));
            adam
        };
        let (mut whole, mut cut) = (make(), make());
        let mut p1: Vec<f32> = (0..n).map(|i| (i as f32 * 0.3).sin()).collect();
        let mut p2 = p1.clone();
        for step in 0..4 {
            let g: Vec<f32> = (0..n).map(|i| ((i + step) as f32 * 0.7).cos()).collect();
            whole.step(&mut p1, &g);
            let mut seen = 0;
            for part in cut.step_parts(&mut p2, 3) {
                let r = part.range();
                assert_eq!(r.start, seen);
                seen = r.end;
                part.apply(&g[r]);
            }
            assert_eq!(seen, n);
            assert_eq!(p1, p2, "step {step}");
        }
        assert_eq!(whole.state(), cut.state());
    }
}
