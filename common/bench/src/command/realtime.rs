//! `mbpo bench realtime`: paced actors under load. Each run is a real `mbpo run --mode
//! pipelined` (its processes, its scheduling) at a control rate, once per real-time priority,
//! while busy threads at normal priority load every core; the figures are what the actors
//! measured at their own steps (`summary.json`'s `pacing`) and the ratio the learner kept.

use std::path::Path;
use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

use anyhow::Context;
use serde_json::{json, Value};

use super::RealtimeBenchArgs;
use crate::out;

pub fn run(args: &RealtimeBenchArgs) -> anyhow::Result<()> {
    std::fs::create_dir_all(&args.out)?;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let load = args.load.unwrap_or(cores);
    let mut rows = Vec::new();
    for &priority in &args.priorities {
        let dir = args.out.join(format!("priority-{priority}"));
        let hog = Hog::start(load);
        let run = run_paced(args, priority, &dir);
        hog.stop();
        let row = figures(&dir, priority, load).with_context(|| format!("{}", dir.display()))?;
        run?;
        out!("{}", serde_json::to_string(&row)?)?;
        rows.push(row);
    }
    let file = args.out.join("realtime.json");
    let report = json!({
        "machine": cpu_model(),
        "cores": cores,
        "config": args.config,
        "steps": args.steps,
        "control_hz": args.control_hz,
        "env_step_ms": args.env_step_ms,
        "busy_threads": load,
        "runs": rows,
    });
    std::fs::write(&file, serde_json::to_string_pretty(&report)? + "\n")?;
    tracing::info!("wrote {}", file.display());
    Ok(())
}

/// `mbpo run` of the config at the bench's rate with `actor.realtime_priority = priority`.
fn run_paced(args: &RealtimeBenchArgs, priority: u32, dir: &Path) -> anyhow::Result<()> {
    let exe = std::env::current_exe()?;
    let set = |k: &str, v: String| ["--set".to_string(), format!("{k}={v}")];
    let status = Command::new(exe)
        .arg("run")
        .arg("--config")
        .arg(&args.config)
        .args(["--mode", "pipelined", "--quiet", "--overwrite"])
        .args(["--steps", &args.steps.to_string()])
        .arg("--out")
        .arg(dir)
        .args(set("actor.control_hz", args.control_hz.to_string()))
        .args(set("actor.env_step_ms", args.env_step_ms.to_string()))
        .args(set("actor.realtime_priority", priority.to_string()))
        .stdout(std::process::Stdio::null())
        .status()?;
    anyhow::ensure!(status.success(), "mbpo run {}: {status}", dir.display());
    Ok(())
}

/// One run's figures from its summary and its actor's log (the scheduling it got).
fn figures(dir: &Path, priority: u32, load: usize) -> anyhow::Result<Value> {
    let summary: Value = serde_json::from_str(&std::fs::read_to_string(dir.join("summary.json"))?)?;
    let pacing = summary.get("pacing").context("no pacing in summary.json")?;
    let actor_log = std::fs::read_to_string(dir.join("logs").join("actor-0.log"))?;
    let scheduling = actor_log
        .lines()
        .find_map(|l| l.split("runs with ").nth(1).map(str::to_string))
        .or_else(|| {
            actor_log
                .contains("refused")
                .then(|| "refused: default".into())
        })
        .unwrap_or_else(|| "default".into());
    let ratios = &summary["ratios"];
    Ok(json!({
        "realtime_priority": priority,
        "scheduling": scheduling,
        "busy_threads": load,
        "wall_seconds": summary["wall_seconds"],
        "intervals": pacing["intervals"],
        "interval_error_us": pacing["interval_error_us"],
        "missed_deadlines": pacing["missed_deadlines"],
        "rests_between_episodes": pacing["rests_between_episodes"],
        "updates_per_env_step": ratios["updates_per_env_step"],
        "target_updates_per_env_step": ratios["target_updates_per_env_step"],
        "actor_policy_lag": ratios["actor_policy_lag"],
        "final_eval_return": summary["final_eval_return"],
    }))
}

/// Busy threads at normal priority (a shared machine's other work).
struct Hog {
    stop: Arc<AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl Hog {
    fn start(n: usize) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let threads = (0..n)
            .map(|_| {
                let stop = stop.clone();
                std::thread::spawn(move || {
                    let mut x = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        for _ in 0..10_000 {
                            x = std::hint::black_box(
                                x.wrapping_mul(6364136223846793005).wrapping_add(1),
                            );
                        }
                    }
                })
            })
            .collect();
        Self { stop, threads }
    }
    fn stop(self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads {
            let _ = t.join();
        }
    }
}

/// The CPU's model name (`/proc/cpuinfo`).
fn cpu_model() -> String {
    let info = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let line = info.lines().find(|l| l.starts_with("model name"));
    let name = line.and_then(|l| l.split(':').nth(1));
    name.map_or_else(|| "unknown".into(), |n| n.trim().to_string())
}
