//! SAC end to end on Pendulum-v1 at a scale CI affords.

use mbpo_train::run_dir::read_eval_curve;
use mbpo_train::{train_sac, ExperimentConfig};

mod support;
use support::temp_dir;

fn small_config(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        steps,
        ..Default::default()
    };
    cfg.eval.every = 500;
    cfg.eval.episodes = 5;
    cfg.sac.hidden = vec![64, 64];
    cfg.sac.batch_size = 64;
    cfg.sac.actor_lr = 1e-3;
    cfg.sac.critic_lr = 1e-3;
    cfg.sac.alpha_lr = 1e-3;
    cfg.sac_loop.random_steps = 500;
    cfg
}

#[test]
fn sac_learns_to_swing_up_pendulum() {
    // A random policy scores about -1200 to -1800; a learned swing-up about -150 to -350.
    // Broken learning (wrong gradient sign, no bootstrapping, frozen actor) stays below -900.
    let dir = temp_dir("sac-learns");
    let summary = train_sac(&small_config(5000), &dir).unwrap();
    let curve = read_eval_curve(&dir.join("metrics.csv")).unwrap();
    assert!(
        curve[0].1 < -900.0,
        "the first evaluation should be untrained: {curve:?}"
    );
    assert!(
        summary.best_eval_return > -400.0,
        "SAC did not learn Pendulum in 5000 steps: {curve:?}"
    );
    assert_eq!(summary.sac_updates, 4501);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn same_seed_reproduces_the_run_bit_for_bit() {
    let cfg = small_config(900);
    let (a, b) = (temp_dir("sac-det-a"), temp_dir("sac-det-b"));
    let sa = train_sac(&cfg, &a).unwrap();
    let sb = train_sac(&cfg, &b).unwrap();
    assert_eq!(sa.policy_sha256, sb.policy_sha256);
    assert_eq!(
        read_eval_curve(&a.join("metrics.csv")).unwrap(),
        read_eval_curve(&b.join("metrics.csv")).unwrap()
    );
    let mut other = cfg.clone();
    other.seed = 1;
    let c = temp_dir("sac-det-c");
    assert_ne!(
        train_sac(&other, &c).unwrap().policy_sha256,
        sa.policy_sha256
    );
    for d in [a, b, c] {
        std::fs::remove_dir_all(d).unwrap();
    }
}
