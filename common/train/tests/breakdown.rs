//! `mbpo bench breakdown`'s measurement: a run keeps checkpoints at multiples of
//! `checkpoint.keep_every`, and continuing from one times every phase of the steps after it.

use mbpo_train::breakdown::breakdown_at;
use mbpo_train::{checkpoint, train_mbpo, Algo, ExperimentConfig};

/// MBPO on Pendulum, small: train points every 100 steps after 200 random ones.
fn small_mbpo(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        algo: Algo::MBPO,
        steps,
        ..Default::default()
    };
    cfg.eval.every = 100;
    cfg.eval.episodes = 1;
    cfg.sac.hidden = vec![32, 32];
    cfg.sac.batch_size = 32;
    cfg.mbpo.init_random_steps = 200;
    cfg.mbpo.epoch_length = 100;
    cfg.mbpo.model_train_freq = 100;
    cfg.mbpo.rollouts_per_step = 10;
    cfg.mbpo.rollout_schedule = [1, 3, 1, 3];
    cfg.mbpo.updates_per_step = 2;
    cfg.model.members = 3;
    cfg.model.elites = 2;
    cfg.model.hidden = vec![16, 16];
    cfg.model.weight_decay = vec![2.5e-5, 5e-5, 1e-4];
    cfg.model.batch_size = 32;
    cfg.model.max_epochs = Some(5);
    cfg.checkpoint.every = 100;
    cfg.checkpoint.keep = 1;
    cfg.checkpoint.keep_every = 200;
    cfg
}

#[test]
fn a_kept_checkpoint_is_continued_and_every_phase_is_counted() {
    let run = std::env::temp_dir().join(format!("mbpo-breakdown-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&run);
    let cfg = small_mbpo(500);
    train_mbpo(&cfg, &run).unwrap();
    // keep = 1 keeps 500 only; keep_every = 200 keeps 200 and 400 as well.
    let mut kept: Vec<String> = std::fs::read_dir(checkpoint::root(&run))
        .unwrap()
        .map(|e| e.unwrap().file_name().into_string().unwrap())
        .collect();
    kept.sort();
    assert_eq!(kept, ["0000000200", "0000000400", "0000000500"]);

    // From 200: two train points (201, 301) in 200 steps of 2 updates each.
    let p = breakdown_at(&cfg, &run, 200, 200).unwrap();
    let ph = p.phases;
    assert_eq!(ph.steps, 200);
    assert_eq!(ph.model_trainings, 2);
    assert!((2..=10).contains(&ph.model_epochs), "{ph:?}");
    assert_eq!(ph.sac_updates, 400);
    // Rollouts of length k = 1 at epoch 0: M · freq = 1000 per training, none terminates.
    assert_eq!((p.rollout_length, ph.imagined), (1, 2000));
    for (phase, s) in [
        ("model training", ph.model_train_seconds),
        ("holdout", ph.model_holdout_seconds),
        ("rollouts", ph.rollout_seconds),
        ("SAC", ph.sac_seconds),
        ("acting", ph.act_seconds),
    ] {
        assert!(s > 0.0, "{phase} took no time: {ph:?}");
    }
    assert!(ph.model_holdout_seconds < ph.model_train_seconds);
    assert!(ph.total_seconds() <= p.wall_seconds);

    // A step with no kept checkpoint is named with what is kept and how to keep more.
    let err = breakdown_at(&cfg, &run, 300, 100).unwrap_err().to_string();
    assert!(
        err.contains("no complete checkpoint at 300")
            && err.contains("200, 400, 500")
            && err.contains("checkpoint.keep_every"),
        "{err}"
    );
    std::fs::remove_dir_all(&run).unwrap();
}
