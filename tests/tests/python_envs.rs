//! Python Gymnasium environments (`env = "gym:..."`) under `mbpo run`: a custom env of the test
//! suite trains with two actors, the bridge keeps lockstep equal to the sequential run, an env
//! that raises stops the run with a checkpoint, an interpreter that exits is restarted.
//!
//! Needs the project venv (`deploy/setup_python.sh`, run by `deploy/test.sh`).

use std::path::{Path, PathBuf};
use std::time::Duration;

use mbpo_integration_tests::*;
use mbpo_train::{checkpoint, train_mbpo, train_mpc, ExperimentConfig};

const TIMEOUT: Duration = Duration::from_secs(180);

fn test_envs_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("python")
}

/// MBPO on the test suite's `Drift` env (50-step episodes), with `kwargs`.
fn drift_config(steps: u64, kwargs: &[(&str, toml::Value)]) -> ExperimentConfig {
    let mut cfg = tiny_config(steps);
    cfg.env = "gym:mbpo_test_envs:Drift".into();
    cfg.termination = Some("never".into());
    cfg.gym.path = vec![test_envs_dir()];
    cfg.gym.max_episode_steps = Some(50);
    for (k, v) in kwargs {
        cfg.gym.kwargs.insert(k.to_string(), v.clone());
    }
    cfg.mbpo.init_random_steps = 100;
    cfg.mbpo.epoch_length = 100;
    cfg.eval.every = 100;
    cfg.eval.episodes = 2;
    cfg
}

fn run(input: &Path, out: &Path, root: &Path, extra: &[&str]) -> std::process::Output {
    wait_output(spawn_run(&run_args(input, out, root, extra)), TIMEOUT)
}

#[test]
fn a_custom_python_env_trains_under_mbpo_run_with_two_actors() {
    let cfg = drift_config(300, &[]);
    let dir = scratch("gym-two-actors");
    let input = write_config(&cfg, &dir);
    let out = dir.join("run");
    let extra = ["--mode", "pipelined", "--actors", "2"];
    let o = run(&input, &out, &ipc_root("gym2"), &extra);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&out);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(s["env"], "gym:mbpo_test_envs:Drift");
    assert_eq!(s["actors"], 2);
    assert_no_loss(&s, 300);
    assert_eq!(s["episodes_lost_to_env_exit"], 0, "{s}");
    assert!(s["final_eval_return"].as_f64().unwrap().is_finite(), "{s}");
    let env: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("env.json")).unwrap()).unwrap();
    assert_eq!(
        (env["obs_dim"].as_u64(), env["restorable"].as_bool()),
        (Some(2), Some(false))
    );
    // Only the processes that step the env start it (the others read env.json).
    for process in ["learner", "model-trainer", "rollout-generator"] {
        let log = std::fs::read_to_string(out.join(format!("logs/{process}.log"))).unwrap();
        assert!(
            !log.contains("Python env"),
            "{process} started the env:\n{log}"
        );
    }
    // Evaluation rows at 100, 200, 300, and `mbpo eval` runs the env of the run's config.
    assert_eq!(metrics_without_timing(&out).len(), 4);
    let eval = eval_run(&out, 1);
    assert!(eval["mean_return"].as_f64().unwrap() <= 0.0, "{eval}");
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn the_run_directory_records_the_layout_of_a_dict_observation() {
    let mut cfg = drift_config(10, &[]);
    cfg.env = "gym:mbpo_test_envs:DictObs".into();
    let dir = scratch("gym-dict");
    let env = cfg.make_env().unwrap();
    mbpo_train::run_dir::write_env_file(&dir, env.as_ref()).unwrap();
    let text = std::fs::read_to_string(dir.join("env.json")).unwrap();
    let json: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(json["obs_dim"], 3, "{text}");
    let parts = serde_json::json!([{"key": "a", "shape": [1]}, {"key": "b", "shape": [2]}]);
    assert_eq!(json["observation_parts"], parts, "{text}");
    let _ = std::fs::remove_dir_all(dir);
}

/// `mbpo config show` makes a `gym:` env once: one that exists is described in the log, an id
/// Gymnasium does not know is refused by name with the fix, and `--no-env-check` skips it.
#[test]
fn config_show_checks_that_a_gym_env_exists() {
    let show = |env: &str, extra: &[&str]| {
        let out = std::process::Command::new(bin_dir().join("mbpo"))
            .args(["config", "show", "--set", &format!("env=\"{env}\"")])
            .args(extra)
            .env("PYTHONPATH", test_envs_dir())
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).into_owned(),
            err,
        )
    };
    let (ok, stdout, err) = show(
        "gym:mbpo_test_envs:Drift",
        &["--set", "gym.max_episode_steps=50"],
    );
    assert!(ok, "{err}");
    assert!(
        stdout.contains("env = \"gym:mbpo_test_envs:Drift\""),
        "{stdout}"
    );
    assert!(
        err.contains(
            "observation 2 wide, action 1 wide (low -2, high 2), episodes of at most 50 steps"
        ),
        "{err}"
    );
    let (ok, stdout, err) = show("gym:NoSuchEnv-v0", &[]);
    assert!(!ok && stdout.is_empty(), "{stdout}");
    assert!(
        err.contains("Gymnasium has no environment NoSuchEnv-v0")
            && err.contains("pprint_registry"),
        "{err}"
    );
    assert!(
        !err.contains("Traceback") && !err.contains("panicked"),
        "{err}"
    );
    let (ok, stdout, err) = show("gym:NoSuchEnv-v0", &["--no-env-check"]);
    assert!(ok && stdout.contains("NoSuchEnv-v0"), "{err}");
}

#[test]
fn lockstep_through_the_bridge_equals_the_sequential_run() {
    let mut cfg = tiny_config(300);
    cfg.env = "gym:Pendulum-v1".into();
    cfg.termination = Some("never".into());
    cfg.mbpo.init_random_steps = 100;
    cfg.mbpo.epoch_length = 100;
    cfg.eval.every = 150;
    cfg.eval.episodes = 1;
    let dir = scratch("gym-lockstep");
    assert_lockstep_equals_sequential(&cfg, &dir, &dir.join("run"), "gymlock");
    let _ = std::fs::remove_dir_all(dir);
}

/// A lockstep `mbpo run` of `cfg` and `mbpo train` of it: the same policy and metrics.
fn assert_lockstep_equals_sequential(cfg: &ExperimentConfig, dir: &Path, out: &Path, name: &str) {
    let input = write_config(cfg, dir);
    bin_dir();
    let root = ipc_root(name);
    let child = spawn_run(&run_args(&input, out, &root, &["--mode", "lockstep"]));
    let seq = train_mbpo(cfg, &dir.join("sequential")).unwrap();
    let o = wait_output(child, TIMEOUT);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(summary(out)["policy_sha256"], seq.policy_sha256.as_str());
    assert_eq!(
        metrics_without_timing(out),
        metrics_without_timing(&dir.join("sequential"))
    );
}

/// The learned termination rule (the default for a gym: env) crosses processes with the model
/// snapshots: lockstep still equals the sequential run, on an env whose episodes terminate.
#[test]
fn lockstep_with_a_learned_termination_rule_equals_the_sequential_run() {
    let mut cfg = drift_config(300, &[("terminate_beyond", 1.2.into())]);
    cfg.termination = None;
    assert_eq!(
        cfg.termination(),
        Ok(mbpo_train::env_config::Termination::Learned)
    );
    let dir = scratch("gym-learned");
    let out = dir.join("run");
    assert_lockstep_equals_sequential(&cfg, &dir, &out, "gymlearned");
    // Episodes did terminate, and the model trainer learned the rule from them.
    let log = std::fs::read_to_string(out.join("logs/model-trainer.log")).unwrap();
    let line = log
        .lines()
        .rfind(|l| l.contains("learned termination"))
        .unwrap();
    assert!(!line.contains("from 0 terminal rows"), "{line}");
    let _ = std::fs::remove_dir_all(dir);
}

/// A termination rule written in Python (batched over NumPy arrays) ends model rollouts in
/// the rollout generator's process as in `mbpo train`.
#[test]
fn lockstep_with_a_python_termination_rule_equals_the_sequential_run() {
    let mut cfg = drift_config(300, &[("terminate_beyond", 1.2.into())]);
    cfg.termination = Some("python:mbpo_test_envs:beyond_1_2".into());
    let dir = scratch("gym-python-rule");
    let out = dir.join("run");
    assert_lockstep_equals_sequential(&cfg, &dir, &out, "gympyrule");
    let log = std::fs::read_to_string(out.join("logs/rollout-generator.log")).unwrap();
    assert!(
        log.contains("python:mbpo_test_envs:beyond_1_2: termination rule up"),
        "{log}"
    );
    // The rule is in effect: without it the same run learns another policy.
    let with_rule = summary(&out)["policy_sha256"].clone();
    cfg.termination = Some("never".into());
    let never = train_mbpo(&cfg, &dir.join("never")).unwrap();
    assert_ne!(with_rule, never.policy_sha256.as_str());
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn an_env_that_raises_stops_the_run_with_a_checkpoint_of_everything_before() {
    let cfg = drift_config(300, &[("raise_at", 50.into())]);
    let dir = scratch("gym-raise");
    let input = write_config(&cfg, &dir);
    let out = dir.join("run");
    let o = run(
        &input,
        &out,
        &ipc_root("gymraise"),
        &["--mode", "pipelined"],
    );
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{err}");
    assert!(
        err.contains("actor-0's environment failed at env step 50")
            && err.contains("checkpoint after step 49")
            && err.contains("RuntimeError: Drift: failing on purpose at step 50"),
        "{err}"
    );
    assert_eq!(summary(&out)["status"], "failed");
    let (dir49, manifest) = checkpoint::latest(&out).unwrap().unwrap();
    assert_eq!(manifest.env_steps, 49, "{}", dir49.display());

    // The same under `mbpo train`: steps 1..49 are kept.
    let seq = dir.join("sequential");
    let e = train_mbpo(&cfg, &seq).unwrap_err().to_string();
    assert!(
        e.contains("failed at env step 50") && e.contains("checkpoint after step 49"),
        "{e}"
    );
    assert_eq!(checkpoint::latest(&seq).unwrap().unwrap().1.env_steps, 49);
    let _ = std::fs::remove_dir_all(dir);
}

#[test]
fn an_interpreter_that_exits_is_restarted_and_the_lost_episode_counted() {
    let dir = scratch("gym-exit");
    let marker = dir.join("exited-once");
    let kwargs = [
        ("exit_at", 30.into()),
        ("exit_marker", marker.to_str().unwrap().into()),
    ];
    let cfg = drift_config(200, &kwargs);
    let input = write_config(&cfg, &dir);
    let out = dir.join("run");
    let o = run(&input, &out, &ipc_root("gymexit"), &["--mode", "pipelined"]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(marker.exists(), "the env never exited");
    let s = summary(&out);
    assert_eq!(s["status"], "completed", "{s}");
    assert_eq!(s["episodes_lost_to_env_exit"], 1, "{s}");
    assert_no_loss(&s, 200);
    let log = std::fs::read_to_string(out.join("logs/actor-0.log")).unwrap();
    assert!(log.contains("Python process restarted (1 so far)"), "{log}");
    let _ = std::fs::remove_dir_all(dir);
}

/// An evaluation whose Python env process exits mid-episode plays that episode again in a new
/// process and the run goes on (MPC's evaluator here; SAC's and TD-MPC2's run the same loop,
/// `mbpo_train::episodes`). The training env's process takes 100 steps; the evaluator's reaches
/// its 130th in the third of its three 50-step episodes at step 100, and exits there once.
#[test]
fn an_evaluation_whose_python_env_exits_plays_the_episode_again() {
    let dir = scratch("gym-eval-exit");
    let marker = dir.join("exited-once");
    let mut cfg = tiny_mpc_config(100);
    cfg.env = "gym:mbpo_test_envs:Drift".into();
    cfg.termination = Some("never".into());
    cfg.gym.path = vec![test_envs_dir()];
    cfg.gym.max_episode_steps = Some(50);
    cfg.gym.kwargs.insert("exit_at".into(), 130.into());
    let marker_text = marker.to_str().unwrap().into();
    cfg.gym.kwargs.insert("exit_marker".into(), marker_text);
    cfg.mpc.reward = mbpo_train::PlanReward::Model;
    cfg.mpc.init_random_steps = 50;
    cfg.mpc.model_train_freq = 50;
    cfg.eval.episodes = 3;
    let run = dir.join("run");
    let summary = train_mpc(&cfg, &run).unwrap();
    assert!(marker.exists(), "the evaluator's env never exited");
    assert!(summary.final_eval_return.is_finite(), "{summary:?}");
    let rows = metrics_without_timing(&run);
    assert_eq!(rows.len(), 2, "a header and the row of step 100: {rows:?}");
    let _ = std::fs::remove_dir_all(dir);
}

/// The Python process dies with the process that started it, even by SIGKILL, also when it is
/// stuck in `step` and so never reads its closed pipe (the env here hangs in its 10th step).
#[test]
fn a_python_env_dies_with_its_actor() {
    let dir = scratch("gym-orphan");
    let stuck = dir.join("stuck");
    let marker = "mbpo_test_envs:drift_for_orphan_check";
    let mut bench = std::process::Command::new(bin_dir().join("mbpo"))
        .args([
            "bench",
            "env",
            "--seconds",
            "60",
            "--env",
            &format!("gym:{marker}"),
        ])
        .env("PYTHONPATH", test_envs_dir())
        .env("MBPO_TEST_HANG_MARKER", &stuck)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let python = || {
        let all = processes_mentioning(marker);
        all.into_iter()
            .filter(|p| p.contains("python"))
            .collect::<Vec<_>>()
    };
    let started = std::time::Instant::now();
    // Only a hang detector: on a loaded machine the interpreters of the other tests here
    // start at the same time (NumPy and Gymnasium imports take seconds each).
    while !stuck.exists() && started.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert!(stuck.exists(), "the env never reached its hanging step");
    assert_eq!(python().len(), 1, "{:?}", python());
    bench.kill().unwrap(); // SIGKILL
    bench.wait().unwrap();
    let killed = std::time::Instant::now();
    while !python().is_empty() && killed.elapsed() < Duration::from_secs(5) {
        std::thread::sleep(Duration::from_millis(50));
    }
    assert!(python().is_empty(), "orphaned: {:?}", python());
    let _ = std::fs::remove_dir_all(dir);
}

/// MPC plans with the rule of a Python env too: the learned one (the default for a gym: env)
/// reaches the planning actor with each model snapshot, so lockstep still equals the
/// sequential run; a Python rule is started by the planner; and the rule changes what MPC
/// does.
#[test]
fn mpc_plans_with_a_learned_or_a_python_termination_rule() {
    let mut cfg = tiny_mpc_config(300);
    cfg.env = "gym:mbpo_test_envs:Drift".into();
    cfg.gym.path = vec![test_envs_dir()];
    cfg.gym.max_episode_steps = Some(50);
    cfg.gym.kwargs.insert("terminate_beyond".into(), 1.2.into());
    cfg.mpc.reward = mbpo_train::PlanReward::Model;
    assert_eq!(
        cfg.termination(),
        Ok(mbpo_train::env_config::Termination::Learned)
    );
    let dir = scratch("gym-mpc-rules");
    let input = write_config(&cfg, &dir);
    bin_dir();
    let root = ipc_root("gymmpc");
    let out = dir.join("run");
    let child = spawn_run(&run_args(&input, &out, &root, &["--mode", "lockstep"]));
    let learned = train_mpc(&cfg, &dir.join("sequential")).unwrap();
    let o = wait_output(child, TIMEOUT);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(
        summary(&out)["policy_sha256"],
        learned.policy_sha256.as_str()
    );
    assert_eq!(
        metrics_without_timing(&out),
        metrics_without_timing(&dir.join("sequential"))
    );
    let log = std::fs::read_to_string(out.join("logs/model-trainer.log")).unwrap();
    let line = log.lines().rfind(|l| l.contains("learned termination"));
    assert!(
        line.is_some_and(|l| !l.contains("from 0 terminal rows")),
        "{log}"
    );

    cfg.termination = Some("python:mbpo_test_envs:beyond_1_2".into());
    let python = train_mpc(&cfg, &dir.join("python")).unwrap();
    cfg.termination = Some("never".into());
    let never = train_mpc(&cfg, &dir.join("never")).unwrap();
    assert_eq!(python.status, "completed");
    assert_ne!(
        python.policy_sha256, never.policy_sha256,
        "the rule is in effect"
    );
    let _ = std::fs::remove_dir_all(dir);
}
