//! The input gradient of the mean prediction (`mean_step_recorded` / `mean_step_backward`,
//! what gradient-based planning backpropagates through) against central finite differences,
//! through a non-trivial input normaliser, several members and a two-step chain.

use mbpo_core::rng::{normal_f32, stream};
use mbpo_model::{InputNormalizer, MeanTape, ModelConfig, ProbabilisticEnsemble};

const OBS: usize = 3;
const ACT: usize = 2;
const N: usize = 7;

fn model() -> ProbabilisticEnsemble {
    let cfg = ModelConfig {
        members: 3,
        elites: 2,
        hidden: vec![16, 12],
        weight_decay: vec![0.0; 3],
        ..ModelConfig::default()
    };
    let mut m = ProbabilisticEnsemble::new(OBS, ACT, cfg, &mut stream(4, "ig.init", 0)).unwrap();
    // Larger weights than the init so the network is clearly non-linear on the test inputs,
    // and a normaliser far from the identity so its chain-rule factor 1/std matters.
    let mut w = m.weights();
    let mut rng = stream(4, "ig.perturb", 0);
    w.params
        .iter_mut()
        .for_each(|p| *p = 2.0 * *p + 0.05 * normal_f32(&mut rng));
    w.normalizer = InputNormalizer {
        mean: vec![0.3, -0.2, 1.0, 0.1, -0.4],
        std: vec![0.5, 2.0, 0.25, 1.5, 0.7],
    };
    m.load_weights(&w).unwrap();
    m
}

fn randn(n: usize, seed: u64) -> Vec<f32> {
    let mut r = stream(seed, "ig.data", n as u64);
    (0..n).map(|_| normal_f32(&mut r)).collect()
}

/// L = Σ c_r·reward_2 + Σ c_n·next_obs_2 + Σ c_r1·reward_1 after two mean steps from (obs, a1)
/// then (next_obs_1, a2): exercises the obs → next_obs identity path and the chain over steps.
struct Objective {
    members: Vec<usize>,
    c_r1: Vec<f32>,
    c_r: Vec<f32>,
    c_n: Vec<f32>,
}

impl Objective {
    fn new() -> Self {
        Self {
            // Every member appears; sample order is not grouped by member.
            members: vec![2, 0, 1, 2, 1, 0, 2],
            c_r1: randn(N, 11),
            c_r: randn(N, 12),
            c_n: randn(N * OBS, 13),
        }
    }

    fn value(&self, m: &ProbabilisticEnsemble, obs: &[f32], a1: &[f32], a2: &[f32]) -> f64 {
        let mut tape = MeanTape::new();
        let (mut r1, mut s1, mut r2, mut s2) = (
            vec![0.0; N],
            vec![0.0; N * OBS],
            vec![0.0; N],
            vec![0.0; N * OBS],
        );
        m.mean_step_recorded(&mut tape, 0, obs, a1, N, &self.members, &mut r1, &mut s1)
            .unwrap();
        m.mean_step_recorded(&mut tape, 1, &s1, a2, N, &self.members, &mut r2, &mut s2)
            .unwrap();
        let dot = |a: &[f32], b: &[f32]| {
            a.iter()
                .zip(b)
                .map(|(&x, &y)| x as f64 * y as f64)
                .sum::<f64>()
        };
        dot(&self.c_r1, &r1) + dot(&self.c_r, &r2) + dot(&self.c_n, &s2)
    }

    /// (∂L/∂obs, ∂L/∂a1, ∂L/∂a2) by the recorded backward passes.
    fn gradient(
        &self,
        m: &ProbabilisticEnsemble,
        obs: &[f32],
        a1: &[f32],
        a2: &[f32],
    ) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
        let mut tape = MeanTape::new();
        let (mut r1, mut s1, mut r2, mut s2) = (
            vec![0.0; N],
            vec![0.0; N * OBS],
            vec![0.0; N],
            vec![0.0; N * OBS],
        );
        m.mean_step_recorded(&mut tape, 0, obs, a1, N, &self.members, &mut r1, &mut s1)
            .unwrap();
        m.mean_step_recorded(&mut tape, 1, &s1, a2, N, &self.members, &mut r2, &mut s2)
            .unwrap();
        let (mut d_s1, mut d_a2) = (vec![0.0; N * OBS], vec![0.0; N * ACT]);
        m.mean_step_backward(&mut tape, 1, &self.c_r, &self.c_n, &mut d_s1, &mut d_a2)
            .unwrap();
        let (mut d_obs, mut d_a1) = (vec![0.0; N * OBS], vec![0.0; N * ACT]);
        m.mean_step_backward(&mut tape, 0, &self.c_r1, &d_s1, &mut d_obs, &mut d_a1)
            .unwrap();
        (d_obs, d_a1, d_a2)
    }
}

#[test]
fn mean_step_input_gradient_matches_finite_differences() {
    let m = model();
    let f = Objective::new();
    let obs = randn(N * OBS, 1);
    let a1 = randn(N * ACT, 2);
    let a2 = randn(N * ACT, 3);
    let (g_obs, g_a1, g_a2) = f.gradient(&m, &obs, &a1, &a2);
    let h = 1e-2f32;
    let mut worst = 0.0f64;
    let mut check = |name: &str, which: usize, analytic: &[f32]| {
        for (i, &g) in analytic.iter().enumerate() {
            let eval = |delta: f32| {
                let (mut o, mut x1, mut x2) = (obs.clone(), a1.clone(), a2.clone());
                [&mut o, &mut x1, &mut x2][which][i] += delta;
                f.value(&m, &o, &x1, &x2)
            };
            let fd = (eval(h) - eval(-h)) / (2.0 * h as f64);
            let err = (fd - g as f64).abs() / fd.abs().max(1.0);
            worst = worst.max(err);
            assert!(
                err < 5e-3,
                "{name}[{i}]: analytic {g} vs finite difference {fd} (relative error {err:.2e})"
            );
        }
    };
    check("obs", 0, &g_obs);
    check("a1", 1, &g_a1);
    check("a2", 2, &g_a2);
    // The gradients are not trivially small (a zero gradient would pass a loose check).
    let norm: f64 = g_a1.iter().map(|&g| (g as f64).powi(2)).sum::<f64>().sqrt();
    assert!(norm > 0.1, "‖∂L/∂a1‖ = {norm}");
    eprintln!("worst relative error {worst:.2e}");
}

#[test]
fn recorded_mean_equals_the_gaussian_prediction() {
    let mut m = model();
    let members = [2, 0, 1, 2, 1, 0, 2];
    let (obs, act) = (randn(N * OBS, 5), randn(N * ACT, 6));
    let (mut r, mut s) = (vec![0.0; N], vec![0.0; N * OBS]);
    m.mean_step_recorded(
        &mut MeanTape::new(),
        0,
        &obs,
        &act,
        N,
        &members,
        &mut r,
        &mut s,
    )
    .unwrap();
    let d = OBS + 1;
    let (mut mean, mut lv) = (vec![0.0; N * d], vec![0.0; N * d]);
    m.predict_gaussian(&obs, &act, N, &members, &mut mean, &mut lv)
        .unwrap();
    for i in 0..N {
        assert!(
            (mean[i * d] - r[i]).abs() <= 1e-4 * r[i].abs().max(1.0),
            "reward {i}"
        );
        for j in 0..OBS {
            let (a, b) = (mean[i * d + 1 + j], s[i * OBS + j]);
            assert!(
                (a - b).abs() <= 1e-4 * a.abs().max(1.0),
                "next_obs {i},{j}: {a} vs {b}"
            );
        }
    }
}

#[test]
fn bad_lengths_and_unrecorded_slots_are_errors() {
    let m = model();
    let mut tape = MeanTape::new();
    let (mut r, mut s) = (vec![0.0; N], vec![0.0; N * OBS]);
    let err = m
        .mean_step_recorded(
            &mut tape,
            0,
            &[0.0; 2],
            &[0.0; N * ACT],
            N,
            &[0; N],
            &mut r,
            &mut s,
        )
        .unwrap_err();
    assert!(err.to_string().contains("obs"), "{err}");
    let err = m
        .mean_step_backward(
            &mut tape,
            3,
            &r,
            &s,
            &mut [0.0; N * OBS],
            &mut [0.0; N * ACT],
        )
        .unwrap_err();
    assert!(err.to_string().contains("tape"), "{err}");
}
