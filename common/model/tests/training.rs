//! Training behaviour: learning Pendulum, early stopping, elites, bootstrap, reproducibility.

mod common;

use common::{pendulum_data, small_config};
use mbpo_core::{stream, Batch};
use mbpo_model::{
    elite_holdout_mse_if_capped, ModelConfig, ProbabilisticEnsemble, StopReason, TrainError,
};

fn elite_mean(m: &ProbabilisticEnsemble, mse: &[f32]) -> f32 {
    m.elites().iter().map(|&e| mse[e]).sum::<f32>() / m.elites().len() as f32
}

#[test]
fn pendulum_model_learns_one_step_dynamics() {
    let train = pendulum_data(8000, 1);
    let test = pendulum_data(2000, 2);
    let cfg = ModelConfig {
        // Patience long enough to see the MSE fall: with MBPO's patience of 5 the first call
        // stops near epoch 12, at MSE ≈ 0.3, while the NLL still improves (MBPO retrains every
        // 250 steps, continuing from there).
        max_epochs: Some(45),
        max_epochs_since_update: 45,
        ..small_config(5, 3, &[128, 128, 128])
    };
    let mut model = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "test.model", 0)).unwrap();
    let untrained = model.evaluate_mse(&test).unwrap();
    let mut rng = stream(0, "test.train", 0);
    let first = model.train(&train, &mut rng).unwrap();
    let trained = model.evaluate_mse(&test).unwrap();
    let (before, after) = (elite_mean(&model, &untrained), elite_mean(&model, &trained));
    eprintln!(
        "held-out one-step MSE: untrained {before:.4}, trained {after:.4}; epochs {}, {:?}",
        first.epochs, first.stop
    );
    // Targets are [reward, Δcosθ, Δsinθ, Δθ̇]; predicting zero gives ≈ E[r²]/4 ≈ 10.
    assert!(before > 5.0, "untrained elites: {before}");
    assert!(after < 0.06, "trained elites: {after}");
    assert_eq!(first.elites, model.elites());
    assert!(
        first.final_holdout_mse.iter().all(|&m| m < 0.1),
        "{:?}",
        first.final_holdout_mse
    );
}

#[test]
fn frozen_weights_stop_after_patience_and_keep_epoch_zero() {
    // lr = 0: the holdout MSE never changes, so epoch 0 improves on 1e10 and epochs 1..=6 do
    // not; the counter exceeds 5 after epoch 6, i.e. 7 epochs.
    let data = pendulum_data(1000, 3);
    let cfg = ModelConfig {
        lr: 0.0,
        ..small_config(3, 2, &[16, 16])
    };
    let mut model = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "test.model", 1)).unwrap();
    let before = model.params().to_vec();
    let r = model.train(&data, &mut stream(0, "test.train", 1)).unwrap();
    assert_eq!((r.epochs, r.stop), (7, StopReason::NoImprovement));
    assert_eq!(r.best_epoch, vec![Some(0); 3]);
    assert_eq!(r.holdout_mse.len(), 7);
    assert_eq!(model.params(), &before[..]);
    assert_eq!(r.final_holdout_mse, r.holdout_mse[6]);
}

#[test]
fn epoch_cap_and_snapshot_restore() {
    let data = pendulum_data(4000, 4);
    let cfg = ModelConfig {
        max_epochs: Some(6),
        max_epochs_since_update: 10,
        ..small_config(2, 1, &[64, 64, 64])
    };
    let mut model = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "test.model", 2)).unwrap();
    let mut rng = stream(0, "test.train", 2);
    let r = model.train(&data, &mut rng).unwrap();
    assert_eq!((r.epochs, r.stop), (6, StopReason::MaxEpochs));
    // After the restore each member's final MSE is its snapshot epoch's.
    for e in 0..2 {
        let best = r.best_epoch[e].expect("the first epoch always improves on 1e10");
        assert_eq!(r.final_holdout_mse[e], r.holdout_mse[best][e], "member {e}");
    }
    // A second call continues from these weights: its first epoch starts far ahead.
    let second = model.train(&data, &mut rng).unwrap();
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    assert!(
        mean(&second.holdout_mse[0]) < 0.5 * mean(&r.holdout_mse[0]),
        "{:?} vs {:?}",
        second.holdout_mse[0],
        r.holdout_mse[0]
    );
}

/// `elite_holdout_mse_if_capped` is what a training capped at c epochs ends with: a capped
/// training of the same model with the same draws reports exactly that elite holdout MSE.
#[test]
fn the_capped_replay_equals_a_capped_training() {
    let data = pendulum_data(1500, 6);
    let train = |max_epochs| {
        let cfg = ModelConfig {
            max_epochs,
            max_epochs_since_update: 2,
            ..small_config(5, 3, &[32, 32])
        };
        let mut model =
            ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "test.model", 3)).unwrap();
        model.train(&data, &mut stream(0, "test.train", 3)).unwrap()
    };
    let full = train(None);
    assert_eq!(full.stop, StopReason::NoImprovement);
    assert!(full.epochs >= 6, "{} epochs", full.epochs);
    let threshold = ModelConfig::default().improvement_threshold;
    let replay = |cap| elite_holdout_mse_if_capped(&full, cap, 3, threshold);
    let e = full.epochs;
    for cap in [1, 2, 3, e / 2, e - 1] {
        let capped = train(Some(cap));
        assert_eq!(capped.epochs, cap);
        assert_eq!(replay(cap), capped.elite_holdout_mse(), "cap {cap} of {e}");
    }
    assert_eq!(replay(e), full.elite_holdout_mse());
    assert_eq!(replay(e + 5), full.elite_holdout_mse());
    assert!(
        replay(1) > full.elite_holdout_mse(),
        "one epoch should cost something"
    );
    assert!(replay(0).is_nan());
}

#[test]
fn elites_are_the_members_with_the_lowest_holdout_mse() {
    // Data whose targets are all zero (reward 0, next_obs = obs). Members 1 and 4 get a zero
    // output layer, so they predict exactly 0 (MSE 0); the others predict something else.
    let mut data = pendulum_data(500, 5);
    data.reward.iter_mut().for_each(|r| *r = 0.0);
    data.next_obs = data.obs.clone();
    let cfg = ModelConfig {
        lr: 0.0,
        ..small_config(5, 2, &[16])
    };
    let mut model = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "test.model", 3)).unwrap();
    let mut p = model.params().to_vec();
    for e in [1, 4] {
        for t in ["w", "b"] {
            let r = model
                .layout()
                .get(&format!("ensemble.m{e}.l1.{t}"))
                .unwrap()
                .range();
            p[r].fill(0.0);
        }
    }
    // Give the others a clearly non-zero output bias.
    for e in [0, 2, 3] {
        let r = model
            .layout()
            .get(&format!("ensemble.m{e}.l1.b"))
            .unwrap()
            .range();
        p[r].fill(0.5 + e as f32);
    }
    model.set_params(&p).unwrap();
    let r = model.train(&data, &mut stream(0, "test.train", 3)).unwrap();
    assert_eq!(r.elites, vec![1, 4]);
    assert_eq!(model.elites(), &[1, 4]);
    assert_eq!((r.final_holdout_mse[1], r.final_holdout_mse[4]), (0.0, 0.0));
    // The rest are ranked by MSE: 0 (bias 0.5) < 2 (2.5) < 3 (3.5).
    assert!(
        r.final_holdout_mse[0] < r.final_holdout_mse[2]
            && r.final_holdout_mse[2] < r.final_holdout_mse[3]
    );
}

#[test]
fn identical_members_diverge_through_their_own_bootstrap_resamples() {
    let data = pendulum_data(1500, 6);
    let cfg = ModelConfig {
        max_epochs: Some(2),
        ..small_config(3, 2, &[32, 32])
    };
    let mut model = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "test.model", 4)).unwrap();
    let mut p = model.params().to_vec();
    let per = p.len() - 2 * 4; // minus the two bounds of width d = 4
    let per_member = per / 3;
    let m0 = p[..per_member].to_vec();
    for e in 1..3 {
        p[e * per_member..(e + 1) * per_member].copy_from_slice(&m0);
    }
    model.set_params(&p).unwrap();
    model.train(&data, &mut stream(0, "test.train", 4)).unwrap();
    let p = model.params();
    let member = |e: usize| &p[e * per_member..(e + 1) * per_member];
    assert_ne!(member(0), member(1));
    assert_ne!(member(1), member(2));
    // And not by a rounding error: the members' predictions differ measurably.
    let mse = model.evaluate_mse(&data).unwrap();
    assert!(mse[0] != mse[1] && mse[1] != mse[2], "{mse:?}");
}

#[test]
fn training_is_bit_reproducible() {
    let data = pendulum_data(1200, 7);
    let run = || {
        let cfg = ModelConfig {
            max_epochs: Some(3),
            ..small_config(3, 2, &[32, 32])
        };
        let mut rng = stream(9, "test.model", 0);
        let mut model = ProbabilisticEnsemble::new(3, 1, cfg, &mut rng).unwrap();
        let mut reports = Vec::new();
        for _ in 0..2 {
            let r = model.train(&data, &mut rng).unwrap();
            reports.push(r.without_timings());
        }
        (model.weights(), reports)
    };
    let (w1, r1) = run();
    let (w2, r2) = run();
    assert_eq!(w1, w2);
    assert_eq!(r1, r2);
}

/// Members, or halves of their minibatches, run in blocks on `threads` threads and every sum
/// keeps member and half order; a member whose halves fall in one block runs whole. So
/// weights, Adam state, reports and elites are bit-identical across the thread counts that
/// cut no member (1, 7; and 4, 8 and 11, whose blocks of 4 and 2 halves hold whole members),
/// across those that cut the same members (5 and 6: blocks of 3 halves cut members 1 and 4),
/// and across those that cut every member (14: one half each; 16, more threads than halves,
/// starts only 14). 2 and 3 threads cut one member each (3 and 2), their own rounding; the
/// gradient of such a mix is checked in `gradcheck.rs`.
/// 641 rows leave a last minibatch of one row (513 training rows), whose second half is empty.
/// The ways of cutting differ only in f32 rounding of the gradient sums.
#[test]
fn training_on_several_threads_is_bit_identical_to_one_thread() {
    let data = pendulum_data(1000, 3);
    let run = |threads: usize| {
        let cfg = ModelConfig {
            max_epochs: Some(4),
            threads,
            ..small_config(7, 5, &[24, 24])
        };
        let mut rng = stream(5, "test.model", 0);
        let mut model = ProbabilisticEnsemble::new(3, 1, cfg, &mut rng).unwrap();
        let mut reports = Vec::new();
        for n in [600, 641, 1000] {
            let mut part = Batch::new(3, 1, n);
            part.obs.copy_from_slice(&data.obs[..3 * n]);
            part.act.copy_from_slice(&data.act[..n]);
            part.reward.copy_from_slice(&data.reward[..n]);
            part.next_obs.copy_from_slice(&data.next_obs[..3 * n]);
            part.terminated.copy_from_slice(&data.terminated[..n]);
            let r = model.train(&part, &mut rng).unwrap();
            reports.push(r.without_timings());
        }
        (model.checkpoint(), reports)
    };
    for (reference, same) in [(1, &[4, 7, 8, 11][..]), (5, &[6][..]), (14, &[16][..])] {
        let (state1, reports1) = run(reference);
        assert!(reports1.iter().all(|r| r.gradient_steps > 0));
        for &threads in same {
            let (state, reports) = run(threads);
            assert_eq!(
                reports, reports1,
                "reports differ: {threads} and {reference} threads"
            );
            assert!(
                state == state1,
                "weights or Adam state differ: {threads} and {reference} threads"
            );
        }
    }
}

#[test]
fn bad_training_data_is_rejected_with_typed_errors() {
    let mut model =
        ProbabilisticEnsemble::new(3, 1, small_config(2, 1, &[8]), &mut stream(0, "t", 0)).unwrap();
    let mut rng = stream(0, "t", 1);
    let err = model.train(&Batch::new(2, 1, 100), &mut rng).unwrap_err();
    assert!(
        matches!(err, TrainError::Dims { found_obs: 2, .. }),
        "{err}"
    );
    let err = model.train(&Batch::new(3, 1, 4), &mut rng).unwrap_err();
    assert!(
        matches!(
            err,
            TrainError::TooFewTransitions {
                found: 4,
                required: 5,
                ..
            }
        ),
        "{err}"
    );
    let mut nan = pendulum_data(50, 8);
    nan.next_obs[3 * 17 + 1] = f32::NAN;
    let err = model.train(&nan, &mut rng).unwrap_err();
    assert_eq!(
        err,
        TrainError::NonFinite {
            row: 17,
            field: "next_obs"
        }
    );
    let mut ragged = pendulum_data(50, 8);
    ragged.reward.truncate(10);
    assert!(matches!(
        model.train(&ragged, &mut rng),
        Err(TrainError::Ragged {
            field: "reward",
            ..
        })
    ));
}

#[test]
fn checkpoint_restores_weights_and_optimiser_so_training_continues_identically() {
    let data = pendulum_data(600, 5);
    let cfg = ModelConfig {
        max_epochs: Some(3),
        ..small_config(3, 2, &[16, 16])
    };
    let build = |seed| {
        ProbabilisticEnsemble::new(3, 1, cfg.clone(), &mut stream(seed, "test.model", 3)).unwrap()
    };
    let mut original = build(0);
    let mut rng = stream(0, "test.train", 3);
    original.train(&data, &mut rng).unwrap();
    let state = original.checkpoint();
    assert!(state.adam.t > 0, "training moved the optimiser");
    let mut restored = build(1); // other initial weights: all must be overwritten
    restored.restore(&state).unwrap();
    let mut rng2 = rng.clone();
    original.train(&data, &mut rng).unwrap();
    restored.train(&data, &mut rng2).unwrap();
    assert_eq!(restored.checkpoint(), original.checkpoint());

    let mut wrong = state.clone();
    wrong.adam.m.pop();
    let err = build(2).restore(&wrong).unwrap_err().to_string();
    assert!(err.contains("moments"), "{err}");
}
