//! Model rollouts and predictions: termination, dropping terminated samples, elites only,
//! grouping by member, sampling statistics, reproducibility, clipping into the real box.

mod common;

use common::small_config;
use mbpo_core::{stream, ReplayBuffer, Rng, StateBox, UniformPolicy};
use mbpo_envs::termination_fn;
use mbpo_model::{
    ModelConfig, PredictError, ProbabilisticEnsemble, RolloutError, RolloutFilter, RolloutStats,
    RolloutTermination,
};

/// A model whose members ignore their input: member e predicts reward `reward[e]` and
/// Δobs `delta[e]` with σ ≈ e^(−15) (zero weights; output bias only; bounds pulled to −30).
fn scripted_model(
    obs_dim: usize,
    act_dim: usize,
    reward: &[f32],
    delta: &[Vec<f32>],
    elites: &[usize],
) -> ProbabilisticEnsemble {
    let members = reward.len();
    let cfg = ModelConfig {
        init_max_logvar: -29.0,
        init_min_logvar: -30.0,
        ..small_config(members, 1, &[4])
    };
    let mut m =
        ProbabilisticEnsemble::new(obs_dim, act_dim, cfg, &mut stream(0, "scripted", 0)).unwrap();
    let d = obs_dim + 1;
    let mut p = vec![0.0f32; m.params().len()];
    for e in 0..members {
        let r = m
            .layout()
            .get(&format!("ensemble.m{e}.l1.b"))
            .unwrap()
            .range();
        let b = &mut p[r];
        b[0] = reward[e];
        b[1..d].copy_from_slice(&delta[e]);
        b[d..].fill(-30.0);
    }
    let bounds = m.layout().get("max_logvar").unwrap().offset;
    p[bounds..bounds + d].fill(-29.0);
    p[bounds + d..].fill(-30.0);
    m.set_params(&p).unwrap();
    let mut w = m.weights();
    w.elites = elites.to_vec();
    m.load_weights(&w).unwrap();
    m
}

/// Check the buffer against the rollout's structure: step t pushed `alive_per_step[t]` rows in
/// order; each row's flag is the termination function's verdict; the next step's start states
/// are exactly the non-terminated next states, in order.
fn check_rollout_chain(
    out: &ReplayBuffer,
    stats: &RolloutStats,
    done: fn(&[f32], &[f32], &[f32]) -> bool,
) {
    let b = out.to_batch();
    let (o, a) = (b.obs_dim, b.act_dim);
    assert_eq!(b.len, stats.transitions);
    assert_eq!(
        stats.alive_per_step.iter().sum::<usize>(),
        stats.transitions
    );
    let mut start = 0;
    let mut terminated = 0;
    for (t, &alive) in stats.alive_per_step.iter().enumerate() {
        let mut survivors = Vec::new();
        for r in start..start + alive {
            let (s, act, s2) = (
                &b.obs[r * o..(r + 1) * o],
                &b.act[r * a..(r + 1) * a],
                &b.next_obs[r * o..(r + 1) * o],
            );
            let flagged = b.terminated[r] == 1.0;
            assert_eq!(flagged, done(s, act, s2), "step {t} row {r}");
            if flagged {
                terminated += 1;
            } else {
                survivors.extend_from_slice(s2);
            }
        }
        start += alive;
        if let Some(&next_alive) = stats.alive_per_step.get(t + 1) {
            assert_eq!(
                next_alive * o,
                survivors.len(),
                "step {t}: terminated samples are dropped"
            );
            assert_eq!(&b.obs[start * o..(start + next_alive) * o], &survivors[..]);
        }
    }
    assert_eq!(terminated, stats.terminated);
}

fn uniform(act_dim: usize) -> UniformPolicy {
    UniformPolicy {
        low: vec![-1.0; act_dim],
        high: vec![1.0; act_dim],
    }
}

#[test]
fn mountain_car_rollouts_stop_at_the_goal() {
    // Every member drives +0.02 in position per step, velocity unchanged.
    let mut model = scripted_model(
        2,
        1,
        &[-1.0, -1.0],
        &[vec![0.02, 0.0], vec![0.02, 0.0]],
        &[0, 1],
    );
    let done = termination_fn("MountainCarContinuous-v0").unwrap();
    #[rustfmt::skip]
    let start = [
        0.401, 0.01,  // goal after 3 steps (0.461)
        0.435, 0.01,  // goal after 1 step
        0.415, 0.01,  // goal after 2 steps
        0.401, -0.01, // moving left: never the goal
        -0.5, 0.03,   // far away
    ];
    let mut out = ReplayBuffer::new(2, 1, 100);
    let stats = model
        .rollout(
            &start,
            5,
            &mut uniform(1),
            5,
            RolloutTermination::Rule(&done),
            RolloutFilter::PAPER,
            &mut stream(0, "r", 0),
            &mut out,
        )
        .unwrap();
    assert_eq!(stats.alive_per_step, vec![5, 4, 3, 2, 2]);
    assert_eq!(
        (stats.steps, stats.transitions, stats.terminated),
        (5, 16, 3)
    );
    assert!((stats.mean_reward + 1.0).abs() < 1e-4);
    check_rollout_chain(&out, &stats, done);
    // The terminal transitions are the ones crossing 0.45 with velocity ≥ 0.
    let b = out.to_batch();
    let terminal: Vec<f32> = (0..b.len)
        .filter(|&r| b.terminated[r] == 1.0)
        .map(|r| b.next_obs[2 * r])
        .collect();
    assert_eq!(terminal.len(), 3);
    assert!(
        terminal.iter().all(|&p| (0.45..0.47).contains(&p)),
        "{terminal:?}"
    );
}

#[test]
fn everything_terminating_ends_the_rollout_after_one_step() {
    let mut model = scripted_model(2, 1, &[0.0], &[vec![0.0, 0.0]], &[0]);
    let mut out = ReplayBuffer::new(2, 1, 100);
    let always = |_: &[f32], _: &[f32], _: &[f32]| true;
    let stats = model
        .rollout(
            &[0.0; 20],
            10,
            &mut uniform(1),
            7,
            RolloutTermination::Rule(&always),
            RolloutFilter::PAPER,
            &mut stream(0, "r", 1),
            &mut out,
        )
        .unwrap();
    assert_eq!(
        (stats.steps, stats.transitions, stats.terminated),
        (1, 10, 10)
    );
    assert_eq!(out.len(), 10);
}

#[test]
fn clipped_rollouts_keep_every_imagined_state_in_the_real_box() {
    // Every member drifts +0.5 in dim 0 and −0.5 in dim 1 per step; the real states seen span
    // [−1, 1] in both. The rule ends a rollout whose next state passes 1 in dim 0, which only
    // an unclipped state can.
    let mut model = scripted_model(2, 1, &[0.0], &[vec![0.5, -0.5]], &[0]);
    let mut real = ReplayBuffer::new(2, 1, 4);
    real.push(&[-1.0, 1.0], &[0.0], 0.0, &[1.0, -1.0], false);
    let real_box = StateBox::of(&real);
    let past_one = |_: &[f32], _: &[f32], s2: &[f32]| s2[0] > 1.0;
    let run = |model: &mut ProbabilisticEnsemble, clip: Option<&StateBox>| {
        let mut out = ReplayBuffer::new(2, 1, 100);
        let stats = model
            .rollout(
                &[0.8, 0.0, -0.6, 0.9],
                2,
                &mut uniform(1),
                3,
                RolloutTermination::Rule(&past_one),
                RolloutFilter {
                    clip,
                    ..RolloutFilter::PAPER
                },
                &mut stream(0, "r", 2),
                &mut out,
            )
            .unwrap();
        (stats, out.to_batch())
    };
    let (stats, b) = run(&mut model, Some(&real_box));
    assert_eq!(
        stats.alive_per_step,
        vec![2, 2, 2],
        "nothing passes 1 once clipped"
    );
    // Rollout 1 is clamped at each of its 3 steps; rollout 2 stays inside.
    assert_eq!(stats.clipped, 3);
    // Row order: step 1 of both rollouts, then step 2, then step 3; each step starts from the
    // clipped state before it.
    let expected = [
        [1.0, -0.5],
        [-0.1, 0.4],
        [1.0, -1.0],
        [0.4, -0.1],
        [1.0, -1.0],
        [0.9, -0.6],
    ];
    for (r, want) in expected.iter().enumerate() {
        let got = &b.next_obs[2 * r..2 * r + 2];
        assert!(
            got.iter().zip(want).all(|(g, w)| (g - w).abs() < 1e-4),
            "row {r}: {got:?}, expected {want:?}"
        );
        assert!(
            got.iter().all(|x| (-1.0..=1.0).contains(x)),
            "row {r} leaves the box: {got:?}"
        );
    }
    assert_eq!(
        &b.obs[4..8],
        &b.next_obs[0..4],
        "step 2 starts from the clipped states"
    );
    // Without the box the same model leaves it at once and the rule ends that rollout.
    let (stats, b) = run(&mut model, None);
    assert_eq!(stats.alive_per_step, vec![2, 1, 1]);
    assert_eq!(stats.clipped, 0);
    assert!((b.next_obs[0] - 1.3).abs() < 1e-4, "{:?}", &b.next_obs[..2]);
}

fn random_start(n: usize, obs_dim: usize, rng: &mut Rng) -> Vec<f32> {
    (0..n * obs_dim)
        .map(|_| mbpo_core::rng::normal_f32(rng))
        .collect()
}

fn fake_done(_: &[f32], _: &[f32], s2: &[f32]) -> bool {
    s2[0] > 0.8
}

/// `n` rollouts of `k` steps under a uniform policy with [`fake_done`], from random starts, in a
/// fresh 5-member model on `threads` threads; everything drawn from `seed`.
fn fake_done_rollouts(
    seed: u64,
    n: usize,
    k: usize,
    threads: usize,
) -> (RolloutStats, ReplayBuffer) {
    let mut rng = stream(seed, "r", 0);
    let cfg = ModelConfig {
        threads,
        ..small_config(5, 3, &[32, 32])
    };
    let mut model = ProbabilisticEnsemble::new(4, 2, cfg, &mut rng).unwrap();
    let start = random_start(n, 4, &mut rng);
    let mut out = ReplayBuffer::new(4, 2, n * k);
    let stats = model
        .rollout(
            &start,
            n,
            &mut uniform(2),
            k,
            RolloutTermination::Rule(&fake_done),
            RolloutFilter::PAPER,
            &mut rng,
            &mut out,
        )
        .unwrap();
    (stats, out)
}

#[test]
fn stochastic_rollouts_drop_terminated_samples() {
    let (stats, out) = fake_done_rollouts(3, 600, 4, 1);
    assert_eq!(stats.steps, 4);
    assert!(
        stats.terminated > 50 && stats.alive_per_step[3] > 50,
        "{stats:?}"
    );
    check_rollout_chain(&out, &stats, fake_done);
}

#[test]
fn rollouts_are_bit_reproducible() {
    let run = || {
        let (stats, out) = fake_done_rollouts(4, 700, 3, 1);
        (stats, out.to_batch())
    };
    assert_eq!(run(), run());
}

#[test]
fn rollouts_use_only_elites() {
    let rewards: Vec<f32> = (0..7).map(|e| 10.0 * e as f32).collect();
    let deltas = vec![vec![0.0; 3]; 7];
    let mut model = scripted_model(3, 1, &rewards, &deltas, &[2, 5]);
    let mut out = ReplayBuffer::new(3, 1, 2000);
    let never = |_: &[f32], _: &[f32], _: &[f32]| false;
    model
        .rollout(
            &[0.0; 3000],
            1000,
            &mut uniform(1),
            1,
            RolloutTermination::Rule(&never),
            RolloutFilter::PAPER,
            &mut stream(5, "r", 0),
            &mut out,
        )
        .unwrap();
    let b = out.to_batch();
    let count = |v: f32| b.reward.iter().filter(|&&r| (r - v).abs() < 1e-3).count();
    let (n20, n50) = (count(20.0), count(50.0));
    assert_eq!(n20 + n50, 1000, "only elites 2 and 5 predict");
    assert!(
        n20 > 400 && n50 > 400,
        "uniform among elites: {n20} / {n50}"
    );
}

#[test]
fn grouped_predictions_equal_single_member_predictions() {
    let mut rng = stream(6, "p", 0);
    let mut model =
        ProbabilisticEnsemble::new(3, 2, small_config(3, 2, &[16, 16]), &mut rng).unwrap();
    let n = 2000; // several inference chunks per member
    let obs = random_start(n, 3, &mut rng);
    let act = random_start(n, 2, &mut rng);
    let members: Vec<usize> = (0..n).map(|i| (i * 7 + i / 3) % 3).collect();
    let (mut mean, mut lv) = (vec![0.0; n * 4], vec![0.0; n * 4]);
    model
        .predict_gaussian(&obs, &act, n, &members, &mut mean, &mut lv)
        .unwrap();
    for e in 0..3 {
        let (mut me, mut le) = (vec![0.0; n * 4], vec![0.0; n * 4]);
        model
            .predict_gaussian(&obs, &act, n, &vec![e; n], &mut me, &mut le)
            .unwrap();
        for i in (0..n).filter(|&i| members[i] == e) {
            assert_eq!(mean[i * 4..(i + 1) * 4], me[i * 4..(i + 1) * 4]);
            assert_eq!(lv[i * 4..(i + 1) * 4], le[i * 4..(i + 1) * 4]);
        }
    }
    assert!(
        lv.iter().all(|&v| (-10.0..=0.5).contains(&v)),
        "log-variances inside the bounds"
    );
}

#[test]
fn samples_follow_the_predicted_gaussian() {
    let mut rng = stream(7, "p", 0);
    let mut model = ProbabilisticEnsemble::new(2, 1, small_config(2, 1, &[8]), &mut rng).unwrap();
    let n = 40_000;
    let obs: Vec<f32> = [0.3f32, -0.2].repeat(n);
    let act = vec![0.5f32; n];
    let members = vec![1usize; n];
    let (mut mean, mut lv) = (vec![0.0; n * 3], vec![0.0; n * 3]);
    model
        .predict_gaussian(&obs, &act, n, &members, &mut mean, &mut lv)
        .unwrap();
    let (mut reward, mut next) = (vec![0.0; n], vec![0.0; n * 2]);
    model
        .predict_sample(&obs, &act, n, &members, &mut rng, &mut reward, &mut next)
        .unwrap();
    for j in 0..3 {
        let xs: Vec<f64> = (0..n).map(|i| if j == 0 { reward[i] } else { next[i * 2 + j - 1] } as f64).collect();
        let m = xs.iter().sum::<f64>() / n as f64;
        let v = xs.iter().map(|x| (x - m).powi(2)).sum::<f64>() / n as f64;
        let (want_m, want_v) = (mean[j] as f64, (lv[j] as f64).exp());
        assert!(
            (m - want_m).abs() < 5.0 * (want_v / n as f64).sqrt(),
            "dim {j}: mean {m} vs {want_m}"
        );
        assert!(
            (v / want_v - 1.0).abs() < 0.05,
            "dim {j}: var {v} vs {want_v}"
        );
    }
}

#[test]
fn bad_rollout_and_prediction_arguments_are_typed_errors() {
    let mut rng = stream(8, "p", 0);
    let mut model = ProbabilisticEnsemble::new(2, 1, small_config(2, 1, &[8]), &mut rng).unwrap();
    let never = |_: &[f32], _: &[f32], _: &[f32]| false;
    let mut out = ReplayBuffer::new(2, 1, 10);
    let err = model
        .rollout(
            &[0.0; 5],
            3,
            &mut uniform(1),
            1,
            RolloutTermination::Rule(&never),
            RolloutFilter::PAPER,
            &mut rng,
            &mut out,
        )
        .unwrap_err();
    assert!(
        matches!(
            err,
            RolloutError::StartObs {
                expected: 6,
                found: 5,
                ..
            }
        ),
        "{err}"
    );
    let mut wrong = ReplayBuffer::new(3, 1, 10);
    let err = model
        .rollout(
            &[0.0; 6],
            3,
            &mut uniform(1),
            1,
            RolloutTermination::Rule(&never),
            RolloutFilter::PAPER,
            &mut rng,
            &mut wrong,
        )
        .unwrap_err();
    assert!(
        matches!(err, RolloutError::BufferDims { found_obs: 3, .. }),
        "{err}"
    );
    let (mut m, mut l) = (vec![0.0; 3], vec![0.0; 3]);
    let err = model
        .predict_gaussian(&[0.0; 2], &[0.0], 1, &[2], &mut m, &mut l)
        .unwrap_err();
    assert_eq!(
        err,
        PredictError::Member {
            member: 2,
            members: 2
        }
    );
    let err = model
        .predict_gaussian(&[0.0; 2], &[0.0], 1, &[0], &mut m[..2], &mut l)
        .unwrap_err();
    assert!(
        matches!(err, PredictError::Length { what: "mean", .. }),
        "{err}"
    );
}

#[test]
fn rollouts_give_the_same_bits_on_any_thread_count() {
    // 2000 rollouts over 5 members: every member has more than one chunk of 256 rows, so the
    // chunks are cut between threads inside members as well as between them.
    let run = |threads: usize| {
        let (stats, out) = fake_done_rollouts(8, 2000, 2, threads);
        assert!(stats.terminated > 0 && stats.steps == 2, "{stats:?}");
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let b = out.to_batch();
        (
            stats,
            bits(&b.obs),
            bits(&b.reward),
            bits(&b.next_obs),
            b.terminated,
        )
    };
    let one = run(1);
    for threads in [2, 3] {
        assert!(run(threads) == one, "{threads} threads");
    }
}

/// A randomly initialised 3-member model (elites 0 and 1) whose members disagree by input.
fn disagreeing_model() -> ProbabilisticEnsemble {
    let cfg = small_config(3, 2, &[8]);
    ProbabilisticEnsemble::new(2, 1, cfg, &mut stream(0, "disagree", 0)).unwrap()
}

#[test]
fn elite_disagreement_is_the_variance_of_the_elites_means() {
    let mut model = disagreeing_model();
    let n = 6;
    let obs: Vec<f32> = (0..2 * n).map(|i| (i as f32 * 0.7).sin() * 2.0).collect();
    let act: Vec<f32> = (0..n).map(|i| i as f32 / n as f32 - 0.5).collect();
    let mut score = vec![0.0; n];
    model.elite_disagreement(&obs, &act, n, &mut score).unwrap();
    // Two elites: Var = ((μ₀ − μ₁)/2)² per dimension of [reward, next_obs], summed.
    let means = |model: &mut ProbabilisticEnsemble, e: usize| {
        let (mut mean, mut logvar) = (vec![0.0; 3 * n], vec![0.0; 3 * n]);
        model
            .predict_gaussian(&obs, &act, n, &vec![e; n], &mut mean, &mut logvar)
            .unwrap();
        mean
    };
    let (m0, m1) = (means(&mut model, 0), means(&mut model, 1));
    for (i, &got) in score.iter().enumerate() {
        let want: f64 = (3 * i..3 * i + 3)
            .map(|j| ((f64::from(m0[j]) - f64::from(m1[j])) / 2.0).powi(2))
            .sum();
        let got = f64::from(got);
        assert!(
            (got - want).abs() <= 1e-5 * want.max(1e-6),
            "row {i}: {got} vs {want}"
        );
        assert!(got > 0.0, "random members disagree");
    }
    // The non-elite member 2 plays no part: making it an elite changes the scores.
    let mut w = model.weights();
    w.elites = vec![0, 2];
    model.load_weights(&w).unwrap();
    let mut other = vec![0.0; n];
    model.elite_disagreement(&obs, &act, n, &mut other).unwrap();
    assert_ne!(other, score);
}

#[test]
fn a_masked_rollout_keeps_the_transitions_the_elites_agree_on() {
    let mut model = disagreeing_model();
    let n = 10;
    let starts: Vec<f32> = (0..2 * n).map(|i| (i as f32 * 1.3).cos() * 3.0).collect();
    // A constant action, so the scores of the start states can be recomputed.
    let mut constant = UniformPolicy {
        low: vec![0.3],
        high: vec![0.3],
    };
    let mut score = vec![0.0; n];
    model
        .elite_disagreement(&starts, &[0.3; 10], n, &mut score)
        .unwrap();
    let mut ranked: Vec<usize> = (0..n).collect();
    ranked.sort_by(|&i, &j| score[i].total_cmp(&score[j]));
    let never = |_: &[f32], _: &[f32], _: &[f32]| false;
    let mut run = |model: &mut ProbabilisticEnsemble, k: usize, keep_fraction: f64| {
        let mut out = ReplayBuffer::new(2, 1, 100);
        let filter = RolloutFilter {
            keep_fraction,
            ..RolloutFilter::PAPER
        };
        let rule = RolloutTermination::Rule(&never);
        let stats = model
            .rollout(
                &starts,
                n,
                &mut constant,
                k,
                rule,
                filter,
                &mut stream(0, "m", 0),
                &mut out,
            )
            .unwrap();
        (stats, out.to_batch())
    };
    // One step keeping 30 %: the 3 start states with the least disagreement, in their order.
    let (stats, b) = run(&mut model, 1, 0.3);
    assert_eq!((stats.transitions, stats.masked), (3, 7));
    let mut want: Vec<usize> = ranked[..3].to_vec();
    want.sort();
    let stored: Vec<&[f32]> = b.obs.chunks_exact(2).collect();
    let expected: Vec<&[f32]> = want.iter().map(|&i| &starts[2 * i..2 * i + 2]).collect();
    assert_eq!(stored, expected);
    // Three steps keeping half: ⌈10/2⌉ = 5, then 3, then 2 transitions; the rest masked.
    let (stats, b) = run(&mut model, 3, 0.5);
    assert_eq!(stats.alive_per_step, vec![10, 5, 3]);
    assert_eq!((stats.transitions, stats.masked, b.len), (10, 8, 10));
    // Keeping everything is the paper's rollout, bit for bit.
    let (all, b_all) = run(&mut model, 3, 1.0);
    let mut paper = ReplayBuffer::new(2, 1, 100);
    let rule = RolloutTermination::Rule(&never);
    let filter = RolloutFilter::PAPER;
    let mut policy = UniformPolicy {
        low: vec![0.3],
        high: vec![0.3],
    };
    let same = model
        .rollout(
            &starts,
            n,
            &mut policy,
            3,
            rule,
            filter,
            &mut stream(0, "m", 0),
            &mut paper,
        )
        .unwrap();
    assert_eq!((all.masked, all.transitions), (0, 30));
    assert_eq!(same, all);
    assert_eq!(paper.to_batch(), b_all);
}
