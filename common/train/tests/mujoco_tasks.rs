//! MBPO on the MuJoCo tasks end to end (cargo feature `mujoco`), at a scale CI affords: the
//! loop, the termination functions in model rollouts and the shipped configs must work with
//! 1000-step episodes that terminate early.
#![cfg(feature = "mujoco")]

use mbpo_train::run_dir::read_eval_curve;
use mbpo_train::{train_mbpo, ExperimentConfig};
use std::path::Path;

mod support;
use support::temp_dir;

/// A shipped MuJoCo config shrunk to seconds: small networks, few updates and rollouts.
fn tiny(config: &str, steps: u64) -> ExperimentConfig {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../../deploy/configs")
        .join(config);
    let mut cfg = ExperimentConfig::load(&path).unwrap();
    cfg.steps = steps;
    cfg.eval.every = steps / 2;
    cfg.sac.hidden = vec![32, 32];
    cfg.sac.batch_size = 32;
    cfg.mbpo.init_random_steps = 150;
    cfg.mbpo.model_train_freq = 100;
    cfg.mbpo.rollouts_per_step = 10;
    cfg.mbpo.updates_per_step = 2;
    cfg.model.members = 3;
    cfg.model.elites = 2;
    cfg.model.hidden = vec![16, 16];
    cfg.model.weight_decay = vec![2.5e-5, 5e-5, 1e-4];
    cfg.model.batch_size = 32;
    cfg
}

#[test]
fn mbpo_runs_on_inverted_pendulum_and_hopper() {
    for config in ["invertedpendulum.toml", "hopper.toml"] {
        let cfg = tiny(config, 400);
        let dir = temp_dir(config);
        let summary = train_mbpo(&cfg, &dir).unwrap();
        assert_eq!(summary.env_steps, 400, "{config}");
        assert_eq!(
            summary.sac_updates,
            250 * 2,
            "{config}: G updates after the warm-up"
        );
        let curve = read_eval_curve(&dir.join("metrics.csv")).unwrap();
        assert_eq!(
            curve.iter().map(|c| c.0).collect::<Vec<_>>(),
            vec![200, 400]
        );
        for (_, r) in curve {
            assert!(r.is_finite(), "{config}: return {r}");
            if config == "invertedpendulum.toml" {
                // 1 per step while the pole is up, for at most 1000 steps.
                assert!(r == r.round() && (0.0..=1000.0).contains(&r), "return {r}");
            }
        }
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
