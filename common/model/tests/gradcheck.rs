//! The hand-written gradient of the training objective against central finite differences, and
//! its value against an independent f64 reference.
//!
//! The objective is Σ_members [mean((μ − y)²·e^(−lv)) + mean(lv)] + 0.01·(Σ max_lv − Σ min_lv),
//! lv = min + softplus(max − softplus(max − raw) − min) (the PETS/MBPO bounded log-variance).
//! The bounds are set close to the raw outputs so both softplus functions run in their curved
//! region; a wrong chain-rule factor (σ vs 1 − σ, a missing bound term, a transposed GEMM) then
//! gives relative errors of order 1, far above the tolerance.

use mbpo_core::rng::{normal_f32, stream};
use mbpo_model::{ModelConfig, ProbabilisticEnsemble};

const OBS: usize = 2;
const ACT: usize = 1;
const D: usize = OBS + 1;
const BATCH: usize = 5;

/// `threads` decides how a training step cuts the work: 1 trains whole members; 4 (which does
/// not divide 2 members) trains halves of 3 and 2 rows, each on its own thread; 2 threads on 3
/// members run member 0 whole and half of member 1 on one thread, the other half and member 2
/// whole on the other.
fn small_model_on(members: usize, threads: usize) -> ProbabilisticEnsemble {
    let cfg = ModelConfig {
        members,
        threads,
        elites: 1,
        hidden: vec![6, 5],
        weight_decay: vec![0.0; 3],
        ..ModelConfig::default()
    };
    let mut m = ProbabilisticEnsemble::new(OBS, ACT, cfg, &mut stream(1, "gc.init", 0)).unwrap();
    let mut p = m.params().to_vec();
    let layout = m.layout().clone();
    let mut rng = stream(1, "gc.perturb", 0);
    for e in layout.entries() {
        let r = e.range();
        if e.name.ends_with(".b") {
            // Non-zero biases so their gradients are exercised away from the init.
            p[r].iter_mut()
                .for_each(|v| *v = 0.3 * normal_f32(&mut rng));
        } else if e.name.contains(".l2.w") {
            // Spread the output layer so raw log-variances straddle the bounds.
            p[r].iter_mut().for_each(|v| *v *= 6.0);
        }
    }
    let max_r = layout.get("max_logvar").unwrap().range();
    let min_r = layout.get("min_logvar").unwrap().range();
    p[max_r].copy_from_slice(&[0.5, 0.2, -0.1]);
    p[min_r].copy_from_slice(&[-1.0, -0.6, -1.4]);
    m.set_params(&p).unwrap();
    m
}

fn randn(n: usize, seed: u64) -> Vec<f32> {
    let mut r = stream(seed, "gc.data", n as u64);
    (0..n).map(|_| normal_f32(&mut r)).collect()
}

fn softplus(x: f64) -> f64 {
    x.max(0.0) + (-x.abs()).exp().ln_1p()
}

/// The objective from scratch in f64, reading parameters by name.
fn reference_loss(m: &ProbabilisticEnsemble, params: &[f32], x: &[f32], y: &[f32]) -> f64 {
    let layout = m.layout();
    let get = |name: &str| -> Vec<f64> {
        params[layout.get(name).unwrap().range()]
            .iter()
            .map(|&v| v as f64)
            .collect()
    };
    let dims = [OBS + ACT, 6, 5, 2 * D];
    let (max_lv, min_lv) = (get("max_logvar"), get("min_logvar"));
    let mut total = 0.0;
    for e in 0..m.members() {
        let mut loss = 0.0;
        for b in 0..BATCH {
            let row = e * BATCH + b;
            let mut a: Vec<f64> = x[row * dims[0]..(row + 1) * dims[0]]
                .iter()
                .map(|&v| v as f64)
                .collect();
            for l in 0..3 {
                let w = get(&format!("ensemble.m{e}.l{l}.w"));
                let bias = get(&format!("ensemble.m{e}.l{l}.b"));
                let mut z = bias.clone();
                for (i, ai) in a.iter().enumerate() {
                    for (j, zj) in z.iter_mut().enumerate() {
                        *zj += ai * w[i * dims[l + 1] + j];
                    }
                }
                a = if l < 2 {
                    z.iter().map(|&v| v / (1.0 + (-v).exp())).collect()
                } else {
                    z
                };
            }
            for j in 0..D {
                let mu = a[j];
                let u = max_lv[j] - softplus(max_lv[j] - a[D + j]);
                let lv = min_lv[j] + softplus(u - min_lv[j]);
                let err = mu - y[row * D + j] as f64;
                loss += err * err * (-lv).exp() + lv;
            }
        }
        total += loss / (BATCH * D) as f64;
    }
    total + 0.01 * (max_lv.iter().sum::<f64>() - min_lv.iter().sum::<f64>())
}

fn small_model() -> ProbabilisticEnsemble {
    small_model_on(2, 1)
}

#[test]
fn gaussian_nll_with_bounded_logvar_matches_finite_differences() {
    check_against_finite_differences(2, 1);
}

#[test]
fn the_gradient_of_half_minibatches_matches_finite_differences() {
    check_against_finite_differences(2, 4);
}

#[test]
fn the_gradient_of_whole_and_cut_members_on_two_threads_matches_finite_differences() {
    check_against_finite_differences(3, 2);
}

fn check_against_finite_differences(members: usize, threads: usize) {
    let mut m = small_model_on(members, threads);
    let x = randn(m.members() * BATCH * (OBS + ACT), 2);
    let y = randn(m.members() * BATCH * D, 3);
    let params = m.params().to_vec();
    let mut grads = vec![0.0f32; params.len()];
    let loss = m.loss_and_gradient(&x, &y, BATCH, &mut grads).unwrap();

    let want = reference_loss(&m, &params, &x, &y);
    assert!(
        (loss - want).abs() < 1e-5 * want.abs().max(1.0),
        "loss {loss} vs f64 reference {want}"
    );

    let eps = 1e-2f32;
    let mut scratch = vec![0.0f32; params.len()];
    let mut eval = |m: &mut ProbabilisticEnsemble, p: &[f32]| {
        m.set_params(p).unwrap();
        m.loss_and_gradient(&x, &y, BATCH, &mut scratch).unwrap()
    };
    let layout = m.layout().clone();
    let mut checked = Vec::new();
    for entry in layout.entries() {
        // The output layer of every member and both bounds, as the derivation goes through them;
        // the hidden layers too, which is cheap at this size.
        for i in entry.range() {
            let mut p = params.clone();
            p[i] += eps;
            let up = eval(&mut m, &p);
            p[i] -= 2.0 * eps;
            let down = eval(&mut m, &p);
            checked.push((
                entry.name.clone(),
                i,
                grads[i] as f64,
                (up - down) / (2.0 * eps as f64),
            ));
        }
    }
    let scale = checked.iter().map(|c| c.3.abs()).fold(0.0, f64::max);
    let mut worst = (0.0f64, String::new());
    for (name, i, analytic, numeric) in &checked {
        let err = (analytic - numeric).abs() / (0.01 * scale + numeric.abs());
        if err > worst.0 {
            worst = (
                err,
                format!("{name}[{i}]: analytic {analytic}, numeric {numeric}"),
            );
        }
    }
    assert!(
        worst.0 < 1e-2,
        "worst relative error {:.3e} at {}",
        worst.0,
        worst.1
    );
    // The bounds really are in play: their gradients differ from the bare ±0.01 regulariser.
    for name in ["max_logvar", "min_logvar"] {
        let r = layout.get(name).unwrap().range();
        assert!(
            grads[r].iter().all(|g| (g.abs() - 0.01).abs() > 1e-3),
            "{name}: {:?}",
            &grads[layout.get(name).unwrap().range()]
        );
    }
}

#[test]
fn frozen_bounds_get_no_gradient() {
    let mut m = small_model();
    let mut cfg = m.config().clone();
    cfg.learn_logvar_bounds = false;
    let mut frozen =
        ProbabilisticEnsemble::new(OBS, ACT, cfg, &mut stream(1, "gc.init", 0)).unwrap();
    frozen.set_params(m.params()).unwrap();
    let x = randn(2 * BATCH * (OBS + ACT), 2);
    let y = randn(2 * BATCH * D, 3);
    let (mut g1, mut g2) = (vec![0.0; m.params().len()], vec![0.0; m.params().len()]);
    m.loss_and_gradient(&x, &y, BATCH, &mut g1).unwrap();
    frozen.loss_and_gradient(&x, &y, BATCH, &mut g2).unwrap();
    let bounds = m.layout().get("max_logvar").unwrap().offset;
    assert_eq!(g1[..bounds], g2[..bounds], "network gradients are the same");
    assert!(g2[bounds..].iter().all(|&g| g == 0.0));
}
