//! A worker host's gateway (`mbpo join`): joins a head, runs the actors it is given as local
//! processes on the worker's own iceoryx2, and carries their channels over the link.
//!
//! The actors are the ordinary `mbpo-actor` binaries with `--behind-gateway` (their only
//! consumer is this gateway). Three threads:
//! * **main** receives from the head: the assignment (config, slots, checkpoint files), control
//!   commands (republished to each actor), weight snapshots (republished when newer), and
//!   acknowledgements;
//! * **to-head**, one per attempt, sleeps on the local transitions and reports and puts them
//!   into the reliable stream (an actor's checkpoint file goes before the report that it was
//!   written); a full window makes it, and so the actors, wait;
//! * **heartbeat** sends heartbeats and the actors' new log lines, resends a stalled stream,
//!   watches the actor processes (one that ends without being told to is reported, and the head
//!   restarts the pipeline from its checkpoint) and the head (silent for `--head-timeout`: the
//!   actors stop and the worker joins again).
//!
//! A head whose session changes has restarted (a new attempt of the pipeline): the worker
//! stops its actors, forgets the old stream, and joins again; the new assignment brings the
//! checkpoint its actors resume from.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use mbpo_runtime::{configure_run, Dims, RuntimeError};
use mbpo_train::checkpoint;
use mbpo_train::run_files::actor_file;
use mbpo_wire::*;
use zenoh::Wait;

use crate::link::Accept;
use crate::peer::{lock, publisher, wait_until, Peer, HEARTBEAT_PERIOD};
use crate::protocol::{decode, Assignment, Body, Envelope, Item, WeightsMsg};
use crate::session::{self, NetOptions, Side};
use crate::{actor_weights, GatewayError};

/// A worker not yet in a run says hello this often: it joins within this of the head starting
/// (a hello is a few bytes; once a second made every remote run start up to 1 s late).
const HELLO_PERIOD: Duration = Duration::from_millis(200);

/// What `mbpo join` is given.
#[derive(Debug, Clone)]
pub struct WorkerOptions {
    /// The head's endpoint and this worker's credentials.
    pub net: NetOptions,
    /// Actors offered.
    pub actors: u16,
    /// This worker's name (host name by default).
    pub name: String,
    /// Where the actors' run directory and logs go.
    pub dir: PathBuf,
    /// Base directory of the local iceoryx2 root.
    pub ipc_root: PathBuf,
    /// Where `mbpo-actor` is.
    pub bin_dir: PathBuf,
    /// A head silent this long is taken for gone: stop the actors and join again.
    pub head_timeout: Duration,
}

/// How a worker's run ended.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct WorkerReport {
    /// The head's run id.
    pub run_id: String,
    /// Actor slots run in the last attempt.
    pub slots: Vec<u16>,
    /// Attempts joined (a head restart is a new one).
    pub attempts: u32,
    /// Transition batches sent in the last attempt.
    pub batches_sent: u64,
    /// Messages of the stream sent more than once.
    pub resent: u64,
    /// Weight snapshots published to the actors.
    pub weights_applied: u64,
    /// Latency of a weight snapshot from its publisher on the head to this host's shared
    /// memory, milliseconds: median and 99th percentile (host clocks must agree).
    pub weights_latency_ms_p50: f64,
    /// See `weights_latency_ms_p50`.
    pub weights_latency_ms_p99: f64,
}

/// One actor process.
struct ActorProc {
    slot: u16,
    child: Child,
    log: PathBuf,
    log_offset: u64,
    told_to_stop: bool,
    reported: bool,
}

/// One attempt: the slots of one head session.
struct Attempt {
    assignment: Assignment,
    run_dir: PathBuf,
    ipc: RunIpc,
    actors: Vec<ActorProc>,
    stop: Arc<AtomicBool>,
    to_head: Option<std::thread::JoinHandle<Result<u64, GatewayError>>>,
    /// When the head's supervisor rolled this attempt back (a process of the head crashed):
    /// once the actors have exited the worker leaves it and joins the next attempt.
    rolled_back: Option<Instant>,
}

struct Shared {
    me: u64,
    head: Option<Peer>,
    attempt: Option<Attempt>,
    finished: bool,
    /// When [`Item::Bye`] went into the stream.
    bye_sent: Option<Instant>,
    weights_have: u64,
    failure: Option<String>,
}

struct Gate {
    state: Mutex<Shared>,
    space: Condvar,
    quit: AtomicBool,
}

/// Join the head at `opts.net.endpoint` and run actors for it until its run ends.
pub fn run_worker(opts: &WorkerOptions) -> Result<WorkerReport, GatewayError> {
    let session = session::open(Side::Worker, &opts.net)?;
    let me = session::new_session_id();
    let to_head = publisher(&session, session::worker_to_head(me))?;
    let sub = session
        .declare_subscriber(session::head_to_worker(me))
        .wait()
        .map_err(|e| GatewayError::Zenoh(format!("subscribing: {e}")))?;
    tracing::info!(
        "worker {} ({me:016x}): joining {} with {} actor(s) (pid {})",
        opts.name,
        opts.net.endpoint,
        opts.actors,
        std::process::id()
    );
    let gate = Arc::new(Gate {
        state: Mutex::new(Shared {
            me,
            head: None,
            attempt: None,
            finished: false,
            bye_sent: None,
            weights_have: 0,
            failure: None,
        }),
        space: Condvar::new(),
        quit: AtomicBool::new(false),
    });
    let heart = {
        let (gate, opts) = (gate.clone(), opts.clone());
        std::thread::Builder::new()
            .name("heartbeat".into())
            .spawn(move || heartbeat(&gate, &opts))
            .map_err(|e| GatewayError::Failed(format!("starting a thread: {e}")))?
    };
    let mut report = WorkerReport::default();
    let mut latencies = Vec::new();
    let result = receive(&gate, &sub, &to_head, opts, &mut report, &mut latencies);
    report.weights_applied = latencies.len() as u64;
    latencies.sort_by(f64::total_cmp);
    let pct = |q: f64| {
        latencies
            .get(((latencies.len() as f64 - 1.0) * q).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    (report.weights_latency_ms_p50, report.weights_latency_ms_p99) = (pct(0.5), pct(0.99));
    gate.quit.store(true, Ordering::Relaxed);
    gate.space.notify_all();
    let _ = heart.join();
    // (Not under the lock: ending an attempt joins its to-head thread, which takes it.)
    let (attempt, resent) = {
        let mut st = lock(&gate.state);
        (st.attempt.take(), st.head.as_ref().map_or(0, Peer::resent))
    };
    report.resent += resent;
    if let Some(a) = attempt {
        report.batches_sent = end_attempt(a, &gate);
    }
    let _ = session.close().wait();
    result.map(|()| report)
}

/// Local ports of the current attempt owned by the main thread.
struct LocalOut {
    head: u64,
    control: ControlPublisher<ipc::Service>,
    weights: WeightsPublisher<ipc::Service>,
    slots: usize,
    actors_listening: bool,
    weights_seen: u64,
    _node: WireNode<ipc::Service>,
}

fn receive(
    gate: &Arc<Gate>,
    sub: &zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
    to_head: &Arc<zenoh::pubsub::Publisher<'static>>,
    opts: &WorkerOptions,
    report: &mut WorkerReport,
    latencies: &mut Vec<f64>,
) -> Result<(), GatewayError> {
    let me = lock(&gate.state).me;
    let hello = crate::protocol::encode(&Envelope {
        version: crate::protocol::PROTOCOL_VERSION,
        session: me,
        body: Body::Hello {
            worker: opts.name.clone(),
            actors: opts.actors,
        },
    });
    let mut last_hello: Option<Instant> = None;
    let mut local: Option<LocalOut> = None;
    let mut refused_logged: Option<String> = None;
    let started = Instant::now();
    let mut next_complaint = Duration::from_secs(5);
    loop {
        if termination_requested() {
            tracing::info!("stopped by a signal");
            return Ok(());
        }
        {
            let st = lock(&gate.state);
            if let Some(why) = &st.failure {
                return Err(GatewayError::Failed(why.clone()));
            }
            // After our Bye: end once the head has it (or has gone: it ends on our Bye).
            if let Some(t) = st.bye_sent {
                let acked = st.head.as_ref().is_none_or(|p| p.outstanding() == 0);
                if acked || t.elapsed() > Duration::from_secs(5) {
                    tracing::info!("the run is over and every actor stopped: the worker ends");
                    return Ok(());
                }
            }
            // The head rolled this attempt back: leave it for the next one.
            if rolled_back_and_stopped(&st) {
                drop(st);
                leave(gate, &mut local, report);
                last_hello = None;
                continue;
            }
            // Not a member: say hello every HELLO_PERIOD, and say it when nobody answers.
            if st.attempt.is_none() && st.head.is_none() {
                let waited = started.elapsed();
                if waited > next_complaint {
                    tracing::warn!(
                        "no answer from the head at {} after {:.0} s: is `mbpo run --listen` running there, is the address reachable, and are this worker's credentials (--credentials) the run's?",
                        opts.net.endpoint,
                        waited.as_secs_f64()
                    );
                    next_complaint = waited * 2;
                }
            }
            if st.attempt.is_none() && last_hello.is_none_or(|t| t.elapsed() > HELLO_PERIOD) {
                to_head
                    .put(hello.clone())
                    .wait()
                    .map_err(|e| GatewayError::Zenoh(format!("sending hello: {e}")))?;
                last_hello = Some(Instant::now());
            }
        }
        // An actor that subscribed after the last snapshot gets it only when the publisher
        // looks for new subscribers (iceoryx2 delivers history then), and the head sends no
        // newer one while the run waits for this very actor.
        if let Some(out) = &local {
            out.weights
                .update_connections()
                .map_err(RuntimeError::from)?;
        }
        let sample = match sub.recv_timeout(Duration::from_millis(100)) {
            Ok(Some(s)) => s,
            Ok(None) => continue,
            Err(e) => return Err(GatewayError::Zenoh(format!("receiving: {e}"))),
        };
        let env = match decode(&sample.payload().to_bytes()) {
            Ok(e) => e,
            Err(e) => {
                tracing::warn!("dropped a message from the head: {e}");
                continue;
            }
        };
        let head = env.session;
        // A head we do not know: a new attempt (or the first). Its Refused counts too: a new
        // head answers the heartbeats of a worker still in the old attempt with one (its old
        // gateway crashed and never told us), and waiting for --head-timeout instead would
        // hold the whole run for a minute.
        let current = lock(&gate.state).head.as_ref().map(|p| p.session);
        if current.is_some_and(|c| c != head) {
            tracing::warn!(
                "the head restarted (session {head:016x}): stopping the actors, joining again"
            );
            leave(gate, &mut local, report);
            last_hello = None;
        }
        match env.body {
            Body::Welcome(assignment) => {
                if lock(&gate.state).attempt.is_some() {
                    continue; // a repeated Welcome
                }
                refused_logged = None;
                report.attempts += 1;
                report.run_id = assignment.run_id.clone();
                report.slots = assignment.slots.clone();
                let pubr = to_head.clone();
                local = Some(start_attempt(gate, opts, head, *assignment, pubr)?);
            }
            Body::Refused { reason } => {
                if refused_logged.as_deref() != Some(reason.as_str()) {
                    tracing::warn!("the head refused this worker: {reason}; trying again");
                    refused_logged = Some(reason);
                }
                if lock(&gate.state)
                    .head
                    .as_ref()
                    .is_some_and(|p| p.session == head)
                {
                    leave(gate, &mut local, report);
                    last_hello = None;
                }
            }
            Body::Data { seq, item } => {
                let Some(out) = local.as_mut().filter(|l| l.head == head) else {
                    continue; // before our Welcome: it comes again
                };
                let accept = {
                    let mut st = lock(&gate.state);
                    let Some(p) = st.head.as_mut() else { continue };
                    p.last_heard = Instant::now();
                    p.accept(seq)
                };
                if accept == Accept::Deliver {
                    deliver(gate, out, item)?;
                }
                let mut st = lock(&gate.state);
                if let Some(p) = st.head.as_mut() {
                    p.acknowledge(accept)?;
                }
            }
            Body::Ack { next } | Body::Heartbeat { next, .. } => {
                let mut st = lock(&gate.state);
                if let Some(p) = st.head.as_mut().filter(|p| p.session == head) {
                    p.last_heard = Instant::now();
                    if p.acked(next) > 0 {
                        gate.space.notify_all();
                    }
                }
            }
            Body::Weights(w) => {
                if let Some(out) = local.as_mut().filter(|l| l.head == head) {
                    let (sent_ns, version) = (w.sent_ns, w.version);
                    let applied = apply_weights(gate, out, *w)?;
                    if applied && out.weights_seen == 0 {
                        tracing::info!("first weights: version {version}");
                    }
                    if applied {
                        out.weights_seen += 1;
                    }
                    if applied && latencies.len() < 1_000_000 {
                        let now = mbpo_wire::schema::now_ns();
                        latencies.push(now.saturating_sub(sent_ns) as f64 / 1e6);
                    }
                }
            }
            Body::Hello { .. } => tracing::warn!("a worker's hello reached a worker"),
        }
    }
}

/// Publish `w` to the actors if it is newer than what they have; true if it was.
fn apply_weights(gate: &Gate, out: &mut LocalOut, w: WeightsMsg) -> Result<bool, GatewayError> {
    if w.version <= out.weights.version() {
        return Ok(false);
    }
    out.weights
        .publish(&w.params, w.version, w.counters)
        .map_err(RuntimeError::from)?;
    lock(&gate.state).weights_have = w.version;
    Ok(true)
}

/// One message of the head's stream, in order.
fn deliver(gate: &Gate, out: &mut LocalOut, item: Item) -> Result<(), GatewayError> {
    match item {
        Item::Control { slot, mut msg } => {
            if !out.actors_listening {
                out.control
                    .wait_for_subscribers(out.slots, Duration::from_secs(120))
                    .map_err(RuntimeError::from)?;
                out.actors_listening = true;
            }
            if let Some(why) = msg.stop_reason() {
                let mut st = lock(&gate.state);
                if let Some(a) = st.attempt.as_mut() {
                    a.actors
                        .iter_mut()
                        .filter(|p| p.slot == slot)
                        .for_each(|p| p.told_to_stop = true);
                    if why == StopReason::RollBack && a.rolled_back.is_none() {
                        tracing::info!(
                            "the head rolls back to its newest checkpoint: stopping the actors, then joining the next attempt"
                        );
                        a.rolled_back = Some(Instant::now());
                    }
                }
            }
            // Each actor gets its own copy, addressed to it.
            msg.target = ProducerId::new(Role::Actor, slot).0;
            out.control.send(&msg).map_err(RuntimeError::from)?;
        }
        Item::Finished => lock(&gate.state).finished = true,
        other => tracing::warn!("the head sent a worker's item: {other:?}"),
    }
    Ok(())
}

/// Set up the local run of `assignment` and start its actors.
fn start_attempt(
    gate: &Arc<Gate>,
    opts: &WorkerOptions,
    head: u64,
    a: Assignment,
    to_head: Arc<zenoh::pubsub::Publisher<'static>>,
) -> Result<LocalOut, GatewayError> {
    let me = lock(&gate.state).me;
    let io = |p: &Path| {
        let p = p.to_path_buf();
        move |source| GatewayError::Io { path: p, source }
    };
    let run_dir = opts.dir.join("run");
    if run_dir.exists() {
        std::fs::remove_dir_all(&run_dir).map_err(io(&run_dir))?;
    }
    std::fs::create_dir_all(run_dir.join("logs")).map_err(io(&run_dir))?;
    std::fs::write(run_dir.join("config.toml"), &a.config_toml).map_err(io(&run_dir))?;
    if let Some(env) = &a.env_json {
        let p = run_dir.join(mbpo_train::run_dir::ENV_FILE);
        std::fs::write(&p, env).map_err(io(&p))?;
    }
    let resume_dir = match &a.resume {
        Some(r) => {
            let dir = checkpoint::dir_for(&run_dir, r.env_steps);
            for (slot, bytes) in &r.files {
                crate::head::write_atomically(&dir.join(actor_file(*slot)), bytes)?;
            }
            Some(dir)
        }
        None => None,
    };
    let plan_path = run_dir.join(mbpo_runtime::run_plan::RUN_PLAN_FILE);
    std::fs::write(&plan_path, &a.run_plan).map_err(io(&plan_path))?;
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
    tracing::info!(
        "joined run {} ({} {}, mode {}): actors {:?} of {}{}",
        a.run_id,
        cfg.env,
        cfg.algo.name(),
        a.mode.name(),
        a.slots,
        a.actors,
        resume_dir
            .as_ref()
            .map(|d| format!(", resuming {}", d.display()))
            .unwrap_or_default()
    );
    let stop = Arc::new(AtomicBool::new(false));
    let thread = {
        let (gate, stop, run_dir, ipc_root, local_id) = (
            gate.clone(),
            stop.clone(),
            run_dir.clone(),
            opts.ipc_root.clone(),
            local_id.clone(),
        );
        std::thread::Builder::new()
            .name("to-head".into())
            .spawn(move || to_head_loop(&gate, &stop, &run_dir, &ipc_root, &local_id, dims))
            .map_err(|e| GatewayError::Failed(format!("starting a thread: {e}")))?
    };
    let mut actors = Vec::new();
    for &slot in &a.slots {
        let log = run_dir.join("logs").join(format!("actor-{slot}.log"));
        let file = std::fs::File::create(&log).map_err(io(&log))?;
        let err = file.try_clone().map_err(io(&log))?;
        let mut cmd = Command::new(opts.bin_dir.join("mbpo-actor"));
        cmd.args(["--run-dir", &run_dir.display().to_string()])
            .args(["--run-id", &local_id])
            .args(["--ipc-root", &opts.ipc_root.display().to_string()])
            .args(["--mode", a.mode.name()])
            .args(["--actors", &a.actors.to_string()])
            .args(["--policy-lag", &a.slack.policy_lag.to_string()])
            .args(["--update-buffer", &a.slack.update_buffer.to_string()])
            .args(["--model-lag", &a.slack.model_lag.to_string()])
            .arg("--behind-gateway")
            .args(mbpo_runtime::pipeline::RoleSpec::new(pipeline.actor, slot).binary_args())
            .stdin(Stdio::null())
            .stdout(file)
            .stderr(err);
        if let Some(d) = &resume_dir {
            cmd.args(["--resume-from", &d.display().to_string()]);
        }
        let child = cmd.spawn().map_err(|e| {
            GatewayError::Failed(format!(
                "starting {}: {e}",
                opts.bin_dir.join("mbpo-actor").display()
            ))
        })?;
        actors.push(ActorProc {
            slot,
            child,
            log,
            log_offset: 0,
            told_to_stop: false,
            reported: false,
        });
    }
    let mut st = lock(&gate.state);
    let mut peer = Peer::new(me, head, "head".into(), to_head);
    peer.last_heard = Instant::now();
    st.head = Some(peer);
    st.finished = false;
    st.bye_sent = None;
    st.weights_have = 0;
    let slots = a.slots.len();
    st.attempt = Some(Attempt {
        assignment: a,
        run_dir,
        ipc,
        actors,
        stop,
        to_head: Some(thread),
        rolled_back: None,
    });
    Ok(LocalOut {
        head,
        control,
        weights,
        slots,
        actors_listening: false,
        weights_seen: 0,
        _node: node,
    })
}

/// Whether the current attempt was rolled back and its actors have exited (or had 5 s to):
/// the worker leaves it for the head's next attempt. (The old head ignores its hellos.)
fn rolled_back_and_stopped(st: &Shared) -> bool {
    st.attempt.as_ref().is_some_and(|a| {
        a.rolled_back.is_some_and(|t| {
            a.actors.iter().all(|p| p.reported) || t.elapsed() > Duration::from_secs(5)
        })
    })
}

/// Leave the current attempt (the head restarted or refused us).
fn leave(gate: &Gate, local: &mut Option<LocalOut>, report: &mut WorkerReport) {
    *local = None;
    let attempt = {
        let mut st = lock(&gate.state);
        report.resent += st.head.take().map_or(0, |p| p.resent());
        st.attempt.take()
    };
    if let Some(a) = attempt {
        end_attempt(a, gate);
    }
}

/// Stop an attempt's actors and thread, remove its shared memory. Returns the transition
/// batches it sent.
fn end_attempt(mut a: Attempt, gate: &Gate) -> u64 {
    a.stop.store(true, Ordering::Relaxed);
    gate.space.notify_all();
    for p in &mut a.actors {
        if matches!(p.child.try_wait(), Ok(None)) {
            // SAFETY: kill(2) on our own child's pid.
            unsafe { libc::kill(p.child.id() as i32, libc::SIGTERM) };
        }
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    for p in &mut a.actors {
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
    tracing::info!(
        "left run {} (actors {:?}); local files in {}",
        a.assignment.run_id,
        a.assignment.slots,
        a.run_dir.display()
    );
    batches
}

/// The to-head thread of one attempt: local transitions and reports into the stream.
fn to_head_loop(
    gate: &Gate,
    stop: &AtomicBool,
    run_dir: &Path,
    ipc_root: &Path,
    local_id: &str,
    dims: Dims,
) -> Result<u64, GatewayError> {
    let mut ipc = RunIpc::new(local_id, ipc_root)?;
    configure_run(&mut ipc);
    let node = ipc.node::<ipc::Service>(Role::Tool, 0)?;
    let real = TransitionSubscriber::create(&node, Channel::Real, dims.rows())?;
    let stats = StatsSubscriber::create(&node)?;
    let mut waiter = Waiter::new().map_err(RuntimeError::from)?;
    waiter.attach(&real).attach(&stats);
    let mut batches = 0u64;
    let send = |item: Item, bytes: usize| -> Result<bool, GatewayError> {
        let st = lock(&gate.state);
        let (mut st, ok) = wait_until(
            &gate.space,
            st,
            |st| st.head.as_ref().is_some_and(|p| !p.window_full(bytes)),
            |st| {
                stop.load(Ordering::Relaxed)
                    || gate.quit.load(Ordering::Relaxed)
                    || st.head.is_none()
            },
        );
        if ok {
            st.head.as_mut().expect("checked").send_item(item)?;
        }
        Ok(ok)
    };
    while !stop.load(Ordering::Relaxed) && !gate.quit.load(Ordering::Relaxed) {
        if waiter
            .wait(Duration::from_millis(200))
            .map_err(RuntimeError::from)?
            == WaitOutcome::Terminate
        {
            break;
        }
        while let Some(batch) = real.receive().map_err(RuntimeError::from)? {
            let h = *batch.header();
            let item = Item::Transitions {
                slot: batch.producer().index(),
                actor_seq: h.seq,
                meta: TransitionMeta {
                    policy_version: h.policy_version,
                    model_version: h.model_version,
                    env_steps: h.env_steps,
                },
                rows: batch.rows().to_vec(),
            };
            drop(batch);
            let bytes = 64 + 4 * dims.rows().width() * h.n_rows as usize;
            if !send(item, bytes)? {
                return Ok(batches);
            }
            batches += 1;
        }
        while let Some(m) = stats.receive().map_err(RuntimeError::from)? {
            let slot = m.producer().index();
            if let Ok(Stats::Barrier(BarrierReport::Written(t))) = Stats::decode(&m.msg) {
                let path = checkpoint::dir_for(run_dir, t).join(actor_file(slot));
                let bytes = std::fs::read(&path).map_err(|source| GatewayError::Io {
                    path: path.clone(),
                    source,
                })?;
                let n = bytes.len();
                if !send(
                    Item::CheckpointFile {
                        slot,
                        env_steps: t,
                        bytes,
                    },
                    n,
                )? {
                    return Ok(batches);
                }
            }
            if !send(
                Item::Stats {
                    slot,
                    record: m.msg,
                },
                160,
            )? {
                return Ok(batches);
            }
        }
    }
    Ok(batches)
}

/// The heartbeat thread: liveness both ways, resends, actor processes and their logs.
fn heartbeat(gate: &Gate, opts: &WorkerOptions) {
    while !gate.quit.load(Ordering::Relaxed) {
        std::thread::sleep(HEARTBEAT_PERIOD);
        let mut st = lock(&gate.state);
        let now = Instant::now();
        let weights = st.weights_have;
        let mut items = Vec::new();
        if let Some(a) = st.attempt.as_mut() {
            for p in &mut a.actors {
                if let Some(text) = new_log_text(&p.log, &mut p.log_offset) {
                    items.push(Item::Log { slot: p.slot, text });
                }
                if p.reported {
                    continue;
                }
                if let Ok(Some(status)) = p.child.try_wait() {
                    p.reported = true;
                    if !(status.success() && p.told_to_stop) {
                        let reason = format!(
                            "its process ended ({status}) without being told to stop; log tail:\n{}",
                            tail(&p.log, 15)
                        );
                        tracing::error!("actor {}: {reason}", p.slot);
                        items.push(Item::SlotFailed {
                            slot: p.slot,
                            reason,
                        });
                    }
                }
            }
        }
        // The run is over and every actor has exited: their last log lines, then Bye.
        let all_exited = st
            .attempt
            .as_ref()
            .is_some_and(|a| a.actors.iter().all(|p| p.reported));
        if st.finished && all_exited && st.bye_sent.is_none() {
            if let Some(a) = st.attempt.as_mut() {
                for p in &mut a.actors {
                    if let Some(text) = new_log_text(&p.log, &mut p.log_offset) {
                        items.push(Item::Log { slot: p.slot, text });
                    }
                }
            }
            items.push(Item::Bye);
            st.bye_sent = Some(now);
        }
        let Some(head) = st.head.as_mut() else {
            continue;
        };
        for item in items {
            if let Err(e) = head.send_item(item) {
                tracing::warn!("sending to the head: {e}");
            }
        }
        let silent = now.duration_since(head.last_heard);
        if silent > opts.head_timeout {
            tracing::error!(
                "the head is silent for {:.0} s (--head-timeout): stopping the actors and joining again",
                silent.as_secs_f64()
            );
            // The main thread sees no attempt and says hello again.
            st.head = None;
            let a = st.attempt.take();
            drop(st);
            if let Some(a) = a {
                end_attempt(a, gate);
            }
            continue;
        }
        let r = head.heartbeat(weights).and_then(|()| head.resend_due(now));
        if let Err(e) = r {
            tracing::warn!("heartbeat: {e}");
        }
    }
}

/// Text appended to `log` since `offset` (at most 64 kB at a time).
fn new_log_text(log: &Path, offset: &mut u64) -> Option<String> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = std::fs::File::open(log).ok()?;
    let len = f.metadata().ok()?.len();
    if len <= *offset {
        return None;
    }
    f.seek(SeekFrom::Start(*offset)).ok()?;
    let mut buf = vec![0u8; (len - *offset).min(64 << 10) as usize];
    f.read_exact(&mut buf).ok()?;
    *offset += buf.len() as u64;
    Some(String::from_utf8_lossy(&buf).into_owned())
}

fn tail(log: &Path, lines: usize) -> String {
    let text = std::fs::read_to_string(log).unwrap_or_default();
    let all: Vec<&str> = text.lines().collect();
    all[all.len().saturating_sub(lines)..].join("\n")
}
