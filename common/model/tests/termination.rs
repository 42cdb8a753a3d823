//! The learned termination rule: its gradient against finite differences, what it learns from
//! rare terminal transitions, its use in model rollouts, and that it travels with the model's
//! weights and checkpoints.

use mbpo_core::rng::{stream, uniform_range_f32};
use mbpo_core::{Batch, ReplayBuffer, UniformPolicy};
use mbpo_model::{
    ModelConfig, ProbabilisticEnsemble, RolloutFilter, RolloutRule, RolloutTermination,
    TerminationClassifier,
};

const OBS: usize = 3;
const ACT: usize = 1;

/// Transitions of a point moved by its action; terminal when |s'[0]| > 1.8 (about 5 % of rows).
fn data(n: usize, seed: u64) -> Batch {
    let mut rng = stream(seed, "term.data", 0);
    let mut b = Batch::new(OBS, ACT, n);
    for i in 0..n {
        for j in 0..OBS {
            b.obs[i * OBS + j] = uniform_range_f32(&mut rng, -2.0, 2.0);
        }
        b.act[i] = uniform_range_f32(&mut rng, -1.0, 1.0);
        for j in 0..OBS {
            b.next_obs[i * OBS + j] = b.obs[i * OBS + j] + 0.1 * b.act[i];
        }
        b.reward[i] = -b.next_obs[i * OBS].powi(2);
        b.terminated[i] = f32::from(b.next_obs[i * OBS].abs() > 1.8);
    }
    b
}

#[test]
fn the_gradient_of_the_weighted_cross_entropy_matches_finite_differences() {
    let mut c = TerminationClassifier::new(OBS, ACT, &mut stream(0, "term.init", 0));
    let d = data(64, 1);
    let rows: Vec<u32> = (0..64).collect();
    assert!(d.terminated.iter().any(|&t| t > 0.5) && d.terminated.iter().any(|&t| t < 0.5));
    c.loss_and_gradient(&d, &rows, 7.0);
    let grads = c.gradient().to_vec();
    let params = c.params_mut().to_vec();
    let eps = 1e-2f32;
    let (mut worst, mut scale) = (0.0f64, 0.0f64);
    let mut numeric = Vec::new();
    for i in 0..params.len() {
        let mut at = |v: f32| {
            c.params_mut().copy_from_slice(&params);
            c.params_mut()[i] = v;
            c.loss_and_gradient(&d, &rows, 7.0)
        };
        let n = (at(params[i] + eps) - at(params[i] - eps)) / (2.0 * eps as f64);
        scale = scale.max(n.abs());
        numeric.push(n);
    }
    for (i, n) in numeric.iter().enumerate() {
        let err = (grads[i] as f64 - n).abs() / (0.01 * scale + n.abs());
        worst = worst.max(err);
    }
    assert!(worst < 1e-2, "worst relative error {worst:.3e}");
}

#[test]
fn it_learns_a_rare_termination_with_high_precision_and_recall() {
    let mut c = TerminationClassifier::new(OBS, ACT, &mut stream(0, "term.init", 0));
    let d = data(6000, 2);
    let positives = d.terminated.iter().filter(|&&t| t > 0.5).count();
    assert!((150..600).contains(&positives), "{positives} terminal rows");
    let report = c.train(&d, &mut stream(0, "term.train", 0));
    assert!(report.holdout_positives > 20, "{report:?}");
    assert!(
        report.precision > 0.85 && report.recall > 0.85,
        "{report:?}"
    );
    // On fresh data too.
    let fresh = data(2000, 3);
    let mut done = vec![false; fresh.len];
    c.predict(
        &fresh.obs,
        &fresh.act,
        &fresh.next_obs,
        fresh.len,
        &mut done,
    );
    let agree = done
        .iter()
        .zip(&fresh.terminated)
        .filter(|(p, &t)| **p == (t > 0.5))
        .count();
    assert!(
        agree as f64 / fresh.len as f64 > 0.97,
        "{agree} of {}",
        fresh.len
    );
}

fn learned_model() -> ProbabilisticEnsemble {
    let cfg = ModelConfig {
        members: 3,
        elites: 2,
        hidden: vec![32, 32],
        weight_decay: vec![1e-5; 3],
        max_epochs: Some(30),
        learn_termination: true,
        ..ModelConfig::default()
    };
    let mut m = ProbabilisticEnsemble::new(OBS, ACT, cfg, &mut stream(0, "term.model", 0)).unwrap();
    let report = m
        .train(&data(3000, 4), &mut stream(0, "term.fit", 0))
        .unwrap();
    let t = report.termination.expect("the model learns termination");
    assert!(t.recall > 0.7, "{t:?}");
    m
}

/// `m`'s architecture without a learned termination rule.
fn without_learned_rule(m: &ProbabilisticEnsemble) -> ProbabilisticEnsemble {
    let cfg = ModelConfig {
        learn_termination: false,
        ..m.config().clone()
    };
    ProbabilisticEnsemble::new(OBS, ACT, cfg, &mut stream(0, "term.plain", 0)).unwrap()
}

#[test]
fn rollouts_of_a_model_with_a_learned_rule_end_where_it_predicts_termination() {
    let mut m = learned_model();
    // Start near the edge so some rollouts cross |x| = 1.8 within a few steps.
    let mut rng = stream(0, "term.rollout", 0);
    let n = 400;
    let start: Vec<f32> = (0..n * OBS)
        .map(|i| match i % OBS {
            0 => uniform_range_f32(&mut rng, 1.5, 1.9) * if i % 2 == 0 { 1.0 } else { -1.0 },
            _ => uniform_range_f32(&mut rng, -1.0, 1.0),
        })
        .collect();
    let mut policy = UniformPolicy {
        low: vec![-1.0],
        high: vec![1.0],
    };
    let mut out = ReplayBuffer::new(OBS, ACT, n * 5);
    let stats = m
        .rollout(
            &start,
            n,
            &mut policy,
            5,
            RolloutTermination::Learned,
            RolloutFilter::PAPER,
            &mut rng,
            &mut out,
        )
        .unwrap();
    assert!(stats.terminated > 20, "{stats:?}");
    // Every stored flag is the classifier's verdict on that transition.
    let b = out.to_batch();
    let mut done = vec![false; b.len];
    let mut c = m.termination().unwrap().clone();
    c.predict(&b.obs, &b.act, &b.next_obs, b.len, &mut done);
    let flags: Vec<bool> = b.terminated.iter().map(|&t| t > 0.5).collect();
    assert_eq!(flags, done);
    assert_eq!(flags.iter().filter(|&&f| f).count(), stats.terminated);

    // A model without a learned rule needs the task's.
    let mut plain = without_learned_rule(&m);
    let e = plain
        .rollout(
            &start,
            n,
            &mut policy,
            1,
            RolloutTermination::Learned,
            RolloutFilter::PAPER,
            &mut rng,
            &mut out,
        )
        .unwrap_err();
    assert!(e.to_string().contains("no termination rule"), "{e}");
}

#[test]
fn the_learned_rule_travels_with_the_weights_and_the_checkpoint() {
    let m = learned_model();
    let mut other = ProbabilisticEnsemble::new(
        OBS,
        ACT,
        m.config().clone(),
        &mut stream(9, "term.other", 0),
    )
    .unwrap();
    assert_ne!(other.weights(), m.weights());
    other.restore(&m.checkpoint()).unwrap();
    assert_eq!(other.checkpoint(), m.checkpoint());
    // Training both on the same data afterwards gives the same rule: the Adam moments came too.
    let d = data(1000, 5);
    let (mut a, mut b) = (m.clone(), other);
    let ra = a.train(&d, &mut stream(0, "again", 0)).unwrap();
    let rb = b.train(&d, &mut stream(0, "again", 0)).unwrap();
    assert_eq!(ra.termination, rb.termination);
    assert_eq!(a.weights(), b.weights());
}

/// The exact rule of [`data`], as a task's Rust rule.
fn beyond_1_8(_obs: &[f32], _act: &[f32], next_obs: &[f32]) -> bool {
    next_obs[0].abs() > 1.8
}

/// A planner asks a [`RolloutRule`] for a whole batch: the learned rule agrees with the exact
/// one on fresh transitions, a Rust rule is applied row by row, and a model without a learned
/// rule is refused by name.
#[test]
fn a_rollout_rule_answers_for_a_batch() {
    let mut m = learned_model();
    let fresh = data(2000, 5);
    let want: Vec<bool> = fresh.terminated.iter().map(|&t| t > 0.5).collect();
    let mut done = vec![false; fresh.len];
    let (o, a, s) = (&fresh.obs, &fresh.act, &fresh.next_obs);
    RolloutRule::Rule(beyond_1_8)
        .done_batch(&mut m, o, a, s, fresh.len, &mut done)
        .unwrap();
    assert_eq!(done, want);
    RolloutRule::Learned
        .done_batch(&mut m, o, a, s, fresh.len, &mut done)
        .unwrap();
    let agree = done.iter().zip(&want).filter(|(p, t)| p == t).count();
    assert!(
        agree as f64 / fresh.len as f64 > 0.95,
        "{agree} of {}",
        fresh.len
    );
    assert!(
        done.iter().any(|&d| d),
        "some fresh transitions are terminal"
    );

    let mut plain = without_learned_rule(&m);
    let err = RolloutRule::Learned
        .done_batch(&mut plain, o, a, s, fresh.len, &mut done)
        .unwrap_err();
    assert!(
        matches!(err, mbpo_model::RolloutError::NoTerminationRule),
        "{err}"
    );
}
