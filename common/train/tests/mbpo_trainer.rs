//! The sequential MBPO reference at a scale CI affords.

use mbpo_core::StateBox;
use mbpo_train::run_dir::read_eval_curve;
use mbpo_train::{train_mbpo, Algo, ExperimentConfig, ImaginedStateClip, Mbpo};

mod support;
use support::temp_dir;

/// MBPO on Pendulum with small networks: 8 SAC updates and 50 rollouts per env step.
fn small_config(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        algo: Algo::MBPO,
        steps,
        ..Default::default()
    };
    cfg.eval.every = 200;
    cfg.eval.episodes = 3;
    cfg.sac.hidden = vec![64, 64];
    cfg.sac.batch_size = 64;
    cfg.sac.actor_lr = 1e-3;
    cfg.sac.critic_lr = 1e-3;
    cfg.sac.alpha_lr = 1e-3;
    cfg.mbpo.init_random_steps = 200;
    cfg.mbpo.epoch_length = 200;
    cfg.mbpo.model_train_freq = 100;
    cfg.mbpo.rollouts_per_step = 50;
    cfg.mbpo.rollout_schedule = [1, 15, 1, 1];
    cfg.mbpo.updates_per_step = 8;
    cfg.model.members = 4;
    cfg.model.elites = 3;
    cfg.model.hidden = vec![32, 32];
    cfg.model.weight_decay = vec![2.5e-5, 5e-5, 1e-4];
    cfg.model.batch_size = 64;
    cfg
}

#[test]
fn mbpo_run_writes_model_columns_and_reproduces_bit_for_bit() {
    let cfg = small_config(500);
    let (a, b) = (temp_dir("mbpo-det-a"), temp_dir("mbpo-det-b"));
    let sa = train_mbpo(&cfg, &a).unwrap();
    let sb = train_mbpo(&cfg, &b).unwrap();
    assert_eq!(sa.policy_sha256, sb.policy_sha256);
    assert_eq!(sa.env_steps, 500);
    assert_eq!(
        sa.sac_updates,
        300 * 8,
        "G updates per env step after the warm-up"
    );
    let metrics = std::fs::read_to_string(a.join("metrics.csv")).unwrap();
    let header: Vec<&str> = metrics.lines().next().unwrap().split(',').collect();
    let last: Vec<&str> = metrics.lines().last().unwrap().split(',').collect();
    let cell = |name: &str| last[header.iter().position(|h| *h == name).unwrap()];
    // model_holdout_mse, rollout_length, model_buffer are filled once the model was trained.
    assert!(
        cell("model_holdout_mse").parse::<f64>().unwrap() > 0.0,
        "{metrics}"
    );
    assert_eq!(cell("rollout_length"), "1");
    assert!(
        cell("model_buffer").parse::<f64>().unwrap() > 0.0,
        "{metrics}"
    );
    // The world model's columns are TD-MPC2's: empty in an MBPO run.
    assert_eq!((cell("consistency_loss"), cell("reward_loss")), ("", ""));
    assert_eq!(
        read_eval_curve(&a.join("metrics.csv")).unwrap(),
        read_eval_curve(&b.join("metrics.csv")).unwrap()
    );
    for d in [a, b] {
        std::fs::remove_dir_all(d).unwrap();
    }
}

#[test]
fn model_buffer_keeps_retain_epochs_of_rollouts_across_retrains() {
    // Regression for a known bug elsewhere (mbrl-lib PR #61): the model buffer was wiped at
    // every retrain. With epoch 200 and train freq 100, one retained epoch holds two trainings'
    // rollouts: 2 x (50 x 100) one-step rollouts (Pendulum never terminates).
    let cfg = small_config(1000);
    let mut mbpo = Mbpo::new(&cfg).unwrap();
    for _ in 0..200 {
        mbpo.warm_up_step().unwrap();
    }
    mbpo.train_model().unwrap();
    mbpo.branch_rollouts(0).unwrap();
    let after_one = mbpo.model_buffer_len();
    assert_eq!(after_one, 5000);
    mbpo.train_model().unwrap();
    mbpo.branch_rollouts(0).unwrap();
    assert_eq!(
        mbpo.model_buffer_len(),
        10_000,
        "second training must not wipe the first's rollouts"
    );
    mbpo.train_model().unwrap();
    mbpo.branch_rollouts(0).unwrap();
    assert_eq!(
        mbpo.model_buffer_len(),
        10_000,
        "FIFO: the oldest rollouts make room"
    );
}

/// Every imagined next state in D_model, and how many leave the box of D_env's states.
fn imagined_outside_the_real_box(mbpo: &mut Mbpo) -> (usize, usize) {
    let (_, d_env, d_model) = mbpo.learner_mut().sac_and_buffers();
    let real_box = StateBox::of(d_env);
    let imagined = d_model.to_batch();
    let o = imagined.obs_dim;
    let mut counts = vec![0; o];
    let outside = imagined
        .next_obs
        .chunks_exact(o)
        .filter(|s| real_box.count_outside(s, &mut counts))
        .count();
    (imagined.len, outside)
}

#[test]
fn clip_imagined_states_keeps_the_model_buffer_in_the_real_box() {
    // A model trained on 60 warm-up steps, rolled out 5 steps: it extrapolates past the real
    // states unless `mbpo.clip_imagined_states = "real_box"` clamps its predictions.
    let outside_with = |clip: ImaginedStateClip| {
        let mut cfg = small_config(1000);
        cfg.mbpo.rollout_schedule = [0, 1, 5, 5];
        cfg.mbpo.clip_imagined_states = clip;
        let mut mbpo = Mbpo::new(&cfg).unwrap();
        for _ in 0..60 {
            mbpo.warm_up_step().unwrap();
        }
        mbpo.train_model().unwrap();
        mbpo.branch_rollouts(5).unwrap();
        imagined_outside_the_real_box(&mut mbpo)
    };
    let (rows, outside) = outside_with(ImaginedStateClip::Off);
    assert_eq!(rows, 5 * 5000, "5-step rollouts of 50 x 100 starts");
    assert!(
        outside > 0,
        "the paper's rollouts leave the box ({outside} of {rows})"
    );
    assert_eq!(outside_with(ImaginedStateClip::RealBox), (rows, 0));
}

#[test]
fn a_keep_fraction_masks_each_rollout_step() {
    // 50 x 100 rollouts of 5 steps keeping half of each step: ⌈5000/2⌉ = 2500, then 1250,
    // 625, 313, 157 transitions (Pendulum never terminates).
    let rows_with = |keep: f64| {
        let mut cfg = small_config(1000);
        cfg.mbpo.rollout_schedule = [0, 1, 5, 5];
        cfg.mbpo.rollout_keep_fraction = keep;
        let mut mbpo = Mbpo::new(&cfg).unwrap();
        for _ in 0..60 {
            mbpo.warm_up_step().unwrap();
        }
        mbpo.train_model().unwrap();
        mbpo.branch_rollouts(5).unwrap();
        mbpo.model_buffer_len()
    };
    assert_eq!(rows_with(1.0), 5 * 5000);
    assert_eq!(rows_with(0.5), 2500 + 1250 + 625 + 313 + 157);
    assert_eq!(
        ExperimentConfig::default().mbpo.rollout_keep_fraction,
        1.0,
        "the paper's rollouts unless asked"
    );
}

#[test]
fn clip_imagined_states_is_read_from_the_config_and_checked() {
    let set = |value: &str| {
        ExperimentConfig::resolve(None, &[format!("mbpo.clip_imagined_states={value}")])
    };
    let clip = |value: &str| set(value).unwrap().mbpo.clip_imagined_states;
    assert_eq!(clip("real_box"), ImaginedStateClip::RealBox);
    assert_eq!(clip("off"), ImaginedStateClip::Off);
    assert_eq!(
        ExperimentConfig::default().mbpo.clip_imagined_states,
        ImaginedStateClip::Off,
        "the paper's rollouts unless asked"
    );
    let err = set("box").unwrap_err().to_string();
    assert!(
        err.contains("mbpo.clip_imagined_states=box") && err.contains("real_box"),
        "{err}"
    );
}

#[test]
fn mbpo_learns_pendulum_faster_than_the_warmup_policy() {
    // A random policy scores about -1200 to -1800. Broken model-based learning (wrong model
    // targets, no rollouts, frozen policy) stays far below -700 at this budget.
    let dir = temp_dir("mbpo-learns");
    let summary = train_mbpo(&small_config(2000), &dir).unwrap();
    let curve = read_eval_curve(&dir.join("metrics.csv")).unwrap();
    assert!(
        curve[0].1 < -900.0,
        "first evaluation should be untrained: {curve:?}"
    );
    assert!(
        summary.best_eval_return > -500.0,
        "MBPO did not learn: {curve:?}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

/// `actor.env_step_ms` slows every env step (a stand-in for a robot or a real-time simulator)
/// and changes nothing else: the run ends with the same policy, and takes at least its steps'
/// time (a lower bound: a busy machine only adds to it). Out-of-range values are refused.
#[test]
fn a_slowed_environment_only_changes_the_timing() {
    let dir = temp_dir("slow-env");
    let cfg = support::small_mbpo(250);
    let plain = train_mbpo(&cfg, &dir.join("plain")).unwrap();
    let mut slow = cfg.clone();
    slow.actor.env_step_ms = 2.0;
    let started = std::time::Instant::now();
    let slowed = train_mbpo(&slow, &dir.join("slow")).unwrap();
    let min_seconds = 250.0 * 2.0 / 1e3;
    assert!(started.elapsed().as_secs_f64() >= min_seconds);
    assert_eq!(slowed.policy_sha256, plain.policy_sha256);
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        slow.actor.env_step_ms = bad;
        let err = slow.validate("test").unwrap_err().to_string();
        assert!(err.contains("actor.env_step_ms"), "{err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
