//! Helpers for the pipeline's end-to-end tests: build the service binaries once, run
//! `mbpo run`, read what a run left behind.
//!
//! The binaries are built with `cargo build --profile test` (optimised, as the tests
//! themselves) into `target/debug`, next to each other, where the supervisor looks for them.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use mbpo_plan::PlannerKind;
use mbpo_train::{Algo, ExperimentConfig, PlanReward};

pub mod code_rules;
pub mod netns;

/// The binaries a pipeline run needs: `mbpo`, the gateway and every role's (the role table's
/// names, which are their packages' names).
pub fn binaries() -> Vec<&'static str> {
    let roles = mbpo_core::roles::ROLES.iter().map(|r| r.binary);
    let mut all: Vec<&str> = ["mbpo", "mbpo-gateway"].into_iter().chain(roles).collect();
    all.dedup();
    all
}

/// Directory holding `mbpo` and the service binaries (built on first use).
pub fn bin_dir() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
        let mut cmd = Command::new(cargo);
        // `--workspace --tests` gives the same feature unification as `cargo test --workspace`
        // (dev-dependencies active, e.g. serde_json's float_roundtrip): the libraries that run
        // built are reused and only the binaries are linked. Building just these packages'
        // binaries resolved other features and rebuilt zenoh, rustls and most crates again
        // (6 minutes of a CI run).
        cmd.current_dir(&root).args([
            "build",
            "--profile",
            "test",
            "--workspace",
            "--tests",
            "--bins",
        ]);
        // What cargo set for this test process would look like a change to build scripts that
        // watch it (ring's watches CARGO_MANIFEST_DIR) and rebuild them and all above them.
        for (key, _) in std::env::vars_os() {
            let key = key.to_string_lossy();
            let set_by_cargo_test = key.starts_with("CARGO_PKG_")
                || key.starts_with("CARGO_BIN_EXE_")
                || [
                    "CARGO_MANIFEST_DIR",
                    "CARGO_MANIFEST_PATH",
                    "CARGO_CRATE_NAME",
                    "CARGO_PRIMARY_PACKAGE",
                    "CARGO_TARGET_TMPDIR",
                    "OUT_DIR",
                ]
                .contains(&key.as_ref());
            if set_by_cargo_test {
                cmd.env_remove(key.as_ref());
            }
        }
        let status = cmd.status().expect("running cargo build");
        assert!(status.success(), "building the service binaries failed");
        // <target>/<profile>/deps/<this test> -> <target>/debug (the test profile's directory).
        let exe = std::env::current_exe().unwrap();
        let dir = exe.ancestors().nth(3).unwrap().join("debug");
        for binary in binaries() {
            assert!(
                dir.join(binary).is_file(),
                "no {binary} in {} after the build",
                dir.display()
            );
        }
        dir
    })
}

/// MBPO on Pendulum with tiny networks (as `common/train/tests/mbpo_trainer.rs`).
pub fn tiny_config(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        algo: Algo::MBPO,
        steps,
        ..Default::default()
    };
    cfg.eval.every = 200;
    cfg.eval.episodes = 3;
    cfg.sac.hidden = vec![64, 64];
    cfg.sac.batch_size = 64;
    cfg.sac.actor_lr = 1e-3;
    cfg.sac.critic_lr = 1e-3;
    cfg.sac.alpha_lr = 1e-3;
    cfg.mbpo.init_random_steps = 200;
    cfg.mbpo.epoch_length = 200;
    cfg.mbpo.model_train_freq = 100;
    cfg.mbpo.rollouts_per_step = 50;
    cfg.mbpo.rollout_schedule = [1, 15, 1, 1];
    cfg.mbpo.updates_per_step = 8;
    cfg.model.members = 4;
    cfg.model.elites = 3;
    cfg.model.hidden = vec![32, 32];
    cfg.model.weight_decay = vec![2.5e-5, 5e-5, 1e-4];
    cfg.model.batch_size = 64;
    cfg
}

/// TD-MPC2 on Pendulum with tiny networks and planner: 100 seed steps and 100 updates at the
/// last of them, then one per step; evaluations every 100 steps, checkpoints every 150.
pub fn tiny_tdmpc_config(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        algo: Algo::TDMPC,
        steps,
        ..Default::default()
    };
    cfg.eval.every = 100;
    cfg.eval.episodes = 1;
    cfg.checkpoint.every = 150;
    let t = &mut cfg.tdmpc;
    (t.latent, t.encoder_hidden, t.hidden) = (Some(16), Some(32), Some(32));
    (t.seed_steps, t.batch_size) = (100, 16);
    let p = &mut t.planner;
    (p.samples, p.policy_samples, p.elites, p.iterations) = (32, 4, 8, 2);
    cfg
}

/// MPC-CEM on Pendulum with a tiny model and planner: warm-up 100, a model every 100 steps,
/// evaluations at 200, 300, 400 (the eval point 100 is still warm-up).
pub fn tiny_mpc_config(steps: u64) -> ExperimentConfig {
    let mut cfg = ExperimentConfig {
        algo: Algo::MPC,
        steps,
        ..Default::default()
    };
    cfg.eval.every = 100;
    cfg.eval.episodes = 1;
    cfg.mpc.init_random_steps = 100;
    cfg.mpc.model_train_freq = 100;
    cfg.mpc.reward = PlanReward::Known;
    let p = &mut cfg.mpc.planner;
    p.kind = PlannerKind::Cem;
    p.horizon = 8;
    p.particles = 2;
    p.cem.candidates = 24;
    p.cem.elites = 4;
    p.cem.iterations = 2;
    cfg.model.members = 2;
    cfg.model.elites = 2;
    cfg.model.hidden = vec![16, 16];
    cfg.model.weight_decay = vec![2.5e-5, 5e-5, 1e-4];
    cfg.model.batch_size = 32;
    cfg.model.max_epochs = Some(20);
    cfg
}

/// A fresh scratch directory.
pub fn scratch(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mbpo-it-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A short per-test iceoryx2 base directory.
pub fn ipc_root(name: &str) -> PathBuf {
    PathBuf::from(format!("/tmp/mbpo-it-{}-{name}", std::process::id()))
}

/// Write `cfg` to `<dir>/config.toml`.
pub fn write_config(cfg: &ExperimentConfig, dir: &Path) -> PathBuf {
    let p = dir.join("input.toml");
    std::fs::write(&p, cfg.to_toml()).unwrap();
    p
}

/// The arguments of `mbpo run` for config `input`, run directory `out` and iceoryx2 base
/// directory `root`, then `extra`.
pub fn run_args<'a>(
    input: &'a Path,
    out: &'a Path,
    root: &'a Path,
    extra: &[&'a str],
) -> Vec<&'a str> {
    let mut args = vec![
        "--config",
        input.to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
        "--ipc-root",
        root.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    args
}

/// `mbpo run` with `args` (plus `--quiet`), not waited for.
pub fn spawn_run(args: &[&str]) -> Child {
    Command::new(bin_dir().join("mbpo"))
        .arg("run")
        .args(args)
        .arg("--quiet")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawning mbpo run")
}

/// Wait for `child` at most `timeout`; kills it and panics on timeout.
pub fn wait_output(mut child: Child, timeout: Duration) -> Output {
    let t = Instant::now();
    loop {
        if child.try_wait().unwrap().is_some() {
            return child.wait_with_output().unwrap();
        }
        if t.elapsed() > timeout {
            let _ = child.kill();
            let out = child.wait_with_output().unwrap();
            panic!(
                "the process did not finish within {timeout:?}; stderr:\n{}",
                String::from_utf8_lossy(&out.stderr)
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// `mbpo eval <run> --episodes <episodes>`: its JSON report (panics with stderr on failure).
pub fn eval_run(run: &Path, episodes: usize) -> serde_json::Value {
    let out = Command::new(bin_dir().join("mbpo"))
        .arg("eval")
        .arg(run)
        .args(["--episodes", &episodes.to_string()])
        .output()
        .expect("running mbpo eval");
    assert!(
        out.status.success(),
        "mbpo eval {}: {}",
        run.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).unwrap()
}

/// A pipelined MBPO run's summary says every one of `steps` real transitions reached every
/// consumer, none lost.
pub fn assert_no_loss(s: &serde_json::Value, steps: u64) {
    let real = &s["real_transitions"];
    assert_eq!(real["produced"], steps, "{s}");
    let consumers = mbpo_runtime::pipeline::real_consumers(Algo::MBPO);
    assert_eq!(
        consumers.len(),
        3,
        "learner, model trainer, rollout generator"
    );
    for consumer in &consumers {
        assert_eq!(real["received"][consumer], steps, "{consumer}: {s}");
    }
    assert_eq!(real["lost"], 0, "{s}");
    // Every transition went env step -> shared memory -> D_env: none waited in a consumer
    // longer than it may hold one in shared memory and had to be copied out.
    for consumer in &consumers {
        assert_eq!(real["spilled"][consumer], 0, "{consumer}: {s}");
    }
}

/// `<dir>/summary.json`.
pub fn summary(dir: &Path) -> serde_json::Value {
    let text = std::fs::read_to_string(dir.join("summary.json"))
        .unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    serde_json::from_str(&text).unwrap()
}

/// The timing columns of `metrics.csv`: they differ between any two runs.
pub const TIMING_COLUMNS: &[&str] = &["wall_seconds", "env_steps_per_sec", "updates_per_sec"];

/// The `metrics.csv` rows (header included) without the [`TIMING_COLUMNS`].
pub fn metrics_without_timing(dir: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
    let header: Vec<&str> = text.lines().next().unwrap_or_default().split(',').collect();
    for c in TIMING_COLUMNS {
        assert!(
            header.contains(c),
            "metrics.csv has no column {c}: {header:?}"
        );
    }
    let keep: Vec<bool> = header.iter().map(|h| !TIMING_COLUMNS.contains(h)).collect();
    text.lines()
        .map(|l| {
            l.split(',')
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(c, _)| c)
                .collect::<Vec<_>>()
                .join(",")
        })
        .collect()
}

/// Every iceoryx2 resource of run `run_id` under `root` that still exists (`/dev/shm` objects
/// with the run's prefix, files under its root path).
pub fn leftovers(run_id: &str, root: &Path) -> Vec<PathBuf> {
    let run = mbpo_wire::RunIpc::new(run_id, root).unwrap();
    let left = run.leftovers();
    // RunIpc::new re-created the (empty) root directory of the run.
    let _ = std::fs::remove_dir(run.root_path());
    left
}

/// Whatever is left under an iceoryx2 base directory; removes the directory.
pub fn base_dir_leftovers(root: &Path) -> Vec<PathBuf> {
    let left = std::fs::read_dir(root)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .collect();
    let _ = std::fs::remove_dir_all(root);
    left
}

pub use mbpo_runtime::processes_mentioning;

/// The pid a service logged at start (`... pid N)`).
pub fn logged_pid(log: &Path, timeout: Duration) -> Option<i32> {
    logged_pids(log, 1, timeout).map(|pids| pids[0])
}

/// The pids a service logged at each of its starts, oldest first, once there are at least
/// `n` (a restarted service appends to the same log).
pub fn logged_pids(log: &Path, n: usize, timeout: Duration) -> Option<Vec<i32>> {
    let t = Instant::now();
    while t.elapsed() < timeout {
        let pids = mbpo_runtime::pids_in_log(&std::fs::read_to_string(log).unwrap_or_default());
        if pids.len() >= n {
            return Some(pids);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    None
}

/// Every rate-limiter range of a pipeline's `summary.json` (`ratios`) lies within the bounds
/// it documents (`lowest_allowed`, `highest_allowed`; null: unbounded on that side).
pub fn assert_ratios_within_allowed(summary: &serde_json::Value) {
    let ratios = &summary["ratios"];
    for name in [
        "learner_updates_owed",
        "actor_policy_lag",
        "rollout_policy_lag",
    ] {
        let r = &ratios[name];
        if r.is_null() {
            continue;
        }
        if let Some(lowest) = r["lowest_allowed"].as_f64() {
            assert!(r["min"].as_f64().unwrap() >= lowest, "{name}: {r}");
        }
        if let Some(highest) = r["highest_allowed"].as_f64() {
            assert!(r["max"].as_f64().unwrap() <= highest, "{name}: {r}");
        }
    }
}

/// Copy the directory tree `from` to `to`.
pub fn copy_dir(from: &Path, to: &Path) {
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
