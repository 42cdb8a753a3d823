//! The pipeline as threads of one process on iceoryx2's `local::Service`
//! (`mbpo_runtime::in_process`): the same role loops and coordinator as `mbpo run`, no binaries.
//! The correctness oracle runs here too: lockstep equals the sequential reference bit for bit.

use std::time::Duration;

use mbpo_integration_tests::*;
use mbpo_runtime::in_process::{run_in_process, InProcessRun};
use mbpo_runtime::{Mode, Slack};
use mbpo_train::tdmpc::train_tdmpc;
use mbpo_train::{train_mbpo, train_mpc, Algo, ExperimentConfig, ImaginedStateClip};

fn how(dir: &std::path::Path, name: &str, mode: Mode, actors: u16) -> InProcessRun {
    InProcessRun {
        out: dir.join(name),
        ipc_root: ipc_root(&format!("ip-{}", &name[..2])),
        mode,
        actors,
        slack: Slack {
            policy_lag: 2,
            update_buffer: 40,
            model_lag: 25,
        },
        timeout: Duration::from_secs(240),
    }
}

/// The lockstep run at `run` ended as the sequential reference at `sequential` did: the same
/// final policy and the same metrics rows (timing columns aside).
fn assert_lockstep_equals(
    lockstep: &str,
    sequential: &str,
    run: &std::path::Path,
    reference: &std::path::Path,
) {
    assert_eq!(lockstep, sequential, "lockstep != sequential");
    assert_eq!(
        metrics_without_timing(run),
        metrics_without_timing(reference)
    );
}

#[test]
fn in_process_lockstep_mbpo_equals_sequential() {
    let cfg = tiny_config(500);
    let dir = scratch("in-process-mbpo");
    let seq = train_mbpo(&cfg, &dir.join("sequential")).unwrap();
    let run = how(&dir, "lockstep", Mode::Lockstep, 1);
    let s = run_in_process(&cfg, &run).unwrap();
    assert_eq!(s.summary.status, "completed");
    assert_lockstep_equals(
        &s.summary.policy_sha256,
        &seq.policy_sha256,
        &run.out,
        &dir.join("sequential"),
    );
    assert_eq!(s.summary.sac_updates, seq.sac_updates);
    assert_eq!(s.real_transitions.produced, 500);
    for consumer in ["model-trainer", "rollout-generator", "learner"] {
        assert_eq!(s.real_transitions.received[consumer], 500, "{consumer}");
    }
    assert_eq!(s.real_transitions.lost, 0);
    assert!(s.pacing.is_none(), "unpaced");
    assert_eq!(
        s.real_transitions.spilled.values().sum::<u64>(),
        0,
        "{:?}",
        s.real_transitions.spilled
    );
    assert_eq!(s.ratios.rollout_batches, 3, "train points 201, 301, 401");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn in_process_lockstep_mbpo_with_clipped_imagined_states_equals_sequential() {
    lockstep_with_an_option_equals_sequential("clip", |cfg| {
        cfg.mbpo.clip_imagined_states = ImaginedStateClip::RealBox
    });
}

#[test]
fn in_process_lockstep_mbpo_with_masked_rollouts_equals_sequential() {
    lockstep_with_an_option_equals_sequential("mask", |cfg| cfg.mbpo.rollout_keep_fraction = 0.5);
}

/// An option of the rollouts lives in the rollout role both paths share; this shows that it
/// reaches the pipeline's rollout generator and keeps lockstep equal to the reference.
fn lockstep_with_an_option_equals_sequential(name: &str, set: fn(&mut ExperimentConfig)) {
    let mut cfg = tiny_config(400);
    cfg.mbpo.rollout_schedule = [0, 1, 3, 3];
    let dir = scratch(&format!("in-process-{name}"));
    let paper = train_mbpo(&cfg, &dir.join("paper")).unwrap();
    set(&mut cfg);
    let seq = train_mbpo(&cfg, &dir.join("sequential")).unwrap();
    assert_ne!(
        seq.policy_sha256, paper.policy_sha256,
        "{name} changed no imagined transition: the test would not see it missing"
    );
    let run = how(&dir, &format!("{name}-lockstep"), Mode::Lockstep, 1);
    let s = run_in_process(&cfg, &run).unwrap();
    assert_eq!(s.summary.status, "completed");
    assert_lockstep_equals(
        &s.summary.policy_sha256,
        &seq.policy_sha256,
        &run.out,
        &dir.join("sequential"),
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn in_process_lockstep_mpc_equals_sequential() {
    let cfg = tiny_mpc_config(400);
    let dir = scratch("in-process-mpc");
    let seq = train_mpc(&cfg, &dir.join("sequential")).unwrap();
    let run = how(&dir, "lockstep", Mode::Lockstep, 1);
    let s = run_in_process(&cfg, &run).unwrap();
    assert_lockstep_equals(
        &s.summary.policy_sha256,
        &seq.policy_sha256,
        &run.out,
        &dir.join("sequential"),
    );
    assert_last_step_checkpointed(&run.out, Algo::MPC, 1, cfg.steps);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// TD-MPC2 on its roles (world-model learner, a latent-planning actor, the evaluator): lockstep
/// equals `mbpo train` (parameters and metrics rows), and a pipelined run loses nothing.
#[test]
fn in_process_tdmpc_lockstep_equals_sequential_and_pipelined_loses_nothing() {
    let cfg = tiny_tdmpc_config(350);
    let dir = scratch("in-process-tdmpc");
    let seq = train_tdmpc(&cfg, &dir.join("sequential")).unwrap();
    let run = how(&dir, "lockstep", Mode::Lockstep, 1);
    let s = run_in_process(&cfg, &run).unwrap();
    assert_lockstep_equals(
        &s.summary.policy_sha256,
        &seq.policy_sha256,
        &run.out,
        &dir.join("sequential"),
    );
    assert_eq!(
        s.summary.sac_updates,
        100 + 250,
        "the burst, then one per step"
    );
    assert_last_step_checkpointed(&run.out, Algo::TDMPC, 1, cfg.steps);
    // Two actors: their rows reach the learner interleaved, and it keeps them as episodes.
    let run = how(&dir, "pipelined", Mode::Pipelined, 2);
    let s = run_in_process(&cfg, &run).unwrap();
    assert_eq!(s.summary.status, "completed");
    assert_eq!(s.real_transitions.produced, 350);
    assert_eq!(s.real_transitions.received["learner"], 350);
    assert_eq!(s.real_transitions.lost, 0);
    assert_eq!(s.summary.sac_updates, 100 + 250, "every update paid");
    // Per env step after the seed steps, the burst of 100 left out (1 per step).
    assert_eq!(s.ratios.updates_per_env_step, 1.0);
    let while_acting = s.ratios.updates_per_env_step_while_acting.unwrap();
    assert!(while_acting <= 1.0, "{while_acting}");
    let rows = metrics_without_timing(&run.out);
    assert_eq!(
        rows.len(),
        5,
        "the header, rows 100, 200, 300 and 350: {rows:?}"
    );
    assert_last_step_checkpointed(&run.out, Algo::TDMPC, 2, cfg.steps);
    let (last, _) = mbpo_train::checkpoint::latest(&run.out).unwrap().unwrap();
    let learner: mbpo_train::run_files::WorldModelLearnerCheckpoint = mbpo_train::checkpoint::read(
        &last.join("learner"),
        mbpo_train::checkpoint::kind::WORLD_MODEL_LEARNER,
    )
    .unwrap();
    let buffer = learner
        .role
        .buffer
        .with_links(learner.episode_links)
        .unwrap();
    // 350 steps of 200-step Pendulum episodes: each actor's first, and at most one second
    // (rows joined by arrival order would break at every switch between the actors).
    assert_eq!(buffer.len(), 350);
    assert!(
        (2..=3).contains(&buffer.episodes()),
        "{}",
        buffer.episodes()
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A finished run's newest complete checkpoint is its last step's, with every role's file:
/// extending the run (`--resume RUN --steps N`) continues from its end.
fn assert_last_step_checkpointed(run: &std::path::Path, algo: Algo, actors: u16, steps: u64) {
    let (dir, manifest) = mbpo_train::checkpoint::latest(run).unwrap().unwrap();
    assert_eq!(manifest.env_steps, steps, "{}", dir.display());
    let want: Vec<String> =
        mbpo_runtime::pipeline::pipeline_files(mbpo_runtime::pipeline::spec(algo).unwrap(), actors)
            .into_iter()
            .map(|(name, _)| name)
            .collect();
    assert_eq!(manifest.files, want);
}

#[test]
fn in_process_pipelined_run_with_two_actors_loses_nothing() {
    let cfg = tiny_config(400);
    let dir = scratch("in-process-pipelined");
    let run = how(&dir, "pipelined", Mode::Pipelined, 2);
    let s = run_in_process(&cfg, &run).unwrap();
    assert_eq!(s.summary.status, "completed");
    assert_eq!(s.summary.env_steps, 400);
    assert_eq!(s.real_transitions.produced, 400);
    for consumer in ["model-trainer", "rollout-generator", "learner"] {
        assert_eq!(s.real_transitions.received[consumer], 400, "{consumer}");
    }
    assert_eq!(s.real_transitions.lost, 0);
    assert!(s.pacing.is_none(), "unpaced");
    assert_eq!(
        s.real_transitions.spilled.values().sum::<u64>(),
        0,
        "{:?}",
        s.real_transitions.spilled
    );
    assert_ratios_within_allowed(&serde_json::to_value(&s).unwrap());
    // The run was resolved once, into the plan every role read its sizes from.
    let plan = mbpo_runtime::ResolvedRun::read(&run.out).unwrap();
    assert_eq!(plan.dims, mbpo_runtime::Dims::of(&cfg).unwrap());
    assert_eq!((plan.mode, plan.actors), (Mode::Pipelined, 2));
    // Rows 200 and 400 (eval.every = 200).
    assert_eq!(metrics_without_timing(&run.out).len(), 3);
    assert_last_step_checkpointed(&run.out, Algo::MBPO, 2, 400);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `eval.stop_when_solved`: a pipelined run whose evaluations reach the target often enough in
/// a row stops at its next checkpoint cut, as `solved`, with nothing lost; the sequential
/// reference stops at the solving evaluation itself.
#[test]
fn a_solved_run_stops_with_a_checkpoint_in_the_pipeline_and_in_one_process() {
    let mut cfg = tiny_config(1000);
    // Every evaluation reaches this target: the run is solved at its second eval point.
    cfg.eval.target_return = Some(-1e9);
    cfg.eval.stop_when_solved = 2;
    cfg.checkpoint.every = 0;
    let dir = scratch("in-process-solved");
    let run = how(&dir, "solved", Mode::Pipelined, 1);
    let s = run_in_process(&cfg, &run).unwrap();
    assert_eq!(s.summary.status, "solved");
    let (_, manifest) = mbpo_train::checkpoint::latest(&run.out).unwrap().unwrap();
    assert!(
        (400..1000).contains(&manifest.env_steps),
        "solved at 400, stopped at the cut after it: {}",
        manifest.env_steps
    );
    assert_eq!(s.real_transitions.lost, 0);
    let reference = dir.join("sequential");
    let opts = mbpo_train::RunOptions::default();
    let sequential = mbpo_train::train_mbpo_with(&cfg, &reference, opts).unwrap();
    assert_eq!(
        (sequential.status.as_str(), sequential.env_steps),
        ("solved", 400)
    );
    // Extended, a solved run takes every step it is given.
    let resume = mbpo_train::RunOptions {
        resume: true,
        ..Default::default()
    };
    let extended = mbpo_train::train_mbpo_with(&cfg, &reference, resume).unwrap();
    assert_eq!(
        (extended.status.as_str(), extended.env_steps),
        ("completed", 1000)
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `actor.control_hz`: the actors of a pipelined run step on a clock (at most `hz` steps a
/// second each: a lower bound on the run's wall time, robust on a busy machine), and the run
/// still loses nothing, also with `actor.catch_up = "never"`. Lockstep refuses it, naming the
/// fix.
#[test]
fn paced_actors_step_on_the_clock_and_lose_nothing() {
    let mut cfg = tiny_config(400);
    cfg.actor.control_hz = 200.0;
    let dir = scratch("in-process-paced");
    let run = how(&dir, "paced", Mode::Pipelined, 2);
    let started = std::time::Instant::now();
    let s = run_in_process(&cfg, &run).unwrap();
    // 200 steps per actor at 200 Hz: at least 199 periods of 5 ms.
    assert!(started.elapsed().as_secs_f64() >= 199.0 * 0.005);
    assert_eq!(
        (s.summary.status.as_str(), s.summary.env_steps),
        ("completed", 400)
    );
    assert_eq!(s.real_transitions.lost, 0);
    // The summary says it was paced (its counts, which depend on timing, cross the wire as the
    // round trip of `mbpo_wire::stats` checks).
    let pacing = s.pacing.expect("a paced run's summary has its pacing");
    assert_eq!(pacing.control_hz, 200.0);
    // Every interval between two steps on one grid is in the histogram: each actor's 200
    // steps less one per grid (the first, and one after each rest).
    let grids = 2 + pacing.rests_between_episodes;
    assert_eq!(pacing.intervals, 400 - grids, "{pacing:?}");
    let binned: u64 = pacing.histogram.iter().map(|b| b.steps).sum();
    assert_eq!(binned, pacing.intervals);
    let e = pacing.interval_error_us;
    assert!(
        e.p50 <= e.p99 && e.p99 <= e.max.max(e.p99) && e.max > 0.0,
        "{e:?}"
    );
    for consumer in ["model-trainer", "rollout-generator", "learner"] {
        assert_eq!(s.real_transitions.received[consumer], 400, "{consumer}");
    }
    // Inside an episode a paced actor acts with whatever it holds: its lag has no slack bound.
    let lag = s.ratios.actor_policy_lag;
    assert_eq!(lag.highest_allowed, None, "{lag:?}");
    assert!(lag.max >= lag.mean && lag.mean >= lag.min, "{lag:?}");
    // `catch_up = "never"`: after its first policy the actor never rests; the learner does the
    // updates it owes after the actor finished, and the summary says how many it had done.
    cfg.actor.catch_up = mbpo_train::CatchUp::Never;
    let never = run_in_process(&cfg, &how(&dir, "paced-never", Mode::Pipelined, 1)).unwrap();
    assert_eq!(never.summary.status, "completed");
    assert_eq!(never.real_transitions.lost, 0);
    let p = never.pacing.expect("paced");
    assert_eq!(p.catch_up, mbpo_train::CatchUp::Never);
    assert!(p.rests_between_episodes <= 1, "{p:?}");
    let r = &never.ratios;
    let acting = r
        .updates_per_env_step_while_acting
        .expect("the actor finished");
    assert!(acting <= r.updates_per_env_step + 1e-9, "{r:?}");
    let lockstep = how(&dir, "paced-lockstep", Mode::Lockstep, 1);
    let err = run_in_process(&cfg, &lockstep).unwrap_err().to_string();
    assert!(
        err.contains("actor.control_hz") && err.contains("--mode pipelined"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
