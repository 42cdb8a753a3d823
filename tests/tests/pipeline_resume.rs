//! Checkpoints of the running pipeline (`mbpo_runtime::barrier`): SIGINT writes one and
//! stops cleanly, `mbpo run --resume` continues, and a lockstep run stopped and resumed ends
//! with the same weights as the sequential reference (= an uninterrupted lockstep run).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use mbpo_integration_tests::*;
use mbpo_train::tdmpc::train_tdmpc_with;
use mbpo_train::{
    train_mbpo, train_mbpo_with, train_mpc, train_mpc_with, ExperimentConfig, RunOptions, Summary,
    TrainError,
};

const TIMEOUT: Duration = Duration::from_secs(300);

/// The complete checkpoints of a run, oldest first, as env steps.
fn checkpoints(run: &Path) -> Vec<u64> {
    let Ok(entries) = std::fs::read_dir(run.join("checkpoints")) else {
        return Vec::new();
    };
    let mut steps: Vec<u64> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.join("COMPLETE").is_file())
        .filter_map(|p| p.file_name()?.to_str()?.parse().ok())
        .collect();
    steps.sort_unstable();
    steps
}

/// Steps of the MPC runs here: long enough (about 2 s) to be stopped after a checkpoint.
const MPC_STEPS: u64 = 1500;

/// The file names in checkpoint `step` of `run`, sorted.
fn checkpoint_files(run: &Path, step: u64) -> Vec<String> {
    let dir = mbpo_train::checkpoint::dir_for(run, step);
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

/// `mbpo run --quiet` with `args`, its stderr going to `log` (a pipe nobody reads while the
/// test waits would fill up and block the supervisor's logging).
fn spawn_logged(args: &[&str], log: &Path) -> Child {
    Command::new(bin_dir().join("mbpo"))
        .arg("run")
        .args(args)
        .arg("--quiet")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(log).unwrap())
        .spawn()
        .expect("spawning mbpo run")
}

/// Wait for `child` at most `timeout`; its exit status and stderr (from `log`).
fn wait_logged(child: Child, log: &Path) -> (ExitStatus, String) {
    let o = wait_output(child, TIMEOUT);
    (o.status, std::fs::read_to_string(log).unwrap_or_default())
}

/// Wait until the run has a complete checkpoint, then SIGINT it.
fn stop_after_first_checkpoint(child: Child, run: &Path, log: &Path) -> (ExitStatus, String) {
    stop_after_checkpoint(child, run, log, 1)
}

/// Ctrl-C once the run has a checkpoint of step `at_least` or later.
fn stop_after_checkpoint(
    mut child: Child,
    run: &Path,
    log: &Path,
    at_least: u64,
) -> (ExitStatus, String) {
    let t = Instant::now();
    while checkpoints(run).last().is_none_or(|&c| c < at_least) {
        let exited = child.try_wait().unwrap();
        assert!(
            exited.is_none(),
            "the run ended ({exited:?}) before its first checkpoint:\n{}",
            std::fs::read_to_string(log).unwrap_or_default()
        );
        assert!(t.elapsed() < TIMEOUT, "no checkpoint within {TIMEOUT:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: kill(2) on our child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    wait_logged(child, log)
}

/// A run stopped by Ctrl-C after its checkpoint of `stopped_at` reports what it did, not
/// zeros: every actor paused at the cut, so the real transitions are exactly the cut's. In
/// lockstep, past the first train point the model trainer trained on the warm-up's
/// transitions and (MBPO) the learner updated (pipelined, a stop abandons a training).
fn assert_summary_counts_what_happened(
    s: &serde_json::Value,
    cfg: &mbpo_train::ExperimentConfig,
    stopped_at: u64,
) {
    assert_eq!(s["env_steps"], stopped_at, "{s}");
    assert_eq!(s["real_transitions"]["produced"], stopped_at, "{s}");
    let schedule = mbpo_train::Schedule::of(cfg);
    let Some(first_train_point) = (1..=stopped_at).find(|&t| schedule.train_point(t).is_some())
    else {
        return;
    };
    if s["mode"] != "lockstep" {
        return;
    }
    let mut consumers = vec!["model-trainer"];
    assert!(s["ratios"]["model_trainings"].as_u64().unwrap() >= 1, "{s}");
    if cfg.algo == mbpo_train::Algo::MBPO && stopped_at > first_train_point {
        assert!(s["sac_updates"].as_u64().unwrap() > 0, "{s}");
        assert!(
            s["ratios"]["updates_per_env_step"].as_f64().unwrap() > 0.0,
            "{s}"
        );
        consumers.extend(["learner", "rollout-generator"]);
    }
    for consumer in consumers {
        let received = s["real_transitions"]["received"][consumer].as_u64();
        let enough = received.is_some_and(|r| r >= first_train_point - 1);
        assert!(enough, "{consumer} (stopped at {stopped_at}): {s}");
    }
}

fn resume(run: &Path, root: &Path, log: &Path) -> (ExitStatus, String) {
    let args = [
        "--resume",
        run.to_str().unwrap(),
        "--ipc-root",
        root.to_str().unwrap(),
    ];
    wait_logged(spawn_logged(&args, log), log)
}

/// Env steps of the metrics rows: every eval point exactly once, in order.
fn metric_steps(run: &Path) -> Vec<u64> {
    let text = std::fs::read_to_string(run.join("metrics.csv")).unwrap();
    text.lines()
        .skip(1)
        .map(|l| l.split(',').next().unwrap().parse().unwrap())
        .collect()
}

fn start(input: &Path, out: &Path, root: &Path, extra: &[&str], log: &Path) -> Child {
    spawn_logged(&run_args(input, out, root, extra), log)
}

/// Lockstep: periodic checkpoints, a SIGINT stop and a resume from disk change nothing -- the
/// final policy equals the sequential run's, and so does every metrics column but the timings.
#[test]
fn lockstep_stop_and_resume_equals_the_uninterrupted_run() {
    let mut cfg = tiny_config(800);
    cfg.checkpoint.every = 100;
    let dir = scratch("resume-lockstep");
    let input = write_config(&cfg, &dir);
    let root = ipc_root("rl");
    let run = dir.join("run");
    let log = dir.join("stderr.log");
    // Sequential first: the pipeline's first checkpoint comes within a second.
    let seq_dir = dir.join("sequential");
    let seq = train_mbpo(&cfg, &seq_dir).unwrap();
    let child = start(&input, &run, &root, &["--mode", "lockstep"], &log);

    // Past the first train point (201), so the summary has trainings and updates to report.
    let (status, err) = stop_after_checkpoint(child, &run, &log, 300);
    assert!(status.success(), "{err}");
    let s = summary(&run);
    assert_eq!(s["status"], "stopped", "{s}");
    let stopped_at = *checkpoints(&run).last().unwrap();
    assert!(
        stopped_at < cfg.steps,
        "stopped at {stopped_at}: too late to test a resume"
    );
    assert_summary_counts_what_happened(&s, &cfg, stopped_at);

    let (status, err) = resume(&run, &root, &log);
    assert!(status.success(), "{err}");
    let s = summary(&run);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(s["mode"], "lockstep");
    assert_eq!(
        s["policy_sha256"],
        seq.policy_sha256.as_str(),
        "stopped at {stopped_at} and resumed != uninterrupted (sequential)"
    );
    assert_eq!(
        metrics_without_timing(&run),
        metrics_without_timing(&seq_dir)
    );
    assert!(checkpoints(&run).len() <= cfg.checkpoint.keep);
    let _ = std::fs::remove_dir_all(dir);
}

/// Run `cfg` (400 steps, periodic checkpoints every 100) to its end in lockstep mode, in a
/// scratch directory `name` (iceoryx2 root tag `tag`); returns the directory, the run, the
/// iceoryx2 root and the log. The run ends with two checkpoints (`checkpoint.keep`): a
/// periodic one and the last step's. A periodic checkpoint is taken when the coordinator hears
/// of a step at or past it while roles still run, so one due near the end of a fast run is
/// skipped (the last step's comes anyway): hence a period well inside the run.
fn finished_lockstep_run(
    cfg: &ExperimentConfig,
    name: &str,
    tag: &str,
) -> (PathBuf, PathBuf, PathBuf, PathBuf) {
    let dir = scratch(name);
    let input = write_config(cfg, &dir);
    let root = ipc_root(tag);
    let run = dir.join("run");
    let log = dir.join("stderr.log");
    let (status, err) = wait_logged(
        start(&input, &run, &root, &["--mode", "lockstep"], &log),
        &log,
    );
    assert!(status.success(), "{err}");
    let steps = checkpoints(&run);
    let every = cfg.checkpoint.every;
    assert!(
        every <= 100 && cfg.checkpoint.keep == 2,
        "see the doc comment"
    );
    assert!(
        steps.len() == 2 && steps[0] >= every && steps[1] == cfg.steps,
        "{steps:?}"
    );
    (dir, run, root, log)
}

/// A finished run extends: `mbpo run --resume RUN --steps N` continues from the checkpoint of
/// its last step (not an older periodic one) and ends where an uninterrupted run of N steps
/// does, every metrics row included (the old last step, 400, is an eval point of both).
#[test]
fn a_finished_lockstep_run_extends_from_its_last_step() {
    let mut cfg = tiny_config(400);
    cfg.checkpoint.every = 100;
    let (dir, run, root, log) = finished_lockstep_run(&cfg, "extend-lockstep", "ex");

    let args = [
        "--resume",
        run.to_str().unwrap(),
        "--steps",
        "600",
        "--ipc-root",
        root.to_str().unwrap(),
    ];
    let (status, err) = wait_logged(spawn_logged(&args, &log), &log);
    assert!(status.success(), "{err}");
    assert!(err.contains("0000000400 (after step 400)"), "{err}");
    let mut longer = cfg.clone();
    longer.steps = 600;
    let seq = train_mbpo(&longer, &dir.join("sequential")).unwrap();
    let s = summary(&run);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(s["policy_sha256"], seq.policy_sha256.as_str());
    assert_eq!(
        metrics_without_timing(&run),
        metrics_without_timing(&dir.join("sequential"))
    );
    // keep = 2: the last step's checkpoint and the one before it, which is 400 or, when the
    // coordinator heard of a step past 500 while the roles still ran, that periodic one (see
    // `finished_lockstep_run`; CI saw 503).
    let kept = checkpoints(&run);
    assert!(
        kept.len() == 2 && (400..600).contains(&kept[0]) && kept[1] == 600,
        "{kept:?}"
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// One checkpoint format for both commands (`mbpo_train::run_files`): an MBPO run
/// checkpointed by `mbpo train` continues under `mbpo run --mode lockstep`, and one
/// checkpointed by `mbpo run --mode lockstep` under `mbpo train`; each ends with the
/// uninterrupted run's policy and every metrics column but the timings.
#[test]
fn mbpo_checkpoints_cross_between_mbpo_train_and_mbpo_run() {
    cross_resume(tiny_config(400), "cross-mbpo", train_mbpo_with);
}

/// [`mbpo_checkpoints_cross_between_mbpo_train_and_mbpo_run`] for MPC (planning actor, model
/// trainer, planning evaluator).
#[test]
fn mpc_checkpoints_cross_between_mbpo_train_and_mbpo_run() {
    cross_resume(tiny_mpc_config(400), "cross-mpc", train_mpc_with);
}

/// [`mbpo_checkpoints_cross_between_mbpo_train_and_mbpo_run`] for TD-MPC2 (world-model
/// learner, latent-planning actor and evaluator); the extension to 600 steps grows the
/// learner's episodes as `mbpo train` would have kept them.
#[test]
fn tdmpc_checkpoints_cross_between_mbpo_train_and_mbpo_run() {
    cross_resume(tiny_tdmpc_config(400), "cross-tdmpc", train_tdmpc_with);
}

type Trainer = fn(&ExperimentConfig, &Path, RunOptions) -> Result<Summary, TrainError>;

/// Run `cfg` (400 steps) with one command, extend it to 600 with the other, both ways; compare
/// with `train`'s uninterrupted 600-step run.
fn cross_resume(cfg: ExperimentConfig, name: &str, train: Trainer) {
    let mut longer = cfg.clone();
    longer.steps = 600;
    let dir = scratch(name);
    let root = ipc_root(&name[..8]);
    let log = dir.join("stderr.log");
    let reference = dir.join("reference");
    let uninterrupted = train(&longer, &reference, RunOptions::default()).unwrap();

    let train_then_run = dir.join("train-then-run");
    train(&cfg, &train_then_run, RunOptions::default()).unwrap();
    let args = [
        "--resume",
        train_then_run.to_str().unwrap(),
        "--steps",
        "600",
        "--mode",
        "lockstep",
        "--ipc-root",
        root.to_str().unwrap(),
    ];
    let (status, err) = wait_logged(spawn_logged(&args, &log), &log);
    assert!(status.success(), "{err}");
    assert!(err.contains("checkpointed by `mbpo train`"), "{err}");
    let s = summary(&train_then_run);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(s["policy_sha256"], uninterrupted.policy_sha256.as_str());
    assert_eq!(
        metrics_without_timing(&train_then_run),
        metrics_without_timing(&reference)
    );

    // Periodic checkpoints too, all kept: `mbpo train` resumes from each of them. A lockstep
    // cut can hold the model training of the step after it already (a cut at the end of the
    // warm-up usually does), which the sequential run then does not repeat.
    let mut periodic = cfg.clone();
    periodic.checkpoint.every = 100;
    periodic.checkpoint.keep = 10;
    let input = write_config(&periodic, &dir);
    let lockstep = dir.join("lockstep");
    let (status, err) = wait_logged(
        start(&input, &lockstep, &root, &["--mode", "lockstep"], &log),
        &log,
    );
    assert!(status.success(), "{err}");
    let cuts = checkpoints(&lockstep);
    assert!(cuts.len() >= 2 && cuts.ends_with(&[400]), "{cuts:?}");
    for &at in &cuts {
        let run = dir.join(format!("lockstep-then-train-{at}"));
        copy_dir(&lockstep, &run);
        for &later in cuts.iter().filter(|&&c| c > at) {
            std::fs::remove_dir_all(mbpo_train::checkpoint::dir_for(&run, later)).unwrap();
        }
        let resume = RunOptions {
            resume: true,
            ..Default::default()
        };
        let resumed = train(&longer, &run, resume)
            .unwrap_or_else(|e| panic!("resuming the lockstep checkpoint after step {at}: {e}"));
        assert_eq!(resumed.status, "completed");
        assert_eq!(
            resumed.policy_sha256, uninterrupted.policy_sha256,
            "from {at}"
        );
        assert_eq!(
            metrics_without_timing(&run),
            metrics_without_timing(&reference),
            "from {at}"
        );
    }
    let _ = std::fs::remove_dir_all(dir);
}

/// MPC (planning actors, model trainer, planning evaluator; no learner), lockstep: a SIGINT
/// stop and a resume change nothing -- the final model and every metrics column but the
/// timings equal the sequential `train_mpc` run's. On resume the model trainer publishes its
/// model again (the planners' checkpoints hold none) and waits only for the evaluator's
/// acknowledgements of eval points after the cut (the earlier ones went with the old processes).
///
/// The run also aims at an evaluation abandoned for a checkpoint: the evaluator starts the
/// evaluation of an eval point as soon as its model arrives (eval point 200 with the model of
/// step 101), an evaluation (3 episodes of 200 planned steps) outlasts the actor steps to the
/// next cut (the periodic one at 150, or the stop's), so the evaluator abandons it and
/// evaluates it again after the cut. Lockstep does not hold the actors for the evaluator
/// before the next model training, so an evaluator that starts or wakes late (a loaded
/// machine) can find the cut already there and never begin that evaluation. Every attempt
/// must equal the sequential run; at least one of [`ABANDON_ATTEMPTS`] must have abandoned an
/// evaluation.
#[test]
fn mpc_lockstep_stop_and_resume_equals_the_sequential_run() {
    let mut cfg = tiny_mpc_config(MPC_STEPS);
    cfg.checkpoint.every = 150;
    cfg.eval.episodes = 3;
    let dir = scratch("resume-mpc");
    let seq_dir = dir.join("sequential");
    let seq = train_mpc(&cfg, &seq_dir).unwrap();
    let mut logs = Vec::new();
    for attempt in 1..=ABANDON_ATTEMPTS {
        let evaluator_log = mpc_lockstep_stop_and_resume(&cfg, &dir, attempt, &seq, &seq_dir);
        if evaluator_log.contains("abandoned after") {
            let _ = std::fs::remove_dir_all(dir);
            return;
        }
        logs.push(evaluator_log);
    }
    panic!(
        "no evaluation was abandoned for the checkpoint in {ABANDON_ATTEMPTS} attempts; the \
         evaluator logs:\n{}",
        logs.join("\n---\n")
    );
}

/// Attempts at the interleaving [`mpc_lockstep_stop_and_resume_equals_the_sequential_run`]
/// aims at; one misses it when the evaluator is late to each of the two cuts (the periodic
/// one and the stop's).
const ABANDON_ATTEMPTS: u32 = 3;

/// One stop (after the first checkpoint) and resume of the lockstep MPC run of `cfg` in a
/// fresh directory under `dir`, checked against the sequential run `seq` (in `seq_dir`);
/// returns the evaluator's log.
fn mpc_lockstep_stop_and_resume(
    cfg: &ExperimentConfig,
    dir: &Path,
    attempt: u32,
    seq: &Summary,
    seq_dir: &Path,
) -> String {
    let here = dir.join(format!("attempt-{attempt}"));
    std::fs::create_dir_all(&here).unwrap();
    let input = write_config(cfg, &here);
    let root = ipc_root(&format!("rm{attempt}"));
    let run = here.join("run");
    let log = here.join("stderr.log");
    let child = start(&input, &run, &root, &["--mode", "lockstep"], &log);

    let (status, err) = stop_after_first_checkpoint(child, &run, &log);
    assert!(status.success(), "{err}");
    assert_eq!(summary(&run)["status"], "stopped");
    let stopped_at = *checkpoints(&run).last().unwrap();
    assert!(stopped_at < cfg.steps, "stopped at {stopped_at}: too late");
    assert_summary_counts_what_happened(&summary(&run), cfg, stopped_at);
    let files = checkpoint_files(&run, stopped_at);
    assert_eq!(
        files,
        [
            "COMPLETE",
            "actor-0",
            "evaluator",
            "model-trainer",
            "run-book",
            "supervisor"
        ],
        "an MPC checkpoint has no learner or rollout generator"
    );
    let evaluator_log = std::fs::read_to_string(run.join("logs/evaluator.log")).unwrap();

    let (status, err) = resume(&run, &root, &log);
    assert!(status.success(), "{err}");
    let s = summary(&run);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(
        s["policy_sha256"],
        seq.policy_sha256.as_str(),
        "stopped at {stopped_at} and resumed != uninterrupted (sequential), attempt {attempt}"
    );
    assert_eq!(
        metrics_without_timing(&run),
        metrics_without_timing(seq_dir)
    );
    evaluator_log
}

/// MPC, lockstep, `--restart on-failure`: the model trainer is killed after the first
/// checkpoint; every process restarts from it and the run ends as the sequential one does.
#[test]
fn mpc_lockstep_crash_restarts_from_the_checkpoint_and_equals_the_sequential_run() {
    let mut cfg = tiny_mpc_config(MPC_STEPS);
    cfg.checkpoint.every = 150;
    lockstep_crash_equals_the_sequential_run(&cfg, ("crash-mpc", "cm"), "model-trainer", |d| {
        train_mpc(&cfg, d).unwrap()
    });
}

/// Pipelined with two actors: SIGINT writes a checkpoint and stops every process; the resumed
/// run ends with each real transition received exactly once by every consumer, the metrics
/// rows continue (each eval point once) and the env-step count reaches the total.
#[test]
fn pipelined_stop_and_resume_loses_and_duplicates_nothing() {
    let mut cfg = tiny_config(800);
    cfg.checkpoint.every = 300;
    let want: Vec<u64> = (1..=cfg.steps)
        .filter(|t| t % cfg.eval.every == 0)
        .collect();
    let consumers = ["model-trainer", "rollout-generator", "learner"];
    pipelined_stop_and_resume(&cfg, ("resume-pipelined", "rp"), &[], &consumers, &want);
}

/// The same for MPC: two planning actors with a model lag, the model trainer the only
/// consumer, no evaluation while warming up.
#[test]
fn mpc_pipelined_stop_and_resume_loses_and_duplicates_nothing() {
    let mut cfg = tiny_mpc_config(MPC_STEPS);
    cfg.checkpoint.every = 300;
    let want: Vec<u64> = (1..=cfg.steps)
        .filter(|t| t % cfg.eval.every == 0 && *t > cfg.mpc.init_random_steps)
        .collect();
    let extra = ["--model-lag", "50"];
    let name = ("resume-mpc-pipelined", "rmp");
    pipelined_stop_and_resume(&cfg, name, &extra, &["model-trainer"], &want);
}

/// Pipelined, Ctrl-C during a model training (one can take minutes) does not wait for it: the
/// trainer abandons it after the epoch under way, the checkpoint holds the trainings done (none
/// here), and the resumed run trains again and completes with every transition received once.
#[test]
fn pipelined_stop_abandons_the_model_training_under_way() {
    let mut cfg = tiny_config(300);
    // The one training (for step 201) runs for 15 s unless abandoned.
    cfg.model.max_epochs_since_update = 1_000_000;
    cfg.model.max_train_seconds = Some(15.0);
    let dir = scratch("stop-in-training");
    let input = write_config(&cfg, &dir);
    let root = ipc_root("sit");
    let run = dir.join("run");
    let log = dir.join("stderr.log");
    let mut child = start(&input, &run, &root, &["--mode", "pipelined"], &log);
    let trainer_log = run.join("logs").join("model-trainer.log");
    let t = Instant::now();
    while !std::fs::read_to_string(&trainer_log)
        .unwrap_or_default()
        .contains("training model v1 for step 201")
    {
        assert!(child.try_wait().unwrap().is_none(), "the run ended early");
        assert!(t.elapsed() < TIMEOUT, "no training started");
        std::thread::sleep(Duration::from_millis(20));
    }
    // SAFETY: kill(2) on our child.
    unsafe { libc::kill(child.id() as i32, libc::SIGINT) };
    let (status, err) = wait_logged(child, &log);
    assert!(status.success(), "{err}");
    assert_eq!(summary(&run)["status"], "stopped");
    let trainer = std::fs::read_to_string(&trainer_log).unwrap();
    assert!(
        trainer.contains("model training for step 201 abandoned"),
        "{trainer}"
    );
    assert!(err.contains("with 0 model trainings"), "{err}");
    assert_eq!(checkpoints(&run).len(), 1);

    let (status, err) = resume(&run, &root, &log);
    assert!(status.success(), "{err}");
    let s = summary(&run);
    assert_eq!(s["status"], "completed", "{s}");
    for consumer in ["model-trainer", "rollout-generator", "learner"] {
        assert_eq!(
            s["real_transitions"]["received"][consumer], cfg.steps,
            "{consumer}: {s}"
        );
    }
    let trainer = std::fs::read_to_string(&trainer_log).unwrap();
    assert!(
        trainer.contains("model v1 trained for step 201"),
        "{trainer}"
    );
    assert_eq!(metric_steps(&run), [200, 300]);
    let _ = std::fs::remove_dir_all(dir);
}

/// MPC pipelined with two planning actors and `--restart on-failure`: the model trainer is
/// killed after the first periodic checkpoint; every eval point ends with exactly one row.
/// (Whether the checkpoint held rows as unwritten, an actor being behind the cut's step,
/// depends on timing; `RunBook::rows_upto` is unit-tested for that case.)
#[test]
fn mpc_pipelined_crash_restarts_without_duplicate_rows() {
    let mut cfg = tiny_mpc_config(MPC_STEPS);
    cfg.checkpoint.every = 200;
    let dir = scratch("crash-mpc-pipelined");
    let input = write_config(&cfg, &dir);
    let root = ipc_root("cmp");
    let run = dir.join("run");
    let log = dir.join("stderr.log");
    let args = [
        "--mode",
        "pipelined",
        "--actors",
        "2",
        "--model-lag",
        "50",
        "--restart",
        "on-failure",
    ];
    let mut child = start(&input, &run, &root, &args, &log);
    crash_service(&run, "model-trainer", true, &mut child);
    let (status, err) = wait_logged(child, &log);
    assert!(status.success(), "{err}");
    let s = summary(&run);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(s["restarts"], 1, "{s}");
    assert_eq!(
        s["real_transitions"]["received"]["model-trainer"], cfg.steps,
        "{s}"
    );
    let want: Vec<u64> = (1..=cfg.steps)
        .filter(|t| t % cfg.eval.every == 0 && *t > cfg.mpc.init_random_steps)
        .collect();
    assert_eq!(metric_steps(&run), want);
    let _ = std::fs::remove_dir_all(dir);
}

/// Run `cfg` pipelined with two actors (plus `extra` flags; `name`: scratch directory and
/// iceoryx2 root), stop it after its first checkpoint, resume it; check every transition reached each of `consumers` once and the
/// metrics rows are exactly the eval points `want`.
fn pipelined_stop_and_resume(
    cfg: &mbpo_train::ExperimentConfig,
    (name, root): (&str, &str),
    extra: &[&str],
    consumers: &[&str],
    want: &[u64],
) {
    let dir = scratch(name);
    let input = write_config(cfg, &dir);
    let root = ipc_root(root);
    let run = dir.join("run");
    let log = dir.join("stderr.log");
    let mut args = vec!["--mode", "pipelined", "--actors", "2"];
    args.extend_from_slice(extra);
    let child = start(&input, &run, &root, &args, &log);
    let (status, err) = stop_after_first_checkpoint(child, &run, &log);
    assert!(status.success(), "{err}");
    let s = summary(&run);
    assert_eq!(s["status"], "stopped", "{s}");
    let alive = processes_mentioning(s["run_id"].as_str().unwrap());
    assert!(alive.is_empty(), "processes still alive: {alive:?}");
    let stopped_at = *checkpoints(&run).last().unwrap();
    assert_summary_counts_what_happened(&s, cfg, stopped_at);

    let (status, err) = resume(&run, &root, &log);
    assert!(status.success(), "{err}");
    let s = summary(&run);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(s["actors"], 2, "the resumed run keeps its actors");
    let real = &s["real_transitions"];
    for consumer in consumers {
        assert_eq!(
            real["received"][consumer], cfg.steps,
            "{consumer} (stopped at {stopped_at}): {s}"
        );
    }
    assert_eq!(real["lost"], 0, "{s}");
    assert_eq!(s["env_steps"], cfg.steps, "{s}");
    assert_eq!(metric_steps(&run), want);
    let left = leftovers(s["run_id"].as_str().unwrap(), &root);
    assert!(left.is_empty(), "shared-memory leftovers: {left:?}");
    let _ = std::fs::remove_dir_all(dir);
}

/// A damaged checkpoint is named, with the problem, before any process starts; a run without
/// checkpoints says so.
#[test]
fn a_damaged_or_missing_checkpoint_is_a_clear_error() {
    let mut cfg = tiny_config(400);
    cfg.checkpoint.every = 100;
    let (dir, run, root, log) = finished_lockstep_run(&cfg, "resume-damaged", "rd");
    // A resume reads the newest checkpoint, the last step's.
    let ckpt: PathBuf = mbpo_train::checkpoint::dir_for(&run, 400);

    let learner = ckpt.join("learner");
    let bytes = std::fs::read(&learner).unwrap();
    std::fs::write(&learner, &bytes[..bytes.len() / 2]).unwrap();
    let (status, err) = resume(&run, &root, &log);
    assert!(!status.success());
    assert!(
        err.contains("learner") && err.contains("truncated"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");

    let mut flipped = bytes.clone();
    *flipped.last_mut().unwrap() ^= 1;
    std::fs::write(&learner, &flipped).unwrap();
    let (_, err) = resume(&run, &root, &log);
    assert!(
        err.contains("learner") && err.contains("corrupted"),
        "{err}"
    );

    std::fs::remove_dir_all(run.join("checkpoints")).unwrap();
    let (_, err) = resume(&run, &root, &log);
    assert!(err.contains("no complete checkpoint"), "{err}");
    let _ = std::fs::remove_dir_all(dir);
}

/// SIGKILL `service` (its pid from its log), once the run has a checkpoint (`after_checkpoint`)
/// or at once.
fn crash_service(run: &Path, service: &str, after_checkpoint: bool, child: &mut Child) {
    let t = Instant::now();
    while after_checkpoint && checkpoints(run).is_empty() {
        assert!(child.try_wait().unwrap().is_none(), "the run ended first");
        assert!(t.elapsed() < TIMEOUT, "no checkpoint within {TIMEOUT:?}");
        std::thread::sleep(Duration::from_millis(10));
    }
    let log = run.join(format!("logs/{service}.log"));
    let pid = logged_pid(&log, Duration::from_secs(30)).expect("the service's pid");
    // SAFETY: kill(2) on a grandchild whose pid we just read; the run is still going.
    unsafe { libc::kill(pid, libc::SIGKILL) };
}

/// Chaos, one kill of each process kind: a pipelined run with two actors and `--restart
/// on-failure` has its second actor, evaluator, model trainer, rollout generator and learner
/// SIGKILLed one after the other (each once the previous restart is up). Every kill restarts
/// the pipeline from the newest checkpoint; the run completes with every real transition
/// received once by every consumer, every eval row once, nothing left behind.
#[test]
fn pipelined_run_survives_a_kill_of_each_process_kind() {
    let mut cfg = tiny_config(4000);
    cfg.checkpoint.every = 100;
    cfg.eval.every = 500;
    let kinds = [
        "actor-1",
        "evaluator",
        "model-trainer",
        "rollout-generator",
        "learner",
    ];
    let (dir, s) = kill_each_in_turn(
        &cfg,
        ("chaos-pipelined", "cp5"),
        &["--mode", "pipelined", "--actors", "2"],
        &kinds,
    );
    let real = &s["real_transitions"];
    assert_eq!(real["produced"], cfg.steps, "{s}");
    for consumer in ["model-trainer", "rollout-generator", "learner"] {
        assert_eq!(real["received"][consumer], cfg.steps, "{consumer}: {s}");
    }
    assert_eq!(real["lost"], 0, "{s}");
    let want: Vec<u64> = (1..=cfg.steps)
        .filter(|t| t % cfg.eval.every == 0)
        .collect();
    assert_eq!(metric_steps(&dir.join("run")), want);
    let _ = std::fs::remove_dir_all(dir);
}

/// The same in lockstep mode (one actor): after a kill of each process kind the run still ends
/// with the sequential run's policy and every metrics column but the timings.
#[test]
fn lockstep_run_killed_in_each_process_kind_equals_the_sequential_run() {
    let mut cfg = tiny_config(1500);
    cfg.checkpoint.every = 100;
    cfg.eval.every = 500;
    let kinds = [
        "actor-0",
        "evaluator",
        "model-trainer",
        "rollout-generator",
        "learner",
    ];
    let (dir, s) = kill_each_in_turn(
        &cfg,
        ("chaos-lockstep", "cl5"),
        &["--mode", "lockstep"],
        &kinds,
    );
    let seq = train_mbpo(&cfg, &dir.join("sequential")).unwrap();
    assert_eq!(s["policy_sha256"], seq.policy_sha256.as_str());
    assert_eq!(
        metrics_without_timing(&dir.join("run")),
        metrics_without_timing(&dir.join("sequential"))
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// Run `cfg` with `mode_args` and `--restart on-failure`, SIGKILL each of `kinds` in turn (each
/// once the pipeline's previous restart is up and a checkpoint exists); check that the run
/// completed after one restart per kill, naming each, and left no shared memory or process.
/// Returns the scratch directory (the run is `run` in it) and the summary.
fn kill_each_in_turn(
    cfg: &ExperimentConfig,
    (name, tag): (&str, &str),
    mode_args: &[&str],
    kinds: &[&str],
) -> (PathBuf, serde_json::Value) {
    let dir = scratch(name);
    let input = write_config(cfg, &dir);
    let root = ipc_root(tag);
    let run = dir.join("run");
    let log = dir.join("stderr.log");
    let mut args = mode_args.to_vec();
    args.extend(["--restart", "on-failure", "--max-restarts", "2"]);
    let mut child = start(&input, &run, &root, &args, &log);
    for (attempt, service) in kinds.iter().enumerate() {
        let t = Instant::now();
        while checkpoints(&run).is_empty() {
            assert!(child.try_wait().unwrap().is_none(), "the run ended first");
            assert!(t.elapsed() < TIMEOUT, "no checkpoint within {TIMEOUT:?}");
            std::thread::sleep(Duration::from_millis(10));
        }
        let service_log = run.join(format!("logs/{service}.log"));
        // Attempt k of the pipeline has logged the k-th pid of every process.
        let pids = logged_pids(&service_log, attempt + 1, TIMEOUT)
            .unwrap_or_else(|| panic!("{service} of attempt {} did not start", attempt + 1));
        assert!(
            child.try_wait().unwrap().is_none(),
            "the run ended before {service}'s kill"
        );
        // SAFETY: kill(2) on a grandchild whose pid it just logged; the run is still going.
        unsafe { libc::kill(pids[attempt], libc::SIGKILL) };
    }
    let (status, err) = wait_logged(child, &log);
    assert!(status.success(), "{err}");
    for service in kinds {
        assert!(
            err.contains(&format!("{service} exited with signal: 9")),
            "{service}: {err}"
        );
    }
    let s = summary(&run);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(s["restarts"], kinds.len(), "{s}");
    let left = leftovers(s["run_id"].as_str().unwrap(), &root);
    assert!(left.is_empty(), "shared-memory leftovers: {left:?}");
    assert!(processes_mentioning(s["run_id"].as_str().unwrap()).is_empty());
    (dir, s)
}

/// Lockstep with `--restart on-failure`: the learner is killed after the first checkpoint;
/// every process restarts from that checkpoint and the run ends exactly as the sequential
/// reference does (the work redone after the cut is the same work).
#[test]
fn lockstep_crash_restarts_from_the_checkpoint_and_equals_the_uninterrupted_run() {
    let mut cfg = tiny_config(800);
    cfg.checkpoint.every = 100;
    lockstep_crash_equals_the_sequential_run(&cfg, ("crash-lockstep", "cl"), "learner", |d| {
        train_mbpo(&cfg, d).unwrap()
    });
}

/// Run `cfg` in lockstep with `--restart on-failure` (`name`: scratch directory and iceoryx2
/// root), SIGKILL `service` after the first checkpoint, and check the restarted run ends with
/// the `sequential` reference's final weights and metrics, leaving nothing behind.
fn lockstep_crash_equals_the_sequential_run(
    cfg: &mbpo_train::ExperimentConfig,
    (name, root): (&str, &str),
    service: &str,
    sequential: impl FnOnce(&Path) -> mbpo_train::Summary,
) {
    let dir = scratch(name);
    let input = write_config(cfg, &dir);
    let root = ipc_root(root);
    let run = dir.join("run");
    let log = dir.join("stderr.log");
    // Sequential first: the pipeline's first checkpoint comes within a second.
    let seq_dir = dir.join("sequential");
    let seq = sequential(&seq_dir);
    let mut child = start(
        &input,
        &run,
        &root,
        &["--mode", "lockstep", "--restart", "on-failure"],
        &log,
    );
    crash_service(&run, service, true, &mut child);
    let (status, err) = wait_logged(child, &log);
    assert!(status.success(), "{err}");
    assert!(
        err.contains(&format!("{service} exited with signal: 9"))
            && err.contains("restarting the pipeline from the checkpoint after step"),
        "{err}"
    );
    let s = summary(&run);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(s["restarts"], 1, "{s}");
    assert_eq!(
        s["policy_sha256"],
        seq.policy_sha256.as_str(),
        "crashed, restarted from a checkpoint != uninterrupted (sequential)"
    );
    assert_eq!(
        metrics_without_timing(&run),
        metrics_without_timing(&seq_dir)
    );
    let left = leftovers(s["run_id"].as_str().unwrap(), &root);
    assert!(left.is_empty(), "shared-memory leftovers: {left:?}");
    assert!(processes_mentioning(s["run_id"].as_str().unwrap()).is_empty());
    let _ = std::fs::remove_dir_all(dir);
}

/// Pipelined, two actors, no checkpoints: a killed actor restarts the pipeline from step 0;
/// the run completes with every real transition received once. A second crash past
/// `--max-restarts` fails the run, naming the process and the restarts.
#[test]
fn pipelined_crash_without_checkpoint_restarts_from_the_start_then_gives_up() {
    let mut cfg = tiny_config(600);
    cfg.checkpoint.every = 0;
    let dir = scratch("crash-pipelined");
    let input = write_config(&cfg, &dir);
    let root = ipc_root("cp");
    let run = dir.join("run");
    let log = dir.join("stderr.log");
    let args = [
        "--mode",
        "pipelined",
        "--actors",
        "2",
        "--restart",
        "on-failure",
        "--max-restarts",
        "1",
    ];
    let mut child = start(&input, &run, &root, &args, &log);
    crash_service(&run, "actor-1", false, &mut child);
    let (status, err) = wait_logged(child, &log);
    assert!(status.success(), "{err}");
    assert!(
        err.contains("actor-1 exited with signal: 9")
            && err.contains("no checkpoint yet: restarting the pipeline from step 0"),
        "{err}"
    );
    let s = summary(&run);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(s["restarts"], 1, "{s}");
    let real = &s["real_transitions"];
    for consumer in ["model-trainer", "rollout-generator", "learner"] {
        assert_eq!(real["received"][consumer], cfg.steps, "{consumer}: {s}");
    }
    assert_eq!(real["lost"], 0, "{s}");
    let want: Vec<u64> = (1..=cfg.steps)
        .filter(|t| t % cfg.eval.every == 0)
        .collect();
    assert_eq!(metric_steps(&run), want);

    // Twice with --max-restarts 1: the second crash fails the run.
    let run2 = dir.join("run2");
    let mut child = start(&input, &run2, &root, &args, &log);
    crash_service(&run2, "actor-1", false, &mut child);
    // The restarted actor logs its own pid below the first one's: wait for it, kill it too.
    let second = logged_pids(&run2.join("logs/actor-1.log"), 2, TIMEOUT)
        .expect("the actor was not restarted")[1];
    // SAFETY: kill(2) on the restarted grandchild whose pid it just logged.
    unsafe { libc::kill(second, libc::SIGKILL) };
    let (status, err) = wait_logged(child, &log);
    assert!(!status.success());
    assert!(
        err.contains("actor-1 exited with signal: 9")
            && err.contains("the run failed after 1 restart(s)"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");
    let s = summary(&run2);
    assert_eq!(s["status"], "failed", "{s}");
    assert!(processes_mentioning(s["run_id"].as_str().unwrap()).is_empty());
    let left = leftovers(s["run_id"].as_str().unwrap(), &root);
    assert!(left.is_empty(), "shared-memory leftovers: {left:?}");
    let _ = std::fs::remove_dir_all(dir);
}
