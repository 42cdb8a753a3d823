//! TD-MPC2's network: every hidden layer is Linear → LayerNorm → Mish, and the output layer is
//! a plain Linear (reward, Q and policy heads) or Linear → LayerNorm → SimNorm (the encoder and
//! the latent dynamics, whose output is a latent state).
//!
//! Like `mbpo_nn::Mlp`, the network owns no numbers: its parameters are one `&[f32]` described
//! by its [`ParamLayout`] (per layer `w` `in x out`, `b`, then `ln_g`, `ln_b` on normed layers),
//! and a [`NormedCache`] keeps what a forward pass needs for its backward pass. The backward
//! pass *adds* into the parameter gradient: the world model applies its dynamics once per step
//! of the horizon, and the gradients of every application sum.

use std::ops::Range;

use mbpo_core::rng::{normal_f32, uniform_f64, Rng};
use mbpo_nn::gemm::bf16::{self, gemm_bf16, Bf16Scratch, PackedBf16};
use mbpo_nn::gemm::{gemm, Op};
use mbpo_nn::ParamLayout;

use crate::elementwise::{
    layer_norm_backward, layer_norm_forward, layer_norm_mish_forward, mish_backward, mish_forward,
    simnorm_backward, simnorm_forward, SIMNORM_GROUP,
};

/// What the output layer is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Head {
    /// A plain Linear layer (logits, a mean and log-std, a value).
    Linear,
    /// Linear → LayerNorm → SimNorm: a latent state (its width a multiple of the group).
    SimNorm,
}

/// The parameter ranges of one layer.
#[derive(Debug, Clone)]
struct LayerParams {
    w: Range<usize>,
    b: Range<usize>,
    /// LayerNorm's γ and β (every layer but a Linear head).
    norm: Option<(Range<usize>, Range<usize>)>,
}

/// A TD-MPC2 network of widths `dims` (see the module docs).
#[derive(Debug, Clone)]
pub struct NormedMlp {
    dims: Vec<usize>,
    head: Head,
    layers: Vec<LayerParams>,
    layout: ParamLayout,
}

impl NormedMlp {
    /// A network of widths `dims` (input, hidden..., output) with output layer `head`.
    pub fn new(dims: &[usize], head: Head) -> Self {
        assert!(
            dims.len() >= 2,
            "a network has an input and an output width"
        );
        if head == Head::SimNorm {
            assert!(
                dims[dims.len() - 1].is_multiple_of(SIMNORM_GROUP),
                "a SimNorm output is a multiple of {SIMNORM_GROUP} wide"
            );
        }
        let mut layout = ParamLayout::new();
        let n = dims.len() - 1;
        let layers = (0..n)
            .map(|l| {
                let (i, o) = (dims[l], dims[l + 1]);
                let w = layout.push(format!("l{l}.w"), &[i, o]);
                let b = layout.push(format!("l{l}.b"), &[o]);
                let normed = l + 1 < n || head == Head::SimNorm;
                let norm = normed.then(|| {
                    let g = layout.push(format!("l{l}.ln_g"), &[o]);
                    (g, layout.push(format!("l{l}.ln_b"), &[o]))
                });
                LayerParams { w, b, norm }
            })
            .collect();
        Self {
            dims: dims.to_vec(),
            head,
            layers,
            layout,
        }
    }

    /// Input width.
    pub fn in_dim(&self) -> usize {
        self.dims[0]
    }
    /// Output width.
    pub fn out_dim(&self) -> usize {
        self.dims[self.dims.len() - 1]
    }
    /// What its output layer is.
    pub fn head(&self) -> Head {
        self.head
    }
    /// Number of parameters.
    pub fn num_params(&self) -> usize {
        self.layout.len()
    }
    /// The parameter layout.
    pub fn layout(&self) -> &ParamLayout {
        &self.layout
    }

    /// TD-MPC2's initialisation: weights N(0, 0.02²) truncated at ±2σ, biases 0, LayerNorm
    /// γ = 1 and β = 0; with `zero_output`, the output layer's weights 0 (its reward and Q
    /// heads start at a value of exactly 0).
    pub fn init(&self, params: &mut [f32], zero_output: bool, rng: &mut Rng) {
        assert_eq!(params.len(), self.num_params());
        let last = self.layers.len() - 1;
        for (l, p) in self.layers.iter().enumerate() {
            for w in &mut params[p.w.clone()] {
                *w = match zero_output && l == last {
                    true => 0.0,
                    false => truncated_normal(rng) * 0.02,
                };
            }
            params[p.b.clone()].fill(0.0);
            if let Some((g, b)) = &p.norm {
                params[g.clone()].fill(1.0);
                params[b.clone()].fill(0.0);
            }
        }
    }

    /// Forward pass on `batch` rows of `x`; the output rows are in `cache`.
    pub fn forward<'c>(
        &self,
        params: &[f32],
        x: &[f32],
        batch: usize,
        cache: &'c mut NormedCache,
    ) -> &'c [f32] {
        cache.ensure(self, batch);
        let last = self.layers.len() - 1;
        for (l, p) in self.layers.iter().enumerate() {
            let (n_in, n_out) = (self.dims[l], self.dims[l + 1]);
            let (done, todo) = cache.layers.split_at_mut(l);
            let input = match l {
                0 => &x[..batch * n_in],
                _ => &done[l - 1].a[..batch * n_in],
            };
            let c = &mut todo[0];
            let z = &mut c.z[..batch * n_out];
            match cache.bf16.as_mut() {
                Some(w) => gemm_bf16(z, input, batch, &w.layers[l], &mut w.scratch),
                None => gemm(
                    z,
                    input,
                    Op::N,
                    &params[p.w.clone()],
                    Op::N,
                    batch,
                    n_in,
                    n_out,
                    false,
                ),
            }
            add_bias(z, &params[p.b.clone()]);
            if l == 0 && cache.dropout_on {
                z.iter_mut().zip(&cache.dropout).for_each(|(z, m)| *z *= m);
            }
            let Some((g, b)) = &p.norm else {
                c.a[..batch * n_out].copy_from_slice(z);
                continue;
            };
            let (gamma, beta) = (&params[g.clone()], &params[b.clone()]);
            if cache.forward_only && l != last {
                layer_norm_mish_forward(z, gamma, beta, &mut c.a[..batch * n_out]);
                continue;
            }
            layer_norm_forward(
                z,
                gamma,
                beta,
                &mut c.x_hat,
                &mut c.inv_std[..batch],
                &mut c.y,
            );
            match l == last {
                true => simnorm_forward(&c.y[..batch * n_out], &mut c.a[..batch * n_out]),
                false => mish_forward(&c.y[..batch * n_out], &mut c.a[..batch * n_out]),
            }
        }
        &cache.layers[last].a[..batch * self.out_dim()]
    }

    /// Backward pass of the last [`NormedMlp::forward`] with `cache` on `x`: `d_out` is
    /// ∂L/∂y; ∂L/∂θ is **added** into `grads` and ∂L/∂x written into `d_input`, when given.
    pub fn backward(
        &self,
        params: &[f32],
        x: &[f32],
        cache: &mut NormedCache,
        d_out: &[f32],
        mut grads: Option<&mut [f32]>,
        d_input: Option<&mut [f32]>,
    ) {
        assert!(
            !cache.forward_only,
            "a forward-only cache keeps nothing for a backward pass"
        );
        let batch = cache.batch;
        let last = self.layers.len() - 1;
        cache.d_a[..batch * self.out_dim()].copy_from_slice(&d_out[..batch * self.out_dim()]);
        let mut d_input = d_input;
        for (l, p) in self.layers.iter().enumerate().rev() {
            let (n_in, n_out) = (self.dims[l], self.dims[l + 1]);
            let rows = batch * n_out;
            let NormedCache {
                layers,
                d_a,
                d_y,
                dropout,
                dropout_on,
                ..
            } = cache;
            let c = &layers[l];
            // ∂L/∂z into d_y: through the activation and the LayerNorm, or as it is.
            if let Some((g, b)) = &p.norm {
                match l == last {
                    true => simnorm_backward(&c.a[..rows], &d_a[..rows], &mut d_y[..rows]),
                    false => mish_backward(&c.y[..rows], &d_a[..rows], &mut d_y[..rows]),
                }
                let affine = grads.as_deref_mut().map(|gr| {
                    let (lo, hi) = gr.split_at_mut(b.start);
                    (&mut lo[g.clone()], &mut hi[..b.len()])
                });
                let gamma = &params[g.clone()];
                let (x_hat, inv_std) = (&c.x_hat[..rows], &c.inv_std[..batch]);
                layer_norm_backward(x_hat, inv_std, gamma, &mut d_y[..rows], affine);
            } else {
                d_y[..rows].copy_from_slice(&d_a[..rows]);
            }
            if l == 0 && *dropout_on {
                d_y[..rows]
                    .iter_mut()
                    .zip(&*dropout)
                    .for_each(|(d, m)| *d *= m);
            }
            let dz = &d_y[..rows];
            let input = match l {
                0 => &x[..batch * n_in],
                _ => &layers[l - 1].a[..batch * n_in],
            };
            if let Some(gr) = grads.as_deref_mut() {
                add_linear_grads(gr, p, input, dz, (n_in, n_out));
            }
            let w = &params[p.w.clone()];
            // ∂L/∂x for the caller on the first layer, ∂L/∂a of the layer below otherwise.
            let below = match l {
                0 => d_input.as_deref_mut(),
                _ => Some(&mut d_a[..]),
            };
            if let Some(out) = below {
                let out = &mut out[..batch * n_in];
                gemm(out, dz, Op::N, w, Op::T, batch, n_out, n_in, false);
            }
        }
    }
}

/// A Linear layer's ∂L/∂W (= inputᵀ·dz) and ∂L/∂b (Σ rows of dz) added into `grads`.
fn add_linear_grads(
    grads: &mut [f32],
    p: &LayerParams,
    input: &[f32],
    dz: &[f32],
    (n_in, n_out): (usize, usize),
) {
    let batch = dz.len() / n_out;
    let w = &mut grads[p.w.clone()];
    gemm(w, input, Op::T, dz, Op::N, n_in, batch, n_out, true);
    let gb = &mut grads[p.b.clone()];
    for row in dz.chunks_exact(n_out) {
        gb.iter_mut().zip(row).for_each(|(g, d)| *g += d);
    }
}

fn add_bias(z: &mut [f32], bias: &[f32]) {
    for row in z.chunks_exact_mut(bias.len()) {
        row.iter_mut().zip(bias).for_each(|(z, b)| *z += b);
    }
}

/// N(0, 1) truncated to [−2, 2] by redrawing (PyTorch's `trunc_normal_` bounds).
fn truncated_normal(rng: &mut Rng) -> f32 {
    loop {
        let v = normal_f32(rng);
        if v.abs() <= 2.0 {
            return v;
        }
    }
}

/// One layer's activations.
#[derive(Debug, Clone, Default)]
struct LayerCache {
    z: Vec<f32>,
    x_hat: Vec<f32>,
    inv_std: Vec<f32>,
    y: Vec<f32>,
    a: Vec<f32>,
}

/// What a forward pass keeps for its backward pass, sized for a batch once.
#[derive(Debug, Clone, Default)]
pub struct NormedCache {
    batch: usize,
    layers: Vec<LayerCache>,
    /// ∂L/∂a of the layer being passed back through (the widest layer's size).
    d_a: Vec<f32>,
    /// ∂L/∂y, then ∂L/∂z, of that layer.
    d_y: Vec<f32>,
    /// Dropout's mask on the first layer's Linear output (0, or 1/(1 − p) for a kept unit),
    /// applied by the passes while `dropout_on`.
    dropout: Vec<f32>,
    dropout_on: bool,
    /// The weights in bf16 when the forward passes multiply on AMX ([`NormedCache::use_bf16`]).
    bf16: Option<Bf16Weights>,
    /// No backward pass follows ([`NormedCache::forward_only`]): hidden layers keep only their
    /// outputs.
    forward_only: bool,
}

/// A network's weight matrices packed for AMX bf16 products, and the scratch they need.
#[derive(Debug, Clone)]
struct Bf16Weights {
    layers: Vec<PackedBf16>,
    scratch: Bf16Scratch,
}

impl NormedCache {
    /// A cache for `batch` rows of `net`.
    pub fn new(net: &NormedMlp, batch: usize) -> Self {
        let mut c = Self::default();
        c.ensure(net, batch);
        c
    }

    /// Drop each unit of the first layer's Linear output with probability `p` in the passes
    /// that follow (TD-MPC2's Q heads while learning: dropout before the first LayerNorm); the
    /// kept ones are scaled by 1/(1 − p). `p` = 0 draws nothing and drops nothing.
    pub fn draw_dropout(&mut self, net: &NormedMlp, batch: usize, p: f32, rng: &mut Rng) {
        self.ensure(net, batch);
        self.dropout_on = p > 0.0;
        if !self.dropout_on {
            return;
        }
        let (n, keep) = (batch * net.dims[1], 1.0 / (1.0 - p));
        self.dropout.resize(n, 0.0);
        for m in &mut self.dropout[..n] {
            *m = if uniform_f64(rng) < p as f64 {
                0.0
            } else {
                keep
            };
        }
    }

    /// From now on no backward pass goes through this cache (a planner's): each hidden layer's
    /// LayerNorm and Mish run as one pass that keeps only its output, with the same bits.
    pub fn forward_only(&mut self) {
        self.forward_only = true;
    }

    /// From now on this cache's forward passes multiply in bf16 on AMX (inputs rounded to bf16,
    /// sums in f32), for up to the rows it was made for -- planning, where a product's rounding
    /// is noise next to the sampling. False, and the passes stay f32, where the CPU or kernel
    /// has no AMX. Call [`NormedCache::pack_bf16`] after every change of the parameters.
    pub fn use_bf16(&mut self, net: &NormedMlp) -> bool {
        if !bf16::available() {
            return false;
        }
        let widest = net.dims.iter().copied().max().unwrap_or(0);
        self.bf16 = Some(Bf16Weights {
            layers: net
                .dims
                .windows(2)
                .map(|d| PackedBf16::new(d[0], d[1]))
                .collect(),
            scratch: Bf16Scratch::new(self.rows_made_for(), widest, widest),
        });
        true
    }

    /// Packs the weight matrices of `params` (the network's own slice) for the bf16 products;
    /// nothing when the cache multiplies in f32. No allocation.
    pub fn pack_bf16(&mut self, net: &NormedMlp, params: &[f32]) {
        let Some(w) = self.bf16.as_mut() else {
            return;
        };
        for (packed, p) in w.layers.iter_mut().zip(&net.layers) {
            packed.pack(&params[p.w.clone()]);
        }
    }

    /// The most rows a forward pass through this cache can take (its buffers' size; `batch`
    /// is only the last pass's).
    fn rows_made_for(&self) -> usize {
        self.layers.first().map_or(0, |l| l.inv_std.len())
    }

    fn ensure(&mut self, net: &NormedMlp, batch: usize) {
        self.batch = batch;
        let widest = net.dims.iter().copied().max().unwrap_or(0) * batch;
        if self.layers.len() == net.layers.len() && self.d_a.len() >= widest {
            return;
        }
        self.layers = net.dims[1..]
            .iter()
            .map(|&o| LayerCache {
                z: vec![0.0; batch * o],
                x_hat: vec![0.0; batch * o],
                inv_std: vec![0.0; batch],
                y: vec![0.0; batch * o],
                a: vec![0.0; batch * o],
            })
            .collect();
        self.d_a = vec![0.0; widest];
        self.d_y = vec![0.0; widest];
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::rng::stream;

    /// ∂(Σ w·net(x))/∂θ and ∂/∂x against central differences.
    /// (`dropout`: with that fraction of the first layer's units dropped, one mask throughout.)
    fn check(net: &NormedMlp, batch: usize, dropout: f32) {
        let mut rng = stream(3, "test.normed", 0);
        let mut params = vec![0.0; net.num_params()];
        net.init(&mut params, false, &mut rng);
        // Larger weights than the init's 0.02 so every path carries a visible gradient.
        for (i, p) in params.iter_mut().enumerate() {
            *p += 0.3 * ((i as f32) * 0.91).sin();
        }
        let x: Vec<f32> = (0..batch * net.in_dim())
            .map(|i| (i as f32 * 0.53).cos())
            .collect();
        let w: Vec<f32> = (0..batch * net.out_dim())
            .map(|i| (i as f32 * 0.29).sin())
            .collect();
        let mut cache = NormedCache::new(net, batch);
        cache.draw_dropout(net, batch, dropout, &mut stream(4, "test.dropout", 0));
        let loss = |p: &[f32], x: &[f32], c: &mut NormedCache| -> f64 {
            let y = net.forward(p, x, batch, c);
            y.iter().zip(&w).map(|(y, w)| (y * w) as f64).sum()
        };
        loss(&params, &x, &mut cache);
        let mut grads = vec![0.0; net.num_params()];
        let mut dx = vec![0.0; x.len()];
        net.backward(&params, &x, &mut cache, &w, Some(&mut grads), Some(&mut dx));
        let eps = 2e-3f32;
        let mut worst = 0.0f64;
        for i in 0..params.len() {
            let mut p = params.clone();
            p[i] += eps;
            let up = loss(&p, &x, &mut cache);
            p[i] -= 2.0 * eps;
            let down = loss(&p, &x, &mut cache);
            let numeric = (up - down) / (2.0 * eps as f64);
            let err = (grads[i] as f64 - numeric).abs() / (1e-2 + numeric.abs());
            worst = worst.max(err);
            assert!(
                err < 5e-2,
                "{} param {i}: analytic {} numeric {numeric}",
                net.layout.describe().len(),
                grads[i]
            );
        }
        for i in 0..x.len() {
            let mut xp = x.clone();
            xp[i] += eps;
            let up = loss(&params, &xp, &mut cache);
            xp[i] -= 2.0 * eps;
            let down = loss(&params, &xp, &mut cache);
            let numeric = (up - down) / (2.0 * eps as f64);
            assert!(
                (dx[i] as f64 - numeric).abs() < 1e-2 + 5e-2 * numeric.abs(),
                "input {i}: {} vs {numeric}",
                dx[i]
            );
        }
        assert!(worst < 5e-2);
    }

    #[test]
    fn gradients_of_a_linear_head_match_finite_differences() {
        check(&NormedMlp::new(&[5, 12, 9, 3], Head::Linear), 4, 0.0);
    }

    #[test]
    fn gradients_through_dropout_match_finite_differences_and_dropped_units_carry_none() {
        let net = NormedMlp::new(&[5, 12, 9, 3], Head::Linear);
        check(&net, 4, 0.3);
        let mut cache = NormedCache::new(&net, 4);
        cache.draw_dropout(&net, 4, 0.3, &mut stream(4, "test.dropout", 0));
        let dropped = cache.dropout[..48].iter().filter(|&&m| m == 0.0).count();
        assert!(
            (5..30).contains(&dropped),
            "{dropped} of 48 units dropped at p = 0.3"
        );
        let kept = cache.dropout[..48].iter().find(|&&m| m > 0.0).copied();
        assert_eq!(kept, Some(1.0 / 0.7));
        cache.draw_dropout(&net, 4, 0.0, &mut stream(4, "test.dropout", 0));
        assert!(!cache.dropout_on, "p = 0 drops nothing");
    }

    #[test]
    fn a_forward_only_pass_gives_the_same_bits_and_refuses_a_backward_pass() {
        for head in [Head::Linear, Head::SimNorm] {
            let net = NormedMlp::new(&[7, 40, 33, 16], head);
            let mut params = vec![0.0; net.num_params()];
            net.init(&mut params, false, &mut stream(5, "test.forward_only", 0));
            for (i, p) in params.iter_mut().enumerate() {
                *p += 0.3 * ((i as f32) * 0.71).sin();
            }
            let x: Vec<f32> = (0..6 * 7).map(|i| (i as f32 * 0.37).cos()).collect();
            let mut kept = NormedCache::new(&net, 6);
            let mut planning = NormedCache::new(&net, 6);
            planning.forward_only();
            let full = net.forward(&params, &x, 6, &mut kept).to_vec();
            let fused = net.forward(&params, &x, 6, &mut planning).to_vec();
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&full), bits(&fused), "{head:?}");
            let refused = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                net.backward(&params, &x, &mut planning, &full, None, None)
            }));
            assert!(
                refused.is_err(),
                "a backward pass through a forward-only cache"
            );
        }
    }

    #[test]
    fn gradients_of_a_simnorm_head_match_finite_differences() {
        check(&NormedMlp::new(&[6, 10, 16], Head::SimNorm), 3, 0.0);
    }

    #[test]
    fn a_backward_pass_adds_to_the_gradient() {
        let net = NormedMlp::new(&[3, 8, 2], Head::Linear);
        let mut params = vec![0.0; net.num_params()];
        net.init(&mut params, false, &mut stream(1, "test.normed", 1));
        let x = [0.1, -0.4, 0.7, 0.2, 0.0, -0.3];
        let d = [1.0, -1.0, 0.5, 0.25];
        let mut cache = NormedCache::new(&net, 2);
        net.forward(&params, &x, 2, &mut cache);
        let mut once = vec![0.0; net.num_params()];
        net.backward(&params, &x, &mut cache, &d, Some(&mut once), None);
        let mut twice = once.clone();
        net.backward(&params, &x, &mut cache, &d, Some(&mut twice), None);
        for (a, b) in once.iter().zip(&twice) {
            assert!((2.0 * a - b).abs() <= 1e-6 * a.abs().max(1.0));
        }
    }
}
