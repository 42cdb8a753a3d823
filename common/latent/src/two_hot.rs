//! Rewards and values as classification (TD-MPC2, after DreamerV3): a scalar x is encoded in
//! symlog space, symlog(x) = sign(x)·ln(1 + |x|), as a "two-hot" vector over `bins` evenly
//! spaced points of [v_min, v_max] -- the two neighbours of symlog(x) share the mass by
//! distance -- and a head's logits are trained by cross-entropy against it. The head's scalar
//! is symexp of the expected bin under softmax(logits). One scale fits every task's rewards.

use mbpo_nn::math::{exp_neg_f32, lane_fold, lane_max, lane_sum, tree_sum, LANES};

/// symlog(x) = sign(x)·ln(1 + |x|).
pub fn symlog(x: f32) -> f32 {
    x.signum() * x.abs().ln_1p()
}

/// symexp(x) = sign(x)·(e^|x| − 1), symlog's inverse.
pub fn symexp(x: f32) -> f32 {
    x.signum() * x.abs().exp_m1()
}

/// The bins of a two-hot head (TD-MPC2: 101 bins over [−10, 10] in symlog space).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TwoHot {
    /// Number of bins (at least 2).
    pub bins: usize,
    /// Lowest bin, in symlog space.
    pub v_min: f32,
    /// Highest bin, in symlog space.
    pub v_max: f32,
}

impl Default for TwoHot {
    fn default() -> Self {
        Self {
            bins: 101,
            v_min: -10.0,
            v_max: 10.0,
        }
    }
}

impl TwoHot {
    fn bin_size(&self) -> f32 {
        (self.v_max - self.v_min) / (self.bins - 1) as f32
    }

    /// The two-hot encoding of `x` into `out` (`bins` values summing to 1).
    pub fn encode(&self, x: f32, out: &mut [f32]) {
        out.fill(0.0);
        let v = symlog(x).clamp(self.v_min, self.v_max);
        let pos = (v - self.v_min) / self.bin_size();
        let lower = (pos.floor() as usize).min(self.bins - 2);
        let upper_weight = (pos - lower as f32).clamp(0.0, 1.0);
        out[lower] = 1.0 - upper_weight;
        out[lower + 1] = upper_weight;
    }

    /// The scalar a head's `logits` stand for: symexp of the expected bin under softmax
    /// (through the CPU's widest SIMD copy: the exponential's fused multiply-adds are
    /// instructions there, a library call per operation otherwise).
    pub fn decode(&self, logits: &[f32]) -> f32 {
        mbpo_nn::simd_dispatch!(Self::decode_kernel[self, logits])
    }

    #[inline(always)]
    fn decode_kernel(&self, logits: &[f32]) -> f32 {
        let max = lane_max(logits);
        let (mut sum, mut weighted) = ([0.0f32; LANES], [0.0f32; LANES]);
        lane_fold(logits, |i, l, lane| {
            let p = exp_neg_f32(max - l);
            sum[lane] += p;
            weighted[lane] += p * (self.v_min + i as f32 * self.bin_size());
        });
        symexp(tree_sum(weighted) / tree_sum(sum))
    }

    /// Cross-entropy of `logits` against the two-hot encoding of `target`; writes
    /// ∂loss/∂logits (softmax − two-hot) into `d_logits` and returns the loss.
    pub fn cross_entropy(&self, logits: &[f32], target: f32, d_logits: &mut [f32]) -> f32 {
        mbpo_nn::simd_dispatch!(Self::cross_entropy_kernel[self, logits, target, d_logits])
    }

    #[inline(always)]
    fn cross_entropy_kernel(&self, logits: &[f32], target: f32, d_logits: &mut [f32]) -> f32 {
        self.encode(target, d_logits);
        let max = lane_max(logits);
        let log_sum = lane_sum(logits, |_, l| exp_neg_f32(max - l)).ln() + max;
        let mut loss = 0.0;
        for (d, &l) in d_logits.iter_mut().zip(logits) {
            let log_p = l - log_sum;
            loss -= *d * log_p;
            *d = log_p.exp() - *d;
        }
        loss
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn symlog_and_symexp_are_inverse() {
        for x in [-1234.5f32, -3.0, -0.1, 0.0, 0.2, 7.0, 800.0] {
            let back = symexp(symlog(x));
            assert!((back - x).abs() <= 1e-4 * x.abs().max(1.0), "{x} -> {back}");
        }
    }

    #[test]
    fn an_encoding_decodes_to_its_value_and_puts_mass_on_two_neighbours() {
        let th = TwoHot::default();
        let mut enc = vec![0.0; th.bins];
        for x in [-500.0f32, -2.5, 0.0, 0.3, 42.0] {
            th.encode(x, &mut enc);
            assert!((enc.iter().sum::<f32>() - 1.0).abs() < 1e-6);
            assert!(enc.iter().filter(|&&p| p > 0.0).count() <= 2);
            // Logits whose softmax is the encoding (up to a tiny floor) decode to x.
            let logits: Vec<f32> = enc.iter().map(|&p| (p + 1e-12).ln()).collect();
            let back = th.decode(&logits);
            assert!((back - x).abs() <= 1e-3 * x.abs().max(1.0), "{x} -> {back}");
        }
    }

    #[test]
    fn the_cross_entropy_gradient_matches_finite_differences() {
        let th = TwoHot {
            bins: 9,
            v_min: -3.0,
            v_max: 3.0,
        };
        let logits: Vec<f32> = (0..9).map(|i| (i as f32 * 0.7).sin()).collect();
        let mut d = vec![0.0; 9];
        let loss = th.cross_entropy(&logits, 2.2, &mut d);
        assert!(loss > 0.0);
        let eps = 1e-2f32;
        for i in 0..9 {
            let at = |delta: f32| {
                let mut l = logits.clone();
                l[i] += delta;
                th.cross_entropy(&l, 2.2, &mut [0.0; 9]) as f64
            };
            let numeric = (at(eps) - at(-eps)) / (2.0 * eps as f64);
            assert!(
                (d[i] as f64 - numeric).abs() < 1e-3,
                "logit {i}: {} vs {numeric}",
                d[i]
            );
        }
    }
}
