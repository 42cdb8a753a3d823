//! `mbpo run`: the pipeline supervisor.
//!
//! Writes the resolved config into the run directory, gives the run its own iceoryx2
//! environment (unique run id -> own prefix and root path; stale resources cleaned at start,
//! everything removed and checked at the end), spawns the service binaries found next to this
//! executable (stderr -> `<run-dir>/logs/<process>.log`), reaps them, restarts the pipeline or
//! fails the run on a crash, and stops every process at the end.
//!
//! This file is the *launcher*: it starts, reaps and restarts processes. Everything the run's
//! protocol needs -- reports, rows, barriers, the stop, the summary -- is the coordinator's
//! (`mbpo_runtime::coordinator`), which talks to the roles only over the wire.
//!
//! Child processes, signals and timers are handled with plain `std::process` + `libc`: the
//! supervisor sleeps in the same [`Waiter`] as the services (stats and policy channels, 250 ms
//! timeout for reaping and the progress bar), so it needs no async runtime.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use mbpo_runtime::coordinator::checkpoints::{self, ResumePoint};
use mbpo_runtime::coordinator::collect::PipelineSummary;
use mbpo_runtime::coordinator::{self, Coordinator, CoordinatorPorts, OnSignal, Phase, RunPlan};
use mbpo_runtime::{configure_run, pipeline, realtime, remote, Mode, ResolvedRun};
use mbpo_train::progress::{Display, Progress};
use mbpo_train::RunDir;
use mbpo_wire::{ipc, RunIpc, StopReason, WaitOutcome, Waiter};

use crate::cli::{RestartPolicy, RunArgs};
use crate::train_cmd::{fresh_run_dir, overwrite_earlier_run, resolve_config, resumed_config};

/// In a service process between fork and exec: SIGTERM when the supervisor dies (kept across
/// exec), and not start at all if it died already. The service sets the signal again at start
/// (`init_service_process`), but a supervisor SIGKILLed between the fork and that line would
/// leave the service running with no one to stop it.
fn exit_with_the_supervisor(supervisor: libc::pid_t) -> std::io::Result<()> {
    // SAFETY: prctl and getppid are async-signal-safe and touch only this process.
    unsafe {
        if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        if libc::getppid() != supervisor {
            return Err(std::io::Error::from_raw_os_error(libc::ESRCH));
        }
    }
    Ok(())
}

/// One supervised process.
struct Proc {
    name: String,
    bin: PathBuf,
    args: Vec<String>,
    log: PathBuf,
    child: Option<Child>,
    exit: Option<ExitStatus>,
    cpu: Option<usize>,
}

impl Proc {
    fn spawn(&mut self) -> anyhow::Result<()> {
        let log = File::options()
            .create(true)
            .append(true)
            .open(&self.log)
            .with_context(|| format!("opening {}", self.log.display()))?;
        use std::os::unix::process::CommandExt;
        let mut command = Command::new(&self.bin);
        let supervisor = std::process::id() as libc::pid_t;
        // SAFETY: runs between fork and exec, calling only async-signal-safe functions.
        unsafe {
            command.pre_exec(move || exit_with_the_supervisor(supervisor));
        }
        let child = command
            .args(&self.args)
            // Own process group: a Ctrl-C at the terminal reaches only the supervisor, which
            // answers it with a checkpoint and a clean stop of every process.
            .process_group(0)
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log)
            .spawn()
            .map_err(|e| {
                let (bin, hint) = (self.bin.display(), build_hint(&self.bin));
                anyhow::anyhow!("starting {} ({bin}): {e}; {hint}", self.name)
            })?;
        if let Some(cpu) = self.cpu {
            pin(child.id() as i32, cpu);
        }
        tracing::debug!("started {} (pid {})", self.name, child.id());
        self.child = Some(child);
        self.exit = None;
        Ok(())
    }

    fn pid(&self) -> Option<i32> {
        self.child.as_ref().map(|c| c.id() as i32)
    }

    /// Reap if exited.
    fn poll(&mut self) -> anyhow::Result<Option<ExitStatus>> {
        let Some(c) = self.child.as_mut() else {
            return Ok(None);
        };
        if let Some(s) = c.try_wait()? {
            self.child = None;
            self.exit = Some(s);
            return Ok(Some(s));
        }
        Ok(None)
    }

    fn signal(&self, sig: i32) {
        if let Some(pid) = self.pid() {
            // SAFETY: plain kill(2) on our own child's pid (not yet reaped, so not reused).
            unsafe { libc::kill(pid, sig) };
        }
    }

    fn log_tail(&self, lines: usize) -> String {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        let all: Vec<&str> = text.lines().collect();
        all[all.len().saturating_sub(lines)..].join("\n")
    }
}

fn pin(pid: i32, cpu: usize) {
    // SAFETY: cpu_set_t is plain data; sched_setaffinity on our own child.
    unsafe {
        let mut set: libc::cpu_set_t = std::mem::zeroed();
        libc::CPU_SET(cpu, &mut set);
        if libc::sched_setaffinity(pid, std::mem::size_of::<libc::cpu_set_t>(), &set) != 0 {
            tracing::warn!("could not pin pid {pid} to cpu {cpu}");
        }
    }
}

fn ncpu() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// A run id that is unique on this host and usable in iceoryx2 names.
fn make_run_id(env: &str, seed: u64) -> String {
    let env: String = env
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '-'
            }
        })
        .collect();
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos() as u64);
    format!(
        "{env}-s{seed}-{}-{:x}",
        std::process::id(),
        nanos & 0xff_ffff
    )
}

/// `mbpo join|certs ARGS`: `mbpo-gateway join|certs ARGS` in place of this process (the
/// gateway links Zenoh; `mbpo` does not).
pub fn gateway(command: &str, args: &[String]) -> anyhow::Result<()> {
    use std::os::unix::process::CommandExt;
    let bin = std::env::current_exe()?
        .parent()
        .map(|d| d.join("mbpo-gateway"))
        .context("locating mbpo-gateway")?;
    let err = std::process::Command::new(&bin)
        .arg(command)
        .args(args)
        .exec();
    Err(anyhow::anyhow!(
        "starting {}: {err}; {}",
        bin.display(),
        build_hint(&bin)
    ))
}

/// What to do when the service binary `bin` (named as its package) cannot be started: build
/// it beside `mbpo`. deploy/build.sh builds only what a role runs (the one-host pipeline has no
/// gateway; a worker no learner), so a command run with another role's build may miss one.
fn build_hint(bin: &Path) -> String {
    let package = bin.file_name().unwrap_or(bin.as_os_str()).to_string_lossy();
    let release = bin.parent().is_some_and(|dir| dir.ends_with("release"));
    let script = if package == "mbpo-gateway" {
        "`bash deploy/build.sh head` builds it with the rest, deploy/worker.sh a worker's"
    } else {
        "`bash deploy/build.sh pipeline` builds every service of a one-host run"
    };
    format!(
        "build it next to mbpo: `cargo build {}-p {package}` ({script})",
        if release { "--release " } else { "" },
    )
}

/// Run the pipeline per `args` with the role binaries installed beside this program.
pub fn run(args: &RunArgs) -> anyhow::Result<()> {
    let bin_dir = std::env::current_exe()?
        .parent()
        .map(Path::to_path_buf)
        .context("locating the service binaries")?;
    launch(args, &bin_dir)
}

/// Run the pipeline per `args` with the role binaries in `bin_dir`. Every algorithm this
/// process knows can be launched: the run plan tells the role processes its roles.
pub fn launch(args: &RunArgs, bin_dir: &Path) -> anyhow::Result<()> {
    // iceoryx2 captures SIGINT/SIGTERM from its first look at them on: from here on a Ctrl-C
    // is not fatal (it would kill this process while it sets the run up, leaving a run
    // directory without a summary) but a request the coordinator answers once it runs: a
    // checkpoint, then a clean stop.
    mbpo_wire::termination_requested();
    let (args, cfg, out, resume) = plan_run(args)?;
    let args = &args;
    let mut run_dir = open_run_dir(args, &cfg, &out, resume.as_ref())?;
    let out = out.canonicalize()?;
    let logs = out.join("logs");
    std::fs::create_dir_all(&logs)?;
    crate::logging::also_to_file(&logs.join("supervisor.log"))?;
    crate::train_cmd::record_env(&cfg, &out)?;
    let run_id = make_run_id(&cfg.env, cfg.seed);
    let ipc = open_ipc(args, &cfg, &run_id, &out)?;
    // A resumed run's clock continues from its checkpoint.
    let elapsed = resume.as_ref().map_or(0.0, |r| r.book.elapsed_seconds);
    let now = Instant::now();
    let started = now
        .checked_sub(Duration::from_secs_f64(elapsed))
        .unwrap_or(now);
    let pipeline = pipeline::spec(cfg.algo)?;
    let cx = AttemptCtx {
        args,
        pipeline,
        remote_services: remote::remote_services(pipeline, &args.remote.remote_roles)
            .map_err(anyhow::Error::msg)?,
        cfg: &cfg,
        ipc: &ipc,
        run_id: &run_id,
        out: &out,
        logs: &logs,
        bin_dir,
        started,
    };
    let outcome = attempts(&cx, &mut run_dir, resume);
    // Every node of the run is gone now (children reaped, ours dropped): remove everything.
    let removed = ipc.remove_all::<ipc::Service>();
    let leftovers = ipc.leftovers();
    let (outcome, report) = match outcome {
        Ok((report, None)) => (Ok(()), Some(report)),
        Ok((report, Some(err))) => (Err(err), Some(report)),
        Err(e) => (Err(e), None),
    };
    match &removed {
        Ok(n) => tracing::info!("removed {n} iceoryx2 file(s) of the run"),
        Err(e) => tracing::error!("cleaning up the run's shared memory failed: {e}"),
    }
    if !leftovers.is_empty() {
        tracing::error!("shared-memory leftovers: {leftovers:?}");
    }
    if let Some(mut r) = report {
        r.ipc_files_removed = removed.as_ref().map_or(0, |n| *n);
        r.ipc_leftovers = leftovers.iter().map(|p| p.display().to_string()).collect();
        r.summary.wall_seconds = started.elapsed().as_secs_f64();
        r.hosts = std::fs::read_to_string(out.join(mbpo_runtime::HOSTS_FILE))
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok());
        let tmp = out.join("summary.json.tmp");
        std::fs::write(&tmp, serde_json::to_string_pretty(&r)? + "\n")?;
        std::fs::rename(tmp, out.join("summary.json"))?;
        crate::run_report::plot_and_point(&out);
        if outcome.is_ok() {
            println!("{}", serde_json::to_string(&r)?);
        }
    }
    outcome
}

/// The run `args` asks for: a resumed run's config, newest checkpoint (every file checked)
/// and the mode, actors and slack it ran with; or a fresh run's config and directory.
fn plan_run(
    args: &RunArgs,
) -> anyhow::Result<(
    RunArgs,
    mbpo_train::ExperimentConfig,
    PathBuf,
    Option<ResumePoint>,
)> {
    let mut args = args.clone();
    if let Some(k) = args.actors_per_core {
        args.actors = k.saturating_mul(ncpu() as u16);
    }
    // From here on `actors` counts every actor of the run, local and remote (slots
    // actors - remote_actors .. actors are remote); a resumed run has its own count.
    if args.resume.is_none() {
        args.actors = args.actors.saturating_add(args.remote.remote_actors);
    }
    let (cfg, out, resume) = match args.resume.clone() {
        Some(dir) => {
            let cfg = resumed_config(&dir, args.common.steps)?;
            let point = checkpoints::latest_verified(&dir, cfg.algo)
                .with_context(|| format!("resuming {}", dir.display()))?;
            // A checkpoint of `mbpo train` (one actor) runs on in the mode given.
            if let Some(sup) = point.supervisor {
                // The checkpoint's shape is the run's: a `--mode`, `--actors` or slack given
                // now is not used, and the log says so.
                tracing::info!(
                    "resuming {} as it was checkpointed: mode {}, {} actor(s), slack {:?} (a --mode, --actors or slack given with --resume is not used)",
                    dir.display(),
                    sup.mode.name(),
                    sup.actors,
                    sup.slack
                );
                args.mode = sup.mode;
                args.actors = sup.actors;
                args.slack = sup.slack;
            } else {
                args.actors = 1;
                tracing::info!(
                    "{} was checkpointed by `mbpo train`: resuming it with one actor, mode {}",
                    dir.display(),
                    args.mode.name()
                );
            }
            (cfg, dir, Some(point))
        }
        None => {
            // `--control-hz H` is `--set actor.control_hz=H`, after the other overrides.
            let mut common = args.common.clone();
            let pace = args.control_hz.map(|hz| format!("actor.control_hz={hz}"));
            common.source.overrides.extend(pace);
            let cfg = resolve_config(&common, None, None)?;
            check_run_args(&args, &cfg)?; // before a run directory is claimed
            let out = fresh_run_dir(&args.common, &cfg)?;
            (cfg, out, None)
        }
    };
    check_run_args(&args, &cfg)?;
    Ok((args, cfg, out, resume))
}

/// The run directory: reopened at a checkpoint, or created.
fn open_run_dir(
    args: &RunArgs,
    cfg: &mbpo_train::ExperimentConfig,
    out: &Path,
    resume: Option<&ResumePoint>,
) -> anyhow::Result<RunDir> {
    let Some(ResumePoint {
        env_steps, book, ..
    }) = resume
    else {
        overwrite_earlier_run(&args.common, cfg, out)?;
        return RunDir::create(out, cfg).with_context(|| format!("creating {}", out.display()));
    };
    // (At N = T there is nothing left to run: every process would only wait for the others'
    // last records, which an MPC run's processes already sent before the cut.)
    if *env_steps >= cfg.steps {
        bail!(
            "the checkpoint is after step {env_steps}, and the run has {} steps; give --steps N with N > {env_steps}",
            cfg.steps
        );
    }
    RunDir::reopen_with_config(out, cfg, book.rows_upto(*env_steps))
        .with_context(|| format!("reopening {}", out.display()))
}

/// A run without a live node is taken for dead only when its iceoryx2 directory is at least
/// this old: a run starting this moment has its directory but no node yet.
const DEAD_RUN_MIN_AGE: Duration = Duration::from_secs(30);

/// The run's own iceoryx2 environment, a dead predecessor's leftovers removed (its own, and
/// those of other runs that died with their launcher).
fn open_ipc(
    args: &RunArgs,
    cfg: &mbpo_train::ExperimentConfig,
    run_id: &str,
    out: &Path,
) -> anyhow::Result<RunIpc> {
    let mut ipc = RunIpc::new(run_id, &args.ipc_root)?;
    configure_run(&mut ipc);
    ipc.mark_launcher()
        .with_context(|| format!("writing the launcher file in {}", ipc.root_path().display()))?;
    let stale = ipc.remove_stale_nodes::<ipc::Service>()?;
    if stale.removed > 0 {
        tracing::warn!("removed the resources of {} dead node(s)", stale.removed);
    }
    // What runs whose launcher was killed (SIGKILL) left on this host.
    let dead = RunIpc::remove_dead_runs::<ipc::Service>(&args.ipc_root, DEAD_RUN_MIN_AGE);
    if !dead.is_empty() {
        tracing::warn!("removed what {} dead run(s) left: {dead:?}", dead.len());
    }
    tracing::info!(
        "run {run_id}: {} seed {} {} steps, mode {}, {} actor(s), run dir {}, iceoryx2 root {}",
        cfg.env,
        cfg.seed,
        cfg.steps,
        args.mode.name(),
        args.actors,
        out.display(),
        ipc.root_path().display()
    );
    Ok(ipc)
}

/// Attempts of the pipeline until one ends: a crashed process restarts the whole pipeline
/// from its newest checkpoint (`--restart on-failure`, see [`roll_back`]).
fn attempts(
    cx: &AttemptCtx,
    run_dir: &mut RunDir,
    mut resume: Option<ResumePoint>,
) -> anyhow::Result<(PipelineSummary, Option<anyhow::Error>)> {
    let mut restarts = Restarts::default();
    loop {
        match supervise(cx, run_dir, resume.take(), &restarts)? {
            Attempt::Finished(report, err) => return Ok((*report, err)),
            Attempt::RollBack { process } => {
                restarts.count(&process);
                let (dir, from) = roll_back(cx.ipc, cx.out, cx.cfg)?;
                *run_dir = dir;
                resume = from;
            }
        }
    }
}

/// How one attempt of the pipeline ended.
enum Attempt {
    /// The run ended: its report, and the error that failed it, if any.
    Finished(Box<PipelineSummary>, Option<anyhow::Error>),
    /// `process` crashed and may be restarted: every process has been stopped, and the whole
    /// pipeline starts again from the newest checkpoint (see [`roll_back`]).
    RollBack { process: String },
}

/// Restarts so far (`--restart on-failure`), per process name.
#[derive(Default)]
struct Restarts {
    per_process: std::collections::BTreeMap<String, u32>,
}

impl Restarts {
    fn of(&self, process: &str) -> u32 {
        self.per_process.get(process).copied().unwrap_or(0)
    }
    fn count(&mut self, process: &str) {
        *self.per_process.entry(process.to_string()).or_default() += 1;
    }
    fn total(&self) -> u32 {
        self.per_process.values().sum()
    }
}

/// After a crash, restart from a consistent state: the newest complete checkpoint of the run
/// (every process at "after step T with K model trainings"), or step 0 when there is none yet.
///
/// Restarting only the crashed process would not be consistent: the others have moved past
/// any state it could restart from (an actor would produce steps the learner already has, a
/// learner would miss the data it had consumed). So every process restarts from the same cut,
/// as in `mbpo run --resume`; the work since the checkpoint is done again (bit for bit the
/// same in lockstep mode), metrics rows after it are dropped, and nothing that was in the
/// checkpoint is lost. The shared memory of the stopped attempt is removed first.
fn roll_back(
    ipc: &RunIpc,
    out: &Path,
    cfg: &mbpo_train::ExperimentConfig,
) -> anyhow::Result<(RunDir, Option<ResumePoint>)> {
    let removed = ipc.remove_all::<ipc::Service>()?;
    tracing::debug!("removed {removed} iceoryx2 file(s) of the stopped attempt");
    if mbpo_train::checkpoint::latest(out)?.is_none() {
        tracing::warn!("no checkpoint yet: restarting the pipeline from step 0");
        let dir =
            RunDir::create(out, cfg).with_context(|| format!("recreating {}", out.display()))?;
        return Ok((dir, None));
    }
    let point = checkpoints::latest_verified(out, cfg.algo)
        .with_context(|| format!("rolling {} back to its newest checkpoint", out.display()))?;
    tracing::warn!(
        "restarting the pipeline from the checkpoint after step {} ({})",
        point.env_steps,
        point.dir.display()
    );
    let dir = RunDir::reopen_with_config(out, cfg, point.book.rows_upto(point.env_steps))
        .with_context(|| format!("reopening {}", out.display()))?;
    Ok((dir, Some(point)))
}

/// Everything one attempt of the pipeline needs.
struct AttemptCtx<'a> {
    args: &'a RunArgs,
    pipeline: &'static pipeline::PipelineSpec,
    /// The roles besides actors that run on worker hosts (`--remote-roles`).
    remote_services: Vec<pipeline::RoleKind>,
    cfg: &'a mbpo_train::ExperimentConfig,
    ipc: &'a RunIpc,
    run_id: &'a str,
    out: &'a Path,
    logs: &'a Path,
    bin_dir: &'a Path,
    started: Instant,
}

/// The role processes of the run, not yet started.
fn role_processes(cx: &AttemptCtx, resume: Option<&Path>) -> Vec<Proc> {
    let args = cx.args;
    let mut common: Vec<String> = vec![
        "--run-dir".into(),
        cx.out.display().to_string(),
        "--run-id".into(),
        cx.run_id.into(),
        "--ipc-root".into(),
        args.ipc_root.display().to_string(),
        "--mode".into(),
        args.mode.name().into(),
        "--actors".into(),
        args.actors.to_string(),
        "--policy-lag".into(),
        args.slack.policy_lag.to_string(),
        "--update-buffer".into(),
        args.slack.update_buffer.to_string(),
        "--model-lag".into(),
        args.slack.model_lag.to_string(),
    ];
    if let Some(dir) = resume {
        common.extend(["--resume-from".into(), dir.display().to_string()]);
    }
    let local = args.local_actors();
    let real_time = realtime::actors_run_real_time(cx.cfg, args.mode);
    let real_time_actors = if real_time { local } else { 0 };
    let roles = cx.pipeline.roles(args.actors);
    let mut procs: Vec<Proc> = roles
        .into_iter()
        .filter(|role| !(role.kind.is_actor() && role.index >= local))
        .filter(|role| !cx.remote_services.contains(&role.kind))
        .enumerate()
        .map(|(i, role)| {
            // A Python env's process inherits its actor's CPU: each env step's two wake-ups are
            // then context switches (the bridge adds ~6 us a step) instead of cross-CPU wake-ups
            // (~70 us on a 2-core VM; deploy/bench_python_bridge.sh).
            // A real-time actor pins itself to a core of its own; the others keep off it.
            let pin = args.pin_cpus || (cx.cfg.is_gym_env() && role.steps_an_env());
            let pin = pin && !(real_time && role.kind.is_actor());
            let mut a = common.clone();
            a.extend(role.binary_args());
            Proc {
                log: cx.logs.join(format!("{}.log", role.name)),
                bin: cx.bin_dir.join(role.binary()),
                name: role.name,
                args: a,
                child: None,
                exit: None,
                cpu: pin.then(|| realtime::launcher_cpu(i, real_time_actors)),
            }
        })
        .collect();
    if let Some(listen) = &args.remote.listen {
        // The remote roles' stand-in on this host (`mbpo_net::head`).
        let mut a = vec!["head".to_string()];
        a.extend(common);
        a.extend([
            "--listen".into(),
            listen.clone(),
            "--local-actors".into(),
            local.to_string(),
            "--worker-timeout".into(),
            args.remote.worker_timeout.to_string(),
        ]);
        if let Some(dir) = &args.remote.credentials {
            a.extend(["--credentials".into(), dir.display().to_string()]);
        }
        procs.push(Proc {
            log: cx.logs.join("gateway.log"),
            bin: cx.bin_dir.join("mbpo-gateway"),
            name: "gateway".into(),
            args: a,
            child: None,
            exit: None,
            cpu: None,
        });
    }
    procs
}

/// How the loop of one attempt ended.
#[derive(Default)]
struct LoopEnd {
    failure: Option<anyhow::Error>,
    crashed: Option<String>,
    interrupted: bool,
    stopped: bool,
    /// Every role is done, the final policy is in and the last step is checkpointed.
    finished: bool,
}

/// One attempt: start every role process, coordinate the run until it ends, fails, is
/// interrupted or a process crashes, then stop every process.
fn supervise(
    cx: &AttemptCtx,
    run_dir: &mut RunDir,
    resume: Option<ResumePoint>,
    restarts: &Restarts,
) -> anyhow::Result<Attempt> {
    let node = coordinator::node::<ipc::Service>(cx.ipc)?;
    // The run resolved once: the only place its sizes are computed (making the env and the
    // model); every process and gateway reads them from the plan.
    let dims = mbpo_runtime::Dims::of_run(cx.cfg, cx.out)?;
    let local = cx.args.local_actors();
    let (mode, actors, slack) = (cx.args.mode, cx.args.actors, cx.args.slack);
    let resolved = ResolvedRun::new(cx.pipeline, dims, mode, actors, local, slack)
        .with_remote_services(cx.remote_services.clone());
    resolved.write(cx.out)?;
    let plan = RunPlan {
        pipeline: cx.pipeline,
        run_id: cx.run_id.into(),
        mode: cx.args.mode,
        actors: cx.args.actors,
        slack: cx.args.slack,
    };
    let ports = CoordinatorPorts::create(&node, &plan, &dims)?;
    if let Some(p) = &resume {
        tracing::info!(
            "resuming from {} (after step {})",
            p.dir.display(),
            p.env_steps
        );
    }
    let mut procs = role_processes(cx, resume.as_ref().map(|r| r.dir.as_path()));
    for p in &mut procs {
        p.spawn()?;
    }
    let from = resume.map(|p| (p.env_steps, p.book));
    let mut coord = Coordinator::new(cx.cfg, dims, plan, cx.out, from, restarts.total());
    let end = coordinate(cx, &ports, &mut coord, &mut procs, run_dir, restarts)?;
    let why = match end.crashed {
        Some(_) => StopReason::RollBack,
        None => StopReason::RunOver,
    };
    coord.send_stop(
        &ports,
        procs.iter().filter(|p| p.child.is_some()).count(),
        why,
    );
    stop_processes(&mut procs, end.interrupted)?;
    if let Some(process) = end.crashed {
        return Ok(Attempt::RollBack { process });
    }
    let mut failure = end.failure;
    if let Some(why) = coord.env_failure() {
        // The failed actor's log ends with the environment's error (a Python traceback).
        let tail = procs.iter().find(|p| why.starts_with(&p.name));
        let tail =
            tail.map(|p| format!("; last lines of {}:\n{}", p.log.display(), p.log_tail(12)));
        failure = Some(anyhow::anyhow!("{why}{}", tail.unwrap_or_default()));
    }
    if failure.is_none() && !end.interrupted {
        failure = exit_failure(&procs, end.finished);
    }
    if end.interrupted && failure.is_none() {
        failure = Some(anyhow::anyhow!(
            "interrupted (SIGINT/SIGTERM) after {} env steps; all processes stopped",
            coord.env_steps()
        ));
    }
    let status = match (&failure, end.interrupted, end.stopped) {
        (Some(_), true, _) => "interrupted",
        (Some(_), false, _) => "failed",
        (None, _, true) if coord.solved() => mbpo_train::run_control::SOLVED,
        (None, _, true) => "stopped",
        (None, _, false) => "completed",
    };
    let report = coord.finish(status, run_dir, cx.started)?;
    Ok(Attempt::Finished(Box::new(report), failure))
}

/// The first process that exited abnormally after the Stop, as the run's failure -- unless the
/// run had `finished` (every role done, the final policy in, the last step checkpointed): then
/// nothing of it is lost, and a process killed while stopping (the OOM killer, a stray
/// SIGKILL) is only a warning.
fn exit_failure(procs: &[Proc], finished: bool) -> Option<anyhow::Error> {
    let (p, s) = procs
        .iter()
        .find_map(|p| p.exit.filter(|s| !s.success()).map(|s| (p, s)))?;
    let what = format!("{} exited with {s}; see {}", p.name, p.log.display());
    if finished {
        tracing::warn!("{what} (while stopping: the run had finished and is complete)");
        return None;
    }
    Some(anyhow::anyhow!(what))
}

/// The attempt's loop: sleep on the coordinator's ports, answer signals, let the coordinator
/// take reports and drive barriers, and watch the processes.
fn coordinate(
    cx: &AttemptCtx,
    ports: &CoordinatorPorts<ipc::Service>,
    coord: &mut Coordinator,
    procs: &mut [Proc],
    run_dir: &mut RunDir,
    restarts: &Restarts,
) -> anyhow::Result<LoopEnd> {
    let mut waiter = Waiter::new()?;
    ports.attach(&mut waiter);
    let display = match cx.args.quiet {
        true => Display::lines(),
        false => Display::auto(),
    };
    let label = format!("mbpo run {} s{}", cx.cfg.env, cx.cfg.seed);
    let mut progress = Progress::new(label, cx.cfg.steps, display);
    let mut end = LoopEnd::default();
    let mut hosts_read = Instant::now();
    let mut last_signal: Option<Instant> = None;
    loop {
        if waiter.wait(Duration::from_millis(250))? == WaitOutcome::Terminate {
            mbpo_wire::take_termination_request();
            if repeated_signal(&mut last_signal) {
                tracing::info!("a second signal within {SAME_REQUEST:?}: the same stop request");
            } else if coord.on_signal(ports)? == OnSignal::StopNow {
                end.interrupted = true;
                break;
            }
        }
        coord.pump(ports, run_dir, cx.started)?;
        coord.collector.show_progress(&mut progress);
        if cx.args.remote.listen.is_some() && hosts_read.elapsed() >= Duration::from_secs(1) {
            hosts_read = Instant::now();
            if let Some(hosts) = mbpo_runtime::LiveHosts::read(run_dir.path()) {
                let local = cx.args.local_actors();
                progress.set_hosts(hosts.progress_text(local));
            }
        }
        if let Some(crash) = first_crash(cx.args, procs, restarts)? {
            match crash {
                Crash::Restart(name) => end.crashed = Some(name),
                Crash::Fail(why) => end.failure = Some(why),
            }
            break;
        }
        match coord.advance(ports, run_dir, cx.started)? {
            Phase::Running => {}
            Phase::Finished => {
                end.finished = true;
                break;
            }
            Phase::Stopped => {
                end.stopped = true;
                break;
            }
        }
    }
    progress.finish();
    Ok(end)
}

/// Signals this close together are one request: GNU `timeout` (and some batch schedulers)
/// send SIGTERM to the process and again to its process group, and a second request would
/// stop the run at once, without the checkpoint the first one asked for. A person's second
/// Ctrl-C comes later than this.
const SAME_REQUEST: Duration = Duration::from_secs(1);

/// Whether a signal arriving now repeats the one before it (within [`SAME_REQUEST`]); a new
/// request restarts the window.
fn repeated_signal(last: &mut Option<Instant>) -> bool {
    if last.is_some_and(|t| t.elapsed() < SAME_REQUEST) {
        return true;
    }
    *last = Some(Instant::now());
    false
}

/// A process that exited before the run finished.
enum Crash {
    /// Restart the pipeline from its newest checkpoint (`--restart on-failure`).
    Restart(String),
    /// Fail the run.
    Fail(anyhow::Error),
}

/// Reap the processes; the first one that exited decides what happens.
fn first_crash(
    args: &RunArgs,
    procs: &mut [Proc],
    restarts: &Restarts,
) -> anyhow::Result<Option<Crash>> {
    for p in procs.iter_mut() {
        let Some(status) = p.poll()? else { continue };
        let tail = p.log_tail(8);
        let why = format!(
            "{} exited with {status} before the run finished; last lines of {}:\n{tail}",
            p.name,
            p.log.display()
        );
        let before = restarts.of(&p.name);
        let on_failure = args.restart == RestartPolicy::OnFailure;
        if on_failure && before < args.max_restarts {
            tracing::warn!(
                "{why}\nrestart {}/{} of {}: stopping every process to restart the pipeline from its newest checkpoint",
                before + 1,
                args.max_restarts,
                p.name
            );
            return Ok(Some(Crash::Restart(p.name.clone())));
        }
        let more = match on_failure {
            true => format!(" after {before} restart(s)"),
            false => String::new(),
        };
        return Ok(Some(Crash::Fail(anyhow::anyhow!(
            "{why}\nthe run failed{more}"
        ))));
    }
    Ok(None)
}

/// Wait for every process to exit after the Stop: SIGTERM after 3 s (at once when
/// `interrupted`), SIGKILL after 10 s.
fn stop_processes(procs: &mut [Proc], interrupted: bool) -> anyhow::Result<()> {
    if interrupted {
        procs.iter().for_each(|p| p.signal(libc::SIGTERM));
    }
    let stop_started = Instant::now();
    let mut termed = interrupted;
    loop {
        let mut alive = 0;
        for p in procs.iter_mut() {
            if p.poll()?.is_none() && p.child.is_some() {
                alive += 1;
            }
        }
        if alive == 0 {
            break;
        }
        if !termed && stop_started.elapsed() > Duration::from_secs(3) {
            tracing::warn!("{alive} process(es) ignored the stop; sending SIGTERM");
            procs.iter().for_each(|p| p.signal(libc::SIGTERM));
            termed = true;
        }
        if stop_started.elapsed() > Duration::from_secs(10) {
            tracing::error!("{alive} process(es) ignored SIGTERM; killing");
            procs.iter().for_each(|p| p.signal(libc::SIGKILL));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    tracing::info!(
        "all processes exited {:.2} s after the stop",
        stop_started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// What `mbpo run` cannot run: SAC, lockstep with several actors, no actors.
fn check_run_args(args: &RunArgs, cfg: &mbpo_train::ExperimentConfig) -> anyhow::Result<()> {
    if let Err(e) = pipeline::spec(cfg.algo) {
        bail!(
            "mbpo run: {e}; the config says algo = \"{}\"",
            cfg.algo.name()
        );
    }
    if args.mode == Mode::Lockstep && cfg.actor.control_hz > 0.0 {
        bail!("actor.control_hz = {} paces the actors of a pipelined run; lockstep takes each step with the sequential run's weights: use --mode pipelined, or actor.control_hz = 0", cfg.actor.control_hz);
    }
    let budget = cfg.mpc.planner.budget_ms;
    if args.mode == Mode::Lockstep && cfg.algo == mbpo_train::Algo::MPC && budget > 0.0 {
        bail!("mpc.planner.budget_ms = {budget} makes each plan depend on the machine's speed, and lockstep equals the sequential run bit for bit: use --mode pipelined, or budget_ms = 0");
    }
    let budget = cfg.tdmpc.planner.budget_ms;
    if args.mode == Mode::Lockstep && cfg.algo == mbpo_train::Algo::TDMPC && budget > 0.0 {
        bail!("tdmpc.planner.budget_ms = {budget} makes each plan depend on the machine's speed, and lockstep equals the sequential run bit for bit: use --mode pipelined, or budget_ms = 0");
    }
    if args.mode == Mode::Lockstep && args.actors != 1 {
        bail!("lockstep mode equals the sequential algorithm, which has exactly one actor: use --actors 1 or --mode pipelined");
    }
    if args.remote.remote_actors > args.actors {
        bail!(
            "--remote-actors {} is more than the run's {} actor(s)",
            args.remote.remote_actors,
            args.actors
        );
    }
    if args.actors == 0 {
        bail!("--actors must be at least 1 (or give --listen E --remote-actors M for actors on other hosts)");
    }
    if let Some(listen) = &args.remote.listen {
        if args.remote.remote_actors == 0 && args.remote.remote_roles.is_empty() {
            bail!("--listen {listen} admits roles of worker hosts, but none is remote: give --remote-actors M, --remote-roles evaluator, or both");
        }
    }
    let pipeline = pipeline::spec(cfg.algo)?;
    remote::remote_services(pipeline, &args.remote.remote_roles).map_err(anyhow::Error::msg)?;
    Ok(())
}
