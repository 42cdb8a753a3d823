//! Parameter initialisers.
//!
//! * [`Init::TorchDefault`]: PyTorch's `nn.Linear` default, W and b ~ U(−1/√fan_in, 1/√fan_in)
//!   (kaiming-uniform with a = √5 reduces to exactly this bound). Used by SAC's networks.
//! * [`Init::TruncatedNormal`]: W ~ N(0, σ²) with σ = 1/(2√fan_in), redrawn outside ±2σ
//!   (TensorFlow's `truncated_normal`, as in the MBPO/PETS dynamics model); b = 0.

use mbpo_core::rng::{normal_f32, uniform_range_f32};
use mbpo_core::Rng;

/// How to draw a dense layer's initial weights and biases.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Init {
    /// PyTorch `nn.Linear` default: uniform ±1/√fan_in for weights and biases.
    TorchDefault,
    /// Truncated normal (±2σ) with σ = 1/(2√fan_in) for weights, zero biases.
    TruncatedNormal,
}

impl Init {
    /// Fill a dense layer's weights `w` (fan_in x fan_out) and biases `b`.
    pub fn fill(self, w: &mut [f32], b: &mut [f32], fan_in: usize, rng: &mut Rng) {
        match self {
            Init::TorchDefault => {
                let bound = 1.0 / (fan_in as f32).sqrt();
                w.iter_mut()
                    .for_each(|x| *x = uniform_range_f32(rng, -bound, bound));
                b.iter_mut()
                    .for_each(|x| *x = uniform_range_f32(rng, -bound, bound));
            }
            Init::TruncatedNormal => {
                let std = 1.0 / (2.0 * (fan_in as f32).sqrt());
                for x in w.iter_mut() {
                    *x = loop {
                        let z = normal_f32(rng);
                        if z.abs() <= 2.0 {
                            break z * std;
                        }
                    };
                }
                b.fill(0.0);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn torch_default_bounds_and_spread() {
        let mut rng = mbpo_core::stream(1, "init", 0);
        let mut w = vec![0.0; 64 * 100];
        let mut b = vec![0.0; 100];
        Init::TorchDefault.fill(&mut w, &mut b, 64, &mut rng);
        let bound = 1.0 / 8.0;
        assert!(w.iter().chain(&b).all(|x| x.abs() <= bound));
        let var = w.iter().map(|x| x * x).sum::<f32>() / w.len() as f32;
        assert!((var - bound * bound / 3.0).abs() < 0.1 * bound * bound / 3.0);
    }

    #[test]
    fn truncated_normal_bounds_and_std() {
        let mut rng = mbpo_core::stream(1, "init", 1);
        let mut w = vec![0.0; 200 * 200];
        let mut b = vec![1.0; 200];
        Init::TruncatedNormal.fill(&mut w, &mut b, 200, &mut rng);
        let std = 1.0 / (2.0 * 200f32.sqrt());
        assert!(w.iter().all(|x| x.abs() <= 2.0 * std));
        assert!(b.iter().all(|&x| x == 0.0));
        // Std of N(0,1) truncated at ±2 is 0.8796.
        let s = (w.iter().map(|x| x * x).sum::<f32>() / w.len() as f32).sqrt();
        assert!((s / std - 0.8796).abs() < 0.01, "{}", s / std);
    }
}
