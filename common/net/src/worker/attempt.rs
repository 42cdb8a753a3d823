//! One attempt of the head's pipeline on this worker: its local run directory (the run's
//! config and plan, the checkpoint files the slots resume from), its own iceoryx2 run, the
//! ports that stand in for the head's side, the to-head thread, and the role processes --
//! the ordinary binaries of the role table, with `--behind-gateway`.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use mbpo_runtime::pipeline::RoleSpec;
use mbpo_runtime::run_plan::Slot;
use mbpo_runtime::{configure_run, RuntimeError};
use mbpo_train::checkpoint;
use mbpo_wire::*;

use super::state::{Attempt, Gate, RoleProc};
use super::to_head::{to_head_loop, ToHead};
use super::WorkerOptions;
use crate::files::write_atomically;
use crate::peer::{lock, Peer};
use crate::protocol::Assignment;
use crate::{actor_weights, GatewayError};

/// The attempt's ports the main thread owns: what the head's side publishes to the roles.
pub(crate) struct LocalOut {
    /// The head's session of this attempt.
    pub head: u64,
    pub control: ControlPublisher<ipc::Service>,
    pub weights: WeightsPublisher<ipc::Service>,
    /// Subscribers of the local control channel once every role is up: each role and the
    /// to-head thread (which forwards the roles' own control messages).
    pub control_subscribers: usize,
    pub roles_listening: bool,
    pub weights_seen: u64,
    _node: WireNode<ipc::Service>,
}

fn io(p: &Path) -> impl FnOnce(std::io::Error) -> GatewayError {
    let path = p.to_path_buf();
    move |source| GatewayError::Io { path, source }
}

/// Write the attempt's run directory afresh (`<dir>/run`): config, plan, env widths, and the
/// checkpoint files its slots resume from. Returns it and the checkpoint directory.
fn write_run_dir(dir: &Path, a: &Assignment) -> Result<(PathBuf, Option<PathBuf>), GatewayError> {
    let run_dir = dir.join("run");
    if run_dir.exists() {
        std::fs::remove_dir_all(&run_dir).map_err(io(&run_dir))?;
    }
    std::fs::create_dir_all(run_dir.join("logs")).map_err(io(&run_dir))?;
    let write = |name: &str, text: &str| {
        let p = run_dir.join(name);
        std::fs::write(&p, text).map_err(io(&p))
    };
    write("config.toml", &a.config_toml)?;
    write(mbpo_runtime::run_plan::RUN_PLAN_FILE, &a.run_plan)?;
    if let Some(env) = &a.env_json {
        write(mbpo_train::run_dir::ENV_FILE, env)?;
    }
    let resume_dir = a.resume.as_ref().map(|r| {
        let dir = checkpoint::dir_for(&run_dir, r.env_steps);
        for (slot, bytes) in &r.files {
            write_atomically(&dir.join(slot.name()), bytes)?;
        }
        Ok::<_, GatewayError>(dir)
    });
    Ok((run_dir, resume_dir.transpose()?))
}

/// Set up the local run of `a` and start its roles.
pub(crate) fn start_attempt(
    gate: &Arc<Gate>,
    opts: &WorkerOptions,
    head: u64,
    a: Assignment,
    to_head: Arc<zenoh::pubsub::Publisher<'static>>,
) -> Result<LocalOut, GatewayError> {
    let me = lock(&gate.state).me;
    let (run_dir, resume_dir) = write_run_dir(&opts.dir, &a)?;
    let cfg = mbpo_runtime::process::load_config(&run_dir)?;
    let pipeline = mbpo_runtime::pipeline::spec(cfg.algo)?;
    let dims = mbpo_runtime::ResolvedRun::read(&run_dir)?.dims;
    let local_id = format!("w{:x}-{}", me & 0xffff_ffff_ffff, head & 0xffff);
    let mut ipc = RunIpc::new(&local_id, &opts.ipc_root)?;
    configure_run(&mut ipc);
    ipc.remove_stale_nodes::<ipc::Service>()
        .map_err(RuntimeError::from)?;
    let node = ipc.node::<ipc::Service>(Role::Supervisor, 0)?;
    let control = ControlPublisher::create(&node)?;
    let (kind, hash, len) = actor_weights(pipeline, &dims);
    let weights = WeightsPublisher::create(&node, kind, hash, len)?;
    let names: Vec<String> = a.slots.iter().map(|s| s.name()).collect();
    tracing::info!(
        "joined run {} ({} {}, mode {}): running {} (the run has {} actors){}",
        a.run_id,
        cfg.env,
        cfg.algo.name(),
        a.mode.name(),
        names.join(", "),
        a.actors,
        resume_dir
            .as_ref()
            .map(|d| format!(", resuming {}", d.display()))
            .unwrap_or_default()
    );
    let to = ToHead {
        run_dir: run_dir.clone(),
        ipc_root: opts.ipc_root.clone(),
        local_id: local_id.clone(),
        dims,
        slots: a.slots.clone(),
    };
    let stop = Arc::new(AtomicBool::new(false));
    let thread = start_to_head(gate, &stop, to)?;
    let launch = Launch {
        opts,
        a: &a,
        run_dir: &run_dir,
        local_id: &local_id,
        resume_dir: resume_dir.as_deref(),
    };
    let procs = a.slots.iter().map(|&s| launch.spawn(s));
    let procs = procs.collect::<Result<Vec<_>, _>>()?;
    let mut st = lock(&gate.state);
    let mut peer = Peer::new(me, head, "head".into(), to_head);
    peer.last_heard = Instant::now();
    (st.head, st.finished, st.bye_sent, st.weights_have) = (Some(peer), false, None, 0);
    let control_subscribers = a.slots.len() + 1;
    st.attempt = Some(Attempt {
        assignment: a,
        run_dir,
        ipc,
        procs,
        stop,
        to_head: Some(thread),
        rolled_back: None,
    });
    Ok(LocalOut {
        head,
        control,
        weights,
        control_subscribers,
        roles_listening: false,
        weights_seen: 0,
        _node: node,
    })
}

/// Start the attempt's to-head thread and wait until its subscribers exist.
fn start_to_head(
    gate: &Arc<Gate>,
    stop: &Arc<AtomicBool>,
    to: ToHead,
) -> Result<std::thread::JoinHandle<Result<u64, GatewayError>>, GatewayError> {
    let (tx, rx) = mpsc::channel();
    let (gate, stop) = (gate.clone(), stop.clone());
    let thread = std::thread::Builder::new()
        .name("to-head".into())
        .spawn(move || to_head_loop(&gate, &stop, &to, tx))
        .map_err(|e| GatewayError::Failed(format!("starting a thread: {e}")))?;
    match rx.recv_timeout(Duration::from_secs(30)) {
        Ok(Ok(())) => Ok(thread),
        Ok(Err(why)) => Err(GatewayError::Failed(format!("the to-head thread: {why}"))),
        Err(_) => Err(GatewayError::Failed(
            "the to-head thread did not open its ports within 30 s".into(),
        )),
    }
}

/// What starting a role process of the attempt needs.
struct Launch<'a> {
    opts: &'a WorkerOptions,
    a: &'a Assignment,
    run_dir: &'a Path,
    local_id: &'a str,
    resume_dir: Option<&'a Path>,
}

impl Launch<'_> {
    /// Start `slot`'s binary (the role table's, with its flags) behind this gateway.
    fn spawn(&self, slot: Slot) -> Result<RoleProc, GatewayError> {
        let (a, opts) = (self.a, self.opts);
        let role = RoleSpec::new(slot.kind, slot.index);
        let log = self.run_dir.join("logs").join(format!("{slot}.log"));
        let file = std::fs::File::create(&log).map_err(io(&log))?;
        let err = file.try_clone().map_err(io(&log))?;
        let bin = opts.bin_dir.join(role.binary());
        let mut cmd = Command::new(&bin);
        cmd.args(["--run-dir", &self.run_dir.display().to_string()])
            .args(["--run-id", self.local_id])
            .args(["--ipc-root", &opts.ipc_root.display().to_string()])
            .args(["--mode", a.mode.name()])
            .args(["--actors", &a.actors.to_string()])
            .args(["--policy-lag", &a.slack.policy_lag.to_string()])
            .args(["--update-buffer", &a.slack.update_buffer.to_string()])
            .args(["--model-lag", &a.slack.model_lag.to_string()])
            .arg("--behind-gateway")
            .args(role.binary_args())
            .stdin(Stdio::null())
            .stdout(file)
            .stderr(err);
        if let Some(d) = self.resume_dir {
            cmd.args(["--resume-from", &d.display().to_string()]);
        }
        let child = cmd
            .spawn()
            .map_err(|e| GatewayError::Failed(format!("starting {}: {e}", bin.display())))?;
        Ok(RoleProc {
            slot,
            child,
            log,
            log_offset: 0,
            told_to_stop: false,
            reported: false,
        })
    }
}

/// Stop an attempt's roles and thread, remove its shared memory. Returns the transition
/// batches it sent.
pub(crate) fn end_attempt(mut a: Attempt, gate: &Gate) -> u64 {
    a.stop.store(true, Ordering::Relaxed);
    gate.space.notify_all();
    for p in &mut a.procs {
        if matches!(p.child.try_wait(), Ok(None)) {
            // SAFETY: kill(2) on our own child's pid.
            unsafe { libc::kill(p.child.id() as i32, libc::SIGTERM) };
        }
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    for p in &mut a.procs {
        while matches!(p.child.try_wait(), Ok(None)) && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(20));
        }
        let _ = p.child.kill();
        let _ = p.child.wait();
    }
    let batches = a
        .to_head
        .take()
        .and_then(|t| t.join().ok())
        .and_then(Result::ok)
        .unwrap_or(0);
    let _ = a.ipc.remove_all::<ipc::Service>();
    let names: Vec<String> = a.assignment.slots.iter().map(|s| s.name()).collect();
    tracing::info!(
        "left run {} ({}); local files in {}",
        a.assignment.run_id,
        names.join(", "),
        a.run_dir.display()
    );
    batches
}
