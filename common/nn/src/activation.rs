//! Element-wise activations and their derivatives.
//!
//! | name | a = f(z) | f'(z) written with what the forward pass kept |
//! |---|---|---|
//! | Identity | z | 1 |
//! | ReLU | max(z, 0) | 1 if z > 0 else 0 (PyTorch's choice at 0) |
//! | SiLU (swish) | z·σ(z) | σ(z) + a·(1 − σ(z)), with σ(z) = a / z |
//! | Tanh | tanh z | 1 − a² |
//!
//! SiLU dominates the dynamics model's element-wise cost (4 hidden layers x 200 units x 7
//! members per sample), so σ uses [`exp_f32`], a branch-free exp the compiler vectorises, and the
//! backward pass recovers σ(z) = a/z by one division instead of a second exp.

use crate::simd;
use serde::{Deserialize, Serialize};

/// An element-wise activation function.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum Activation {
    /// f(z) = z.
    Identity,
    /// f(z) = max(z, 0).
    Relu,
    /// f(z) = z·σ(z), a.k.a. swish (the dynamics model's activation).
    Silu,
    /// f(z) = tanh(z).
    Tanh,
}

impl Activation {
    /// Short stable name, used in parameter-layout descriptions.
    pub fn name(self) -> &'static str {
        match self {
            Activation::Identity => "identity",
            Activation::Relu => "relu",
            Activation::Silu => "silu",
            Activation::Tanh => "tanh",
        }
    }

    /// `a = f(z)` element-wise. For `Identity` the caller may skip the call (it copies).
    pub fn forward(self, z: &[f32], a: &mut [f32]) {
        simd::dispatch!(forward_kernel(self, z, a))
    }

    /// Row-wise `z ← z + b` then `a = f(z)` in one pass over memory (the dense layer's
    /// epilogue). `z` holds whole rows of `bias.len()` values. For `Identity`, `a` is untouched.
    pub fn bias_forward(self, z: &mut [f32], bias: &[f32], a: &mut [f32]) {
        simd::dispatch!(bias_forward_kernel(self, z, bias, a))
    }

    /// `dz = g · f'(z)` element-wise, given the forward pass's `z` and `a = f(z)`.
    pub fn backward(self, z: &[f32], a: &[f32], g: &[f32], dz: &mut [f32]) {
        simd::dispatch!(backward_kernel(self, z, a, g, dz))
    }
}

/// Branch-free loops (a data-dependent branch per element mispredicts half the time on ReLU's
/// signs) written with zipped iterators so that they vectorise.
#[inline(always)]
fn forward_kernel(act: Activation, z: &[f32], a: &mut [f32]) {
    let a = &mut a[..z.len()];
    match act {
        Activation::Identity => a.copy_from_slice(z),
        Activation::Relu => a.iter_mut().zip(z).for_each(|(a, &z)| *a = z.max(0.0)),
        Activation::Silu => a.iter_mut().zip(z).for_each(|(a, &z)| *a = z * sigmoid(z)),
        Activation::Tanh => a.iter_mut().zip(z).for_each(|(a, &z)| *a = z.tanh()),
    }
}

#[inline(always)]
fn bias_forward_kernel(act: Activation, z: &mut [f32], bias: &[f32], a: &mut [f32]) {
    let width = bias.len();
    for (r, zrow) in z.chunks_exact_mut(width).enumerate() {
        zrow.iter_mut().zip(bias).for_each(|(z, &b)| *z += b);
        if act != Activation::Identity {
            forward_kernel(act, zrow, &mut a[r * width..(r + 1) * width]);
        }
    }
}

#[inline(always)]
fn backward_kernel(act: Activation, z: &[f32], a: &[f32], g: &[f32], dz: &mut [f32]) {
    let n = g.len();
    let (z, a, dz) = (&z[..n], &a[..n], &mut dz[..n]);
    match act {
        Activation::Identity => dz.copy_from_slice(g),
        Activation::Relu => dz
            .iter_mut()
            .zip(z.iter().zip(g))
            .for_each(|(d, (&z, &g))| *d = if z > 0.0 { g } else { 0.0 }),
        Activation::Silu => {
            dz.iter_mut()
                .zip(z.iter().zip(a.iter().zip(g)))
                .for_each(|(d, (&z, (&a, &g)))| {
                    // σ(z) = a / z away from 0; σ(0) = 1/2.
                    let s = if z.abs() > 1e-12 { a / z } else { 0.5 };
                    *d = g * (s + a * (1.0 - s));
                })
        }
        Activation::Tanh => dz
            .iter_mut()
            .zip(a.iter().zip(g))
            .for_each(|(d, (&a, &g))| *d = g * (1.0 - a * a)),
    }
}

/// Logistic sigmoid 1 / (1 + e^(−z)).
#[inline(always)]
pub fn sigmoid(z: f32) -> f32 {
    1.0 / (1.0 + exp_f32(-z))
}

/// e^x in f32 without branches or calls, so loops over it vectorise.
///
/// Cody-Waite range reduction x = n·ln2 + r with |r| ≤ ln2/2, a degree-6 polynomial for e^r
/// (Cephes `expf` coefficients), and 2^n built from exponent bits. The input is clamped to
/// [−87, 88], so the result is never a denormal, zero or infinity. Relative error below 3e-7
/// (checked against `f32::exp` in the tests).
#[inline(always)]
pub fn exp_f32(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const ROUND: f32 = 12_582_912.0; // 1.5·2^23: adding and subtracting it rounds to an integer.
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let x = x.clamp(-87.0, 88.0);
    let n = (x * LOG2E + ROUND) - ROUND;
    let r = x - n * LN2_HI - n * LN2_LO;
    let mut p = 1.987_569_1e-4f32;
    p = p * r + 1.398_199_9e-3;
    p = p * r + 8.333_452e-3;
    p = p * r + 4.166_579_6e-2;
    p = p * r + 1.666_666_5e-1;
    p = p * r + 0.5;
    let er = p * r * r + r + 1.0;
    let scale = f32::from_bits(((n as i32 + 127) as u32) << 23);
    er * scale
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_f32_matches_std_to_a_few_ulps() {
        let mut worst = 0.0f64;
        let mut x = -87.0f32;
        while x <= 88.0 {
            let want = (x as f64).exp();
            let got = exp_f32(x) as f64;
            worst = worst.max(((got - want) / want).abs());
            x += 0.001_37;
        }
        assert!(worst < 3e-7, "worst relative error {worst}");
        assert_eq!(exp_f32(0.0), 1.0);
        assert!(exp_f32(-1e4) > 0.0 && exp_f32(1e4).is_finite());
    }

    #[test]
    fn silu_backward_handles_zero_and_saturation() {
        let z = [0.0f32, -200.0, 200.0, 1.5];
        let mut a = [0.0; 4];
        Activation::Silu.forward(&z, &mut a);
        let mut dz = [0.0; 4];
        Activation::Silu.backward(&z, &a, &[1.0; 4], &mut dz);
        assert!((dz[0] - 0.5).abs() < 1e-7);
        assert!(dz[1].abs() < 1e-6);
        assert!((dz[2] - 1.0).abs() < 1e-6);
        let s = 1.0 / (1.0 + (-1.5f64).exp());
        assert!((dz[3] as f64 - (s + 1.5 * s * (1.0 - s))).abs() < 1e-6);
    }
}
