//! Multi-layer perceptrons with a manual backward pass.
//!
//! Layer l computes `z_l = a_{l−1} W_l + b_l` and `a_l = f_l(z_l)` on a row-major batch, with
//! `a_{−1} = x`, `W_l` of shape `in x out`, the hidden activation on every layer but the last and
//! the output activation on the last. The backward pass takes `∂L/∂y` and produces, by the chain
//! rule, `∂L/∂z_l = ∂L/∂a_l · f'(z_l)`, `∂L/∂W_l = a_{l−1}ᵀ ∂L/∂z_l`, `∂L/∂b_l = Σ_rows ∂L/∂z_l`
//! and `∂L/∂a_{l−1} = ∂L/∂z_l W_lᵀ`, down to the input gradient `∂L/∂x` that SAC's actor update
//! and gradient-based planning need.
//!
//! [`Mlp::with_hidden_layer_norm`] puts a LayerNorm between every hidden layer's affine map and
//! its activation (`a_l = f(LN(z_l))`, the critics of DroQ and RLPD, the `sac.critic_layer_norm`
//! option); the backward pass then goes through LayerNorm's ([`crate::norm`]) between the
//! activation's derivative and the weights.

use crate::activation::Activation;
use crate::gemm::{gemm, Op};
use crate::init::Init;
use crate::layout::ParamLayout;
use crate::norm::{layer_norm_backward, layer_norm_forward};
use mbpo_core::Rng;
use std::ops::Range;

/// Architecture of an MLP; owns no parameters (see the crate docs).
#[derive(Debug, Clone, PartialEq)]
pub struct Mlp {
    dims: Vec<usize>,
    hidden: Activation,
    output: Activation,
    layout: ParamLayout,
    weights: Vec<Range<usize>>,
    biases: Vec<Range<usize>>,
    /// LayerNorm's γ and β of each layer that has one (the hidden ones, when asked for).
    norms: Vec<Option<(Range<usize>, Range<usize>)>>,
}

impl Mlp {
    /// An MLP with layer widths `dims = [in, h_1, ..., out]`.
    pub fn new(dims: &[usize], hidden: Activation, output: Activation) -> Self {
        Self::build(dims, hidden, output, false)
    }

    /// [`Mlp::new`] with a LayerNorm after every hidden layer's affine map, before its
    /// activation; its γ and β (`l{l}.ln_g`, `l{l}.ln_b`) follow the layer's bias in the layout.
    pub fn with_hidden_layer_norm(dims: &[usize], hidden: Activation, output: Activation) -> Self {
        Self::build(dims, hidden, output, true)
    }

    fn build(dims: &[usize], hidden: Activation, output: Activation, normed: bool) -> Self {
        assert!(
            dims.len() >= 2,
            "an MLP needs at least an input and an output width"
        );
        assert!(dims.iter().all(|&d| d > 0), "layer widths must be positive");
        let mut layout = ParamLayout::new();
        let (mut weights, mut biases, mut norms) = (Vec::new(), Vec::new(), Vec::new());
        let layers = dims.len() - 1;
        for l in 0..layers {
            weights.push(layout.push(format!("l{l}.w"), &[dims[l], dims[l + 1]]));
            biases.push(layout.push(format!("l{l}.b"), &[dims[l + 1]]));
            norms.push((normed && l + 1 < layers).then(|| {
                let gamma = layout.push(format!("l{l}.ln_g"), &[dims[l + 1]]);
                (gamma, layout.push(format!("l{l}.ln_b"), &[dims[l + 1]]))
            }));
        }
        Self {
            dims: dims.to_vec(),
            hidden,
            output,
            layout,
            weights,
            biases,
            norms,
        }
    }

    /// Whether the hidden layers are LayerNormed ([`Mlp::with_hidden_layer_norm`]).
    pub fn has_layer_norm(&self) -> bool {
        self.norms.iter().any(Option::is_some)
    }

    /// Layer widths `[in, h_1, ..., out]`.
    pub fn dims(&self) -> &[usize] {
        &self.dims
    }
    /// Input width.
    pub fn in_dim(&self) -> usize {
        self.dims[0]
    }
    /// Output width.
    pub fn out_dim(&self) -> usize {
        *self.dims.last().unwrap()
    }
    /// Number of dense layers.
    pub fn num_layers(&self) -> usize {
        self.dims.len() - 1
    }
    /// Total parameter count.
    pub fn num_params(&self) -> usize {
        self.layout.len()
    }
    /// Names and shapes of the parameters.
    pub fn layout(&self) -> &ParamLayout {
        &self.layout
    }
    /// Range of layer `l`'s weights in the flat vector.
    pub fn weight_range(&self, l: usize) -> Range<usize> {
        self.weights[l].clone()
    }
    /// Range of layer `l`'s biases in the flat vector.
    pub fn bias_range(&self, l: usize) -> Range<usize> {
        self.biases[l].clone()
    }
    /// Activation applied after layer `l`.
    pub fn activation(&self, l: usize) -> Activation {
        if l + 1 == self.num_layers() {
            self.output
        } else {
            self.hidden
        }
    }

    /// Multiply-add flops (2 per MAC) of the GEMMs of one forward pass on `batch` rows.
    pub fn forward_flops(&self, batch: usize) -> u64 {
        self.dims
            .windows(2)
            .map(|w| 2 * (batch * w[0] * w[1]) as u64)
            .sum()
    }

    /// GEMM flops of one [`Mlp::backward`] on `batch` rows: `∂W` for every layer when
    /// `param_grads`, `∂a` for every layer above the input, and `∂x` when `input_grad`.
    pub fn backward_flops(&self, batch: usize, param_grads: bool, input_grad: bool) -> u64 {
        let per_layer: Vec<u64> = self
            .dims
            .windows(2)
            .map(|w| 2 * (batch * w[0] * w[1]) as u64)
            .collect();
        let dw: u64 = if param_grads {
            per_layer.iter().sum()
        } else {
            0
        };
        let dx: u64 =
            per_layer[1..].iter().sum::<u64>() + if input_grad { per_layer[0] } else { 0 };
        dw + dx
    }

    /// Draw initial parameters layer by layer from `rng` (the same draws with or without
    /// LayerNorm, whose γ starts at 1 and β at 0).
    pub fn init(&self, params: &mut [f32], init: Init, rng: &mut Rng) {
        assert_eq!(params.len(), self.num_params());
        for l in 0..self.num_layers() {
            let (w, b) = params.split_at_mut(self.biases[l].start);
            init.fill(
                &mut w[self.weights[l].clone()],
                &mut b[..self.dims[l + 1]],
                self.dims[l],
                rng,
            );
            if let Some((gamma, beta)) = &self.norms[l] {
                params[gamma.clone()].fill(1.0);
                params[beta.clone()].fill(0.0);
            }
        }
    }

    /// Forward pass on `batch` rows of `x` (row-major, `batch x in`); returns the output rows
    /// (`batch x out`) held in `cache`, which also keeps what the backward pass needs.
    pub fn forward<'c>(
        &self,
        params: &[f32],
        x: &[f32],
        batch: usize,
        cache: &'c mut MlpCache,
    ) -> &'c [f32] {
        debug_assert_eq!(params.len(), self.num_params());
        assert!(
            x.len() >= batch * self.in_dim(),
            "input shorter than batch x in_dim"
        );
        cache.ensure(self, batch);
        for l in 0..self.num_layers() {
            let (n_in, n_out) = (self.dims[l], self.dims[l + 1]);
            let (done, todo) = cache.layers.split_at_mut(l);
            let input = if l == 0 {
                &x[..batch * n_in]
            } else {
                done[l - 1].output(self.activation(l - 1), batch * n_in)
            };
            let layer = &mut todo[0];
            let w = &params[self.weights[l].clone()];
            let bias = &params[self.biases[l].clone()];
            let Some((gamma, beta)) = &self.norms[l] else {
                let z = &mut layer.z[..batch * n_out];
                gemm(z, input, Op::N, w, Op::N, batch, n_in, n_out, false);
                self.activation(l).bias_forward(z, bias, &mut layer.a);
                continue;
            };
            // z = LN(x W + b), then a = f(z): the activation's epilogue without a bias.
            let pre = &mut layer.pre[..batch * n_out];
            gemm(pre, input, Op::N, w, Op::N, batch, n_in, n_out, false);
            Activation::Identity.bias_forward(pre, bias, &mut []);
            let (gamma, beta) = (&params[gamma.clone()], &params[beta.clone()]);
            let (x_hat, inv_std) = (
                &mut layer.x_hat[..batch * n_out],
                &mut layer.inv_std[..batch],
            );
            let z = &mut layer.z[..batch * n_out];
            layer_norm_forward(pre, gamma, beta, x_hat, inv_std, z);
            self.activation(l).epilogue(z, &mut layer.a);
        }
        let last = self.num_layers() - 1;
        cache.layers[last].output(self.output, batch * self.out_dim())
    }

    /// Backward pass for the batch of the last [`Mlp::forward`] on `x` with this `cache`.
    ///
    /// `d_out` is `∂L/∂y` (`batch x out`). Writes `∂L/∂θ` into `grads` (same layout as the
    /// parameters, overwritten) when given, and `∂L/∂x` into `d_input` (`batch x in`) when given.
    pub fn backward(
        &self,
        params: &[f32],
        x: &[f32],
        cache: &mut MlpCache,
        d_out: &[f32],
        mut grads: Option<&mut [f32]>,
        mut d_input: Option<&mut [f32]>,
    ) {
        let batch = cache.batch;
        let n_layers = self.num_layers();
        assert!(d_out.len() >= batch * self.out_dim());
        let params_len = grads.as_deref().map_or(self.num_params(), <[f32]>::len);
        assert_eq!(
            params_len,
            self.num_params(),
            "grads must match the parameter layout"
        );
        let mut gbuf = std::mem::take(&mut cache.grad);
        let mut dz_buf = std::mem::take(&mut cache.dz);
        for l in (0..n_layers).rev() {
            let (n_in, n_out) = (self.dims[l], self.dims[l + 1]);
            // Ping-pong: layer l writes ∂L/∂a_{l−1} into one buffer while reading ∂L/∂a_l
            // from the other, which the layer above wrote.
            let (b0, b1) = gbuf.split_at_mut(1);
            let (read, write) = if (n_layers - 1 - l).is_multiple_of(2) {
                (&b1[0], &mut b0[0])
            } else {
                (&b0[0], &mut b1[0])
            };
            // ∂L/∂a_l: the caller's d_out on the top layer.
            let g: &[f32] = if l + 1 == n_layers {
                &d_out[..batch * n_out]
            } else {
                &read[..batch * n_out]
            };
            let input = if l == 0 {
                &x[..batch * n_in]
            } else {
                cache.layers[l - 1].output(self.activation(l - 1), batch * n_in)
            };
            let mut grads_l = grads.as_deref_mut().map(|g| self.layer_grads(l, g));
            let layer = &cache.layers[l];
            let dz = self.affine_grad(l, params, layer, g, &mut dz_buf, grads_l.as_mut());
            if let Some(gl) = grads_l {
                gemm(gl.w, input, Op::T, dz, Op::N, n_in, batch, n_out, false);
            }
            // ∂L/∂a_{l−1} = ∂L/∂z_l W_lᵀ: for the layer below, or the caller's ∂L/∂x.
            let w = &params[self.weights[l].clone()];
            let below = match l {
                0 => d_input.as_deref_mut(),
                _ => Some(&mut write[..]),
            };
            if let Some(out) = below {
                let out = &mut out[..batch * n_in];
                gemm(out, dz, Op::N, w, Op::T, batch, n_out, n_in, false);
            }
        }
        cache.grad = gbuf;
        cache.dz = dz_buf;
    }

    /// Layer `l`'s share of a parameter gradient `grads` (the whole layout).
    fn layer_grads<'g>(&self, l: usize, grads: &'g mut [f32]) -> LayerGrads<'g> {
        let n_out = self.dims[l + 1];
        let (head, tail) = grads.split_at_mut(self.biases[l].start);
        let (b, rest) = tail.split_at_mut(n_out);
        // γ and β follow the bias (`build` pushes them so).
        let norm = self.norms[l].as_ref().map(|(gamma, _)| {
            debug_assert_eq!(gamma.start, self.biases[l].end);
            let (dg, rest) = rest.split_at_mut(n_out);
            (dg, &mut rest[..n_out])
        });
        LayerGrads {
            w: &mut head[self.weights[l].clone()],
            b,
            norm,
        }
    }

    /// ∂L/∂(a_{l−1} W_l + b_l) of layer `l` from `g` = ∂L/∂a_l (in `dz_buf`, or `g` itself for
    /// a plain linear layer), with the bias gradient Σ_rows of it (and LayerNorm's γ and β
    /// gradients) into `grads` when given, fused with the activation's derivative where it can.
    fn affine_grad<'b>(
        &self,
        l: usize,
        params: &[f32],
        layer: &LayerCache,
        g: &'b [f32],
        dz_buf: &'b mut [f32],
        grads: Option<&mut LayerGrads<'_>>,
    ) -> &'b [f32] {
        let (act, n) = (self.activation(l), g.len());
        let (z, a) = layer.kept(act);
        let Some((gamma, _)) = &self.norms[l] else {
            if act == Activation::Identity {
                if let Some(gl) = grads {
                    sum_rows(g, gl.b);
                }
                return g;
            }
            let dz = &mut dz_buf[..n];
            match grads {
                Some(gl) => act.backward_bias_grad(z, a, g, dz, gl.b),
                None => act.backward(z, a, g, dz),
            }
            return dz;
        };
        // Through the activation to LN's output, then through LN (in place) to its input.
        let d = &mut dz_buf[..n];
        act.backward(z, a, g, d);
        let rows = n / self.dims[l + 1];
        let (x_hat, inv_std) = (&layer.x_hat[..n], &layer.inv_std[..rows]);
        let gamma = &params[gamma.clone()];
        match grads {
            Some(gl) => {
                let (dg, db) = gl.norm.as_mut().expect("a normed layer has γ and β");
                dg.fill(0.0);
                db.fill(0.0);
                layer_norm_backward(x_hat, inv_std, gamma, d, Some((&mut **dg, &mut **db)));
                sum_rows(d, gl.b);
            }
            None => layer_norm_backward(x_hat, inv_std, gamma, d, None),
        }
        d
    }

    /// [`Mlp::affine_grad`] without parameter gradients on gathered rows: row i of `g` (and
    /// of the result) belongs to row `rows[i]` of the layer's kept values.
    fn rows_affine_grad<'b>(
        &self,
        l: usize,
        params: &[f32],
        layer: &LayerCache,
        rows: &[usize],
        g: &'b [f32],
        dz_buf: &'b mut [f32],
    ) -> &'b [f32] {
        let (act, n) = (self.activation(l), self.dims[l + 1]);
        let norm = &self.norms[l];
        if act == Activation::Identity && norm.is_none() {
            return g;
        }
        let (z, a) = layer.kept(act);
        let dz = &mut dz_buf[..g.len()];
        act.backward_rows(z, a, n, rows, g, dz);
        if let Some((gamma, _)) = norm {
            let gamma = &params[gamma.clone()];
            for (&r, d) in rows.iter().zip(dz.chunks_exact_mut(n)) {
                let (x_hat, inv_std) = (&layer.x_hat[r * n..][..n], &layer.inv_std[r..r + 1]);
                layer_norm_backward(x_hat, inv_std, gamma, d, None);
            }
        }
        dz
    }

    /// Input gradient of the last [`Mlp::forward`] for a subset of its rows and input columns:
    /// row i of `d_input` (`rows.len() x cols.len()`) is `∂L/∂x[rows[i], cols]` for
    /// `d_out` = ∂L/∂y of those rows (`rows.len() x out`). No parameter gradients.
    ///
    /// Rows outside `rows` are treated as having zero output gradient, so they are skipped
    /// rather than multiplied through: SAC's actor loss differentiates min(Q₁, Q₂), which sends
    /// each row's gradient through one critic only, and this halves that backward pass. Only
    /// the weight rows of `cols` enter the last product (SAC needs ∂Q/∂a, not ∂Q/∂s).
    pub fn input_grad_rows(
        &self,
        params: &[f32],
        cache: &mut MlpCache,
        rows: &[usize],
        d_out: &[f32],
        cols: Range<usize>,
        d_input: &mut [f32],
    ) {
        let (m, n_layers) = (rows.len(), self.num_layers());
        assert!(
            rows.iter().all(|&r| r < cache.batch),
            "row outside the batch"
        );
        assert!(cols.end <= self.in_dim() && d_input.len() >= m * cols.len());
        assert!(d_out.len() >= m * self.out_dim());
        let mut gbuf = [
            std::mem::take(&mut cache.grad[0]),
            std::mem::take(&mut cache.grad[1]),
        ];
        let mut dz_buf = std::mem::take(&mut cache.dz);
        for l in (0..n_layers).rev() {
            let (n_in, n_out) = (self.dims[l], self.dims[l + 1]);
            let (b0, b1) = gbuf.split_at_mut(1);
            let (read, write) = if (n_layers - 1 - l).is_multiple_of(2) {
                (&b1[0], &mut b0[0])
            } else {
                (&b0[0], &mut b1[0])
            };
            let g: &[f32] = if l + 1 == n_layers {
                &d_out[..m * n_out]
            } else {
                &read[..m * n_out]
            };
            let dz = self.rows_affine_grad(l, params, &cache.layers[l], rows, g, &mut dz_buf);
            let w = &params[self.weights[l].clone()];
            if l > 0 {
                gemm(
                    &mut write[..m * n_in],
                    dz,
                    Op::N,
                    w,
                    Op::T,
                    m,
                    n_out,
                    n_in,
                    false,
                );
            } else {
                // W's rows `cols` (a contiguous `cols.len() x n_out` block, row-major).
                let block = &w[cols.start * n_out..cols.end * n_out];
                let k = cols.len();
                gemm(
                    &mut d_input[..m * k],
                    dz,
                    Op::N,
                    block,
                    Op::T,
                    m,
                    n_out,
                    k,
                    false,
                );
            }
        }
        cache.grad = gbuf;
        cache.dz = dz_buf;
    }
}

/// One layer's share of a parameter gradient.
struct LayerGrads<'g> {
    w: &'g mut [f32],
    b: &'g mut [f32],
    /// LayerNorm's ∂γ and ∂β.
    norm: Option<(&'g mut [f32], &'g mut [f32])>,
}

/// One layer's forward values.
#[derive(Debug, Clone, Default)]
struct LayerCache {
    z: Vec<f32>,
    a: Vec<f32>,
    /// With LayerNorm: its input x W + b, its normalised x̂ and each row's 1/√(σ² + ε).
    pre: Vec<f32>,
    x_hat: Vec<f32>,
    inv_std: Vec<f32>,
}

impl LayerCache {
    /// a = f(z): in z's buffer for in-place activations, else in its own.
    fn output(&self, act: Activation, len: usize) -> &[f32] {
        if act.in_place() {
            &self.z[..len]
        } else {
            &self.a[..len]
        }
    }

    /// What the activation's derivative reads, as (z, a); an in-place layer kept only a.
    fn kept(&self, act: Activation) -> (&[f32], &[f32]) {
        if act.in_place() {
            (&self.z, &self.z)
        } else {
            (&self.z, &self.a)
        }
    }
}

/// Activations and scratch buffers for one MLP at up to `capacity` rows.
///
/// Buffers grow only when a larger batch arrives, so a steady-state loop allocates nothing.
#[derive(Debug, Clone, Default)]
pub struct MlpCache {
    capacity: usize,
    batch: usize,
    layers: Vec<LayerCache>,
    grad: [Vec<f32>; 2],
    dz: Vec<f32>,
}

impl MlpCache {
    /// A cache for `mlp` sized for `batch` rows.
    pub fn new(mlp: &Mlp, batch: usize) -> Self {
        let mut c = Self::default();
        c.ensure(mlp, batch);
        c
    }

    /// Rows of the last forward pass.
    pub fn batch(&self) -> usize {
        self.batch
    }

    /// Output rows of the last forward pass (`batch x out`).
    pub fn output<'c>(&'c self, mlp: &Mlp) -> &'c [f32] {
        let last = mlp.num_layers() - 1;
        self.layers[last].output(mlp.activation(last), self.batch * mlp.out_dim())
    }

    fn ensure(&mut self, mlp: &Mlp, batch: usize) {
        self.batch = batch;
        if batch <= self.capacity && self.layers.len() == mlp.num_layers() {
            return;
        }
        let cap = batch.max(self.capacity);
        let widest = *mlp.dims().iter().max().unwrap();
        self.layers = (0..mlp.num_layers())
            .map(|l| {
                let n = cap * mlp.dims()[l + 1];
                let a = if mlp.activation(l).in_place() { 0 } else { n };
                let (normed, rows) = match mlp.norms[l] {
                    Some(_) => (n, cap),
                    None => (0, 0),
                };
                LayerCache {
                    z: vec![0.0; n],
                    a: vec![0.0; a],
                    pre: vec![0.0; normed],
                    x_hat: vec![0.0; normed],
                    inv_std: vec![0.0; rows],
                }
            })
            .collect();
        self.grad = [vec![0.0; cap * widest], vec![0.0; cap * widest]];
        self.dz = vec![0.0; cap * widest];
        self.capacity = cap;
    }
}

/// `sums[j] = Σ_rows g[row, j]` (`g` row-major with `sums.len()` columns): the bias gradient of
/// a layer without activation.
fn sum_rows(g: &[f32], sums: &mut [f32]) {
    sums.fill(0.0);
    for row in g.chunks_exact(sums.len()) {
        sums.iter_mut().zip(row).for_each(|(s, &v)| *s += v);
    }
}
