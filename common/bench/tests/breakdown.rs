//! `mbpo bench breakdown` on a small run: a kept checkpoint is continued and every phase of
//! the steps after it is timed.

use mbpo_bench::breakdown::breakdown_at;
use mbpo_train::{checkpoint, train_mbpo};

// The train crate's test helpers (a small MBPO config, temporary directories).
#[path = "../../train/tests/support/mod.rs"]
mod support;
use support::small_mbpo;

/// `mbpo bench breakdown`'s measurement: a run keeps checkpoints at multiples of
/// `checkpoint.keep_every`, and continuing from one times every phase of the steps after it.
#[test]
fn a_kept_checkpoint_is_continued_and_every_phase_is_counted() {
    let run = std::env::temp_dir().join(format!("mbpo-breakdown-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&run);
    let mut cfg = small_mbpo(500);
    (cfg.checkpoint.keep, cfg.checkpoint.keep_every) = (1, 200);
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
    // Each training's epochs are kept, and the epoch caps replay them: a cap never gives a
    // better model (snapshots only ever improve), one above every training changes nothing.
    assert_eq!(p.training_epochs.len(), 2);
    assert_eq!(
        p.training_epochs.iter().sum::<usize>() as u64,
        ph.model_epochs
    );
    let most = *p.training_epochs.iter().max().unwrap();
    for c in &p.epoch_caps {
        assert!(c.holdout_ratio >= 1.0, "{c:?}");
        if c.cap >= most {
            assert_eq!((c.epochs_fraction, c.holdout_ratio), (1.0, 1.0), "{c:?}");
        }
    }

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
