//! TD-MPC2's element-wise pieces, forward and backward, on row-major batches:
//!
//! | piece | forward | backward (what the forward pass kept) |
//! |---|---|---|
//! | Mish | a = z·tanh(softplus(z)) | tanh(sp) + z·σ(z)·(1 − tanh²(sp)), from z |
//! | LayerNorm | x̂ = (z − μ)/√(σ² + ε), y = γ·x̂ + β | dz = (g − mean(g) − x̂·mean(g·x̂)) / √(σ² + ε), g = γ·dy |
//! | SimNorm | softmax within each group of `SIMNORM_GROUP` | dz = s ⊙ (dy − Σ_group dy·s) |
//!
//! (Hansen, Su, Wang, "TD-MPC2", ICLR 2024: every hidden layer is Linear → LayerNorm → Mish;
//! the latent state is normalised by SimNorm, groups of 8.)

use mbpo_nn::math::exp_neg_f32;
/// LayerNorm lives with the dense layers (`mbpo_nn::norm`): SAC's critics use it too.
pub use mbpo_nn::norm::{layer_norm_backward, layer_norm_forward, row_moments, LAYER_NORM_EPS};

/// Width of a SimNorm group: the latent is a set of `dim / 8` simplices.
pub const SIMNORM_GROUP: usize = 8;

/// tanh(softplus(z)) and eᶻ from one exponential: with n = eᶻ, tanh(ln(1 + n)) =
/// n(n + 2) / (n(n + 2) + 2). Above z = 20 it is 1 in f32 (PyTorch's softplus switches to z
/// there), so z is capped there and the exponential never overflows. Branch-free, so a loop
/// over it vectorises (`mbpo_nn::math`): libm's exp, log1p and tanh per element had been 80 %
/// of an update's time.
#[inline(always)]
fn tanh_softplus(z: f32) -> (f32, f32) {
    let n = exp_neg_f32(-z.min(20.0));
    let q = n * (n + 2.0);
    (q / (q + 2.0), n)
}

/// `a = mish(z)` element-wise (through the CPU's widest SIMD copy: `mbpo_nn::simd`).
pub fn mish_forward(z: &[f32], a: &mut [f32]) {
    mbpo_nn::simd_dispatch!(mish_forward_kernel[z, a])
}

#[inline(always)]
fn mish_forward_kernel(z: &[f32], a: &mut [f32]) {
    for (a, &z) in a.iter_mut().zip(z) {
        *a = z * tanh_softplus(z).0;
    }
}

/// `a = mish(LayerNorm(z))` row by row (width `gamma.len()`), keeping neither x̂ nor the
/// normalised rows: a hidden layer's forward pass that no backward pass follows (planning). The
/// operations of [`layer_norm_forward`] then [`mish_forward`] in one pass over the row, so the
/// same bits with a third of the stores.
pub fn layer_norm_mish_forward(z: &[f32], gamma: &[f32], beta: &[f32], a: &mut [f32]) {
    mbpo_nn::simd_dispatch!(layer_norm_mish_forward_kernel[z, gamma, beta, a])
}

#[inline(always)]
fn layer_norm_mish_forward_kernel(z: &[f32], gamma: &[f32], beta: &[f32], a: &mut [f32]) {
    let n = gamma.len();
    for (row, out) in z.chunks_exact(n).zip(a.chunks_exact_mut(n)) {
        let (mean, inv) = row_moments(row);
        for j in 0..n {
            let y = gamma[j] * ((row[j] - mean) * inv) + beta[j];
            out[j] = y * tanh_softplus(y).0;
        }
    }
}

/// `dz = dy · mish'(z)` element-wise: mish'(z) = t + z·(1 − t²)·σ(z) with t = tanh(softplus(z))
/// and σ(z) = n / (1 + n).
pub fn mish_backward(z: &[f32], dy: &[f32], dz: &mut [f32]) {
    mbpo_nn::simd_dispatch!(mish_backward_kernel[z, dy, dz])
}

#[inline(always)]
fn mish_backward_kernel(z: &[f32], dy: &[f32], dz: &mut [f32]) {
    for ((dz, &z), &dy) in dz.iter_mut().zip(z).zip(dy) {
        let (t, n) = tanh_softplus(z);
        *dz = dy * (t + z * (1.0 - t * t) * (n / (1.0 + n)));
    }
}

/// SimNorm: `s` = softmax of each group of [`SIMNORM_GROUP`] consecutive values of `z`.
pub fn simnorm_forward(z: &[f32], s: &mut [f32]) {
    mbpo_nn::simd_dispatch!(simnorm_forward_kernel[z, s])
}

#[inline(always)]
fn simnorm_forward_kernel(z: &[f32], s: &mut [f32]) {
    for (zg, sg) in z
        .chunks_exact(SIMNORM_GROUP)
        .zip(s.chunks_exact_mut(SIMNORM_GROUP))
    {
        let max = zg.iter().fold(f32::NEG_INFINITY, |m, &v| m.max(v));
        let mut sum = 0.0;
        for (s, &z) in sg.iter_mut().zip(zg) {
            *s = exp_neg_f32(max - z);
            sum += *s;
        }
        sg.iter_mut().for_each(|s| *s /= sum);
    }
}

/// SimNorm's backward pass: `dz` from `dy` and the forward output `s`.
pub fn simnorm_backward(s: &[f32], dy: &[f32], dz: &mut [f32]) {
    for ((sg, dyg), dzg) in s
        .chunks_exact(SIMNORM_GROUP)
        .zip(dy.chunks_exact(SIMNORM_GROUP))
        .zip(dz.chunks_exact_mut(SIMNORM_GROUP))
    {
        let dot: f32 = sg.iter().zip(dyg).map(|(s, d)| s * d).sum();
        for ((dz, &s), &dy) in dzg.iter_mut().zip(sg).zip(dyg) {
            *dz = s * (dy - dot);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Central differences of `f` at `x` along each input, against `analytic` (∂(Σ w·f)/∂x).
    fn check(x: &[f32], w: &[f32], f: &dyn Fn(&[f32]) -> Vec<f32>, analytic: &[f32]) {
        let eps = 1e-2f32;
        for i in 0..x.len() {
            let at = |d: f32| {
                let mut x = x.to_vec();
                x[i] += d;
                f(&x)
                    .iter()
                    .zip(w)
                    .map(|(y, w)| (y * w) as f64)
                    .sum::<f64>()
            };
            let numeric = (at(eps) - at(-eps)) / (2.0 * eps as f64);
            let err = (analytic[i] as f64 - numeric).abs();
            assert!(
                err < 2e-3 + 1e-2 * numeric.abs(),
                "input {i}: analytic {} numeric {numeric}",
                analytic[i]
            );
        }
    }

    fn values(n: usize, seed: u32) -> Vec<f32> {
        (0..n)
            .map(|i| ((i as f32 + 1.0) * 0.37 * seed as f32).sin() * 2.5)
            .collect()
    }

    #[test]
    fn mish_matches_its_definition_and_its_derivative_finite_differences() {
        let mut z = values(16, 1);
        z.extend([-90.0, -30.0, 19.0, 25.0, 400.0]);
        let mut a = vec![0.0; z.len()];
        mish_forward(&z, &mut a);
        for (&z, &a) in z.iter().zip(&a) {
            let exact = z as f64 * (z as f64).exp().ln_1p().tanh();
            let tolerance = 2e-6 * exact.abs().max(1.0);
            assert!(
                (a as f64 - exact).abs() < tolerance,
                "mish({z}) = {a}, not {exact}"
            );
        }
        let w = values(z.len(), 2);
        let mut dz = vec![0.0; z.len()];
        mish_backward(&z, &w, &mut dz);
        let f = |z: &[f32]| {
            let mut a = vec![0.0; z.len()];
            mish_forward(z, &mut a);
            a
        };
        check(&z, &w, &f, &dz);
    }

    #[test]
    fn layer_norm_gradients_match_finite_differences() {
        let (rows, n) = (3, 6);
        let z = values(rows * n, 3);
        let (gamma, beta) = (values(n, 4), values(n, 5));
        let w = values(rows * n, 6);
        let f = |z: &[f32]| {
            let (mut xh, mut inv, mut y) =
                (vec![0.0; rows * n], vec![0.0; rows], vec![0.0; rows * n]);
            layer_norm_forward(z, &gamma, &beta, &mut xh, &mut inv, &mut y);
            y
        };
        let y = f(&z);
        for r in 0..rows {
            let row: Vec<f32> = (0..n)
                .map(|j| (y[r * n + j] - beta[j]) / gamma[j])
                .collect();
            let mean = row.iter().sum::<f32>() / n as f32;
            assert!(mean.abs() < 1e-5, "a normalised row has mean 0, not {mean}");
        }
        let (mut xh, mut inv, mut out) =
            (vec![0.0; rows * n], vec![0.0; rows], vec![0.0; rows * n]);
        layer_norm_forward(&z, &gamma, &beta, &mut xh, &mut inv, &mut out);
        let (mut dz, mut dg, mut db) = (w.clone(), vec![0.0; n], vec![0.0; n]);
        layer_norm_backward(&xh, &inv, &gamma, &mut dz, Some((&mut dg, &mut db)));
        check(&z, &w, &f, &dz);
        // dγ and dβ: the same check with γ (then β) as the input.
        let of_gamma = |g: &[f32]| {
            let (mut xh, mut inv, mut y) =
                (vec![0.0; rows * n], vec![0.0; rows], vec![0.0; rows * n]);
            layer_norm_forward(&z, g, &beta, &mut xh, &mut inv, &mut y);
            y
        };
        check(&gamma, &w, &of_gamma, &dg);
        let of_beta = |b: &[f32]| {
            let (mut xh, mut inv, mut y) =
                (vec![0.0; rows * n], vec![0.0; rows], vec![0.0; rows * n]);
            layer_norm_forward(&z, &gamma, b, &mut xh, &mut inv, &mut y);
            y
        };
        check(&beta, &w, &of_beta, &db);
    }

    #[test]
    fn simnorm_makes_simplices_and_its_gradient_matches_finite_differences() {
        let z = values(2 * SIMNORM_GROUP, 7);
        let mut s = vec![0.0; z.len()];
        simnorm_forward(&z, &mut s);
        for g in s.chunks_exact(SIMNORM_GROUP) {
            assert!((g.iter().sum::<f32>() - 1.0).abs() < 1e-6);
            assert!(g.iter().all(|&v| v > 0.0));
        }
        let w = values(z.len(), 8);
        let mut dz = vec![0.0; z.len()];
        simnorm_backward(&s, &w, &mut dz);
        let f = |z: &[f32]| {
            let mut s = vec![0.0; z.len()];
            simnorm_forward(z, &mut s);
            s
        };
        check(&z, &w, &f, &dz);
    }
}
