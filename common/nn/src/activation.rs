//! Element-wise activations and their derivatives.
//!
//! | name | a = f(z) | f'(z) written with what the forward pass kept |
//! |---|---|---|
//! | Identity | z | 1 |
//! | ReLU | max(z, 0) | 1 if a > 0 else 0 (a > 0 exactly when z > 0: PyTorch's choice at 0) |
//! | SiLU (swish) | z·σ(z) | σ(z) + a·(1 − σ(z)), with σ(z) = a / z |
//! | Tanh | tanh z | 1 − a² |
//!
//! Every derivative but SiLU's is a function of a alone, so those layers keep only a, written
//! over z in place ([`Activation::in_place`]): one read-modify-write pass over the layer instead
//! of reading z and writing both z and a (the epilogue was 4 % of a SAC update before).
//!
//! SiLU dominates the dynamics model's element-wise cost, so σ uses [`exp_neg_f32`], a
//! branch-free exp the compiler vectorises, and the backward pass recovers σ(z) = a/z by one
//! division instead of a second exp.

use crate::math::exp_neg_f32;
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

    /// Whether the derivative needs only a = f(z), so a layer keeps a in z's buffer and no
    /// separate output buffer (every activation but SiLU).
    pub fn in_place(self) -> bool {
        self != Activation::Silu
    }

    /// `a = f(z)` element-wise. For `Identity` the caller may skip the call (it copies).
    pub fn forward(self, z: &[f32], a: &mut [f32]) {
        simd::dispatch!(forward_kernel(self, z, a))
    }

    /// The dense layer's epilogue without a bias (after a LayerNorm, whose β is one): `z ←
    /// f(z)` in place when [`Activation::in_place`] (`a` is untouched), else `a = f(z)`.
    pub fn epilogue(self, z: &mut [f32], a: &mut [f32]) {
        match self {
            Activation::Silu => self.forward(z, &mut a[..z.len()]),
            _ => simd::dispatch!(in_place_kernel(self, z)),
        }
    }

    /// The dense layer's epilogue, row-wise on `z` holding whole rows of `bias.len()` values:
    /// `z ← f(z + b)` in place when [`Activation::in_place`] (`a` is untouched), else
    /// `z ← z + b` and `a = f(z)`.
    pub fn bias_forward(self, z: &mut [f32], bias: &[f32], a: &mut [f32]) {
        simd::dispatch!(bias_forward_kernel(self, z, bias, a))
    }

    /// `dz = g · f'(z)` element-wise, given the forward pass's `z` and `a = f(z)` (for an
    /// in-place activation pass the kept buffer as both).
    pub fn backward(self, z: &[f32], a: &[f32], g: &[f32], dz: &mut [f32]) {
        simd::dispatch!(backward_kernel(self, z, a, g, dz))
    }

    /// [`Activation::backward`] fused with the bias gradient: `dz = g · f'(z)` and
    /// `db = Σ_rows dz` (overwritten) over rows of `db.len()` values, in one pass.
    pub fn backward_bias_grad(
        self,
        z: &[f32],
        a: &[f32],
        g: &[f32],
        dz: &mut [f32],
        db: &mut [f32],
    ) {
        simd::dispatch!(backward_bias_grad_kernel(self, z, a, g, dz, db))
    }

    /// [`Activation::backward`] on gathered rows: row i of the compact `g`/`dz`
    /// (`rows.len() x width`) belongs to row `rows[i]` of the layer's `z`/`a`.
    pub fn backward_rows(
        self,
        z: &[f32],
        a: &[f32],
        width: usize,
        rows: &[usize],
        g: &[f32],
        dz: &mut [f32],
    ) {
        for (i, &r) in rows.iter().enumerate() {
            let src = r * width..(r + 1) * width;
            let dst = i * width..(i + 1) * width;
            // One row is a whole vectorised loop (width is a hidden size); the dispatch check
            // per row is a cached flag.
            let (z, a) = (&z[src.clone()], &a[src]);
            simd::dispatch!(backward_kernel(self, z, a, &g[dst.clone()], &mut dz[dst]))
        }
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
fn in_place_kernel(act: Activation, z: &mut [f32]) {
    match act {
        Activation::Identity | Activation::Silu => {}
        Activation::Relu => z.iter_mut().for_each(|z| *z = z.max(0.0)),
        Activation::Tanh => z.iter_mut().for_each(|z| *z = z.tanh()),
    }
}

#[inline(always)]
fn bias_forward_kernel(act: Activation, z: &mut [f32], bias: &[f32], a: &mut [f32]) {
    let width = bias.len();
    for (r, zrow) in z.chunks_exact_mut(width).enumerate() {
        match act {
            Activation::Identity => zrow.iter_mut().zip(bias).for_each(|(z, &b)| *z += b),
            Activation::Relu => zrow
                .iter_mut()
                .zip(bias)
                .for_each(|(z, &b)| *z = (*z + b).max(0.0)),
            Activation::Tanh => zrow
                .iter_mut()
                .zip(bias)
                .for_each(|(z, &b)| *z = (*z + b).tanh()),
            Activation::Silu => {
                zrow.iter_mut().zip(bias).for_each(|(z, &b)| *z += b);
                forward_kernel(act, zrow, &mut a[r * width..(r + 1) * width]);
            }
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
            .zip(a.iter().zip(g))
            .for_each(|(d, (&a, &g))| *d = if a > 0.0 { g } else { 0.0 }),
        Activation::Silu => dz
            .iter_mut()
            .zip(z.iter().zip(a.iter().zip(g)))
            .for_each(|(d, (&z, (&a, &g)))| *d = g * silu_grad(z, a)),
        Activation::Tanh => dz
            .iter_mut()
            .zip(a.iter().zip(g))
            .for_each(|(d, (&a, &g))| *d = g * (1.0 - a * a)),
    }
}

#[inline(always)]
fn backward_bias_grad_kernel(
    act: Activation,
    z: &[f32],
    a: &[f32],
    g: &[f32],
    dz: &mut [f32],
    db: &mut [f32],
) {
    let width = db.len();
    db.fill(0.0);
    let rows = g.len() / width;
    for r in 0..rows {
        let span = r * width..(r + 1) * width;
        let (dzr, gr) = (&mut dz[span.clone()], &g[span.clone()]);
        backward_kernel(act, &z[span.clone()], &a[span], gr, dzr);
        db.iter_mut().zip(dzr.iter()).for_each(|(s, &v)| *s += v);
    }
}

/// SiLU's derivative σ(z) + a·(1 − σ(z)) with σ(z) = a / z away from 0 and σ(0) = 1/2.
#[inline(always)]
fn silu_grad(z: f32, a: f32) -> f32 {
    let s = if z.abs() > 1e-12 { a / z } else { 0.5 };
    s + a * (1.0 - s)
}

/// Logistic sigmoid 1 / (1 + e^(−z)).
#[inline(always)]
pub fn sigmoid(z: f32) -> f32 {
    1.0 / (1.0 + exp_neg_f32(z))
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn fused_and_gathered_backward_equal_the_plain_one() {
        let (rows, width) = (5, 8);
        let z: Vec<f32> = (0..rows * width)
            .map(|i| (i as f32 * 0.61).sin() * 3.0)
            .collect();
        let g: Vec<f32> = (0..rows * width).map(|i| (i as f32 * 0.23).cos()).collect();
        for act in [
            Activation::Identity,
            Activation::Relu,
            Activation::Silu,
            Activation::Tanh,
        ] {
            // What a layer keeps: a in z's buffer for in-place activations.
            let mut kept_z = z.clone();
            let mut a = vec![0.0; z.len()];
            act.bias_forward(&mut kept_z, &[0.0; 8], &mut a);
            let kept_a = if act.in_place() {
                kept_z.clone()
            } else {
                a.clone()
            };
            let mut want_a = vec![0.0; z.len()];
            act.forward(&z, &mut want_a);
            assert_eq!(kept_a, want_a, "{act:?} forward");
            let mut dz = vec![0.0; z.len()];
            act.backward(&kept_z, &kept_a, &g, &mut dz);
            let (mut fused, mut db) = (vec![0.0; z.len()], vec![1.0; width]);
            act.backward_bias_grad(&kept_z, &kept_a, &g, &mut fused, &mut db);
            assert_eq!(dz, fused, "{act:?} fused dz");
            for j in 0..width {
                let want: f32 = (0..rows).map(|r| dz[r * width + j]).sum();
                assert!((db[j] - want).abs() < 1e-6, "{act:?} db");
            }
            let pick = [3usize, 0];
            let gc: Vec<f32> = pick
                .iter()
                .flat_map(|&r| g[r * width..(r + 1) * width].to_vec())
                .collect();
            let mut dc = vec![0.0; gc.len()];
            act.backward_rows(&kept_z, &kept_a, width, &pick, &gc, &mut dc);
            for (i, &r) in pick.iter().enumerate() {
                assert_eq!(
                    dc[i * width..(i + 1) * width],
                    dz[r * width..(r + 1) * width]
                );
            }
        }
    }
}
