//! The gradient planner's ∂J/∂(actions) against central finite differences of J: on the toy
//! tracker (analytic model), and through the learned ensemble with the task's known reward and
//! with the model's reward head (particles bound to different elites, a non-trivial normaliser).

mod common;

use common::Tracker;
use mbpo_core::rng::{normal_f32, stream, uniform_range_f32};
use mbpo_model::{InputNormalizer, ModelConfig, ProbabilisticEnsemble};
use mbpo_plan::{
    EnsembleModel, GradientPlanner, PlannerConfig, PlannerKind, PlanningModel, RewardSource,
};

const H: usize = 4;
const S: usize = 2;

fn planner(particles: usize, act_dim: usize) -> GradientPlanner {
    let cfg = PlannerConfig {
        kind: PlannerKind::Grad,
        horizon: H,
        particles,
        ..PlannerConfig::default()
    };
    GradientPlanner::new(&cfg, act_dim)
}

/// Compare every coordinate of ∂J/∂a with (J(a + h) − J(a − h)) / 2h.
fn check(model: &mut dyn PlanningModel, particles: usize, obs: &[f32], tol: f64, what: &str) {
    let a = model.act_dim();
    let mut p = planner(particles, a);
    p.bind_particles(model.members(), &mut stream(1, "gc.bind", 0));
    let mut rng = stream(2, "gc.seq", 0);
    let seqs: Vec<f32> = (0..S * H * a)
        .map(|_| uniform_range_f32(&mut rng, -0.8, 0.8))
        .collect();
    let (mut ret, mut grads) = (vec![0.0; S], vec![0.0; S * H * a]);
    p.objective_and_gradient(model, obs, &seqs, &mut ret, &mut grads)
        .unwrap();
    let h = 1e-2f32;
    let mut worst = 0.0f64;
    let mut norm = 0.0f64;
    for i in 0..seqs.len() {
        let s = i / (H * a);
        let mut j = |delta: f32| {
            let mut x = seqs.clone();
            x[i] += delta;
            let (mut r, mut g) = (vec![0.0; S], vec![0.0; S * H * a]);
            p.objective_and_gradient(model, obs, &x, &mut r, &mut g)
                .unwrap();
            r[s] as f64
        };
        let fd = (j(h) - j(-h)) / (2.0 * h as f64);
        let err = (fd - grads[i] as f64).abs() / fd.abs().max(1e-2);
        worst = worst.max(err);
        norm += (grads[i] as f64).powi(2);
        assert!(
            err < tol,
            "{what}: ∂J/∂a[{i}] analytic {} vs finite difference {fd} (relative error {err:.2e})",
            grads[i]
        );
    }
    eprintln!(
        "{what}: J = {ret:?}, ‖∇J‖ = {:.3}, worst relative error {worst:.2e}",
        norm.sqrt()
    );
    assert!(
        norm.sqrt() > 1e-2,
        "{what}: the gradient is trivially small"
    );
}

#[test]
fn gradient_matches_finite_differences_on_the_toy_tracker() {
    let mut model = Tracker::new(2);
    let obs = model.start(1.0);
    check(&mut model, 1, &obs, 2e-3, "tracker");
}

fn pendulum_ensemble() -> ProbabilisticEnsemble {
    let cfg = ModelConfig {
        members: 3,
        elites: 2,
        hidden: vec![24, 24],
        weight_decay: vec![0.0; 3],
        ..ModelConfig::default()
    };
    let mut m = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(3, "gc.model", 0)).unwrap();
    let mut w = m.weights();
    let mut rng = stream(3, "gc.perturb", 0);
    w.params
        .iter_mut()
        .for_each(|p| *p = 1.5 * *p + 0.02 * normal_f32(&mut rng));
    w.normalizer = InputNormalizer {
        mean: vec![0.1, -0.2, 0.5, 0.0],
        std: vec![0.7, 0.6, 2.5, 0.6],
    };
    w.elites = vec![2, 0];
    m.load_weights(&w).unwrap();
    m
}

#[test]
fn gradient_matches_finite_differences_through_the_ensemble_with_the_known_reward() {
    let reward = mbpo_envs::reward_fn("Pendulum-v1").unwrap();
    let mut model = EnsembleModel::new(
        pendulum_ensemble(),
        RewardSource::Known(reward),
        None,
        &[-2.0],
        &[2.0],
    )
    .unwrap();
    // θ = 0.5 rad, θ̇ = −1: far from atan2's branch cut at θ = ±π.
    let obs = [0.5f32.cos(), 0.5f32.sin(), -1.0];
    check(&mut model, 3, &obs, 5e-3, "ensemble + known reward");
}

#[test]
fn gradient_matches_finite_differences_through_the_ensemble_reward_head() {
    let mut model = EnsembleModel::new(
        pendulum_ensemble(),
        RewardSource::Model,
        None,
        &[-2.0],
        &[2.0],
    )
    .unwrap();
    let obs = [0.5f32.cos(), 0.5f32.sin(), -1.0];
    check(&mut model, 3, &obs, 5e-3, "ensemble reward head");
}
