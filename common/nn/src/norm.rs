//! LayerNorm on row-major batches, forward and backward (Ba, Kiros, Hinton 2016):
//! x̂ = (z − μ)/√(σ² + ε), y = γ·x̂ + β per row; backward dz = (g − mean(g) − x̂·mean(g·x̂)) /
//! √(σ² + ε) with g = γ·dy. TD-MPC2's networks normalise every hidden layer with it
//! (`mbpo_latent`), and [`crate::Mlp`] can (SAC's critics with `sac.critic_layer_norm`).

/// LayerNorm's ε (PyTorch's default, as TD-MPC2 uses it).
pub const LAYER_NORM_EPS: f32 = 1e-5;

use crate::math::lane_sum;

/// Row-wise LayerNorm of `rows` rows of `z` (width `gamma.len()`) into `y`, keeping the
/// normalised `x_hat` and each row's `inv_std` for the backward pass.
pub fn layer_norm_forward(
    z: &[f32],
    gamma: &[f32],
    beta: &[f32],
    x_hat: &mut [f32],
    inv_std: &mut [f32],
    y: &mut [f32],
) {
    crate::simd_dispatch!(layer_norm_forward_kernel[z, gamma, beta, x_hat, inv_std, y])
}

#[inline(always)]
fn layer_norm_forward_kernel(
    z: &[f32],
    gamma: &[f32],
    beta: &[f32],
    x_hat: &mut [f32],
    inv_std: &mut [f32],
    y: &mut [f32],
) {
    let n = gamma.len();
    for (r, inv) in inv_std.iter_mut().enumerate() {
        let row = &z[r * n..(r + 1) * n];
        let mean;
        (mean, *inv) = row_moments(row);
        let (xh, out) = (&mut x_hat[r * n..(r + 1) * n], &mut y[r * n..(r + 1) * n]);
        for j in 0..n {
            xh[j] = (row[j] - mean) * *inv;
            out[j] = gamma[j] * xh[j] + beta[j];
        }
    }
}

/// A row's mean and 1/√(σ² + ε): what LayerNorm normalises it by (every forward pass here
/// takes them from this one function, so fused passes give the same bits).
#[inline(always)]
pub fn row_moments(row: &[f32]) -> (f32, f32) {
    let n = row.len() as f32;
    let mean = lane_sum(row, |_, v| v) / n;
    let var = lane_sum(row, |_, v| (v - mean) * (v - mean)) / n;
    (mean, 1.0 / (var + LAYER_NORM_EPS).sqrt())
}

/// LayerNorm's backward pass, in place: `d` holds ∂L/∂y and receives ∂L/∂z; `dγ`, `dβ` are
/// added into `d_affine` when given.
pub fn layer_norm_backward(
    x_hat: &[f32],
    inv_std: &[f32],
    gamma: &[f32],
    d: &mut [f32],
    d_affine: Option<(&mut [f32], &mut [f32])>,
) {
    crate::simd_dispatch!(layer_norm_backward_kernel[x_hat, inv_std, gamma, d, d_affine])
}

#[inline(always)]
fn layer_norm_backward_kernel(
    x_hat: &[f32],
    inv_std: &[f32],
    gamma: &[f32],
    d: &mut [f32],
    mut d_affine: Option<(&mut [f32], &mut [f32])>,
) {
    let n = gamma.len();
    for (r, &inv) in inv_std.iter().enumerate() {
        let (xh, g_out) = (&x_hat[r * n..(r + 1) * n], &mut d[r * n..(r + 1) * n]);
        if let Some((dg, db)) = d_affine.as_mut() {
            for j in 0..n {
                dg[j] += g_out[j] * xh[j];
                db[j] += g_out[j];
            }
        }
        let mean_g = lane_sum(g_out, |j, v| gamma[j] * v) / n as f32;
        let mean_gx = lane_sum(g_out, |j, v| gamma[j] * v * xh[j]) / n as f32;
        // Each output reads only its own input and the row's means: in place is safe.
        for j in 0..n {
            g_out[j] = (gamma[j] * g_out[j] - mean_g - xh[j] * mean_gx) * inv;
        }
    }
}
