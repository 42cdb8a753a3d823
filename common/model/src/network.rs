//! The ensemble's passes: a fused forward/loss/backward for training and a forward for inference.
//!
//! Each member is an MLP `[obs + act] → h_1 → … → h_L → 2d` with SiLU hidden layers and a linear
//! output read as `[μ (d) | raw logvar (d)]`, d = 1 + obs_dim (reward, Δobs). The architecture
//! and the member-major parameter layout are [`mbpo_nn::EnsembleMlp`]'s; the passes are written
//! here rather than calling `Mlp::forward`/`backward` because fusing the element-wise work into
//! the GEMM epilogues (bias + SiLU + σ kept for the backward pass; SiLU' + bias gradient; the
//! whole Gaussian NLL and its gradient in one pass over the outputs) halves the passes over the
//! activations, which is what stands between the GEMMs and the machine's roofline.
//!
//! The flat parameter vector θ is `[ensemble weights and biases | max_logvar (d) | min_logvar (d)]`.

use crate::simd::{dispatch, LogvarBounds, NllAccumulators};
use mbpo_nn::gemm::{gemm, Op};
use mbpo_nn::{Activation, EnsembleMlp, Mlp, ParamLayout};
use std::ops::Range;

/// Rows per inference GEMM: large enough for full-speed GEMMs, small enough that one layer's
/// activations (rows x 200 x 4 B, twice) stay in L2.
pub(crate) const INFER_CHUNK: usize = 256;

/// Architecture of the ensemble and the offsets of everything in θ.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Net {
    ens: EnsembleMlp,
    /// Target width d = 1 + obs_dim.
    d: usize,
    layout: ParamLayout,
}

impl Net {
    pub(crate) fn new(members: usize, in_dim: usize, hidden: &[usize], d: usize) -> Self {
        let dims: Vec<usize> = std::iter::once(in_dim)
            .chain(hidden.iter().copied())
            .chain(std::iter::once(2 * d))
            .collect();
        let ens = EnsembleMlp::new(
            members,
            Mlp::new(&dims, Activation::Silu, Activation::Identity),
        );
        let mut layout = ParamLayout::new();
        layout.extend_prefixed("ensemble", ens.layout());
        layout.push("max_logvar", &[d]);
        layout.push("min_logvar", &[d]);
        Self { ens, d, layout }
    }

    pub(crate) fn ensemble(&self) -> &EnsembleMlp {
        &self.ens
    }
    pub(crate) fn mlp(&self) -> &Mlp {
        self.ens.mlp()
    }
    pub(crate) fn layout(&self) -> &ParamLayout {
        &self.layout
    }
    pub(crate) fn members(&self) -> usize {
        self.ens.members()
    }
    pub(crate) fn d(&self) -> usize {
        self.d
    }
    pub(crate) fn in_dim(&self) -> usize {
        self.mlp().in_dim()
    }
    /// Length of θ.
    pub(crate) fn num_params(&self) -> usize {
        self.layout.len()
    }
    /// Parameters of the MLPs (the prefix of θ).
    pub(crate) fn num_net_params(&self) -> usize {
        self.ens.num_params()
    }
    /// Range of `max_logvar` in θ.
    pub(crate) fn max_logvar_range(&self) -> Range<usize> {
        let s = self.num_net_params();
        s..s + self.d
    }
    /// Range of `min_logvar` in θ.
    pub(crate) fn min_logvar_range(&self) -> Range<usize> {
        let s = self.num_net_params() + self.d;
        s..s + self.d
    }
    /// Widest layer (buffer sizing).
    fn widest(&self) -> usize {
        *self.mlp().dims().iter().max().unwrap()
    }
    fn hidden_layers(&self) -> usize {
        self.mlp().num_layers() - 1
    }

    /// GEMM flops of one forward pass of one member on `rows` rows (2 per multiply-add).
    pub(crate) fn forward_flops(&self, rows: usize) -> u64 {
        self.mlp()
            .dims()
            .windows(2)
            .map(|w| 2 * (rows * w[0] * w[1]) as u64)
            .sum()
    }

    /// GEMM flops of one training step of one member on `rows` rows: the forward pass, `∂W` of
    /// every layer and `∂a` of every layer but the input (which needs no gradient).
    pub(crate) fn train_step_flops(&self, rows: usize) -> u64 {
        let dims = self.mlp().dims();
        let first = 2 * (rows * dims[0] * dims[1]) as u64;
        3 * self.forward_flops(rows) - first
    }
}

/// Per-member buffers of a training step at up to `batch` rows; sized once per model.
#[derive(Debug, Clone, Default)]
pub(crate) struct TrainBuffers {
    batch: usize,
    /// Hidden activations a_l (`batch x h_l`), input of layer l + 1.
    act: Vec<Vec<f32>>,
    /// σ(z_l) of each hidden layer, kept for SiLU's derivative.
    sig: Vec<Vec<f32>>,
    /// Output layer values, then ∂L/∂(output) (`batch x 2d`).
    y: Vec<f32>,
    /// Ping-pong buffers for ∂L/∂a.
    g: [Vec<f32>; 2],
    /// Per-dimension scratch of the loss pass.
    scratch: Vec<f32>,
}

impl TrainBuffers {
    pub(crate) fn ensure(&mut self, net: &Net, batch: usize) {
        if self.batch >= batch && self.act.len() == net.hidden_layers() {
            return;
        }
        let dims = net.mlp().dims();
        self.act = dims[1..dims.len() - 1]
            .iter()
            .map(|&h| vec![0.0; batch * h])
            .collect();
        self.sig = self.act.clone();
        self.y = vec![0.0; batch * 2 * net.d];
        self.g = [
            vec![0.0; batch * net.widest()],
            vec![0.0; batch * net.widest()],
        ];
        self.scratch = vec![0.0; net.d];
        self.batch = batch;
    }
}

/// Split a member's gradient slice into layer l's weight and bias gradients.
fn layer_grads<'g>(mlp: &Mlp, grads: &'g mut [f32], l: usize) -> (&'g mut [f32], &'g mut [f32]) {
    let (wr, br) = (mlp.weight_range(l), mlp.bias_range(l));
    debug_assert!(wr.end <= br.start);
    let (gw, gb) = grads.split_at_mut(br.start);
    (&mut gw[wr], &mut gb[..br.len()])
}

/// One member's Gaussian NLL on a minibatch and its gradient, by a fused forward, loss and
/// backward pass (see the module docs).
///
/// * `theta`: all parameters; `e`: the member; `x`: standardised inputs (`batch x in`);
///   `targets`: `[reward, Δobs]` rows (`batch x d`); `mean_over`: the rows the loss is a
///   mean over (`batch`, or the whole minibatch when these rows are a part of it).
/// * `g_member`: member e's MLP gradient (its range of θ), overwritten.
/// * `g_bounds`: `[∂/∂max_logvar | ∂/∂min_logvar]` (`2d`), *added to*: the bounds are shared
///   by all members, and callers give each member its own zeroed slot and add the slots in
///   member order, so the sum does not depend on how members are spread over threads.
///
/// Returns this member's loss `mean((μ − y)²·e^(−lv)) + mean(lv)` (means over `mean_over`
/// rows and the dims).
#[allow(clippy::too_many_arguments)]
pub(crate) fn member_loss_and_grad(
    net: &Net,
    theta: &[f32],
    e: usize,
    x: &[f32],
    targets: &[f32],
    batch: usize,
    mean_over: usize,
    buf: &mut TrainBuffers,
    g_member: &mut [f32],
    g_bounds: &mut [f32],
) -> f64 {
    buf.ensure(net, batch);
    let mlp = net.mlp();
    let d = net.d;
    let member = net.ensemble().member_range(e);
    debug_assert_eq!(g_member.len(), member.len());
    let p = &theta[member];
    let (max_lv, min_lv) = (
        &theta[net.max_logvar_range()],
        &theta[net.min_logvar_range()],
    );
    let (d_max, d_min) = g_bounds.split_at_mut(d);
    train_forward(net, p, x, batch, buf);

    // Loss and ∂L/∂(output), ∂L/∂b_out, ∂L/∂bounds in one pass.
    let out = net.hidden_layers();
    let scale = 1.0 / (mean_over * d) as f32;
    let (_, gb_out) = layer_grads(mlp, g_member, out);
    let mut acc = NllAccumulators {
        db: gb_out,
        d_max,
        d_min,
        scratch: &mut buf.scratch,
    };
    let bounds = LogvarBounds {
        max: max_lv,
        min: min_lv,
    };
    let loss = dispatch!(gaussian_nll_rows(
        &mut buf.y[..batch * mlp.dims()[out + 1]],
        &targets[..batch * d],
        &p[mlp.bias_range(out)],
        &bounds,
        scale,
        &mut acc
    ));
    train_backward(net, p, x, batch, buf, g_member);
    loss
}

/// The forward pass of [`member_loss_and_grad`] with member parameters `p`: z_l = a_{l−1} W_l,
/// then a_l = SiLU(z_l + b_l) with σ kept, and the output layer's z (its bias is added by the
/// loss pass) into `buf.y`.
fn train_forward(net: &Net, p: &[f32], x: &[f32], batch: usize, buf: &mut TrainBuffers) {
    let mlp = net.mlp();
    let dims = mlp.dims();
    let hidden = net.hidden_layers();
    for l in 0..hidden {
        let (n_in, n_out) = (dims[l], dims[l + 1]);
        let (done, todo) = buf.act.split_at_mut(l);
        let input: &[f32] = if l == 0 {
            &x[..batch * n_in]
        } else {
            &done[l - 1][..batch * n_in]
        };
        let z = &mut todo[0][..batch * n_out];
        gemm(
            z,
            input,
            Op::N,
            &p[mlp.weight_range(l)],
            Op::N,
            batch,
            n_in,
            n_out,
            false,
        );
        let sig = &mut buf.sig[l][..batch * n_out];
        dispatch!(bias_silu(z, Some(sig), &p[mlp.bias_range(l)]));
    }
    let out = hidden;
    let (n_in, n_out) = (dims[out], dims[out + 1]);
    let top = &buf.act[out - 1][..batch * n_in];
    let y = &mut buf.y[..batch * n_out];
    gemm(
        y,
        top,
        Op::N,
        &p[mlp.weight_range(out)],
        Op::N,
        batch,
        n_in,
        n_out,
        false,
    );
}

/// The backward pass of [`member_loss_and_grad`], `buf.y` holding ∂L/∂(output): the weight
/// gradients into `g_member` (the biases' were added by the loss pass and by
/// `silu_backward_bias_grad`), layer by layer from the top.
fn train_backward(
    net: &Net,
    p: &[f32],
    x: &[f32],
    batch: usize,
    buf: &mut TrainBuffers,
    g_member: &mut [f32],
) {
    let mlp = net.mlp();
    let dims = mlp.dims();
    let hidden = net.hidden_layers();
    let out = hidden;
    let (n_in, n_out) = (dims[out], dims[out + 1]);
    let top = &buf.act[out - 1][..batch * n_in];
    let y = &buf.y[..batch * n_out];
    let (gw_out, _) = layer_grads(mlp, g_member, out);
    gemm(gw_out, top, Op::T, y, Op::N, n_in, batch, n_out, false);
    let [g0, g1] = &mut buf.g;
    gemm(
        &mut g0[..batch * n_in],
        y,
        Op::N,
        &p[mlp.weight_range(out)],
        Op::T,
        batch,
        n_out,
        n_in,
        false,
    );
    // Hidden layers, top down; `g_cur` holds ∂L/∂a_l on entry.
    let (mut g_cur, mut g_next) = (g0, g1);
    for l in (0..hidden).rev() {
        let (n_in, n_out) = (dims[l], dims[l + 1]);
        let (gw, gb) = layer_grads(mlp, g_member, l);
        let dz = &mut g_cur[..batch * n_out];
        dispatch!(silu_backward_bias_grad(
            dz,
            &buf.act[l][..batch * n_out],
            &buf.sig[l][..batch * n_out],
            gb
        ));
        let input: &[f32] = if l == 0 {
            &x[..batch * n_in]
        } else {
            &buf.act[l - 1][..batch * n_in]
        };
        gemm(gw, input, Op::T, dz, Op::N, n_in, batch, n_out, false);
        if l > 0 {
            gemm(
                &mut g_next[..batch * n_in],
                dz,
                Op::N,
                &p[mlp.weight_range(l)],
                Op::T,
                batch,
                n_out,
                n_in,
                false,
            );
            std::mem::swap(&mut g_cur, &mut g_next);
        }
    }
}

/// Buffers of an inference forward pass over up to [`INFER_CHUNK`] rows.
#[derive(Debug, Clone, Default)]
pub(crate) struct InferBuffers {
    h: [Vec<f32>; 2],
    /// Outputs `[μ | logvar]` (`rows x 2d`), bias and bounds applied.
    pub(crate) y: Vec<f32>,
}

impl InferBuffers {
    pub(crate) fn ensure(&mut self, net: &Net) {
        if self.y.len() == INFER_CHUNK * 2 * net.d && self.h[0].len() == INFER_CHUNK * net.widest()
        {
            return;
        }
        self.h = [
            vec![0.0; INFER_CHUNK * net.widest()],
            vec![0.0; INFER_CHUNK * net.widest()],
        ];
        self.y = vec![0.0; INFER_CHUNK * 2 * net.d];
    }
}

/// Member e's prediction on `rows` (≤ [`INFER_CHUNK`]) standardised inputs `x`: leaves
/// `[μ | logvar]` rows in `buf.y` (logvar bounded). With `with_logvar` false only μ is finished
/// (the logvar half holds raw outputs), which is all a holdout MSE needs.
pub(crate) fn member_forward(
    net: &Net,
    theta: &[f32],
    e: usize,
    x: &[f32],
    rows: usize,
    buf: &mut InferBuffers,
    with_logvar: bool,
) {
    assert!(rows <= INFER_CHUNK);
    buf.ensure(net);
    let mlp = net.mlp();
    let dims = mlp.dims();
    let hidden = net.hidden_layers();
    let p = &theta[net.ensemble().member_range(e)];
    let [h0, h1] = &mut buf.h;
    let (mut cur, mut next) = (h0, h1);
    for l in 0..hidden {
        let (n_in, n_out) = (dims[l], dims[l + 1]);
        let input: &[f32] = if l == 0 {
            &x[..rows * n_in]
        } else {
            &cur[..rows * n_in]
        };
        let z = &mut next[..rows * n_out];
        gemm(
            z,
            input,
            Op::N,
            &p[mlp.weight_range(l)],
            Op::N,
            rows,
            n_in,
            n_out,
            false,
        );
        dispatch!(bias_silu(z, None, &p[mlp.bias_range(l)]));
        std::mem::swap(&mut cur, &mut next);
    }
    let (n_in, n_out) = (dims[hidden], dims[hidden + 1]);
    let y = &mut buf.y[..rows * n_out];
    let w = &p[mlp.weight_range(hidden)];
    gemm(
        y,
        &cur[..rows * n_in],
        Op::N,
        w,
        Op::N,
        rows,
        n_in,
        n_out,
        false,
    );
    let bias = &p[mlp.bias_range(hidden)];
    if with_logvar {
        let max_lv = &theta[net.max_logvar_range()];
        let min_lv = &theta[net.min_logvar_range()];
        dispatch!(gaussian_head(y, bias, max_lv, min_lv));
    } else {
        dispatch!(add_bias(y, bias));
    }
}

/// Member e's holdout MSE of the mean prediction on `n` standardised rows `x` with `[reward,
/// Δobs]` targets (mean over rows and dims, summed in f64 in row order).
pub(crate) fn member_mse(
    net: &Net,
    theta: &[f32],
    e: usize,
    x: &[f32],
    targets: &[f32],
    n: usize,
    buf: &mut InferBuffers,
) -> f32 {
    let (in_dim, d) = (net.in_dim(), net.d);
    let mut sum = 0.0f64;
    let mut start = 0;
    while start < n {
        let rows = (n - start).min(INFER_CHUNK);
        let xs = &x[start * in_dim..(start + rows) * in_dim];
        member_forward(net, theta, e, xs, rows, buf, false);
        let ts = &targets[start * d..(start + rows) * d];
        for (row, t) in buf.y.chunks_exact(2 * d).zip(ts.chunks_exact(d)) {
            sum += row[..d]
                .iter()
                .zip(t)
                .map(|(&m, &v)| ((m - v) as f64).powi(2))
                .sum::<f64>();
        }
        start += rows;
    }
    (sum / (n * d).max(1) as f64) as f32
}

/// [`member_mse`] of every member, one after the other.
pub(crate) fn members_mse(
    net: &Net,
    theta: &[f32],
    x: &[f32],
    targets: &[f32],
    n: usize,
    buf: &mut InferBuffers,
    mse: &mut [f32],
) {
    for (e, out) in mse.iter_mut().enumerate().take(net.members()) {
        *out = member_mse(net, theta, e, x, targets, n, buf);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::rng::normal_f32;
    use mbpo_core::stream;
    use mbpo_nn::{Init, MlpCache};

    #[test]
    fn fused_inference_forward_matches_the_nn_crate() {
        let net = Net::new(3, 5, &[32, 24], 4);
        let mut rng = stream(1, "net", 0);
        let mut theta = vec![0.0f32; net.num_params()];
        let n_net = net.num_net_params();
        net.ensemble()
            .init(&mut theta[..n_net], Init::TruncatedNormal, &mut rng);
        theta[..n_net]
            .iter_mut()
            .for_each(|p| *p += 0.05 * normal_f32(&mut rng));
        let rows = 37;
        let x: Vec<f32> = (0..rows * 5).map(|_| normal_f32(&mut rng)).collect();
        let mut buf = InferBuffers::default();
        let mut cache = MlpCache::new(net.mlp(), rows);
        for e in 0..3 {
            member_forward(&net, &theta, e, &x, rows, &mut buf, false);
            let want = net
                .ensemble()
                .forward_member(e, &theta[..n_net], &x, rows, &mut cache);
            for (i, (&got, &want)) in buf.y[..rows * 8].iter().zip(want).enumerate() {
                assert!(
                    (got - want).abs() <= 1e-5 * want.abs().max(1.0),
                    "member {e} output {i}: {got} vs {want}"
                );
            }
        }
    }
}
