//! `mbpo run`: the pipeline supervisor.
//!
//! Writes the resolved config into the run directory, gives the run its own iceoryx2
//! environment (unique run id -> own prefix and root path; stale resources cleaned at start,
//! everything removed and checked at the end), spawns the service binaries found next to this
//! executable (stderr -> `<run-dir>/logs/<process>.log`), reaps them, restarts or fails on a
//! crash, forwards SIGINT/SIGTERM as a Stop, and turns the services' [`StatsRecord`]s into
//! `metrics.csv` rows (same columns as `mbpo train`) and `summary.json`.
//!
//! Child processes, signals and timers are handled with plain `std::process` + `libc`: the
//! supervisor sleeps in the same [`Waiter`] as the services (stats and policy channels, 250 ms
//! timeout for reaping and the progress bar), so it needs no async runtime.

mod checkpoints;
mod collect;

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use mbpo_runtime::{configure_run, Mode};
use mbpo_train::progress::{Display, Progress};
use mbpo_train::{policy_sha256, Algo, RunDir};
use mbpo_wire::{
    ipc, ControlCommand, ControlMsg, ControlPublisher, Role, RunIpc, StatsSubscriber, WaitOutcome,
    Waiter, WeightsKind, WeightsSubscriber, CONTROL_TARGET_ALL,
};
use mbpo_wire::{policy_wire_version, Stats};

use crate::cli::{RestartPolicy, RunArgs};
use crate::train_cmd::{fresh_run_dir, overwrite_earlier_run, resolve_config, resumed_config};
use checkpoints::{Barrier, SupervisorCheckpoint};
use collect::Collector;

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
        let child = Command::new(&self.bin)
            .args(&self.args)
            // Own process group: a Ctrl-C at the terminal reaches only the supervisor, which
            // answers it with a checkpoint and a clean stop of every process.
            .process_group(0)
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log)
            .spawn()
            .with_context(|| {
                format!(
                    "starting {} ({}): build the service binaries next to mbpo (cargo build -p mbpo-actor -p mbpo-model-trainer -p mbpo-rollout-generator -p mbpo-sac-learner)",
                    self.name,
                    self.bin.display()
                )
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

/// Run the pipeline per `args`.
pub fn run(args: &RunArgs) -> anyhow::Result<()> {
    let mut args = args.clone();
    if let Some(k) = args.actors_per_core {
        args.actors = k.saturating_mul(ncpu() as u16);
    }
    // A resumed run: its config, its newest checkpoint (every file checked), and the mode,
    // actors and slack it ran with.
    let (cfg, out, resume) = match args.resume.clone() {
        Some(dir) => {
            let cfg = resumed_config(&dir, args.common.steps)?;
            let (ckpt, env_steps, state) = checkpoints::latest_verified(&dir, cfg.algo)
                .with_context(|| format!("resuming {}", dir.display()))?;
            args.mode = state.mode;
            args.actors = state.actors;
            args.slack = state.slack;
            (cfg, dir, Some((ckpt, env_steps, state)))
        }
        None => {
            let cfg = resolve_config(&args.common, None, None)?;
            check_run_args(&args, &cfg)?; // before a run directory is claimed
            let out = fresh_run_dir(&args.common, &cfg)?;
            (cfg, out, None)
        }
    };
    let args = &args;
    check_run_args(args, &cfg)?;
    let mut run_dir = match &resume {
        Some((_, env_steps, state)) => {
            // (At N = T there is nothing left to run: every process would only wait for the
            // others' last records, which an MPC run's processes already sent before the cut.)
            if *env_steps >= cfg.steps {
                bail!(
                    "the checkpoint is after step {env_steps}, and the run has {} steps; give --steps N with N > {env_steps}",
                    cfg.steps
                );
            }
            RunDir::reopen_with_config(&out, &cfg, state.book.rows_upto(*env_steps))
                .with_context(|| format!("reopening {}", out.display()))?
        }
        None => {
            overwrite_earlier_run(&args.common, &cfg, &out)?;
            RunDir::create(&out, &cfg).with_context(|| format!("creating {}", out.display()))?
        }
    };
    let out = out.canonicalize()?;
    let logs = out.join("logs");
    std::fs::create_dir_all(&logs)?;
    crate::logging::also_to_file(&logs.join("supervisor.log"))?;
    let bin_dir = std::env::current_exe()?
        .parent()
        .map(Path::to_path_buf)
        .context("locating the service binaries")?;

    let run_id = make_run_id(&cfg.env, cfg.seed);
    let mut ipc = RunIpc::new(&run_id, &args.ipc_root)?;
    configure_run(&mut ipc);
    let stale = ipc.remove_stale_nodes::<ipc::Service>()?;
    if stale.removed > 0 {
        tracing::warn!("removed the resources of {} dead node(s)", stale.removed);
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

    // A resumed run's clock continues from its checkpoint.
    let elapsed = resume.as_ref().map_or(0.0, |r| r.2.elapsed_seconds);
    let now = Instant::now();
    let started = now
        .checked_sub(Duration::from_secs_f64(elapsed))
        .unwrap_or(now);
    let mut restarts = Restarts::default();
    let mut resume = resume;
    let outcome = loop {
        let attempt = supervise(
            args,
            &cfg,
            &ipc,
            &run_id,
            &out,
            &logs,
            &bin_dir,
            &mut run_dir,
            started,
            resume.take(),
            &restarts,
        );
        match attempt {
            Ok(Attempt::Finished(report, err)) => break Ok((*report, err)),
            Err(e) => break Err(e),
            Ok(Attempt::RollBack { process }) => {
                restarts.count(&process);
                match roll_back(&ipc, &out, &cfg) {
                    Ok((dir, from)) => {
                        run_dir = dir;
                        resume = from;
                    }
                    Err(e) => break Err(e),
                }
            }
        }
    };

    // Every node of the run is gone now (children reaped, ours dropped): remove everything.
    let removed = ipc.remove_all::<ipc::Service>();
    let leftovers = ipc.leftovers();
    let (outcome, mut report) = match outcome {
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
    if let Some(r) = report.as_mut() {
        r.ipc_files_removed = removed.as_ref().map_or(0, |n| *n);
        r.ipc_leftovers = leftovers.iter().map(|p| p.display().to_string()).collect();
        r.summary.wall_seconds = started.elapsed().as_secs_f64();
        let tmp = out.join("summary.json.tmp");
        std::fs::write(&tmp, serde_json::to_string_pretty(r)? + "\n")?;
        std::fs::rename(tmp, out.join("summary.json"))?;
        if outcome.is_ok() {
            println!("{}", serde_json::to_string(r)?);
        }
    }
    outcome
}

/// A checkpoint to start from: its directory, its env steps, the supervisor's state in it.
type ResumePoint = (PathBuf, u64, SupervisorCheckpoint);

/// How one attempt of the pipeline ended.
enum Attempt {
    /// The run ended: its report, and the error that failed it, if any.
    Finished(Box<collect::PipelineSummary>, Option<anyhow::Error>),
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
    let (ckpt, env_steps, state) = checkpoints::latest_verified(out, cfg.algo)
        .with_context(|| format!("rolling {} back to its newest checkpoint", out.display()))?;
    tracing::warn!(
        "restarting the pipeline from the checkpoint after step {env_steps} ({})",
        ckpt.display()
    );
    let dir = RunDir::reopen_with_config(out, cfg, state.book.rows_upto(env_steps))
        .with_context(|| format!("reopening {}", out.display()))?;
    Ok((dir, Some((ckpt, env_steps, state))))
}

#[allow(clippy::too_many_arguments)]
fn supervise(
    args: &RunArgs,
    cfg: &mbpo_train::ExperimentConfig,
    ipc: &RunIpc,
    run_id: &str,
    out: &Path,
    logs: &Path,
    bin_dir: &Path,
    run_dir: &mut RunDir,
    started: Instant,
    resume: Option<ResumePoint>,
    restarts: &Restarts,
) -> anyhow::Result<Attempt> {
    let node = ipc.node::<ipc::Service>(Role::Supervisor, 0)?;
    let stats = StatsSubscriber::create(&node)?;
    let dims = mbpo_runtime::Dims::of(cfg)?;
    // The run's final "policy": the SAC actor (MBPO), or the last model version (MPC).
    let policy = if cfg.algo == Algo::Mpc {
        WeightsSubscriber::create(
            &node,
            WeightsKind::Model,
            dims.model.layout_hash,
            dims.model.len(),
        )?
    } else {
        WeightsSubscriber::create(
            &node,
            WeightsKind::Policy,
            dims.policy_hash,
            dims.policy_len,
        )?
    };
    let control = ControlPublisher::create(&node)?;

    let common: Vec<String> = vec![
        "--run-dir".into(),
        out.display().to_string(),
        "--run-id".into(),
        run_id.into(),
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
    let mut common = common;
    if let Some((dir, env_steps, _)) = &resume {
        tracing::info!("resuming from {} (after step {env_steps})", dir.display());
        common.extend(["--resume-from".into(), dir.display().to_string()]);
    }
    let mut procs = Vec::new();
    let mut add = |name: String, bin: &str, extra: Vec<String>| {
        let mut a = common.clone();
        a.extend(extra);
        let cpu = args.pin_cpus.then(|| procs.len() % ncpu());
        procs.push(Proc {
            log: logs.join(format!("{name}.log")),
            name,
            bin: bin_dir.join(bin),
            args: a,
            child: None,
            exit: None,
            cpu,
        });
    };
    // MPC plans on the model trainer's ensemble: no SAC learner, no rollout generator.
    let mpc = cfg.algo == Algo::Mpc;
    if !mpc {
        add("learner".into(), "mbpo-sac-learner", vec![]);
    }
    add("model-trainer".into(), "mbpo-model-trainer", vec![]);
    if !mpc {
        add("rollout-generator".into(), "mbpo-rollout-generator", vec![]);
    }
    add("evaluator".into(), "mbpo-actor", vec!["--eval".into()]);
    for i in 0..args.actors {
        add(
            format!("actor-{i}"),
            "mbpo-actor",
            vec!["--index".into(), i.to_string()],
        );
    }
    for p in &mut procs {
        p.spawn()?;
    }

    let mut col = Collector::new(cfg, args, run_id);
    let schedule = mbpo_train::roles::Schedule::of(cfg);
    let every = cfg.checkpoint.every;
    let mut next_checkpoint = every;
    if let Some((_, env_steps, state)) = resume {
        col.restore(state.book);
        next_checkpoint = env_steps + every;
    }
    col.book.restarts = restarts.total();
    let mut barrier: Option<Barrier> = None;
    let mut stopped = false;
    let final_wire = if cfg.algo == Algo::Mpc {
        let schedule = mbpo_train::roles::Schedule::of(cfg);
        schedule.train_points_upto(cfg.steps)
    } else {
        policy_wire_version(cfg.steps)
    };
    // An MPC run shorter than its warm-up trains no model: nothing to wait for.
    let mut final_params: Option<Vec<f32>> = (final_wire == 0).then(Vec::new);
    let mut waiter = Waiter::new()?;
    waiter.attach(&stats).attach(&policy);
    let display = if args.quiet {
        Display::lines()
    } else {
        Display::auto()
    };
    let label = format!("mbpo run {} s{}", cfg.env, cfg.seed);
    let mut progress = Progress::new(label, cfg.steps, display);
    let mut failure: Option<anyhow::Error> = None;
    let mut crashed: Option<String> = None;
    let mut interrupted = false;
    let mut finishing = false;
    loop {
        if waiter.wait(Duration::from_millis(250))? == WaitOutcome::Terminate {
            mbpo_wire::take_termination_request();
            let state = RunState {
                barrier: barrier.as_ref().map(|b| b.stop_after),
                all_done: col.all_done(args.actors),
                actors_done: col.actors_done(args.actors),
                finishing,
            };
            match on_signal(state) {
                OnSignal::CheckpointAndStop => {
                    tracing::warn!("stopping: writing a checkpoint first (press Ctrl-C again to stop at once, without one)");
                    barrier = Some(start_barrier(&control, cfg.algo, args.actors, true)?);
                }
                OnSignal::StopAfterBarrier => {
                    tracing::warn!("stopping after the checkpoint under way (press Ctrl-C again to stop at once)");
                    if let Some(b) = barrier.as_mut() {
                        b.stop_after = true;
                    }
                    send_pause(&control, true)?;
                }
                OnSignal::Finish => {
                    tracing::warn!("the actors are done: finishing the run's last updates and evaluations (press Ctrl-C again to stop at once, without a checkpoint)");
                    finishing = true;
                }
                OnSignal::StopNow => {
                    interrupted = true;
                    break;
                }
            }
        }
        loop {
            match stats.receive() {
                Ok(Some(r)) => match (Stats::decode(&r.msg), barrier.as_mut()) {
                    (Ok(Stats::Barrier(report)), Some(b)) => b.on_report(r.producer(), report),
                    (Ok(Stats::Barrier(report)), None) => {
                        tracing::warn!("{}: {report:?} outside a barrier", r.producer())
                    }
                    (Ok(stats), _) => col.on_stats(r.producer(), stats),
                    (Err(e), _) => tracing::warn!("stats from {}: {e}", r.producer()),
                },
                Ok(None) => break,
                Err(e) => tracing::warn!("stats: {e}"),
            }
        }
        match policy.receive_latest() {
            Ok(Some(w)) if w.version() == final_wire => final_params = Some(w.params().to_vec()),
            Ok(_) => {}
            Err(e) => tracing::warn!("policy: {e}"),
        }
        col.write_rows(run_dir, started)?;
        col.show_progress(&mut progress);
        for p in procs.iter_mut() {
            let Some(status) = p.poll()? else { continue };
            let tail = p.log_tail(8);
            let why = format!(
                "{} exited with {status} before the run finished; last lines of {}:\n{tail}",
                p.name,
                p.log.display()
            );
            let before = restarts.of(&p.name);
            if args.restart == RestartPolicy::OnFailure && before < args.max_restarts {
                tracing::warn!(
                    "{why}\nrestart {}/{} of {}: stopping every process to restart the pipeline from its newest checkpoint",
                    before + 1,
                    args.max_restarts,
                    p.name
                );
                crashed = Some(p.name.clone());
            } else {
                let more = if args.restart == RestartPolicy::OnFailure {
                    format!(" after {before} restart(s)")
                } else {
                    String::new()
                };
                failure = Some(anyhow::anyhow!("{why}\nthe run failed{more}"));
            }
            break;
        }
        if failure.is_some() || crashed.is_some() {
            break;
        }
        if col.all_done(args.actors) && final_params.is_some() {
            break;
        }
        // Periodic checkpoints (`[checkpoint] every` env steps).
        if barrier.is_none()
            && every > 0
            && col.env_steps() >= next_checkpoint
            && !col.all_done(args.actors)
        {
            barrier = Some(start_barrier(&control, cfg.algo, args.actors, false)?);
        }
        if let Some(b) = barrier.as_mut() {
            if let Some(cut) = b.take_cut(&schedule, args.mode) {
                tracing::info!(
                    "checkpoint cut: after step {} with {} model trainings",
                    cut.env_steps,
                    cut.model_trainings
                );
                control.send(&ControlMsg::request(
                    ControlCommand::Checkpoint,
                    cut.model_trainings,
                    CONTROL_TARGET_ALL,
                    cut.env_steps,
                ))?;
            }
            if let Some(cut) = b.complete() {
                col.write_rows(run_dir, started)?;
                let missing = col.missing_at_cut(cut.env_steps);
                anyhow::ensure!(
                    missing == 0,
                    "checkpoint after step {}: the records of {missing} eval point(s) up to it are not in",
                    cut.env_steps
                );
                let state = SupervisorCheckpoint {
                    mode: args.mode,
                    actors: args.actors,
                    slack: args.slack,
                    book: col.book_at(cut.env_steps),
                    elapsed_seconds: started.elapsed().as_secs_f64(),
                };
                checkpoints::finish(out, cfg.algo, cut, &state, cfg.checkpoint.keep)?;
                tracing::info!(
                    "checkpoint after step {} complete ({:.2} s barrier): {}",
                    cut.env_steps,
                    b.started.elapsed().as_secs_f64(),
                    mbpo_train::checkpoint::dir_for(out, cut.env_steps).display()
                );
                next_checkpoint = cut.env_steps + every.max(1);
                if b.stop_after {
                    stopped = true;
                    break;
                }
                control.send(&ControlMsg::request(
                    ControlCommand::Resume,
                    cut.model_trainings,
                    CONTROL_TARGET_ALL,
                    cut.env_steps,
                ))?;
                barrier = None;
            } else if b.started.elapsed() > checkpoints::BARRIER_WARN_AFTER * (b.warnings + 1) {
                b.warnings += 1;
                tracing::warn!("checkpoint barrier still waiting for {}", b.waiting_for());
            }
        }
    }
    progress.finish();
    // Stop everyone: a Stop message (services wait for it after their work), SIGTERM after 3 s,
    // SIGKILL after 10 s.
    let _ = control.wait_for_subscribers(
        procs.iter().filter(|p| p.child.is_some()).count(),
        Duration::from_secs(2),
    );
    if let Err(e) = control.send(&ControlMsg::request(
        ControlCommand::Stop,
        1,
        CONTROL_TARGET_ALL,
        cfg.steps,
    )) {
        tracing::warn!("sending stop: {e}");
    }
    if interrupted {
        for p in &procs {
            p.signal(libc::SIGTERM);
        }
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
    drop(waiter);
    if let Some(process) = crashed {
        return Ok(Attempt::RollBack { process });
    }
    for p in &procs {
        if let Some(s) = p.exit {
            if !s.success() && failure.is_none() && !interrupted {
                failure = Some(anyhow::anyhow!(
                    "{} exited with {s}; see {}",
                    p.name,
                    p.log.display()
                ));
            }
        }
    }
    if interrupted && failure.is_none() {
        failure = Some(anyhow::anyhow!(
            "interrupted (SIGINT/SIGTERM) after {} env steps; all processes stopped",
            col.env_steps()
        ));
    }
    let status = if failure.is_some() {
        if interrupted {
            "interrupted"
        } else {
            "failed"
        }
    } else if stopped {
        "stopped"
    } else {
        "completed"
    };
    // MPC: the model snapshot is θ | normaliser | elites; `train_mpc` hashes θ.
    let hashed = if cfg.algo == Algo::Mpc {
        dims.model.n_params
    } else {
        dims.policy_len
    };
    let sha = final_params
        .as_deref()
        .map(|p| policy_sha256(&p[..hashed.min(p.len())]))
        .unwrap_or_default();
    // The policy the run ended with: periodic checkpoints rarely fall on the last step.
    if let (Some(p), "completed", false) = (&final_params, status, cfg.algo == Algo::Mpc) {
        let actor = &p[..hashed.min(p.len())];
        mbpo_train::policy_file::write_final_policy(out, col.env_steps(), actor)?;
    }
    let to_target = run_dir.env_steps_to_target(cfg.target_return())?;
    let report = col.summary(status, sha, started, to_target);
    Ok(Attempt::Finished(Box::new(report), failure))
}

/// What `mbpo run` cannot run: SAC, lockstep with several actors, no actors.
fn check_run_args(args: &RunArgs, cfg: &mbpo_train::ExperimentConfig) -> anyhow::Result<()> {
    if cfg.algo == Algo::Sac {
        bail!("mbpo run runs MBPO or MPC; the config says algo = \"sac\" (use `mbpo train --algo sac` for the SAC baseline)");
    }
    if args.mode == Mode::Lockstep && args.actors != 1 {
        bail!("lockstep mode equals the sequential algorithm, which has exactly one actor: use --actors 1 or --mode pipelined");
    }
    if args.actors == 0 {
        bail!("--actors must be at least 1");
    }
    Ok(())
}

/// What the supervisor knows when a SIGINT/SIGTERM arrives.
#[derive(Debug, Clone, Copy)]
struct RunState {
    /// The checkpoint barrier under way, if any: whether the run stops after it.
    barrier: Option<bool>,
    /// Every process sent its Done record.
    all_done: bool,
    /// Every actor sent its Done record.
    actors_done: bool,
    /// An earlier signal chose [`OnSignal::Finish`].
    finishing: bool,
}

/// What a SIGINT/SIGTERM does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum OnSignal {
    /// Write a checkpoint, then stop (resumable with `--resume`).
    CheckpointAndStop,
    /// A periodic checkpoint is under way: stop after it.
    StopAfterBarrier,
    /// Every actor is done: a checkpoint would be at the run's last step, which no resume
    /// continues (`--resume` needs steps left), while what is left -- the learner's last
    /// updates, the last evaluations -- is short. Finish the run instead.
    Finish,
    /// A second signal, or nothing left to do: stop at once, without a checkpoint.
    StopNow,
}

fn on_signal(run: RunState) -> OnSignal {
    match run.barrier {
        _ if run.finishing => OnSignal::StopNow,
        // A periodic barrier at the last step resumes the run, which then finishes.
        Some(false) | None if run.actors_done && !run.all_done => OnSignal::Finish,
        Some(false) => OnSignal::StopAfterBarrier,
        None if !run.all_done => OnSignal::CheckpointAndStop,
        Some(true) | None => OnSignal::StopNow,
    }
}

/// Broadcast the Pause that starts a checkpoint barrier.
fn start_barrier(
    control: &ControlPublisher<ipc::Service>,
    algo: Algo,
    actors: u16,
    stop_after: bool,
) -> anyhow::Result<Barrier> {
    send_pause(control, stop_after)?;
    Ok(Barrier::new(algo, actors, stop_after))
}

/// Broadcast a Pause, saying whether the run stops after the barrier (processes may then
/// abandon work the cut does not need, such as a model training under way).
fn send_pause(control: &ControlPublisher<ipc::Service>, stop_after: bool) -> anyhow::Result<()> {
    let to_stop = if stop_after {
        mbpo_runtime::barrier::PAUSE_TO_STOP
    } else {
        0
    };
    control.send(&ControlMsg::request(
        ControlCommand::Pause,
        to_stop,
        CONTROL_TARGET_ALL,
        0,
    ))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn state(barrier: Option<bool>, actors_done: bool, all_done: bool) -> RunState {
        RunState {
            barrier,
            all_done,
            actors_done,
            finishing: false,
        }
    }

    #[test]
    fn a_signal_checkpoints_unless_the_actors_are_done_then_the_run_finishes() {
        use OnSignal::*;
        let cases = [
            // (barrier under way, actors done, all done) -> first signal
            (None, false, false, CheckpointAndStop),
            (Some(false), false, false, StopAfterBarrier),
            (Some(true), false, false, StopNow),
            (None, true, false, Finish),
            (Some(false), true, false, Finish),
            (None, true, true, StopNow),
            (Some(false), true, true, StopAfterBarrier),
        ];
        for (barrier, actors_done, all_done, want) in cases {
            let run = state(barrier, actors_done, all_done);
            assert_eq!(on_signal(run), want, "{run:?}");
        }
        // A second signal while finishing stops at once.
        let finishing = RunState {
            finishing: true,
            ..state(None, true, false)
        };
        assert_eq!(on_signal(finishing), StopNow);
    }
}
