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
    assert_eq!(eval["checkpoint_env_steps"].as_u64(), Some(end));
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
    std::fs::remove_dir_all(dir).unwrap();
}
