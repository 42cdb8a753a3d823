//! Every backward pass against central finite differences.
//!
//! The loss is `L = Σ c_i·y_i` with fixed random `c`, so `∂L/∂y = c` is what the backward pass
//! receives. Each analytic derivative is compared with `(L(θ+ε) − L(θ−ε)) / 2ε`, the loss summed
//! in f64. Errors are measured relative to the derivative's scale; a wrong transpose, a missing
//! activation derivative or a mixed-up buffer gives errors of order 1, far above the tolerance.

use mbpo_core::rng::{normal_f32, stream};
use mbpo_nn::{Activation, EnsembleCache, EnsembleMlp, Init, Mlp, MlpCache};

const TOL: f64 = 2e-2;

fn loss(y: &[f32], c: &[f32]) -> f64 {
    y.iter().zip(c).map(|(&a, &b)| a as f64 * b as f64).sum()
}

fn randn(n: usize, seed: u64, scale: f32) -> Vec<f32> {
    let mut r = stream(seed, "gradcheck", n as u64);
    (0..n).map(|_| normal_f32(&mut r) * scale).collect()
}

/// Compare analytic and numeric derivatives; returns the worst relative error.
fn compare(what: &str, analytic: &[f32], numeric: &[f64]) -> f64 {
    let scale = numeric
        .iter()
        .map(|v| v.abs())
        .fold(0.0, f64::max)
        .max(1e-3);
    let mut worst = 0.0f64;
    for (i, (&a, &n)) in analytic.iter().zip(numeric).enumerate() {
        let err = (a as f64 - n).abs() / (scale * 0.1 + n.abs());
        if err > worst {
            worst = err;
        }
        assert!(
            err < TOL,
            "{what}[{i}]: analytic {a} vs numeric {n} (rel err {err:.3e})"
        );
    }
    worst
}

fn check_mlp(dims: &[usize], hidden: Activation, output: Activation, eps: f32, seed: u64) {
    check_net(&Mlp::new(dims, hidden, output), eps, seed);
}

/// Initial parameters of `net`; a LayerNormed one's γ and β moved off their 1 and 0, so
/// their gradients are checked away from the identity map.
fn init_params(net: &Mlp, seed: u64) -> Vec<f32> {
    let mut params = vec![0.0; net.num_params()];
    net.init(
        &mut params,
        Init::TorchDefault,
        &mut stream(seed, "init", 0),
    );
    if net.has_layer_norm() {
        for (p, n) in params
            .iter_mut()
            .zip(randn(net.num_params(), seed + 7, 0.3))
        {
            *p += n;
        }
    }
    params
}

fn check_net(net: &Mlp, eps: f32, seed: u64) {
    let (dims, hidden, output) = (
        net.dims(),
        net.activation(0),
        net.activation(net.num_layers() - 1),
    );
    let batch = 3;
    let params = init_params(net, seed);
    let x = randn(batch * net.in_dim(), seed, 1.0);
    let c = randn(batch * net.out_dim(), seed + 1, 1.0);
    let mut cache = MlpCache::new(net, batch);
    net.forward(&params, &x, batch, &mut cache);
    let mut grads = vec![0.0; net.num_params()];
    let mut dx = vec![0.0; x.len()];
    net.backward(&params, &x, &mut cache, &c, Some(&mut grads), Some(&mut dx));

    let eval = |p: &[f32], x: &[f32]| {
        let mut cache = MlpCache::new(net, batch);
        loss(net.forward(p, x, batch, &mut cache), &c)
    };
    let numeric_params: Vec<f64> = (0..params.len())
        .map(|i| {
            let mut p = params.clone();
            p[i] += eps;
            let up = eval(&p, &x);
            p[i] -= 2.0 * eps;
            let down = eval(&p, &x);
            (up - down) / (2.0 * eps as f64)
        })
        .collect();
    let numeric_x: Vec<f64> = (0..x.len())
        .map(|i| {
            let mut xx = x.clone();
            xx[i] += eps;
            let up = eval(&params, &xx);
            xx[i] -= 2.0 * eps;
            let down = eval(&params, &xx);
            (up - down) / (2.0 * eps as f64)
        })
        .collect();
    let normed = if net.has_layer_norm() {
        " LayerNorm"
    } else {
        ""
    };
    let name = format!("{dims:?} {hidden:?}/{output:?}{normed}");
    compare(&format!("{name} dθ"), &grads, &numeric_params);
    compare(&format!("{name} dx"), &dx, &numeric_x);
    assert!(
        grads.iter().any(|&g| g != 0.0),
        "all-zero gradient is not a test"
    );
}

#[test]
fn identity_mlp_gradients_match_finite_differences() {
    check_mlp(
        &[4, 5, 3],
        Activation::Identity,
        Activation::Identity,
        1e-2,
        1,
    );
}

#[test]
fn relu_mlp_gradients_match_finite_differences() {
    // Piecewise linear: a small ε keeps every perturbation on one side of each kink.
    check_mlp(&[4, 6, 5, 3], Activation::Relu, Activation::Relu, 1e-3, 2);
}

#[test]
fn silu_mlp_gradients_match_finite_differences() {
    check_mlp(&[4, 6, 5, 3], Activation::Silu, Activation::Silu, 3e-3, 3);
}

#[test]
fn tanh_mlp_gradients_match_finite_differences() {
    check_mlp(&[4, 6, 5, 3], Activation::Tanh, Activation::Tanh, 3e-3, 4);
}

#[test]
fn deep_mixed_mlp_gradients_match_finite_differences() {
    // Model-like: SiLU hidden layers, linear output.
    check_mlp(
        &[5, 7, 7, 7, 7, 4],
        Activation::Silu,
        Activation::Identity,
        3e-3,
        5,
    );
    // Policy-like: ReLU hidden layers, tanh output.
    check_mlp(&[3, 8, 8, 2], Activation::Relu, Activation::Tanh, 1e-3, 6);
}

#[test]
fn layer_normed_mlp_gradients_match_finite_differences() {
    // Critic-like: ReLU hidden layers, each LayerNormed, a linear output.
    let critic = Mlp::with_hidden_layer_norm(&[5, 8, 8, 1], Activation::Relu, Activation::Identity);
    check_net(&critic, 1e-3, 31);
    let smooth = Mlp::with_hidden_layer_norm(&[4, 6, 5, 3], Activation::Tanh, Activation::Tanh);
    check_net(&smooth, 3e-3, 32);
    let silu = Mlp::with_hidden_layer_norm(&[4, 6, 3], Activation::Silu, Activation::Identity);
    check_net(&silu, 3e-3, 33);
    // γ and β after each hidden layer's bias, none on the output layer.
    let names: Vec<&str> = critic
        .layout()
        .entries()
        .iter()
        .map(|e| e.name.as_str())
        .collect();
    assert_eq!(
        names,
        [
            "l0.w", "l0.b", "l0.ln_g", "l0.ln_b", "l1.w", "l1.b", "l1.ln_g", "l1.ln_b", "l2.w",
            "l2.b"
        ]
    );
}

#[test]
fn layer_norm_leaves_the_draws_of_the_weights_alone() {
    let plain = Mlp::new(&[5, 8, 8, 1], Activation::Relu, Activation::Identity);
    let normed = Mlp::with_hidden_layer_norm(&[5, 8, 8, 1], Activation::Relu, Activation::Identity);
    let (mut p, mut q) = (
        vec![0.0; plain.num_params()],
        vec![0.0; normed.num_params()],
    );
    plain.init(&mut p, Init::TorchDefault, &mut stream(3, "init", 0));
    normed.init(&mut q, Init::TorchDefault, &mut stream(3, "init", 0));
    for l in 0..3 {
        assert_eq!(p[plain.weight_range(l)], q[normed.weight_range(l)]);
        assert_eq!(p[plain.bias_range(l)], q[normed.bias_range(l)]);
    }
    assert!(!plain.has_layer_norm() && normed.has_layer_norm());
}

#[test]
fn ensemble_gradients_match_finite_differences_and_members_are_independent() {
    let (members, batch) = (3, 2);
    let ens = EnsembleMlp::new(
        members,
        Mlp::new(&[3, 5, 5, 2], Activation::Silu, Activation::Identity),
    );
    let mut params = vec![0.0; ens.num_params()];
    ens.init(
        &mut params,
        Init::TruncatedNormal,
        &mut stream(9, "init", 0),
    );
    // Non-zero biases so bias gradients are exercised away from the init.
    params.iter_mut().for_each(|p| *p += 0.05);
    let x = randn(members * batch * 3, 10, 1.0);
    let c = randn(members * batch * 2, 11, 1.0);
    let total = |p: &[f32], x: &[f32]| {
        let mut cache = EnsembleCache::new(&ens, batch);
        ens.forward(p, x, batch, &mut cache);
        (0..members)
            .map(|e| {
                loss(
                    cache.output(&ens, e),
                    &c[e * batch * 2..(e + 1) * batch * 2],
                )
            })
            .sum::<f64>()
    };
    let mut cache = EnsembleCache::new(&ens, batch);
    ens.forward(&params, &x, batch, &mut cache);
    let mut grads = vec![0.0; ens.num_params()];
    let mut dx = vec![0.0; x.len()];
    ens.backward(&params, &x, &mut cache, &c, Some(&mut grads), Some(&mut dx));
    let eps = 3e-3f32;
    let fd = |f: &dyn Fn(&[f32], &[f32]) -> f64, p: &[f32], xx: &[f32], i: usize, on_p: bool| {
        let (mut p, mut xx) = (p.to_vec(), xx.to_vec());
        let v = if on_p { &mut p[i] } else { &mut xx[i] };
        *v += eps;
        let up = f(&p, &xx);
        let v = if on_p { &mut p[i] } else { &mut xx[i] };
        *v -= 2.0 * eps;
        (up - f(&p, &xx)) / (2.0 * eps as f64)
    };
    let np: Vec<f64> = (0..params.len())
        .map(|i| fd(&total, &params, &x, i, true))
        .collect();
    let nx: Vec<f64> = (0..x.len())
        .map(|i| fd(&total, &params, &x, i, false))
        .collect();
    compare("ensemble dθ", &grads, &np);
    compare("ensemble dx", &dx, &nx);

    // Member 1's output must not change when member 0's parameters or inputs change.
    let mut p2 = params.clone();
    p2[ens.member_range(0)].iter_mut().for_each(|p| *p *= 2.0);
    let mut x2 = x.clone();
    x2[..batch * 3].iter_mut().for_each(|v| *v += 1.0);
    let mut cache2 = EnsembleCache::new(&ens, batch);
    ens.forward(&p2, &x2, batch, &mut cache2);
    assert_eq!(cache.output(&ens, 1), cache2.output(&ens, 1));
    assert_ne!(cache.output(&ens, 0), cache2.output(&ens, 0));
    // forward_member agrees with the batched forward.
    let mut single = MlpCache::new(ens.mlp(), batch);
    let y1 = ens.forward_member(2, &params, &x[2 * batch * 3..], batch, &mut single);
    assert_eq!(y1, cache.output(&ens, 2));
}

#[test]
fn backward_without_param_grads_gives_the_same_input_gradient() {
    let net = Mlp::new(&[4, 8, 1], Activation::Relu, Activation::Identity);
    let mut params = vec![0.0; net.num_params()];
    net.init(&mut params, Init::TorchDefault, &mut stream(3, "init", 0));
    let x = randn(8, 12, 1.0);
    let mut cache = MlpCache::new(&net, 2);
    net.forward(&params, &x, 2, &mut cache);
    let (mut dx1, mut dx2) = (vec![0.0; 8], vec![0.0; 8]);
    let mut grads = vec![0.0; net.num_params()];
    net.backward(
        &params,
        &x,
        &mut cache,
        &[1.0, -1.0],
        Some(&mut grads),
        Some(&mut dx1),
    );
    net.backward(&params, &x, &mut cache, &[1.0, -1.0], None, Some(&mut dx2));
    assert_eq!(dx1, dx2);
}

#[test]
fn a_smaller_batch_after_a_larger_one_uses_only_its_rows() {
    let net = Mlp::new(&[2, 4, 3], Activation::Tanh, Activation::Identity);
    let mut params = vec![0.0; net.num_params()];
    net.init(&mut params, Init::TorchDefault, &mut stream(4, "init", 0));
    let x = randn(2 * 10, 13, 1.0);
    let mut big = MlpCache::new(&net, 10);
    let y_big = net.forward(&params, &x, 10, &mut big).to_vec();
    let y_small = net.forward(&params, &x[..4], 2, &mut big).to_vec();
    assert_eq!(y_small.len(), 6);
    assert_eq!(&y_big[..6], &y_small[..]);
}

/// `input_grad_rows` on a subset of rows and input columns, for L = Σ over those rows of c·y:
/// each entry against central differences of L in that input, and every other row's input
/// must not matter (the rows are independent).
fn check_input_grad_rows(hidden: Activation, output: Activation, seed: u64) {
    check_input_grad_rows_of(&Mlp::new(&[5, 7, 6, 2], hidden, output), seed);
}

fn check_input_grad_rows_of(net: &Mlp, seed: u64) {
    let (hidden, output) = (net.activation(0), net.activation(net.num_layers() - 1));
    assert_eq!((net.in_dim(), net.out_dim()), (5, 2));
    let batch = 6;
    let rows = [4usize, 1, 3];
    let cols = 2..5;
    let params = init_params(net, seed);
    let x = randn(batch * 5, seed, 1.0);
    let c = randn(rows.len() * 2, seed + 1, 1.0);
    let loss_rows = |x: &[f32]| {
        let mut cache = MlpCache::new(net, batch);
        let y = net.forward(&params, x, batch, &mut cache);
        rows.iter()
            .enumerate()
            .map(|(i, &r)| loss(&y[r * 2..r * 2 + 2], &c[i * 2..i * 2 + 2]))
            .sum::<f64>()
    };
    let mut cache = MlpCache::new(net, batch);
    net.forward(&params, &x, batch, &mut cache);
    let mut d = vec![0.0; rows.len() * cols.len()];
    net.input_grad_rows(&params, &mut cache, &rows, &c, cols.clone(), &mut d);
    let eps = 1e-2f32;
    let mut numeric = Vec::new();
    for &r in &rows {
        for j in cols.clone() {
            let mut xx = x.clone();
            xx[r * 5 + j] += eps;
            let up = loss_rows(&xx);
            xx[r * 5 + j] -= 2.0 * eps;
            numeric.push((up - loss_rows(&xx)) / (2.0 * eps as f64));
        }
    }
    compare(
        &format!("input_grad_rows {hidden:?}/{output:?}"),
        &d,
        &numeric,
    );
    assert!(
        d.iter().any(|&g| g != 0.0),
        "all-zero gradient is not a test"
    );
}

#[test]
fn input_gradient_of_selected_rows_and_columns_matches_finite_differences() {
    check_input_grad_rows(Activation::Relu, Activation::Identity, 21);
    check_input_grad_rows(Activation::Silu, Activation::Tanh, 22);
    let normed = Mlp::with_hidden_layer_norm(&[5, 7, 6, 2], Activation::Relu, Activation::Identity);
    check_input_grad_rows_of(&normed, 23);
}
