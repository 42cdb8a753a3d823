//! The multi-process pipeline end to end: real binaries, real shared memory.

use std::time::{Duration, Instant};

use mbpo_integration_tests::*;
use mbpo_train::policy_file::{newest_policy, FINAL_POLICY_FILE};
use mbpo_train::{policy_sha256, train_mbpo};

const TIMEOUT: Duration = Duration::from_secs(120);

fn run_id(s: &serde_json::Value) -> String {
    s["run_id"].as_str().unwrap().to_string()
}

/// THE correctness oracle: a lockstep pipeline equals the sequential reference bit for bit
/// (final policy, every metrics column but the timings). Two lockstep runs of the same run
/// config go concurrently on one iceoryx2 base directory: they must not see each other.
#[test]
fn lockstep_equals_sequential_and_concurrent_runs_do_not_interfere() {
    let mut cfg = tiny_config(500);
    // Two SAC threads: the learner's sharded update must be as deterministic across processes
    // as the single-threaded one (one thread is the same code with one shard).
    cfg.sac.threads = 2;
    // Two model-training threads in the pipeline, one in the reference: 4 members on 2
    // threads train whole members in blocks, as on one, and must give the same bits.
    cfg.model.threads = 2;
    let mut reference = cfg.clone();
    reference.model.threads = 1;
    let dir = scratch("lockstep");
    let input = write_config(&cfg, &dir);
    let root = ipc_root("lockstep");
    let (a, b) = (dir.join("run-a"), dir.join("run-b"));
    let spawn = |out: &std::path::Path| {
        spawn_run(&[
            "--config",
            input.to_str().unwrap(),
            "--mode",
            "lockstep",
            "--out",
            out.to_str().unwrap(),
            "--ipc-root",
            root.to_str().unwrap(),
        ])
    };
    bin_dir();
    let (ca, cb) = (spawn(&a), spawn(&b));
    let seq = train_mbpo(&reference, &dir.join("sequential")).unwrap();
    let seq_policy = newest_policy(&dir.join("sequential")).unwrap();
    assert_eq!(
        seq_policy.file,
        dir.join("sequential").join(FINAL_POLICY_FILE)
    );
    assert_eq!(
        policy_sha256(&seq_policy.policy.actor_params),
        seq.policy_sha256
    );
    let outputs = [wait_output(ca, TIMEOUT), wait_output(cb, TIMEOUT)];
    for (o, out) in outputs.iter().zip([&a, &b]) {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let s = summary(out);
        assert_eq!(s["status"], "completed");
        assert_eq!(
            s["policy_sha256"],
            seq.policy_sha256.as_str(),
            "lockstep != sequential"
        );
        assert_eq!(s["final_eval_return"], seq.final_eval_return);
        assert_eq!(s["sac_updates"], seq.sac_updates);
        // The policy the run ended with is kept (the last checkpoint is long before the end),
        // the same bits as the sequential run's, and it is what `mbpo eval` evaluates.
        let kept = newest_policy(out).unwrap();
        assert_eq!(kept.file, out.join(FINAL_POLICY_FILE));
        assert_eq!(kept.policy.env_steps, 500);
        assert_eq!(policy_sha256(&kept.policy.actor_params), seq.policy_sha256);
        let eval = eval_run(out, 1);
        assert_eq!(eval["policy_env_steps"], 500);
        assert!(eval["policy_file"]
            .as_str()
            .unwrap()
            .ends_with(FINAL_POLICY_FILE));
        assert_eq!(
            metrics_without_timing(out),
            metrics_without_timing(&dir.join("sequential")),
            "metrics.csv differs from the sequential run"
        );
        assert_no_loss(&s, 500);
        assert_eq!(s["ratios"]["updates_per_env_step"], 8.0);
        assert_eq!(s["ratios"]["actor_policy_lag"]["max"], 0.0);
        // Lockstep allows no slack: the learner owes between 0 and G updates.
        let owed = &s["ratios"]["learner_updates_owed"];
        assert_eq!(owed["highest_allowed"], 8.0, "{owed}");
        assert_ratios_within_allowed(&s);
        assert_eq!(s["ipc_leftovers"].as_array().unwrap().len(), 0);
        assert!(out.join("logs/learner.log").exists());
        let left = leftovers(&run_id(&s), &root);
        assert!(left.is_empty(), "shared-memory leftovers: {left:?}");
    }
    assert_ne!(run_id(&summary(&a)), run_id(&summary(&b)));
    assert_eq!(base_dir_leftovers(&root), Vec::<std::path::PathBuf>::new());
    let _ = std::fs::remove_dir_all(dir);
}

/// Pipelined with two actors: completes, loses nothing, holds the ratios within their buffers.
#[test]
fn pipelined_run_holds_its_ratios_and_loses_nothing() {
    let cfg = tiny_config(600);
    let dir = scratch("pipelined");
    let input = write_config(&cfg, &dir);
    let root = ipc_root("pipelined");
    let out = dir.join("run");
    let o = wait_output(
        spawn_run(&[
            "--config",
            input.to_str().unwrap(),
            "--mode",
            "pipelined",
            "--actors",
            "2",
            "--policy-lag",
            "3",
            "--update-buffer",
            "24",
            "--model-lag",
            "20",
            "--out",
            out.to_str().unwrap(),
            "--ipc-root",
            root.to_str().unwrap(),
        ]),
        TIMEOUT,
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&out);
    assert_eq!(s["status"], "completed");
    assert_no_loss(&s, 600);
    let r = &s["ratios"];
    eprintln!("ratios: {r}");
    // Exactly G updates per env step after the warm-up in total ...
    assert_eq!(r["updates_per_env_step"], 8.0);
    // ... and never more than the buffer ahead or behind while running.
    let owed = &r["learner_updates_owed"];
    assert_eq!(
        (&owed["lowest_allowed"], &owed["highest_allowed"]),
        (&serde_json::json!(-24.0), &serde_json::json!(8.0 + 24.0)),
        "{owed}"
    );
    assert_ratios_within_allowed(&s);
    assert!(r["actor_policy_lag"]["max"].as_f64().unwrap() <= 3.0, "{r}");
    assert_eq!(r["model_trainings"], 4);
    assert_eq!(r["rollout_batches"], 4);
    let rows = metrics_without_timing(&out);
    assert_eq!(
        rows.len(),
        1 + 3,
        "header + eval at 200, 400, 600: {rows:?}"
    );
    let left = leftovers(&run_id(&s), &root);
    assert!(left.is_empty(), "shared-memory leftovers: {left:?}");
    assert_eq!(base_dir_leftovers(&root), Vec::<std::path::PathBuf>::new());
    let _ = std::fs::remove_dir_all(dir);
}

/// SIGINT stops every process within 5 s -- after a checkpoint (status `stopped`, exit 0,
/// resumable) -- and removes the run's shared memory.
#[test]
fn sigint_stops_the_run_cleanly() {
    let cfg = tiny_config(20_000);
    let dir = scratch("sigint");
    let input = write_config(&cfg, &dir);
    let root = ipc_root("sigint");
    let out = dir.join("run");
    let child = spawn_run(&run_args(&input, &out, &root, &[]));
    // Let it get past start-up and into training.
    assert!(logged_pid(&out.join("logs/learner.log"), Duration::from_secs(30)).is_some());
    std::thread::sleep(Duration::from_millis(1500));
    // SAFETY: kill(2) on our child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let t = Instant::now();
    let o = wait_output(child, Duration::from_secs(30));
    let took = t.elapsed();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(took < Duration::from_secs(5), "stop took {took:?}");
    let s = summary(&out);
    assert_eq!(s["status"], "stopped");
    let (ckpt, manifest) = mbpo_train::checkpoint::latest(&out)
        .unwrap()
        .expect("no complete checkpoint after the stop");
    // A stopped run has no final policy; `mbpo eval` reads the learner's checkpoint file.
    assert!(!out.join(FINAL_POLICY_FILE).exists());
    let eval = eval_run(&out, 1);
    assert_eq!(eval["policy_env_steps"], manifest.env_steps);
    assert_eq!(
        eval["policy_file"].as_str().unwrap(),
        ckpt.join("learner").display().to_string()
    );
    let left = leftovers(&run_id(&s), &root);
    assert!(left.is_empty(), "shared-memory leftovers: {left:?}");
    assert_eq!(base_dir_leftovers(&root), Vec::<std::path::PathBuf>::new());
    let alive = processes_mentioning(&run_id(&s));
    assert!(alive.is_empty(), "processes still alive: {alive:?}");
    let _ = std::fs::remove_dir_all(dir);
}

/// Ctrl-C while the run starts. While the supervisor sets the run up, the signal is captured
/// from its first line on (it used to kill the process, leaving a run directory without a
/// summary). While the processes start: the control channel keeps no history, so a role that
/// subscribes after the stop's checkpoint barrier began has not got its Pause; the coordinator
/// sends the barrier again when it sees a new control subscriber (before, the barrier waited
/// for that role's report forever: a Ctrl-C 50 ms after `mbpo run` hung). Several moments of
/// start-up; each run must stop with a complete checkpoint.
#[test]
fn sigint_during_start_up_still_checkpoints_and_stops() {
    let cfg = tiny_config(20_000);
    let dir = scratch("sigint-start-up");
    let input = write_config(&cfg, &dir);
    // (what has started, milliseconds after it): the run directory (the supervisor is setting
    // the run up), then the first role process (the supervisor made its ports; roles start).
    let moments = [
        ("config.toml", 0),
        ("a role's log", 0),
        ("a role's log", 20),
        ("a role's log", 60),
        ("a role's log", 150),
    ];
    for (case, (after, delay_ms)) in moments.into_iter().enumerate() {
        let root = ipc_root(&format!("ss{case}"));
        let out = dir.join(format!("run-{case}"));
        let mut child = spawn_run(&run_args(&input, &out, &root, &[]));
        let logs = out.join("logs");
        let started = || match after {
            "config.toml" => out.join("config.toml").exists(),
            _ => std::fs::read_dir(&logs).map_or(0, |d| d.count()) >= 2,
        };
        let t = Instant::now();
        while !started() {
            if child.try_wait().unwrap().is_some() {
                let o = child.wait_with_output().unwrap();
                panic!("{after}: mbpo run ended at start-up: {o:?}");
            }
            assert!(
                t.elapsed() < TIMEOUT,
                "{after}: not there within {TIMEOUT:?}"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
        std::thread::sleep(Duration::from_millis(delay_ms));
        // SAFETY: kill(2) on our child.
        unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
        let o = wait_output(child, TIMEOUT);
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{delay_ms} ms after {after}: {stderr}");
        let s = summary(&out);
        assert_eq!(
            s["status"], "stopped",
            "{delay_ms} ms after {after}: {stderr}"
        );
        assert!(
            mbpo_train::checkpoint::latest(&out).unwrap().is_some(),
            "{delay_ms} ms after {after}: no complete checkpoint after the stop: {stderr}"
        );
        let left = leftovers(&run_id(&s), &root);
        assert!(
            left.is_empty(),
            "{delay_ms} ms after {after}: shared-memory leftovers: {left:?}"
        );
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// Two SIGTERMs 5 ms apart (as GNU `timeout` sends them, to the process and to its group) are
/// one stop request: the run stops within 5 s with a checkpoint (`stopped`), leaves no process
/// or shared memory, and that checkpoint resumes. (A second request stops at once, without a
/// checkpoint: that decision is tested in `coordinator::signal`.)
#[test]
fn two_sigterms_at_once_are_one_stop_with_a_checkpoint_that_resumes() {
    let mut cfg = tiny_config(20_000);
    cfg.checkpoint.every = 100;
    let dir = scratch("sigterm-twice");
    let input = write_config(&cfg, &dir);
    let root = ipc_root("sigterm2");
    let out = dir.join("run");
    let mut child = spawn_run(&run_args(&input, &out, &root, &[]));
    let t = Instant::now();
    while mbpo_train::checkpoint::latest(&out).unwrap().is_none() {
        assert!(child.try_wait().unwrap().is_none(), "the run ended first");
        assert!(
            t.elapsed() < Duration::from_secs(60),
            "no checkpoint within 60 s"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    for _ in 0..2 {
        // SAFETY: kill(2) on our child.
        unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
        std::thread::sleep(Duration::from_millis(5));
    }
    let t = Instant::now();
    let o = wait_output(child, Duration::from_secs(30));
    let took = t.elapsed();
    assert!(took < Duration::from_secs(5), "stop took {took:?}");
    let s = summary(&out);
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert_eq!(s["status"], "stopped", "{stderr}");
    assert!(o.status.success(), "{stderr}");
    assert!(processes_mentioning(&run_id(&s)).is_empty());
    assert!(leftovers(&run_id(&s), &root).is_empty());
    let point = mbpo_runtime::coordinator::checkpoints::latest_verified(&out, cfg.algo).unwrap();
    let steps = (point.env_steps + 50).to_string();
    let o = wait_output(
        spawn_run(&[
            "--resume",
            out.to_str().unwrap(),
            "--steps",
            &steps,
            "--ipc-root",
            root.to_str().unwrap(),
        ]),
        Duration::from_secs(120),
    );
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(summary(&out)["status"], "completed");
    let _ = std::fs::remove_dir_all(dir);
}

/// A crashed service fails the run with a message naming it; nothing is left behind.
#[test]
fn a_crash_fails_the_run_with_a_clear_message() {
    let cfg = tiny_config(20_000);
    let dir = scratch("crash");
    let input = write_config(&cfg, &dir);
    let root = ipc_root("crash");
    let out = dir.join("run");
    let child = spawn_run(&run_args(&input, &out, &root, &[]));
    let pid = logged_pid(&out.join("logs/model-trainer.log"), Duration::from_secs(30)).unwrap();
    std::thread::sleep(Duration::from_millis(800));
    // SAFETY: kill(2) on a grandchild we just read the pid of (still alive: the run is long).
    unsafe { libc::kill(pid, libc::SIGKILL) };
    let o = wait_output(child, Duration::from_secs(30));
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("model-trainer exited with signal: 9"), "{err}");
    assert!(err.contains("the run failed"), "{err}");
    let s = summary(&out);
    assert_eq!(s["status"], "failed");
    let left = leftovers(&run_id(&s), &root);
    assert!(left.is_empty(), "shared-memory leftovers: {left:?}");
    assert_eq!(base_dir_leftovers(&root), Vec::<std::path::PathBuf>::new());
    assert!(processes_mentioning(&run_id(&s)).is_empty());
    let _ = std::fs::remove_dir_all(dir);
}
