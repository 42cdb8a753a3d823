//! `mbpo chaos` ([`run`]): runs the pipeline several times with `--restart on-failure` and SIGKILLs
//! randomly chosen processes (actor, evaluator, model trainer, rollout generator, learner) at
//! random times, then reports per run what a user must be able to trust: it completed, how
//! often it restarted, nothing was lost (every consumer received every real transition), no
//! shared memory and no process was left behind, and -- in lockstep mode -- it ended on the
//! sequential run's `policy_sha256`. One JSON line per run, one for all, and `<out>/chaos.json`.
//!
//! With `--kill-supervisor` the victim is `mbpo run` itself: each kill reports how long the
//! run's processes outlived it (goal: gone within 5 s) and the shared memory it left, and the
//! run continues with `mbpo run --resume`, which must complete and remove those leftovers.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use mbpo_core::rng::{index, stream, uniform_range_f64};
use mbpo_runtime::Mode;
use serde_json::{json, Value};

/// What `mbpo chaos` is asked to do (its command line, with the `mbpo` binary that runs).
#[derive(Debug, Clone)]
pub struct ChaosPlan {
    /// Experiment config file (defaults for keys it does not set).
    pub config: Option<PathBuf>,
    /// `--set key=value` overrides, in order.
    pub overrides: Vec<String>,
    /// Total real env steps of each run (overrides the config's `steps`).
    pub steps: Option<u64>,
    /// Runs.
    pub runs: u64,
    /// SIGKILLs per run (each once the previous restart is up).
    pub kills: u32,
    /// Hand-off mode.
    pub mode: Mode,
    /// Training actors.
    pub actors: u16,
    /// A kill comes a uniform random 0..this many seconds after its kill point.
    pub max_delay_seconds: f64,
    /// Seed of the kill schedule (which process, when).
    pub kill_seed: u64,
    /// Kill `mbpo run` itself, then continue the run with `mbpo run --resume`.
    pub kill_supervisor: bool,
    /// Output directory: the runs and `chaos.json`.
    pub out: PathBuf,
    /// Base directory of the runs' iceoryx2 files.
    pub ipc_root: PathBuf,
    /// The `mbpo` executable whose `mbpo run` is tested.
    pub mbpo: PathBuf,
}

/// A kill waits at most this long for the pipeline's previous restart to be up.
const START_TIMEOUT: Duration = Duration::from_secs(300);

/// Run the chaos of `args`, handing each JSON line (one per run, one for all) to `print`.
pub fn run(
    args: &ChaosPlan,
    print: &mut dyn FnMut(&str) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    let mut cfg = mbpo_train::ExperimentConfig::resolve(args.config.as_deref(), &args.overrides)?;
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
        print(&report.to_string())?;
        reports.push(report);
    }
    let all = totals(&reports, args);
    print(&all.to_string())?;
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

/// The processes a kill picks from: every role of an MBPO pipeline with `actors` actors.
fn kinds(actors: u16) -> Vec<String> {
    let roles = mbpo_runtime::pipeline::spec(mbpo_train::Algo::MBPO).map(|p| p.roles(actors));
    roles.into_iter().flatten().map(|r| r.name).collect()
}

/// Run `r`: start it, kill `args.kills` processes at random points of the run, wait for its
/// end, report.
fn one_run(
    args: &ChaosPlan,
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
    let mut supervisor_kills = Vec::new();
    for (attempt, &point) in points.iter().enumerate() {
        let victim = &kinds[index(&mut rng, kinds.len())];
        let delay = uniform_range_f64(&mut rng, 0.0, args.max_delay_seconds);
        let when = KillAt {
            attempt,
            point,
            delay,
            end: cfg.steps,
        };
        if args.kill_supervisor {
            let Some(kill) = kill_supervisor_when_up(&mut child, &run, root, when)? else {
                break; // the run ended first
            };
            supervisor_kills.push(kill);
            killed.push(SUPERVISOR.to_string());
            child = resume(args, &run, root)?;
            continue;
        }
        match kill_when_up(&mut child, &run, victim, when)? {
            true => killed.push(victim.clone()),
            false => break, // the run ended first
        }
    }
    let status = child.wait().context("waiting for mbpo run")?;
    let outcome = Outcome {
        run: r,
        exited_ok: status.success(),
        killed,
        supervisor_kills,
        started,
    };
    report(&run, root, cfg.steps, outcome, reference)
}

/// The name a kill of `mbpo run` itself has in the reports.
const SUPERVISOR: &str = "supervisor";

/// How long the run's processes may outlive a killed `mbpo run` (the goal is 5 s: their
/// parent-death signal and their coordinator's liveness check).
const ORPHAN_DEADLINE: Duration = Duration::from_secs(5);
/// How long a kill report waits for them at most.
const ORPHAN_WAIT: Duration = Duration::from_secs(15);

/// `mbpo run` of the config into `run`, restarting on failure, quiet, its stderr in
/// `<run>.stderr.log`.
fn start(args: &ChaosPlan, config: &Path, run: &Path, root: &Path) -> anyhow::Result<Child> {
    std::fs::create_dir_all(root)?;
    let log = std::fs::File::create(run.with_extension("stderr.log"))?;
    let mut cmd = mbpo_run(args, root, log)?;
    cmd.args(["--config".as_ref(), config.as_os_str()])
        .args(["--out".as_ref(), run.as_os_str()])
        .args(["--mode", args.mode.name()])
        .args(["--actors", &args.actors.to_string()]);
    cmd.spawn().context("starting mbpo run")
}

/// `mbpo run --resume` of `run` (its mode and actors are the run's), its stderr appended to
/// the log.
fn resume(args: &ChaosPlan, run: &Path, root: &Path) -> anyhow::Result<Child> {
    let log = std::fs::OpenOptions::new()
        .append(true)
        .create(true)
        .open(run.with_extension("stderr.log"))?;
    let mut cmd = mbpo_run(args, root, log)?;
    cmd.args(["--resume".as_ref(), run.as_os_str()]);
    cmd.spawn().context("starting mbpo run --resume")
}

/// The `mbpo run` command line every run of the chaos shares: the plan's executable, the IPC root,
/// restarts on failure (one per kill), quiet, stderr into `log`.
fn mbpo_run(args: &ChaosPlan, root: &Path, log: std::fs::File) -> anyhow::Result<Command> {
    let mut cmd = Command::new(&args.mbpo);
    cmd.arg("run")
        .args(["--ipc-root".as_ref(), root.as_os_str()])
        .args(["--restart", "on-failure"])
        .args(["--max-restarts", &args.kills.to_string(), "--quiet"])
        .stdout(Stdio::null())
        .stderr(log);
    Ok(cmd)
}

/// What a SIGKILL of `mbpo run` left: its run id, how long its processes lived on, and the
/// shared-memory files nobody removed (the resumed run must).
struct SupervisorKill {
    run_id: String,
    /// Seconds from the kill until no process of the run was left (None: not within
    /// [`ORPHAN_WAIT`]).
    services_gone_seconds: Option<f64>,
    /// The run's processes still alive [`ORPHAN_DEADLINE`] after the kill.
    orphans_after_deadline: usize,
    shm_files_left: usize,
}

/// SIGKILL the supervisor (`child`) once the newest checkpoint is at `at.point` or later and
/// its learner runs, then watch its processes go. `Ok(None)`: the run ended first.
fn kill_supervisor_when_up(
    child: &mut Child,
    run: &Path,
    root: &Path,
    at: KillAt,
) -> anyhow::Result<Option<SupervisorKill>> {
    let t = Instant::now();
    let run_id = loop {
        if child.try_wait()?.is_some() {
            return Ok(None);
        }
        let newest = mbpo_train::checkpoint::latest(run).ok().flatten();
        let reached = newest.is_some_and(|(_, m)| m.env_steps >= at.point);
        let learner = logged_pids(&run.join("logs").join("learner.log"))
            .last()
            .copied();
        match learner.and_then(run_id_of) {
            Some(id) if reached => break id,
            _ => {}
        }
        if t.elapsed() > START_TIMEOUT {
            bail!(
                "the run did not reach env step {} within {START_TIMEOUT:?}",
                at.point
            );
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    std::thread::sleep(Duration::from_secs_f64(at.delay));
    let newest = mbpo_train::checkpoint::latest(run).ok().flatten();
    if child.try_wait()?.is_some() || newest.is_some_and(|(_, m)| m.env_steps >= at.end) {
        return Ok(None);
    }
    tracing::info!("killing mbpo run (pid {}) of run {run_id}", child.id());
    child.kill().context("killing mbpo run")?; // SIGKILL
    child.wait().context("reaping mbpo run")?;
    let killed = Instant::now();
    let mut orphans_after_deadline = None;
    let services_gone_seconds = loop {
        let left = mbpo_runtime::processes_mentioning(&run_id).len();
        if left == 0 {
            break Some(killed.elapsed().as_secs_f64());
        }
        if killed.elapsed() >= ORPHAN_DEADLINE && orphans_after_deadline.is_none() {
            orphans_after_deadline = Some(left);
        }
        if killed.elapsed() > ORPHAN_WAIT {
            break None;
        }
        std::thread::sleep(Duration::from_millis(20));
    };
    let shm_files_left = mbpo_wire::RunIpc::new(&run_id, root)?.leftovers().len();
    Ok(Some(SupervisorKill {
        run_id,
        services_gone_seconds,
        orphans_after_deadline: orphans_after_deadline.unwrap_or(0),
        shm_files_left,
    }))
}

/// The `--run-id` on the command line of process `pid`, if it lives.
fn run_id_of(pid: i32) -> Option<String> {
    let cmdline = std::fs::read(format!("/proc/{pid}/cmdline")).ok()?;
    let mut args = cmdline.split(|&b| b == 0).map(String::from_utf8_lossy);
    args.find(|a| a == "--run-id")?;
    args.next().map(|id| id.into_owned())
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

/// How a run went, for its report.
struct Outcome {
    run: u64,
    exited_ok: bool,
    killed: Vec<String>,
    supervisor_kills: Vec<SupervisorKill>,
    started: Instant,
}

/// One run's line: completed, kills, restarts, lost, received per consumer, final return,
/// shared memory and processes left, lockstep hash check.
fn report(
    run: &Path,
    root: &Path,
    steps: u64,
    outcome: Outcome,
    reference: Option<&str>,
) -> anyhow::Result<Value> {
    let text = std::fs::read_to_string(run.join("summary.json")).unwrap_or_default();
    let s: Value = serde_json::from_str(&text).unwrap_or(Value::Null);
    let real = &s["real_transitions"];
    let received_all = mbpo_runtime::pipeline::real_consumers(mbpo_train::Algo::MBPO)
        .iter()
        .all(|c| real["received"][c] == steps);
    // Every run id the run had: one per `mbpo run` (a resumed run gets a new one, and must
    // have removed what a killed predecessor left).
    let mut run_ids: Vec<&str> = outcome
        .supervisor_kills
        .iter()
        .map(|k| k.run_id.as_str())
        .collect();
    run_ids.extend(s["run_id"].as_str());
    let (mut shm_left, mut orphans) = (0, 0);
    for run_id in run_ids {
        let ipc = mbpo_wire::RunIpc::new(run_id, root)?;
        shm_left += ipc.leftovers().len();
        let _ = std::fs::remove_dir(ipc.root_path());
        orphans += mbpo_runtime::processes_mentioning(run_id).len();
    }
    let supervisor_kills: Vec<Value> = outcome
        .supervisor_kills
        .iter()
        .map(|k| {
            json!({
                "services_gone_seconds": k.services_gone_seconds.map(|t| (t * 100.0).round() / 100.0),
                "orphans_after_5s": k.orphans_after_deadline,
                "shm_files_left_by_the_kill": k.shm_files_left,
            })
        })
        .collect();
    let (r, started) = (outcome.run, outcome.started);
    Ok(json!({
        "run": r,
        "completed": outcome.exited_ok && s["status"] == "completed",
        "killed": outcome.killed,
        "supervisor_kills": supervisor_kills,
        "restarts": s["restarts"],
        "produced": real["produced"],
        "received": real["received"],
        "every_consumer_received_every_transition": received_all,
        "lost": real["lost"],
        "final_eval_return": s["final_eval_return"],
        "shm_left": shm_left,
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
        && r["supervisor_kills"].as_array().is_none_or(|kills| {
            kills
                .iter()
                .all(|k| k["orphans_after_5s"] == 0 && !k["services_gone_seconds"].is_null())
        })
}

/// The line over all runs.
fn totals(reports: &[Value], args: &ChaosPlan) -> Value {
    let count = |f: &dyn Fn(&Value) -> bool| reports.iter().filter(|r| f(r)).count();
    let sum = |key: &str| {
        reports
            .iter()
            .map(|r| r[key].as_u64().unwrap_or(0))
            .sum::<u64>()
    };
    let kills: Vec<&Value> = reports
        .iter()
        .flat_map(|r| r["supervisor_kills"].as_array().into_iter().flatten())
        .collect();
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
        "supervisor_kills": kills.len(),
        "orphans_after_5s": kills.iter().map(|k| k["orphans_after_5s"].as_u64().unwrap_or(0)).sum::<u64>(),
        "slowest_services_gone_seconds": kills
            .iter()
            .filter_map(|k| k["services_gone_seconds"].as_f64())
            .fold(None, |m: Option<f64>, t| Some(m.map_or(t, |m| m.max(t)))),
        "equal_to_sequential": (args.mode == Mode::Lockstep)
            .then(|| count(&|r| r["policy_sha256_equals_sequential"] == true)),
    })
}
