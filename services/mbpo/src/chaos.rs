//! `mbpo chaos`: runs the pipeline several times with `--restart on-failure` and SIGKILLs
//! randomly chosen processes (actor, evaluator, model trainer, rollout generator, learner) at
//! random times, then reports per run what a user must be able to trust: it completed, how
//! often it restarted, nothing was lost (every consumer received every real transition), no
//! shared memory and no process was left behind, and -- in lockstep mode -- it ended on the
//! sequential run's `policy_sha256`. One JSON line per run, one for all, and `<out>/chaos.json`.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use mbpo_core::rng::{index, stream, uniform_range_f64};
use mbpo_runtime::Mode;
use serde_json::{json, Value};

use crate::cli::ChaosArgs;

/// A kill waits at most this long for the pipeline's previous restart to be up.
const START_TIMEOUT: Duration = Duration::from_secs(300);

/// Run the chaos command.
pub fn run(args: &ChaosArgs) -> anyhow::Result<()> {
    let mut cfg = mbpo_train::ExperimentConfig::resolve(
        args.source.config.as_deref(),
        &args.source.overrides,
    )?;
    if let Some(steps) = args.steps {
        cfg.steps = steps;
    }
    if args.mode == Mode::Lockstep && args.actors != 1 {
        bail!("lockstep mode has exactly one actor: use --actors 1 or --mode pipelined");
    }
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let config = args.out.join("config.toml");
    std::fs::write(&config, cfg.to_toml())
        .with_context(|| format!("writing {}", config.display()))?;
    let reference = match args.mode {
        Mode::Lockstep => {
            Some(mbpo_train::train_mbpo(&cfg, &args.out.join("sequential"))?.policy_sha256)
        }
        Mode::Pipelined => None,
    };
    let mut reports = Vec::new();
    for r in 0..args.runs {
        let report = one_run(args, &config, &cfg, r, reference.as_deref())?;
        println!("{report}");
        reports.push(report);
    }
    let all = totals(&reports, args);
    println!("{all}");
    let file = args.out.join("chaos.json");
    let text = serde_json::to_string_pretty(&json!({"runs": reports, "totals": all}))?;
    std::fs::write(&file, text).with_context(|| format!("writing {}", file.display()))?;
    let failed = reports.iter().filter(|r| !held(r)).count();
    if failed > 0 {
        bail!(
            "{failed} of {} runs did not complete cleanly (see {}): each run's line says what failed",
            reports.len(),
            file.display()
        );
    }
    Ok(())
}

/// The processes a kill picks from.
fn kinds(actors: u16) -> Vec<String> {
    let mut kinds: Vec<String> = (0..actors).map(|i| format!("actor-{i}")).collect();
    kinds.extend(["evaluator", "model-trainer", "rollout-generator", "learner"].map(String::from));
    kinds
}

/// Run `r`: start it, kill `args.kills` processes at random points of the run, wait for its
/// end, report.
fn one_run(
    args: &ChaosArgs,
    config: &Path,
    cfg: &mbpo_train::ExperimentConfig,
    r: u64,
    reference: Option<&str>,
) -> anyhow::Result<Value> {
    let run = args.out.join(format!("run-{r}"));
    let root = &args.ipc_root;
    let _ = std::fs::remove_dir_all(&run);
    let mut child = start(args, config, &run, root)?;
    let started = Instant::now();
    let mut rng = stream(args.kill_seed, "chaos", r);
    let kinds = kinds(args.actors);
    // Kill points: env steps of the newest checkpoint, uniform over the run's first 80 % (a
    // later one may find the run already finished).
    let (first, last) = (cfg.checkpoint.every as f64, 0.8 * cfg.steps as f64);
    let mut points: Vec<u64> = (0..args.kills)
        .map(|_| uniform_range_f64(&mut rng, first, last.max(first)) as u64)
        .collect();
    points.sort_unstable();
    let mut killed = Vec::new();
    for (attempt, &point) in points.iter().enumerate() {
        let victim = &kinds[index(&mut rng, kinds.len())];
        let delay = uniform_range_f64(&mut rng, 0.0, args.max_delay_seconds);
        let when = KillAt {
            attempt,
            point,
            delay,
            end: cfg.steps,
        };
        match kill_when_up(&mut child, &run, victim, when)? {
            true => killed.push(victim.clone()),
            false => break, // the run ended first
        }
    }
    let status = child.wait().context("waiting for mbpo run")?;
    let outcome = (r, status.success(), killed, started);
    report(&run, root, cfg.steps, outcome, reference)
}

/// `mbpo run` of the config into `run`, restarting on failure, quiet, its stderr in a log.
fn start(args: &ChaosArgs, config: &Path, run: &Path, root: &Path) -> anyhow::Result<Child> {
    let exe = std::env::current_exe().context("finding the mbpo executable")?;
    std::fs::create_dir_all(root)?;
    let log = std::fs::File::create(run.with_extension("stderr.log"))?;
    Command::new(exe)
        .arg("run")
        .args(["--config".as_ref(), config.as_os_str()])
        .args(["--out".as_ref(), run.as_os_str()])
        .args(["--ipc-root".as_ref(), root.as_os_str()])
        .args([
            "--mode",
            args.mode.name(),
            "--actors",
            &args.actors.to_string(),
        ])
        .args([
            "--restart",
            "on-failure",
            "--max-restarts",
            &args.kills.to_string(),
            "--quiet",
        ])
        .stdout(Stdio::null())
        .stderr(log)
        .spawn()
        .context("starting mbpo run")
}

/// When a kill comes: in the pipeline's attempt `attempt + 1` (after `attempt` kills), once
/// the newest checkpoint is at `point` env steps or later, `delay` seconds after.
struct KillAt {
    attempt: usize,
    point: u64,
    delay: f64,
    /// The run's last step: once it is checkpointed the run is stopping, too late to kill.
    end: u64,
}

/// SIGKILL `victim` when `at` says. `Ok(false)`: the run ended (or reached its end) first.
fn kill_when_up(child: &mut Child, run: &Path, victim: &str, at: KillAt) -> anyhow::Result<bool> {
    let log = run.join("logs").join(format!("{victim}.log"));
    let attempt = at.attempt;
    let t = Instant::now();
    let pid = loop {
        if child.try_wait()?.is_some() {
            return Ok(false);
        }
        let pids = logged_pids(&log);
        let newest = mbpo_train::checkpoint::latest(run).ok().flatten();
        let reached = newest.is_some_and(|(_, m)| m.env_steps >= at.point);
        if pids.len() > attempt && reached {
            break pids[attempt];
        }
        if t.elapsed() > START_TIMEOUT {
            bail!(
                "{victim} of attempt {} did not start within {START_TIMEOUT:?}",
                attempt + 1
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    std::thread::sleep(Duration::from_secs_f64(at.delay));
    let newest = mbpo_train::checkpoint::latest(run).ok().flatten();
    if child.try_wait()?.is_some() || newest.is_some_and(|(_, m)| m.env_steps >= at.end) {
        return Ok(false);
    }
    tracing::info!("killing {victim} (pid {pid}) of attempt {}", attempt + 1);
    // SAFETY: kill(2) with a pid this run's service logged; the run is still going.
    let killed = unsafe { libc::kill(pid, libc::SIGKILL) } == 0;
    Ok(killed)
}

/// The pids a service logged at each start, oldest first.
fn logged_pids(log: &Path) -> Vec<i32> {
    mbpo_runtime::pids_in_log(&std::fs::read_to_string(log).unwrap_or_default())
}

/// One run's line: completed, kills, restarts, lost, received per consumer, final return,
/// shared memory and processes left, lockstep hash check.
fn report(
    run: &Path,
    root: &Path,
    steps: u64,
    (r, exited_ok, killed, started): (u64, bool, Vec<String>, Instant),
    reference: Option<&str>,
) -> anyhow::Result<Value> {
    let text = std::fs::read_to_string(run.join("summary.json")).unwrap_or_default();
    let s: Value = serde_json::from_str(&text).unwrap_or(Value::Null);
    let run_id = s["run_id"].as_str().unwrap_or_default();
    let real = &s["real_transitions"];
    let received_all = ["model-trainer", "rollout-generator", "learner"]
        .iter()
        .all(|c| real["received"][c] == steps);
    let shm_left = match run_id.is_empty() {
        true => Vec::new(),
        false => {
            let ipc = mbpo_wire::RunIpc::new(run_id, root)?;
            let left = ipc.leftovers();
            let _ = std::fs::remove_dir(ipc.root_path());
            left
        }
    };
    let orphans = match run_id.is_empty() {
        true => 0,
        false => mbpo_runtime::processes_mentioning(run_id).len(),
    };
    Ok(json!({
        "run": r,
        "completed": exited_ok && s["status"] == "completed",
        "killed": killed,
        "restarts": s["restarts"],
        "produced": real["produced"],
        "received": real["received"],
        "every_consumer_received_every_transition": received_all,
        "lost": real["lost"],
        "final_eval_return": s["final_eval_return"],
        "shm_left": shm_left.len(),
        "orphans": orphans,
        "policy_sha256_equals_sequential": reference.map(|h| s["policy_sha256"] == h),
        "wall_seconds": (started.elapsed().as_secs_f64() * 10.0).round() / 10.0,
        "run_dir": run,
    }))
}

/// A run completed with every transition received, nothing left behind and (lockstep) the
/// sequential policy.
fn held(r: &Value) -> bool {
    r["completed"] == true
        && r["every_consumer_received_every_transition"] == true
        && r["lost"] == 0
        && r["shm_left"] == 0
        && r["orphans"] == 0
        && r["policy_sha256_equals_sequential"] != false
}

/// The line over all runs.
fn totals(reports: &[Value], args: &ChaosArgs) -> Value {
    let count = |f: &dyn Fn(&Value) -> bool| reports.iter().filter(|r| f(r)).count();
    let sum = |key: &str| {
        reports
            .iter()
            .map(|r| r[key].as_u64().unwrap_or(0))
            .sum::<u64>()
    };
    json!({
        "mode": args.mode.name(),
        "runs": reports.len(),
        "kills_per_run": args.kills,
        "completed": count(&|r| r["completed"] == true),
        "every_transition_received": count(&|r| r["every_consumer_received_every_transition"] == true),
        "kills": reports.iter().map(|r| r["killed"].as_array().map_or(0, Vec::len)).sum::<usize>(),
        "lost": sum("lost"),
        "shm_left": sum("shm_left"),
        "orphans": sum("orphans"),
        "equal_to_sequential": (args.mode == Mode::Lockstep)
            .then(|| count(&|r| r["policy_sha256_equals_sequential"] == true)),
    })
}
