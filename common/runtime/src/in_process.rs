//! The whole pipeline in one process: every role's worker on its own thread and the
//! coordinator on the caller's, on iceoryx2's `local::Service` ([`run_in_process`]). The same
//! workers and the same coordinator as `mbpo run`, without spawning binaries, so a test can run
//! the lockstep ≡ sequential oracle in the normal suite (and a debugger sees every role at
//! once). [`run_in_process_with`] picks another transport and may serve a role with a worker of
//! the caller's (`tests/tests/extension_points.rs`: a toy evaluator over `ipc_threadsafe`).

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mbpo_train::{ExperimentConfig, RunDir};
use mbpo_wire::{local, RunIpc, StopReason, Transport, WaitOutcome, Waiter};

use crate::coordinator::collect::PipelineSummary;
use crate::coordinator::{self, Coordinator, CoordinatorPorts, Phase, RunPlan};
use crate::services::{service_loop, ServiceLoop};
use crate::{configure_run, Dims, Mode, ResolvedRun, Result, RuntimeError, ServiceArgs, Slack};
use crate::{pipeline, RoleKind};

/// How to run a pipeline in this process.
#[derive(Debug, Clone)]
pub struct InProcessRun {
    /// The run directory (created; `config.toml` is written into it).
    pub out: PathBuf,
    /// Base directory of the run's iceoryx2 files.
    pub ipc_root: PathBuf,
    /// Hand-off mode.
    pub mode: Mode,
    /// Training actors (1 in lockstep).
    pub actors: u16,
    /// Slack of pipelined mode.
    pub slack: Slack,
    /// Give up after this long (a hung role fails the run instead of the test).
    pub timeout: Duration,
}

type RoleThread = (String, JoinHandle<Result<()>>);

/// Run `cfg` to its end with every role as a thread; returns the run's summary (also in
/// `<out>/summary.json`).
pub fn run_in_process(cfg: &ExperimentConfig, how: &InProcessRun) -> Result<PipelineSummary> {
    run_in_process_with::<local::Service>(cfg, how, &service_loop::<local::Service>)
}

/// [`run_in_process`] on transport `S`, each role served by `loops(kind)` (the project's own:
/// [`service_loop`]).
pub fn run_in_process_with<S: Transport>(
    cfg: &ExperimentConfig,
    how: &InProcessRun,
    loops: &dyn Fn(RoleKind) -> ServiceLoop,
) -> Result<PipelineSummary> {
    static RUNS: AtomicU64 = AtomicU64::new(0);
    let run_id = format!(
        "inproc-{}-{}",
        std::process::id(),
        RUNS.fetch_add(1, Ordering::Relaxed)
    );
    pipeline::spec(cfg.algo)?;
    let mut run_dir = RunDir::create(&how.out, cfg).map_err(|source| RuntimeError::Io {
        path: how.out.clone(),
        source,
    })?;
    let mut ipc = RunIpc::new(&run_id, &how.ipc_root)?;
    configure_run(&mut ipc);
    let result = coordinate::<S>(cfg, how, loops, &run_id, &ipc, &mut run_dir);
    // (Not when a role thread is still running on the run's services: see `join_roles`.)
    let stuck = matches!(&result, Err(RuntimeError::RolesStuck(_)));
    if !stuck {
        if let Err(e) = ipc.remove_all::<S>() {
            tracing::warn!("removing the in-process run's resources: {e}");
        }
    }
    let summary = result?;
    let text = serde_json::to_string_pretty(&summary).map_err(|e| RuntimeError::Io {
        path: how.out.join("summary.json"),
        source: e.into(),
    })?;
    std::fs::write(how.out.join("summary.json"), text + "\n").map_err(|source| {
        RuntimeError::Io {
            path: how.out.join("summary.json"),
            source,
        }
    })?;
    Ok(summary)
}

fn coordinate<S: Transport>(
    cfg: &ExperimentConfig,
    how: &InProcessRun,
    loops: &dyn Fn(RoleKind) -> ServiceLoop,
    run_id: &str,
    ipc: &RunIpc,
    run_dir: &mut RunDir,
) -> Result<PipelineSummary> {
    // The coordinator's ports first: the roles wait for the stats subscriber.
    let node = coordinator::node::<S>(ipc)?;
    // The run resolved once: every role thread reads its sizes from the plan.
    let dims = Dims::of(cfg)?;
    let pipeline = pipeline::spec(cfg.algo)?;
    ResolvedRun::new(pipeline, dims, how.mode, how.actors, how.actors, how.slack)
        .write(&how.out)?;
    let plan = RunPlan {
        pipeline,
        run_id: run_id.into(),
        mode: how.mode,
        actors: how.actors,
        slack: how.slack,
    };
    let ports = CoordinatorPorts::create(&node, &plan, &dims)?;
    let mut coord = Coordinator::new(cfg, dims, plan, &how.out, None, 0);
    let args = ServiceArgs {
        run_dir: how.out.clone(),
        run_id: run_id.into(),
        ipc_root: how.ipc_root.clone(),
        index: 0,
        mode: how.mode,
        actors: how.actors,
        slack: how.slack,
        resume_from: None,
        behind_gateway: false,
    };
    let mut threads = Vec::new();
    let started = Instant::now();
    // Whatever ends the run, every role started is told to stop and joined before the caller
    // removes the run's shared memory.
    let outcome = start_roles(cfg, &args, loops, &mut threads)
        .and_then(|()| drive(&mut coord, &ports, &mut threads, how, run_dir, started));
    coord.send_stop(&ports, threads.len(), StopReason::RunOver);
    let ended = join_roles(&mut threads, STOP_DEADLINE);
    let status = outcome?;
    ended?;
    coord.finish(status, run_dir, started)
}

/// The coordinator's loop, until every role is done (or one ended early, or the timeout);
/// the run's status: `completed`, or `solved` when `eval.stop_when_solved` stopped it.
fn drive<S: Transport>(
    coord: &mut Coordinator,
    ports: &CoordinatorPorts<S>,
    threads: &mut Vec<RoleThread>,
    how: &InProcessRun,
    run_dir: &mut RunDir,
    started: Instant,
) -> Result<&'static str> {
    let mut waiter = Waiter::new()?;
    ports.attach(&mut waiter);
    loop {
        if waiter.wait(Duration::from_millis(100))? == WaitOutcome::Terminate {
            return Err(RuntimeError::protocol("interrupted (SIGINT/SIGTERM)"));
        }
        coord.pump(ports, run_dir, started)?;
        if let Some(i) = threads.iter().position(|t| t.1.is_finished()) {
            let (name, handle) = threads.swap_remove(i);
            let why = match handle.join() {
                Ok(Ok(())) => "stopped".to_string(),
                Ok(Err(e)) => crate::error_chain(&e),
                Err(_) => "panicked".to_string(),
            };
            return Err(RuntimeError::protocol(format!(
                "{name} ended before the run finished: {why}"
            )));
        }
        if started.elapsed() > how.timeout {
            return Err(RuntimeError::protocol(format!(
                "the run did not finish within {:?}",
                how.timeout
            )));
        }
        match coord.advance(ports, run_dir, started)? {
            Phase::Finished => return Ok("completed"),
            Phase::Running => {}
            Phase::Stopped if coord.solved() => return Ok(mbpo_train::run_control::SOLVED),
            Phase::Stopped => {
                let why = coord.env_failure();
                return Err(RuntimeError::protocol(
                    why.unwrap_or("stopped at a checkpoint".into()),
                ));
            }
        }
    }
}

/// Start every role's loop on a thread of its own (ports are created on it: they are not
/// `Send`), into `threads` (which keeps those started if one cannot be).
fn start_roles(
    cfg: &ExperimentConfig,
    args: &ServiceArgs,
    loops: &dyn Fn(RoleKind) -> ServiceLoop,
    threads: &mut Vec<RoleThread>,
) -> Result<()> {
    for role in pipeline::spec(cfg.algo)?.roles(args.actors) {
        let run = loops(role.kind);
        let a = ServiceArgs {
            index: role.index,
            ..args.clone()
        };
        let handle = std::thread::Builder::new()
            .name(role.name.clone())
            .spawn(move || run(&a))
            .map_err(|source| RuntimeError::Io {
                path: Path::new("<thread>").join(&role.name),
                source,
            })?;
        threads.push((role.name, handle));
    }
    Ok(())
}

/// How long roles get to stop after the Stop before the run fails naming them.
const STOP_DEADLINE: Duration = Duration::from_secs(30);

/// Wait up to `deadline` for every role thread; the first error (or panic) is the run's. Roles
/// still running then are named in [`RuntimeError::RolesStuck`] and left detached (a thread
/// cannot be killed), so a hung role fails the run instead of hanging the caller.
fn join_roles(threads: &mut Vec<RoleThread>, deadline: Duration) -> Result<()> {
    let until = Instant::now() + deadline;
    while Instant::now() < until && threads.iter().any(|t| !t.1.is_finished()) {
        std::thread::sleep(Duration::from_millis(10));
    }
    let stuck: Vec<String> = threads
        .iter()
        .filter(|t| !t.1.is_finished())
        .map(|t| t.0.clone())
        .collect();
    if !stuck.is_empty() {
        threads.clear();
        return Err(RuntimeError::RolesStuck(stuck));
    }
    let mut first = Ok(());
    for (name, handle) in threads.drain(..) {
        let ended = match handle.join() {
            Ok(r) => r,
            Err(_) => Err(RuntimeError::protocol(format!("{name} panicked"))),
        };
        if let (Err(e), true) = (ended, first.is_ok()) {
            first = Err(RuntimeError::protocol(format!("{name}: {e}")));
        }
    }
    first
}
