//! Checkpoints and resume of the single-process trainers: a run that is stopped (or crashes)
//! and is resumed ends with the very weights and metrics of an uninterrupted run.

use mbpo_train::checkpoint;
use mbpo_train::{
    train_mbpo, train_mbpo_with, train_sac, train_sac_with, ExperimentConfig, RunOptions,
};
use std::path::Path;
use std::sync::atomic::AtomicBool;

mod support;
use support::{small_mbpo, temp_dir};

fn small_sac(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        steps,
        ..Default::default()
    };
    cfg.eval.every = 50;
    cfg.eval.episodes = 1;
    cfg.sac.hidden = vec![32, 32];
    cfg.sac.batch_size = 32;
    cfg.sac_loop.random_steps = 100;
    cfg.checkpoint.every = 100;
    cfg.checkpoint.keep = 10;
    cfg
}

/// metrics.csv without the two timing columns (wall_seconds, env_steps_per_sec).
fn metrics_without_timings(run: &Path) -> Vec<String> {
    std::fs::read_to_string(run.join("metrics.csv"))
        .unwrap()
        .lines()
        .map(|l| {
            let cells: Vec<&str> = l.split(',').collect();
            cells[..13].join(",")
        })
        .collect()
}

/// A crash right after the checkpoint of `at`: later checkpoints and the summary are gone,
/// metrics rows after `at` were already written (resume must drop them).
fn simulate_crash_after(run: &Path, at: u64) {
    for entry in std::fs::read_dir(checkpoint::root(run)).unwrap() {
        let dir = entry.unwrap().path();
        let steps: u64 = dir.file_name().unwrap().to_str().unwrap().parse().unwrap();
        if steps > at {
            std::fs::remove_dir_all(dir).unwrap();
        }
    }
    std::fs::remove_file(run.join("summary.json")).unwrap();
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_dir(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

#[test]
fn mbpo_resumed_after_a_crash_equals_the_uninterrupted_run() {
    let cfg = small_mbpo(450);
    let full = temp_dir("mbpo-full");
    let reference = train_mbpo(&cfg, &full).unwrap();
    // 300: the next step is a train point; 200: the last warm-up step; 100: mid warm-up.
    for at in [300, 200, 100] {
        let crashed = temp_dir(&format!("mbpo-crash-{at}"));
        copy_dir(&full, &crashed);
        simulate_crash_after(&crashed, at);
        let opts = RunOptions {
            resume: true,
            ..Default::default()
        };
        let resumed = train_mbpo_with(&cfg, &crashed, opts).unwrap();
        assert_eq!(
            resumed.policy_sha256, reference.policy_sha256,
            "crash at {at}"
        );
        assert_eq!(resumed.sac_updates, reference.sac_updates);
        assert_eq!(resumed.env_steps, 450);
        assert_eq!(
            metrics_without_timings(&crashed),
            metrics_without_timings(&full),
            "crash at {at}"
        );
        std::fs::remove_dir_all(crashed).unwrap();
    }
    stopped_during_the_model_training_of_301(&cfg, &full, &reference.policy_sha256);
    std::fs::remove_dir_all(full).unwrap();
}

/// Ctrl-C while the model training of step 301 is under way (a training can take minutes)
/// stops after the epoch under way: the training is undone and the state after step 300 is
/// checkpointed -- the roles' files byte for byte the uninterrupted run's checkpoint 300 -- and
/// a resume does the training again and ends with the uninterrupted run.
fn stopped_during_the_model_training_of_301(cfg: &ExperimentConfig, full: &Path, sha: &str) {
    let run = temp_dir("mbpo-stop-in-training");
    copy_dir(full, &run);
    simulate_crash_after(&run, 300);
    let stop = AtomicBool::new(true);
    let opts = RunOptions {
        resume: true,
        stop: Some(&stop),
    };
    let stopped = train_mbpo_with(cfg, &run, opts).unwrap();
    assert_eq!(
        (stopped.status.as_str(), stopped.env_steps),
        ("stopped", 300)
    );
    // Every role's file (not the run's book: it holds the wall clock).
    let roles = mbpo_train::mbpo_trainer::role_files();
    assert_same_checkpoint(full, &run, 300, &roles);
    let done = train_mbpo_with(
        cfg,
        &run,
        RunOptions {
            resume: true,
            stop: None,
        },
    )
    .unwrap();
    assert_eq!(done.status, "completed");
    assert_eq!(done.policy_sha256, sha);
    assert_eq!(metrics_without_timings(&run), metrics_without_timings(full));
    std::fs::remove_dir_all(run).unwrap();
}

/// The newest checkpoint of `b` is the one of step `at`, and each of `files` in it equals `a`'s.
fn assert_same_checkpoint(a: &Path, b: &Path, at: u64, files: &[String]) {
    let (_, newest) = checkpoint::latest(b).unwrap().unwrap();
    assert_eq!(newest.env_steps, at);
    for f in files {
        let read = |run: &Path| std::fs::read(checkpoint::dir_for(run, at).join(f)).unwrap();
        assert!(read(a) == read(b), "{f} of checkpoint {at} differs");
    }
}

/// A MuJoCo episode lasts up to 1000 steps, so this checkpoint falls mid-episode: the resumed
/// run must still be the uninterrupted one, which takes the environment's resume state (MuJoCo's
/// solver warm start) in the actor's checkpoint. HalfCheetah: contacts, never terminates.
#[cfg(feature = "mujoco")]
#[test]
fn mbpo_on_halfcheetah_resumed_mid_episode_equals_the_uninterrupted_run() {
    let mut cfg = small_mbpo(450);
    cfg.env = "HalfCheetah-v5".into();
    let full = temp_dir("mbpo-cheetah-full");
    let reference = train_mbpo(&cfg, &full).unwrap();
    let crashed = temp_dir("mbpo-cheetah-crash");
    copy_dir(&full, &crashed);
    simulate_crash_after(&crashed, 300);
    let opts = RunOptions {
        resume: true,
        ..Default::default()
    };
    let resumed = train_mbpo_with(&cfg, &crashed, opts).unwrap();
    assert_eq!(resumed.policy_sha256, reference.policy_sha256);
    assert_eq!(
        metrics_without_timings(&crashed),
        metrics_without_timings(&full)
    );
    // The f32 data the learner sees can hide a drift in the last bits of the simulation for a
    // while; the actor's final checkpoint holds the f64 physical state itself.
    let actor_at_end = |run: &Path| {
        std::fs::read(checkpoint::dir_for(run, 450).join(mbpo_train::run_files::actor_file(0)))
            .unwrap()
    };
    assert!(
        actor_at_end(&crashed) == actor_at_end(&full),
        "the resumed episode's physical state differs from the uninterrupted one"
    );
    std::fs::remove_dir_all(crashed).unwrap();
    std::fs::remove_dir_all(full).unwrap();
}

#[test]
fn mbpo_stopped_cleanly_then_resumed_equals_the_uninterrupted_run() {
    let cfg = small_mbpo(330);
    let full = temp_dir("mbpo-stop-full");
    let reference = train_mbpo(&cfg, &full).unwrap();
    let run = temp_dir("mbpo-stop");
    let stop = AtomicBool::new(true); // stop after the first step ...
    let first = train_mbpo_with(
        &cfg,
        &run,
        RunOptions {
            stop: Some(&stop),
            ..Default::default()
        },
    )
    .unwrap();
    assert_eq!((first.status.as_str(), first.env_steps), ("stopped", 1));
    // ... resume and stop again right away: a stop checkpoints off the periodic schedule ...
    let again = train_mbpo_with(
        &cfg,
        &run,
        RunOptions {
            resume: true,
            stop: Some(&stop),
        },
    )
    .unwrap();
    assert_eq!((again.status.as_str(), again.env_steps), ("stopped", 2));
    // ... then run to the end.
    let last = train_mbpo_with(
        &cfg,
        &run,
        RunOptions {
            resume: true,
            stop: None,
        },
    )
    .unwrap();
    assert_eq!(last.status, "completed");
    assert_eq!(last.policy_sha256, reference.policy_sha256);
    assert_eq!(
        metrics_without_timings(&run),
        metrics_without_timings(&full)
    );
    for dir in [full, run] {
        std::fs::remove_dir_all(dir).unwrap();
    }
}

#[test]
fn sac_resumed_after_a_crash_equals_the_uninterrupted_run() {
    let cfg = small_sac(350);
    let full = temp_dir("sac-full");
    let reference = train_sac(&cfg, &full).unwrap();
    let crashed = temp_dir("sac-crash");
    copy_dir(&full, &crashed);
    simulate_crash_after(&crashed, 200);
    let opts = RunOptions {
        resume: true,
        ..Default::default()
    };
    let resumed = train_sac_with(&cfg, &crashed, opts).unwrap();
    assert_eq!(resumed.policy_sha256, reference.policy_sha256);
    assert_eq!(
        metrics_without_timings(&crashed),
        metrics_without_timings(&full)
    );
    for dir in [full, crashed] {
        std::fs::remove_dir_all(dir).unwrap();
    }
}

#[test]
fn damaged_or_missing_checkpoints_are_clear_errors_not_fresh_starts() {
    let cfg = small_mbpo(210);
    let run = temp_dir("mbpo-damaged");
    let opts = RunOptions {
        resume: true,
        ..Default::default()
    };
    let err = train_mbpo_with(&cfg, &run, opts).unwrap_err().to_string();
    assert!(err.contains("no complete checkpoint"), "{err}");

    train_mbpo(&cfg, &run).unwrap();
    let (latest, manifest) = checkpoint::latest(&run).unwrap().unwrap();
    assert_eq!(manifest.env_steps, 210);
    let learner = latest.join("learner");
    let bytes = std::fs::read(&learner).unwrap();
    std::fs::write(&learner, &bytes[..bytes.len() / 2]).unwrap();
    let err = train_mbpo_with(&cfg, &run, opts).unwrap_err().to_string();
    assert!(err.contains("learner: truncated"), "{err}");
    let mut flipped = bytes.clone();
    let mid = flipped.len() / 2;
    flipped[mid] ^= 0x40;
    std::fs::write(&learner, &flipped).unwrap();
    let err = train_mbpo_with(&cfg, &run, opts).unwrap_err().to_string();
    assert!(err.contains("corrupted"), "{err}");
    // The damaged run's files are untouched by the failed resumes.
    assert!(run.join("summary.json").is_file());
    std::fs::remove_dir_all(run).unwrap();
}

/// Steps `cfg` to its end in one process; at every `every` steps after the warm-up, writes the
/// checkpoint, restores a fresh trainer from it and checks that its D_model is the running
/// one's, slot for slot, and that it came from the stored branches when `expect_branches(t)`.
/// Returns the rows of each stored branch.
fn d_model_round_trips(
    cfg: &ExperimentConfig,
    name: &str,
    every: u64,
    expect_branches: impl Fn(u64) -> bool,
) -> Vec<usize> {
    use mbpo_train::checkpoint_writer::CheckpointFiles;
    use mbpo_train::eval::Evaluator;
    use mbpo_train::run_files::{file, kind, LearnerCheckpoint};
    use mbpo_train::Mbpo;
    let run = temp_dir(name);
    let mut mbpo = Mbpo::new(cfg).unwrap();
    let evaluator = Evaluator::new(cfg).unwrap();
    let mut branch_rows = vec![];
    for t in 1..=cfg.steps {
        assert!(mbpo.step_unless(t, |_| false).unwrap());
        if t <= cfg.mbpo.init_random_steps || t % every != 0 {
            continue;
        }
        let dir = checkpoint::dir_for(&run, t);
        let files: CheckpointFiles = mbpo
            .encode_checkpoint(&dir, t, &evaluator, &mbpo.book)
            .unwrap();
        files.write().unwrap();
        let learner: LearnerCheckpoint =
            checkpoint::read(&dir.join(file::LEARNER), kind::LEARNER).unwrap();
        assert_eq!(
            learner.d_model_branches.is_some(),
            expect_branches(t),
            "step {t}"
        );
        if expect_branches(t) {
            assert_eq!(
                learner.role.d_model.slots.len, 0,
                "step {t}: rows stored as well"
            );
        }
        let branches = learner.d_model_branches.iter().flat_map(|d| &d.branches);
        branch_rows.extend(branches.map(|b| b.rows));
        let mut restored = Mbpo::new(cfg).unwrap();
        restored.restore_checkpoint(&dir, t).unwrap();
        let d_model = |m: &mut Mbpo| m.learner_mut().sac_and_buffers().2.clone();
        let (now, back) = (d_model(&mut mbpo), d_model(&mut restored));
        assert!(!now.is_empty());
        assert!(
            back == now,
            "step {t}: D_model restored differs from the run's ({} / {} rows)",
            back.len(),
            now.len()
        );
        // The restore left the rollout generator as the checkpoint had it.
        let rollout = |m: &mut Mbpo| m.rollout_mut().checkpoint();
        assert_eq!(rollout(&mut restored), rollout(&mut mbpo), "step {t}");
    }
    std::fs::remove_dir_all(run).unwrap();
    branch_rows
}

/// Pendulum with two retained epochs of four branches each and k growing from 1 to 3, so
/// D_model is resized and wraps: the checkpoint stores the branches, not the rows, and the
/// restore puts every row back in its slot.
#[test]
fn d_model_stored_as_its_branches_is_restored_slot_for_slot() {
    let mut cfg = small_mbpo(450);
    cfg.mbpo.retain_epochs = 2;
    cfg.mbpo.model_train_freq = 50;
    d_model_round_trips(&cfg, "d-model-branches", 50, |_| true);
}

/// Masked rollouts (`mbpo.rollout_keep_fraction`) add fewer rows per branch than the paper's,
/// and the branches stored for them give the same rows back.
#[test]
fn d_model_of_masked_rollouts_is_restored_slot_for_slot() {
    let mut cfg = small_mbpo(450);
    cfg.mbpo.retain_epochs = 2;
    cfg.mbpo.model_train_freq = 50;
    cfg.mbpo.rollout_keep_fraction = 0.5;
    let rows = d_model_round_trips(&cfg, "d-model-masked", 50, |_| true);
    let rollouts = cfg.mbpo.rollouts_per_step * cfg.mbpo.model_train_freq as usize;
    assert!(
        !rows.is_empty() && rows.iter().all(|&r| r < rollouts),
        "each branch keeps about half of its first step: {rows:?} of {rollouts} rollouts"
    );
}

/// Once D_env wraps (after 300 steps), a branch's start states are gone from it: the rows
/// are stored.
#[test]
fn d_model_is_stored_as_rows_once_the_real_data_wrapped() {
    let mut cfg = small_mbpo(350);
    cfg.mbpo.replay_capacity = 300;
    cfg.mbpo.model_train_freq = 50;
    d_model_round_trips(&cfg, "d-model-rows", 50, |t| t <= 300);
}

/// Hopper's rollouts end early (its termination rule), so branches add different numbers of
/// rows and the buffer's oldest branch is cut mid-way.
#[cfg(feature = "mujoco")]
#[test]
fn hopper_d_model_with_early_ends_is_restored_slot_for_slot() {
    let mut cfg = small_mbpo(450);
    cfg.env = "Hopper-v5".into();
    cfg.mbpo.retain_epochs = 2;
    cfg.mbpo.model_train_freq = 50;
    let rows = d_model_round_trips(&cfg, "d-model-hopper", 50, |_| true);
    let rollouts = cfg.mbpo.rollouts_per_step * cfg.mbpo.model_train_freq as usize;
    assert!(
        rows.iter().any(|r| r % rollouts != 0),
        "no rollout ended early: {rows:?}"
    );
}

/// A build that rounds differently computes other rows from a branch's inputs: the restore
/// says how many branches differ and goes on with the recomputed rows.
#[test]
fn a_branch_done_again_with_other_rows_is_counted() {
    use mbpo_train::run_files::{file, kind, LearnerCheckpoint};
    use mbpo_train::Mbpo;
    let mut cfg = small_mbpo(300);
    cfg.mbpo.retain_epochs = 2;
    cfg.mbpo.model_train_freq = 50;
    let run = temp_dir("d-model-differing");
    train_mbpo(&cfg, &run).unwrap();
    let dir = checkpoint::dir_for(&run, 300);
    let learner: LearnerCheckpoint =
        checkpoint::read(&dir.join(file::LEARNER), kind::LEARNER).unwrap();
    let mut branches = learner.d_model_branches.expect("stored as branches");
    assert!(branches.branches.len() >= 2);
    branches.branches[1].digest ^= 1;
    let mut mbpo = Mbpo::new(&cfg).unwrap();
    mbpo.restore_checkpoint(&dir, 300).unwrap();
    let d_model = mbpo.learner_mut().sac_and_buffers().2.clone();
    let d_env = mbpo.learner_mut().sac_and_buffers().1.clone();
    let rollout = mbpo.rollout_mut();
    let dims = (d_env.obs_dim(), d_env.act_dim());
    let replayed = branches
        .replay(dims, &learner.role.d_model, |inputs| {
            rollout.replay(inputs, &d_env)
        })
        .unwrap();
    assert_eq!(replayed.differing, 1);
    assert!(replayed.buffer == d_model);
    std::fs::remove_dir_all(run).unwrap();
}
