//! The `mbpo` command's experiment workflow end to end: config overrides and `config show`,
//! a clean stop by SIGINT, `train --resume`, `eval`.

use mbpo_integration_tests::{bin_dir, scratch};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn mbpo() -> Command {
    Command::new(bin_dir().join("mbpo"))
}

fn config_file() -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../deploy/configs/pendulum-tiny.toml")
}

#[test]
fn config_show_applies_overrides_and_rejects_bad_ones_by_name() {
    let out = mbpo()
        .args(["config", "show", "--config"])
        .arg(config_file())
        .args(["--set", "sac.gamma=0.9", "--set", "mbpo.updates_per_step=3"])
        .output()
        .unwrap();
    assert!(out.status.success());
    let shown: toml::Table = toml::from_str(&String::from_utf8(out.stdout).unwrap()).unwrap();
    assert_eq!(shown["sac"]["gamma"].as_float(), Some(0.9));
    assert_eq!(shown["mbpo"]["updates_per_step"].as_integer(), Some(3));
    assert_eq!(shown["steps"].as_integer(), Some(500), "from the file");

    let out = mbpo()
        .args(["config", "show", "--set", "mbpo.updates_per_stp=3"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains("--set mbpo.updates_per_stp=3") && err.contains("updates_per_step"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
}

/// A reader that closes the pipe early (`mbpo bench gemm | head -1`) ends the command quietly:
/// success and no panic trace (`println!` would panic on the broken pipe).
#[test]
fn output_into_a_closed_pipe_ends_quietly() {
    let mut child = mbpo()
        .args(["bench", "gemm", "--seconds", "0.05"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Gone before the first line: each line is printed after 0.05 s of measurement.
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(out.status.success(), "{:?}: {err}", out.status);
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn sigint_stops_with_a_checkpoint_and_resume_finishes_the_run() {
    let dir = scratch("cli-resume");
    let run = dir.join("run");
    // Slow enough to be interrupted mid-run: G = 8 updates per step on 64x64 networks.
    let mut child = mbpo()
        .args(["train", "--config"])
        .arg(config_file())
        .args(["--steps", "3000", "--set", "checkpoint.every=250", "--out"])
        .arg(&run)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Interrupt once the first checkpoint exists (the run is then well past its warm-up).
    let deadline = Instant::now() + Duration::from_secs(300);
    while !run.join("checkpoints/0000000250/COMPLETE").is_file() {
        assert!(Instant::now() < deadline, "no checkpoint after 300 s");
        assert!(child.try_wait().unwrap().is_none(), "run ended early");
        std::thread::sleep(Duration::from_millis(50));
    }
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success(), "a clean stop exits 0");
    let stopped: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(stopped["status"], "stopped");
    let at = stopped["env_steps"].as_u64().unwrap();
    assert!((250..3000).contains(&at), "stopped at {at}");

    // Resume with a shorter total: the run ends at the new total.
    let end = at + 40;
    let out = mbpo()
        .args(["train", "--resume"])
        .arg(&run)
        .args(["--steps", &end.to_string()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let done: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(done["status"], "completed");
    assert_eq!(done["env_steps"].as_u64(), Some(end));
    let metrics = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    let steps: Vec<u64> = metrics
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect();
    let mut unique = steps.clone();
    unique.dedup();
    assert_eq!(steps, unique, "no metrics row written twice");
    assert_eq!(steps.last(), Some(&end));

    // Resuming with fewer steps than the checkpoint holds is refused, and the run is untouched.
    let out = mbpo()
        .args(["train", "--resume"])
        .arg(&run)
        .args(["--steps", &(end - 10).to_string()])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains(&format!(
            "the checkpoint is after step {end}, past the run's {} steps; give --steps N with N >= {end}",
            end - 10
        )),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(run.join("metrics.csv")).unwrap(),
        metrics
    );

    let out = mbpo()
        .arg("eval")
        .arg(&run)
        .args(["--episodes", "3"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let eval: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(eval["policy_env_steps"].as_u64(), Some(end));
    assert_eq!(
        eval["policy_file"].as_str().unwrap(),
        run.join("policy.ckpt").display().to_string()
    );
    assert_eq!(eval["returns"].as_array().unwrap().len(), 3);
    let mean = eval["mean_return"].as_f64().unwrap();
    assert!(
        (-2000.0..=0.0).contains(&mean),
        "Pendulum returns are in [-2000, 0]: {mean}"
    );

    // A resume of a directory without checkpoints is an error, not a fresh start.
    let empty = dir.join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    std::fs::copy(run.join("config.toml"), empty.join("config.toml")).unwrap();
    let out = mbpo()
        .args(["train", "--resume"])
        .arg(&empty)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("no complete checkpoint"), "{err}");
    assert!(!empty.join("metrics.csv").exists());
    // ... and so is evaluating it, with what would have held a policy.
    let out = mbpo().arg("eval").arg(&empty).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("has no policy yet"), "{err}");

    // A damaged run: the error names the missing file and says why once.
    std::fs::remove_file(run.join("policy.ckpt")).unwrap();
    let (newest, _) = mbpo_train::checkpoint::latest(&run).unwrap().unwrap();
    std::fs::remove_file(newest.join("learner")).unwrap();
    let out = mbpo().arg("eval").arg(&run).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains(&newest.join("learner").display().to_string()),
        "{err}"
    );
    assert_eq!(err.matches("No such file or directory").count(), 1, "{err}");
    std::fs::remove_dir_all(dir).unwrap();
}

/// `mbpo train --steps <steps>` with the tiny config, run in `cwd`, plus `extra` arguments.
fn tiny_train(cwd: &std::path::Path, steps: u64, extra: &[&str]) -> std::process::Output {
    mbpo()
        .current_dir(cwd)
        .args(["train", "--config"])
        .arg(config_file())
        .args(["--steps", &steps.to_string()])
        .args(extra)
        .output()
        .unwrap()
}

#[test]
fn a_fresh_run_never_writes_over_an_earlier_one() {
    let dir = scratch("cli-fresh-dirs");
    std::fs::create_dir_all(&dir).unwrap();
    // The same command twice: the second run takes the next free default directory.
    let first = tiny_train(&dir, 300, &[]);
    let second = tiny_train(&dir, 300, &[]);
    assert!(first.status.success() && second.status.success());
    let runs = dir.join("runs");
    let (a, b) = (
        runs.join("mbpo-Pendulum-v1-s0"),
        runs.join("mbpo-Pendulum-v1-s0-2"),
    );
    let hash = |run: &std::path::Path| summary_of(run)["policy_sha256"].clone();
    assert_eq!(hash(&a), hash(&b), "same seed, same run");
    assert!(String::from_utf8_lossy(&second.stderr).contains("holds an earlier run: writing"));

    // An explicit --out holding a run is refused, naming the ways on, and left as it was.
    let metrics = std::fs::read_to_string(a.join("metrics.csv")).unwrap();
    for cmd in ["train", "run"] {
        let out = mbpo()
            .current_dir(&dir)
            .args([cmd, "--config"])
            .arg(config_file())
            .args(["--out", "runs/mbpo-Pendulum-v1-s0"])
            .output()
            .unwrap();
        assert!(!out.status.success(), "{cmd}");
        let err = String::from_utf8(out.stderr).unwrap();
        assert!(
            err.contains("runs/mbpo-Pendulum-v1-s0 holds an earlier run (newest checkpoint after 300 env steps)")
                && err.contains("--resume runs/mbpo-Pendulum-v1-s0")
                && err.contains("--overwrite"),
            "{cmd}: {err}"
        );
    }
    assert_eq!(
        std::fs::read_to_string(a.join("metrics.csv")).unwrap(),
        metrics
    );

    // --overwrite replaces it: none of the earlier run's checkpoints survive (a file of the
    // user's in the directory does).
    std::fs::write(a.join("notes.txt"), "mine").unwrap();
    let out = tiny_train(
        &dir,
        250,
        &["--out", "runs/mbpo-Pendulum-v1-s0", "--overwrite"],
    );
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert_eq!(summary_of(&a)["env_steps"].as_u64(), Some(250));
    let (newest, manifest) = mbpo_train::checkpoint::latest(&a).unwrap().unwrap();
    assert_eq!(manifest.env_steps, 250, "{}", newest.display());
    assert!(!mbpo_train::checkpoint::dir_for(&a, 300).exists());
    assert_eq!(
        std::fs::read_to_string(a.join("notes.txt")).unwrap(),
        "mine"
    );

    // A directory that is not a run but holds a config.toml a run would replace is refused.
    std::fs::create_dir_all(dir.join("project")).unwrap();
    std::fs::write(dir.join("project/config.toml"), "[tool]\n").unwrap();
    let out = tiny_train(&dir, 250, &["--out", "project"]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains("holds config.toml that a run would replace"),
        "{err}"
    );
    assert_eq!(
        std::fs::read_to_string(dir.join("project/config.toml")).unwrap(),
        "[tool]\n"
    );

    // --out naming a file is refused before anything runs.
    let out = tiny_train(&dir, 250, &["--out", "runs/mbpo-Pendulum-v1-s0/notes.txt"]);
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("notes.txt is a file"), "{err}");
    std::fs::remove_dir_all(dir).unwrap();
}

/// `mbpo bench learning` output of one seed: (final return, policy hash of its run).
fn bench_learning(out: &std::path::Path, steps: &str, extra: &[&str]) -> std::process::Output {
    mbpo()
        .args(["bench", "learning", "--config"])
        .arg(config_file())
        .args(["--seeds", "1", "--threads", "1", "--steps", steps])
        .args(["--set", "checkpoint.every=100", "--out"])
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

/// Ctrl-C during `mbpo bench learning` stops the seed under way with a checkpoint and begins
/// no queued seed; the same command then continues.
#[test]
fn learning_bench_stopped_begins_no_queued_seed() {
    let dir = scratch("cli-bench-stop");
    // One seed at a time: seed 1 first (the queue's end), seed 0 queued behind it.
    let mut child = mbpo()
        .args(["bench", "learning", "--config"])
        .arg(config_file())
        .args(["--seeds", "2", "--threads", "1", "--steps", "3000"])
        .args(["--set", "checkpoint.every=250", "--out"])
        .arg(&dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let first = dir.join("runs/mbpo-Pendulum-v1-s1/checkpoints/0000000250/COMPLETE");
    let deadline = Instant::now() + Duration::from_secs(300);
    while !first.is_file() {
        assert!(Instant::now() < deadline, "no checkpoint after 300 s");
        assert!(
            child.try_wait().unwrap().is_none(),
            "the benchmark ended early"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    // SAFETY: kill(2) on our child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "a stopped benchmark has no results: {err}"
    );
    assert!(err.contains("rerun the same command to continue"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let stopped = summary_of(&dir.join("runs/mbpo-Pendulum-v1-s1"));
    assert_eq!(stopped["status"], "stopped", "{stopped}");
    assert!(
        !dir.join("runs/mbpo-Pendulum-v1-s0").exists(),
        "the queued seed 0 was begun after the stop: {err}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

fn summary_of(run: &std::path::Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(run.join("summary.json")).unwrap()).unwrap()
}

#[test]
fn learning_bench_continues_and_reuses_its_runs() {
    let dir = scratch("cli-bench-resume");
    let (split, whole) = (dir.join("split"), dir.join("whole"));
    let run = |out: &std::path::Path| out.join("runs/mbpo-Pendulum-v1-s0");

    // 300 steps, then the same command for 500: the second continues the first run, here with
    // another model thread count (a machine setting; 4 members on 1 or 2 threads train whole
    // members, the same bits) and
    // another target return (neither does that: the first run counts every evaluation as at
    // its target of -1e9, the continued one must recount for -200).
    let low_target = ["--set", "eval.target_return=-1e9"];
    let first = bench_learning(&split, "300", &low_target);
    assert!(first.status.success(), "{first:?}");
    let second = bench_learning(&split, "500", &["--set", "model.threads=2"]);
    assert!(second.status.success(), "{second:?}");
    let log = String::from_utf8_lossy(&second.stderr);
    assert!(
        log.contains("continuing from its newest checkpoint"),
        "{log}"
    );
    // Each seed logs into its run's directory, across the two invocations.
    let seed_log = std::fs::read_to_string(run(&split).join("logs/train.log")).unwrap();
    for line in [
        "seed 0: step 200 eval",
        "continuing from its newest checkpoint",
        "seed 0: step 500 eval",
    ] {
        assert!(
            seed_log.contains(line),
            "{line:?} not in the seed's log:\n{seed_log}"
        );
    }
    let metrics = std::fs::read_to_string(run(&split).join("metrics.csv")).unwrap();
    let steps: Vec<&str> = metrics
        .lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap())
        .collect();
    let mut unique = steps.clone();
    unique.dedup();
    assert_eq!(steps, unique, "a metrics row written twice");
    // The run's summary and the benchmark agree on the (recounted) steps to -200.
    let report: serde_json::Value = serde_json::from_slice(&second.stdout).unwrap();
    let summary = summary_of(&run(&split));
    assert_eq!(report["target_return"], -200.0, "{report}");
    assert_eq!(summary["target_return"], -200.0, "{summary}");
    assert_eq!(
        report["env_steps_to_target"][0], summary["env_steps_to_target"],
        "the benchmark and the resumed run disagree on when -200 was reached: {report} {summary}"
    );

    // ... and ends where one uninterrupted 500-step benchmark run ends (its target every
    // evaluation reaches: the first, pendulum-tiny.toml evaluates every 200 steps).
    let uninterrupted = bench_learning(&whole, "500", &low_target);
    assert!(uninterrupted.status.success(), "{uninterrupted:?}");
    assert_eq!(
        summary_of(&run(&split))["policy_sha256"],
        summary_of(&run(&whole))["policy_sha256"]
    );
    let report: serde_json::Value = serde_json::from_slice(&uninterrupted.stdout).unwrap();
    assert_eq!(report["env_steps_to_target"][0], 200, "{report}");
    assert_eq!(summary_of(&run(&whole))["env_steps_to_target"], 200);

    // The same command again reuses the completed run instead of training; with another
    // target too, reading the steps to it off the run's curve.
    let again = bench_learning(&split, "500", &[]);
    assert!(again.status.success(), "{again:?}");
    assert!(String::from_utf8_lossy(&again.stderr).contains("already completed"));
    let seed_log = std::fs::read_to_string(run(&split).join("logs/train.log")).unwrap();
    assert!(seed_log.contains("already completed"), "{seed_log}");
    let lower = bench_learning(&split, "500", &low_target);
    assert!(lower.status.success(), "{lower:?}");
    assert!(String::from_utf8_lossy(&lower.stderr).contains("already completed"));
    let report: serde_json::Value = serde_json::from_slice(&lower.stdout).unwrap();
    assert_eq!(report["target_return"], -1e9, "{report}");
    assert_eq!(report["env_steps_to_target"][0], 200, "{report}");

    // Another config over the same runs is refused, naming the run directory.
    let other = bench_learning(&split, "500", &["--set", "sac.gamma=0.9"]);
    assert!(!other.status.success());
    let err = String::from_utf8_lossy(&other.stderr);
    assert!(
        err.contains("mbpo-Pendulum-v1-s0") && err.contains("another config"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Seeds of `mbpo bench learning` run on their own threads, each logging into its own run's
/// `logs/train.log`, not into another seed's.
#[test]
fn learning_bench_logs_each_seed_into_its_run() {
    let dir = scratch("cli-bench-logs");
    let out = mbpo()
        .args(["bench", "learning", "--config"])
        .arg(config_file())
        .args(["--seeds", "2", "--threads", "2", "--steps", "300", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(out.status.success(), "{out:?}");
    for (seed, other) in [(0, 1), (1, 0)] {
        let log = dir.join(format!("runs/mbpo-Pendulum-v1-s{seed}/logs/train.log"));
        let text = std::fs::read_to_string(&log).unwrap();
        assert!(
            text.contains(&format!("seed {seed}: step 200 eval")),
            "{text}"
        );
        assert!(!text.contains(&format!("seed {other}:")), "{text}");
    }
    std::fs::remove_dir_all(dir).unwrap();
}

/// `mbpo chaos` of one 2000-step run with one kill and two actors (plus `extra`), in
/// `dir/chaos`: its lines (the run's, then the totals). The kill comes as soon as a checkpoint
/// passes its point (at most 1600): hundreds of steps before the end, so it always lands.
fn chaos_one_kill(dir: &std::path::Path, extra: &[&str]) -> Vec<serde_json::Value> {
    let out = mbpo()
        .args(["chaos", "--config"])
        .arg(config_file())
        .args(["--steps", "2000", "--set", "checkpoint.every=100"])
        .args(["--max-delay-seconds", "0", "--runs", "1", "--kills", "1"])
        .args(["--actors", "2"])
        .args(extra)
        .arg("--out")
        .arg(dir.join("chaos"))
        .stderr(Stdio::null())
        .output()
        .unwrap();
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(out.status.success(), "{text}");
    let lines: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), 2, "{text}");
    lines
}

/// The run completed with every transition received once by every consumer, none lost, and
/// nothing left behind (shared memory, processes).
fn assert_run_held(run: &serde_json::Value) {
    assert_eq!(run["completed"], true, "{run}");
    assert_eq!(
        run["every_consumer_received_every_transition"], true,
        "{run}"
    );
    assert_eq!(
        (run["lost"].as_u64(), run["produced"].as_u64()),
        (Some(0), Some(2000)),
        "{run}"
    );
    assert_eq!(
        (&run["shm_left"], &run["orphans"]),
        (&0.into(), &0.into()),
        "{run}"
    );
}

/// `mbpo chaos` runs the pipeline with kills and reports each run: one run, one kill, which
/// restarts the pipeline; the run completes with every transition received by every consumer
/// and nothing left behind, and the report says so.
#[test]
fn chaos_kills_a_process_and_reports_the_run() {
    let dir = scratch("cli-chaos");
    let lines = chaos_one_kill(&dir, &[]);
    let (run, totals) = (&lines[0], &lines[1]);
    assert_eq!(run["killed"].as_array().map(Vec::len), Some(1), "{run}");
    assert_eq!(run["restarts"], 1, "{run}");
    assert_run_held(run);
    assert_eq!(
        (&totals["runs"], &totals["completed"]),
        (&1.into(), &1.into())
    );
    assert!(dir.join("chaos/chaos.json").is_file());
    let _ = std::fs::remove_dir_all(dir);
}

/// `mbpo chaos --kill-supervisor`: `mbpo run` itself is SIGKILLed once; its processes are gone
/// within 5 s, it leaves shared memory that the resumed run (`mbpo run --resume`) removes, and
/// the resumed run completes with every transition received once.
#[test]
fn chaos_kills_the_supervisor_and_the_resumed_run_completes_and_cleans_up() {
    let dir = scratch("cli-chaos-supervisor");
    let lines = chaos_one_kill(&dir, &["--kill-supervisor"]);
    let run = &lines[0];
    assert_eq!(run["killed"], serde_json::json!(["supervisor"]), "{run}");
    let kill = &run["supervisor_kills"][0];
    assert_eq!(kill["orphans_after_5s"], 0, "{run}");
    assert!(
        kill["services_gone_seconds"]
            .as_f64()
            .is_some_and(|t| t <= 5.0),
        "{run}"
    );
    assert!(
        kill["shm_files_left_by_the_kill"].as_u64() > Some(0),
        "a SIGKILLed launcher cannot clean up: {run}"
    );
    // Nothing of either `mbpo run` is left: the resumed one removed the killed one's files.
    assert_run_held(run);
    let _ = std::fs::remove_dir_all(dir);
}

/// The output of a command that runs a binary this test just copied. Another test's thread
/// may fork while the copy's file is still open for writing; until that child execs, it holds
/// the file open and exec fails with "Text file busy" (ETXTBSY), so that error is retried
/// (at most 100 times, 20 ms apart).
fn output_of_fresh_binary(
    run: impl Fn() -> std::io::Result<std::process::Output>,
) -> std::process::Output {
    for _ in 0..100 {
        match run() {
            Err(e) if e.kind() == std::io::ErrorKind::ExecutableFileBusy => {
                std::thread::sleep(Duration::from_millis(20))
            }
            other => return other.unwrap(),
        }
    }
    panic!("the copied binary stayed busy (ETXTBSY) for 2 s");
}

/// A service binary missing beside `mbpo` (a hand-made build of some packages only) is named
/// with the command that builds it, not left as a bare "No such file or directory".
#[test]
fn a_missing_service_binary_is_named_with_the_command_that_builds_it() {
    let dir = scratch("lone-mbpo");
    std::fs::copy(bin_dir().join("mbpo"), dir.join("mbpo")).unwrap();
    let lone = || Command::new(dir.join("mbpo"));
    let out = output_of_fresh_binary(|| {
        lone()
            .args(["run", "--config"])
            .arg(config_file())
            .args(["--steps", "100", "--out"])
            .arg(dir.join("run"))
            .output()
    });
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(err.contains("No such file"), "{err}");
    assert!(
        err.contains("cargo build") && err.contains("-p mbpo-"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");

    let out = output_of_fresh_binary(|| {
        lone()
            .args(["certs", "--out"])
            .arg(dir.join("creds"))
            .output()
    });
    assert!(!out.status.success());
    let err = String::from_utf8(out.stderr).unwrap();
    assert!(
        err.contains("mbpo-gateway") && err.contains("-p mbpo-gateway"),
        "{err}"
    );
    assert!(err.contains("deploy/worker.sh"), "{err}");
    std::fs::remove_dir_all(dir).unwrap();
}

/// `mbpo run --control-hz` is `actor.control_hz`: refused in lockstep and when negative, each
/// time naming the key and the fix, before a run directory is made.
#[test]
fn control_hz_is_refused_where_it_cannot_hold() {
    let dir = scratch("cli-control-hz");
    for (args, want) in [
        (
            ["--mode", "lockstep", "--control-hz", "50"],
            "--mode pipelined",
        ),
        (
            ["--mode", "pipelined", "--control-hz", "-5"],
            "0 or a positive number",
        ),
    ] {
        let err = refused_run(&dir, &args);
        assert!(
            err.contains("actor.control_hz") && err.contains(want),
            "{err}"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `mbpo run` refuses remote roles the gateways cannot carry, unknown ones, and a `--listen`
/// with nothing remote, each by name and before a run directory is made.
#[test]
fn remote_roles_are_refused_where_the_gateways_cannot_carry_them() {
    let dir = scratch("cli-remote-roles");
    for (args, want) in [
        (
            vec!["--remote-roles", "learner"],
            "--remote-roles learner: the learner receives real, which the gateways do not carry",
        ),
        (
            vec!["--remote-roles", "critic"],
            "--remote-roles critic: the mbpo run has no role of that name; its roles are learner, model-trainer, rollout-generator, evaluator",
        ),
        (vec![], "none is remote: give --remote-actors M"),
    ] {
        let mut args = args;
        args.splice(0..0, ["--listen", "tcp/127.0.0.1:7447"]);
        let err = refused_run(&dir, &args);
        assert!(err.contains(want), "{err}");
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// `mbpo run` of the tiny config with `args` into `dir/run`, which must be refused before a run
/// directory is made; its stderr.
fn refused_run(dir: &std::path::Path, args: &[&str]) -> String {
    let out = mbpo()
        .args(["run", "--config"])
        .arg(config_file())
        .args(args)
        .arg("--out")
        .arg(dir.join("run"))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!out.status.success(), "{err}");
    assert!(
        !dir.join("run").exists(),
        "no run directory for a refused run"
    );
    err
}

/// `mbpo join --help` is `mbpo`'s own, with the worker's options; a bad argument is refused
/// by `mbpo` itself, naming it.
#[test]
fn mbpo_join_has_its_own_help_and_checks_its_arguments() {
    let help = mbpo().args(["join", "--help"]).output().unwrap();
    let text = String::from_utf8_lossy(&help.stdout);
    assert!(help.status.success(), "{text}");
    for option in ["--actors", "--roles", "--credentials", "--head-timeout"] {
        assert!(text.contains(option), "{option}: {text}");
    }
    let bad = mbpo()
        .args(["join", "tcp/127.0.0.1:1", "--actors", "many"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(!bad.status.success());
    assert!(err.contains("--actors") && err.contains("many"), "{err}");
}
