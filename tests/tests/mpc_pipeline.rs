//! The MPC pipeline end to end (algo = "mpc": planning actors, model trainer, planning
//! evaluator; no learner, no rollout generator).

use std::time::Duration;

use mbpo_integration_tests::*;
use mbpo_train::{train_mpc, ExperimentConfig};

const TIMEOUT: Duration = Duration::from_secs(180);

fn run(
    cfg: &ExperimentConfig,
    name: &str,
    extra: &[&str],
) -> (std::path::PathBuf, serde_json::Value) {
    let dir = scratch(name);
    let input = write_config(cfg, &dir);
    let root = ipc_root(name);
    let out = dir.join("run");
    let o = wait_output(spawn_run(&run_args(&input, &out, &root, extra)), TIMEOUT);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s = summary(&out);
    assert_eq!(s["status"], "completed");
    assert_eq!(s["algo"], "mpc");
    let real = &s["real_transitions"];
    assert_eq!(real["produced"], cfg.steps, "{s}");
    assert_eq!(real["received"]["model-trainer"], cfg.steps, "{s}");
    assert_eq!(real["lost"], 0, "{s}");
    assert!(
        !out.join("logs/learner.log").exists(),
        "MPC runs spawn no SAC learner"
    );
    assert!(!out.join("logs/rollout-generator.log").exists());
    let left = leftovers(s["run_id"].as_str().unwrap(), &root);
    assert!(left.is_empty(), "shared-memory leftovers: {left:?}");
    assert_eq!(base_dir_leftovers(&root), Vec::<std::path::PathBuf>::new());
    (dir, s)
}

/// The oracle for the planning pipeline: in lockstep it equals `train_mpc` bit for bit (final
/// model, every metrics column but the timings).
#[test]
fn mpc_lockstep_equals_the_sequential_run() {
    let cfg = tiny_mpc_config(400);
    bin_dir();
    let (dir, s) = run(&cfg, "mpc-lockstep", &["--mode", "lockstep"]);
    let seq = train_mpc(&cfg, &dir.join("sequential")).unwrap();
    assert_eq!(
        s["policy_sha256"],
        seq.policy_sha256.as_str(),
        "final model differs"
    );
    assert_eq!(s["final_eval_return"], seq.final_eval_return);
    let rows = metrics_without_timing(&dir.join("run"));
    assert_eq!(rows, metrics_without_timing(&dir.join("sequential")));
    assert_eq!(
        rows.len(),
        1 + 3,
        "header + eval at 200, 300, 400: {rows:?}"
    );
    assert_eq!(s["ratios"]["model_trainings"], 3);
    assert_eq!(
        s["ratios"]["actor_policy_lag"]["max"], 0.0,
        "no model lag in lockstep"
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// Pipelined with two planning actors: completes, loses nothing, plans with a model at most
/// one version old (model lag 50 steps < the 100-step training period).
#[test]
fn mpc_pipelined_with_two_actors_completes() {
    let cfg = tiny_mpc_config(400);
    bin_dir();
    let (dir, s) = run(
        &cfg,
        "mpc-pipelined",
        &["--mode", "pipelined", "--actors", "2", "--model-lag", "50"],
    );
    let lag = &s["ratios"]["actor_policy_lag"];
    assert!(
        lag["max"].as_f64().unwrap() <= 1.0,
        "model versions behind: {lag}"
    );
    assert_eq!(metrics_without_timing(&dir.join("run")).len(), 1 + 3);
    let _ = std::fs::remove_dir_all(dir);
}
