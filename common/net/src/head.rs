//! The head's gateway (`mbpo-gateway head`, started by `mbpo run --listen`): it stands in for
//! the run's remote actors on the head's iceoryx2, so the coordinator, learner, model trainer
//! and rollout generator cannot tell a remote actor from a local one.
//!
//! For every remote slot k (actor indices `--local-actors`..`--actors`) it owns a node
//! `actor-k` with the ports an actor has: a transition publisher and a stats publisher (fed by
//! the worker's stream), a control subscriber and a weights subscriber (forwarded to the
//! worker). Three threads:
//! * **main** receives from workers: admits them ([`Body::Hello`] -> [`Body::Welcome`]),
//!   publishes their transitions and reports under the slot's producer id, writes their
//!   checkpoint files into the run directory and their logs under `logs/<worker>/`, and
//!   acknowledges. It blocks when the consumers' queues are full, and then acknowledges
//!   nothing, so the worker's window fills and its actors wait: the rate limits hold across
//!   hosts.
//! * **to-workers** sleeps on the slots' control and weights subscribers and forwards; control
//!   for a slot no worker holds yet waits in that slot's queue.
//! * **heartbeat** sends heartbeats, resends stalled streams and newer weights, and fails the
//!   gateway when a worker is silent for `--worker-timeout`.
//!
//! Any loss of a remote actor's state (its worker restarted, went silent, or reported a failed
//! actor) ends the gateway with an error: the supervisor then restarts the whole pipeline from
//! its newest checkpoint (`--restart on-failure`), exactly as for a local process, and the
//! worker rejoins the new attempt, its actors resuming from their checkpoint files.
//!
//! A rollback that starts on the head (one of its own processes crashed) reaches the remote
//! actors as a Stop with [`StopReason::RollBack`]: the gateway forwards it, answers no more
//! hellos, and ends once the workers have it; the workers stop their actors and join the next
//! attempt. Only a Stop with [`StopReason::RunOver`] ends the workers ([`Item::Finished`]).

use std::collections::{HashMap, VecDeque};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::{Duration, Instant};

use mbpo_runtime::hosts::{LiveHosts, LiveWorker};
use mbpo_runtime::{configure_run, Dims, PipelineSpec, ResolvedRun, RuntimeError, ServiceArgs};
use mbpo_train::checkpoint;
use mbpo_train::run_files::actor_file;
use mbpo_wire::*;
use zenoh::Wait;

use crate::link::Accept;
use crate::peer::{lock, publisher, wait_until, Peer, HEARTBEAT_PERIOD};
use crate::protocol::{
    decode, encode, Assignment, Body, Envelope, Item, ResumeFiles, WeightsMsg, PROTOCOL_VERSION,
};
use crate::session::{self, NetOptions, Side};
use crate::{actor_weights, GatewayError};

/// A worker silent this long is logged (the run waits for it meanwhile).
const SILENCE_WARNING: Duration = Duration::from_secs(2);

/// What `mbpo-gateway head` is given.
#[derive(Debug, Clone)]
pub struct HeadOptions {
    /// The arguments every service of the run gets (`--actors` counts remote ones too).
    pub service: ServiceArgs,
    /// Where to listen, with which credentials.
    pub net: NetOptions,
    /// Actors running on the head (slots 0..local_actors); the rest are remote.
    pub local_actors: u16,
    /// A worker silent this long has lost its actors' state.
    pub worker_timeout: Duration,
}

/// What the three threads share.
struct Shared {
    me: u64,
    first_slot: u16,
    workers: HashMap<u64, Peer>,
    /// Worker session holding each remote slot.
    owner: Vec<Option<u64>>,
    /// Control commands for slots no worker holds yet.
    pending: Vec<VecDeque<ControlMsg>>,
    /// Per remote slot, the Stop it was told and why: the run is over, or this attempt is
    /// rolled back and the run goes on.
    stopped: Vec<Option<StopReason>>,
    /// The newest weights: version and encoded envelope.
    weights: Option<(u64, Arc<Vec<u8>>)>,
    /// Per worker: newest weight version it has, and when we last sent it one.
    weights_seen: HashMap<u64, (u64, Option<Instant>)>,
    /// Why the gateway must end (a remote actor's state is lost).
    failure: Option<String>,
    finished_sent: bool,
    /// Workers whose [`Item::Bye`] arrived.
    said_bye: std::collections::HashSet<u64>,
}

impl Shared {
    fn slot_index(&self, slot: u16) -> Option<usize> {
        slot.checked_sub(self.first_slot)
            .map(usize::from)
            .filter(|&i| i < self.owner.len())
    }
    /// Whether every remote slot was told to stop for `why`.
    fn all_stopped(&self, why: StopReason) -> bool {
        self.stopped.iter().all(|&s| s == Some(why))
    }
    fn fail(&mut self, why: String) {
        if self.failure.is_none() {
            tracing::error!("{why}");
            self.failure = Some(why);
        }
    }
}

struct Gate {
    state: Mutex<Shared>,
    space: Condvar,
    quit: AtomicBool,
}

impl Gate {
    fn stopping(&self) -> bool {
        self.quit.load(Ordering::Relaxed) || lock(&self.state).failure.is_some()
    }
}

/// The run's plan, checked against this gateway's slots: it stands in for actors
/// `--local-actors..--actors`, and there must be at least one.
fn remote_slots_of_plan(opts: &HeadOptions) -> Result<ResolvedRun, GatewayError> {
    let args = &opts.service;
    let resolved = ResolvedRun::read(&args.run_dir)?;
    if resolved.local_actors != opts.local_actors {
        return Err(GatewayError::Failed(format!(
            "--local-actors {}, but the run plan has {} local actors",
            opts.local_actors, resolved.local_actors
        )));
    }
    if opts.local_actors >= args.actors {
        return Err(GatewayError::Failed(format!(
            "--local-actors {} leaves no remote slot of --actors {}",
            opts.local_actors, args.actors
        )));
    }
    Ok(resolved)
}

/// Run the head's gateway until the run stops it, or a remote actor's state is lost (error).
pub fn run_head(opts: &HeadOptions) -> Result<(), GatewayError> {
    let args = &opts.service;
    let cfg = mbpo_runtime::process::load_config(&args.run_dir)?;
    let pipeline = mbpo_runtime::pipeline::spec(cfg.algo)?;
    let dims = remote_slots_of_plan(opts)?.dims;
    let remote = usize::from(args.actors - opts.local_actors);
    let session = session::open(Side::Head, &opts.net)?;
    let me = session::new_session_id();
    let gate = Arc::new(Gate {
        state: Mutex::new(Shared {
            me,
            first_slot: opts.local_actors,
            workers: HashMap::new(),
            owner: vec![None; remote],
            pending: vec![VecDeque::new(); remote],
            stopped: vec![None; remote],
            weights: None,
            weights_seen: HashMap::new(),
            failure: None,
            finished_sent: false,
            said_bye: Default::default(),
        }),
        space: Condvar::new(),
        quit: AtomicBool::new(false),
    });
    tracing::info!(
        "gateway of run {}: listening on {} for actors {}..{} (pid {})",
        args.run_id,
        opts.net.endpoint,
        opts.local_actors,
        args.actors,
        std::process::id()
    );
    let to_workers = {
        let (gate, args) = (gate.clone(), args.clone());
        let first = opts.local_actors;
        std::thread::Builder::new()
            .name("to-workers".into())
            .spawn(move || {
                let r = to_workers(&gate, &args, pipeline, dims, first);
                if let Err(e) = &r {
                    lock(&gate.state).fail(format!("forwarding to workers: {e}"));
                }
                r
            })
            .map_err(|e| GatewayError::Failed(format!("starting a thread: {e}")))?
    };
    let heart = {
        let gate = gate.clone();
        let timeout = opts.worker_timeout;
        let run_dir = args.run_dir.clone();
        std::thread::Builder::new()
            .name("heartbeat".into())
            .spawn(move || heartbeat(&gate, timeout, &run_dir))
            .map_err(|e| GatewayError::Failed(format!("starting a thread: {e}")))?
    };
    let mut counts = HashMap::new();
    let account = HostsAccount::load(&args.run_dir);
    let result = from_workers(&gate, &session, opts, pipeline, dims, &account, &mut counts);
    gate.quit.store(true, Ordering::Relaxed);
    gate.space.notify_all();
    let _ = heart.join();
    let _ = to_workers.join();
    let _ = session.close().wait();
    account.write_or_warn(&lock(&gate.state), &counts);
    result?;
    let failure = lock(&gate.state).failure.take();
    match failure {
        Some(why) => Err(GatewayError::Failed(why)),
        None => Ok(()),
    }
}

/// The ports of one remote slot that carry its worker's data to the head's consumers.
struct SlotOut {
    real: TransitionPublisher<ipc::Service>,
    stats: StatsPublisher<ipc::Service>,
    /// The actor's next batch number (checked end to end).
    next_actor_seq: u64,
    consumers_ready: bool,
    transitions: u64,
}

/// The main thread: everything that arrives from workers.
fn from_workers(
    gate: &Gate,
    session: &zenoh::Session,
    opts: &HeadOptions,
    pipeline: &'static PipelineSpec,
    dims: Dims,
    account: &HostsAccount,
    counts: &mut HashMap<u16, u64>,
) -> Result<(), GatewayError> {
    let args = &opts.service;
    let mut run = RunIpc::new(&args.run_id, &args.ipc_root)?;
    configure_run(&mut run);
    let mut slots = Vec::new();
    let mut nodes = Vec::new(); // alive as long as their ports
    for slot in opts.local_actors..args.actors {
        let node = run.node::<ipc::Service>(Role::Actor, slot)?;
        slots.push(SlotOut {
            real: TransitionPublisher::create(&node, Channel::Real, dims.rows(), 1)?,
            stats: StatsPublisher::create(&node)?,
            next_actor_seq: 0,
            consumers_ready: false,
            transitions: 0,
        });
        nodes.push(node);
    }
    let sub = session
        .declare_subscriber(session::FROM_ANY_WORKER)
        .wait()
        .map_err(|e| GatewayError::Zenoh(format!("subscribing to workers: {e}")))?;
    let consumers = pipeline.real_consumers();
    let mut finished_at: Option<Instant> = None;
    let mut rolled_back_at: Option<Instant> = None;
    // (workers when last written, when); looked at every ACCOUNT_CHECK, not per message.
    let mut account_written: Option<(usize, Instant)> = None;
    let mut account_checked = Instant::now();
    loop {
        if account_checked.elapsed() >= ACCOUNT_CHECK {
            account_checked = Instant::now();
            let st = lock(&gate.state);
            let due = account_written.is_none_or(|(workers, at)| {
                workers != st.workers.len() || at.elapsed() >= HOSTS_REWRITE
            });
            if due && !st.workers.is_empty() {
                account.write_or_warn(&st, counts);
                account_written = Some((st.workers.len(), Instant::now()));
            }
        }
        if termination_requested() {
            tracing::info!("stopped by a signal");
            return Ok(());
        }
        if gate.stopping() {
            return Ok(());
        }
        // The run is over once every remote slot was told to stop: tell the workers, and end
        // when each said Bye (its actors exited, its last data and logs are in; or after 10 s).
        {
            let mut st = lock(&gate.state);
            let all_stopped = st.all_stopped(StopReason::RunOver);
            if all_stopped && !st.finished_sent {
                for w in st.workers.values_mut() {
                    w.send_item(Item::Finished)?;
                }
                st.finished_sent = true;
                finished_at = Some(Instant::now());
            }
            // A rollback: end once every worker has the Stop (they join the next attempt).
            if st.all_stopped(StopReason::RollBack) {
                let t = *rolled_back_at.get_or_insert_with(Instant::now);
                let delivered = st.workers.values().all(|w| w.outstanding() == 0);
                if delivered || t.elapsed() > Duration::from_secs(5) {
                    tracing::info!(
                        "the pipeline rolls back to its newest checkpoint: the gateway ends, the workers join the next attempt"
                    );
                    return Ok(());
                }
            }
            if let Some(t) = finished_at {
                let all_bye = st.workers.keys().all(|w| st.said_bye.contains(w));
                if all_bye || t.elapsed() > Duration::from_secs(10) {
                    if !all_bye {
                        tracing::warn!("a worker did not say goodbye within 10 s");
                    }
                    tracing::info!("every remote actor stopped: the gateway ends");
                    return Ok(());
                }
            }
        }
        let sample = match sub.recv_timeout(Duration::from_millis(100)) {
            Ok(Some(s)) => s,
            Ok(None) => continue,
            Err(e) => return Err(GatewayError::Zenoh(format!("receiving: {e}"))),
        };
        let bytes = sample.payload().to_bytes();
        let env = match decode(&bytes) {
            Ok(e) => e,
            Err(e) => {
                tracing::warn!("dropped a message from {}: {e}", sample.key_expr());
                continue;
            }
        };
        let r = handle(gate, session, opts, &mut slots, consumers, env);
        for (i, slot) in slots.iter().enumerate() {
            counts.insert(opts.local_actors + i as u16, slot.transitions);
        }
        r?;
    }
}

/// `<run>/hosts.json`, the account per worker host: its actors, transition batches, attempts
/// joined and restarts (attempts it ended by losing its actors' state).
///
/// The file is read once when the gateway starts (the earlier attempts' account) and this
/// attempt's part is added to that each time it is written: on every change of the workers,
/// every [`HOSTS_REWRITE`] while the attempt runs, and when the gateway ends. So writing it
/// again is harmless, and a gateway that is killed leaves its attempt in the file with counts
/// at most that old.
struct HostsAccount {
    path: std::path::PathBuf,
    before: serde_json::Map<String, serde_json::Value>,
}

/// How often a running attempt rewrites `hosts.json`.
const HOSTS_REWRITE: Duration = Duration::from_secs(2);

/// How often the receiving loop looks whether `hosts.json` is due (a change of the workers is
/// written at most this late).
const ACCOUNT_CHECK: Duration = Duration::from_millis(100);

impl HostsAccount {
    fn load(run_dir: &Path) -> Self {
        let path = run_dir.join(mbpo_runtime::HOSTS_FILE);
        let before = std::fs::read_to_string(&path)
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .unwrap_or_default();
        Self { path, before }
    }

    /// Write the earlier attempts' account plus this attempt's as it stands.
    fn write(&self, st: &Shared, counts: &HashMap<u16, u64>) -> Result<(), GatewayError> {
        let mut hosts = self.before.clone();
        for (session, w) in &st.workers {
            let slots: Vec<u16> = (0..st.owner.len())
                .filter(|&i| st.owner[i] == Some(*session))
                .map(|i| st.first_slot + i as u16)
                .collect();
            let batches: u64 = slots.iter().filter_map(|s| counts.get(s)).sum();
            let e = hosts.entry(w.name.clone()).or_insert_with(
                || serde_json::json!({"attempts": 0, "restarts": 0, "transition_batches": 0}),
            );
            let failed = st
                .failure
                .as_deref()
                .is_some_and(|f| f.contains(&format!("worker {} ", w.name)));
            let n = |k: &str| e[k].as_u64().unwrap_or(0);
            *e = serde_json::json!({
                "actors": slots,
                "attempts": n("attempts") + 1,
                "restarts": n("restarts") + u64::from(failed),
                "transition_batches": n("transition_batches") + batches,
                "resent": w.resent(),
                "duplicates_dropped": w.duplicates(),
            });
        }
        let text = serde_json::to_string_pretty(&hosts).unwrap_or_default() + "\n";
        write_atomically(&self.path, text.as_bytes())
    }

    /// [`HostsAccount::write`], a failure logged (the account must not stop the run).
    fn write_or_warn(&self, st: &Shared, counts: &HashMap<u16, u64>) {
        if let Err(e) = self.write(st, counts) {
            tracing::warn!("writing {}: {e}", self.path.display());
        }
    }
}

fn handle(
    gate: &Gate,
    session: &zenoh::Session,
    opts: &HeadOptions,
    slots: &mut [SlotOut],
    consumers: usize,
    env: Envelope,
) -> Result<(), GatewayError> {
    let from = env.session;
    match env.body {
        Body::Hello { worker, actors } => admit(gate, session, opts, from, worker, actors),
        Body::Data { seq, item } => {
            let accept = {
                let mut st = lock(&gate.state);
                let Some(w) = st.workers.get_mut(&from) else {
                    return Ok(()); // a worker of an earlier attempt: its heartbeat tells it
                };
                w.last_heard = Instant::now();
                w.accept(seq)
            };
            if accept == Accept::Deliver {
                deliver(gate, opts, slots, consumers, from, item)?;
            }
            let mut st = lock(&gate.state);
            if let Some(w) = st.workers.get_mut(&from) {
                w.acknowledge(accept)?;
            }
            Ok(())
        }
        Body::Ack { next } => {
            let mut st = lock(&gate.state);
            if let Some(w) = st.workers.get_mut(&from) {
                w.last_heard = Instant::now();
                if w.acked(next) > 0 {
                    gate.space.notify_all();
                }
            }
            Ok(())
        }
        Body::Heartbeat { next, weights } => {
            let mut st = lock(&gate.state);
            if let Some(w) = st.workers.get_mut(&from) {
                w.last_heard = Instant::now();
                if w.acked(next) > 0 {
                    gate.space.notify_all();
                }
                if let Some(seen) = st.weights_seen.get_mut(&from) {
                    seen.0 = seen.0.max(weights);
                }
            } else {
                // Not (or no longer) a member: say so, so it joins again.
                drop(st);
                refuse(
                    session,
                    gate,
                    from,
                    "this worker is not a member of the run's current attempt: join again",
                )?;
            }
            Ok(())
        }
        other => {
            tracing::warn!("a worker sent a head's message: {other:?}");
            Ok(())
        }
    }
}

fn refuse(
    session: &zenoh::Session,
    gate: &Gate,
    to: u64,
    reason: &str,
) -> Result<(), GatewayError> {
    let me = lock(&gate.state).me;
    let bytes = encode(&Envelope {
        version: PROTOCOL_VERSION,
        session: me,
        body: Body::Refused {
            reason: reason.to_string(),
        },
    });
    session
        .put(session::head_to_worker(to), bytes)
        .wait()
        .map_err(|e| GatewayError::Zenoh(format!("answering a worker: {e}")))
}

/// A worker's Hello: give it free slots, or say why not.
fn admit(
    gate: &Gate,
    session: &zenoh::Session,
    opts: &HeadOptions,
    from: u64,
    worker: String,
    actors: u16,
) -> Result<(), GatewayError> {
    let mut st = lock(&gate.state);
    if st.stopped.contains(&Some(StopReason::RollBack)) {
        // This attempt is over: the worker's hello is for the next one.
        return Ok(());
    }
    if let Some(w) = st.workers.get_mut(&from) {
        // Our Welcome was lost: it comes again below from the stored assignment.
        w.last_heard = Instant::now();
    } else {
        if let Some(old) = st.workers.values().find(|w| w.name == worker) {
            let why = format!(
                "worker {worker} restarted (session {:016x} -> {from:016x}): its actors' state since the last checkpoint is gone",
                old.session
            );
            st.fail(why);
            return Ok(());
        }
        let free: Vec<usize> = (0..st.owner.len())
            .filter(|&i| st.owner[i].is_none())
            .collect();
        if free.is_empty() || actors == 0 {
            drop(st);
            let reason = format!(
                "the run's {} remote actor slot(s) are all taken",
                opts.service.actors - opts.local_actors
            );
            tracing::warn!("refused worker {worker}: {reason}");
            return refuse(session, gate, from, &reason);
        }
        let take: Vec<usize> = free.into_iter().take(usize::from(actors)).collect();
        let pubr = publisher(session, session::head_to_worker(from))?;
        let mut peer = Peer::new(st.me, from, worker.clone(), pubr);
        peer.last_heard = Instant::now();
        let first = st.first_slot;
        let slots: Vec<u16> = take.iter().map(|&i| first + i as u16).collect();
        tracing::info!("worker {worker} ({from:016x}) joined: actors {slots:?}");
        for &i in &take {
            st.owner[i] = Some(from);
        }
        st.workers.insert(from, peer);
        st.weights_seen.insert(from, (0, None));
    }
    let w = &st.workers[&from];
    let slots: Vec<u16> = (0..st.owner.len())
        .filter(|&i| st.owner[i] == Some(from))
        .map(|i| st.first_slot + i as u16)
        .collect();
    let assignment = assignment(opts, slots.clone())?;
    w.send_now(Body::Welcome(Box::new(assignment)))?;
    // Control that waited for these slots, in order.
    for slot in slots {
        let i = st.slot_index(slot).expect("an owned slot");
        while let Some(msg) = st.pending[i].pop_front() {
            st.workers
                .get_mut(&from)
                .expect("just admitted")
                .send_item(Item::Control { slot, msg })?;
        }
    }
    if let Some((_, bytes)) = st.weights.clone() {
        st.workers[&from].put(bytes.to_vec())?;
        if let Some(seen) = st.weights_seen.get_mut(&from) {
            seen.1 = Some(Instant::now());
        }
    }
    Ok(())
}

/// What worker needs to run `slots`: the run's config and, when resuming, their files.
fn assignment(opts: &HeadOptions, slots: Vec<u16>) -> Result<Assignment, GatewayError> {
    let args = &opts.service;
    let read = |p: &Path| {
        std::fs::read(p).map_err(|source| GatewayError::Io {
            path: p.to_path_buf(),
            source,
        })
    };
    let config_toml =
        String::from_utf8_lossy(&read(&args.run_dir.join("config.toml"))?).into_owned();
    let run_plan = String::from_utf8_lossy(&read(
        &args.run_dir.join(mbpo_runtime::run_plan::RUN_PLAN_FILE),
    )?)
    .into_owned();
    let env_path = args.run_dir.join(mbpo_train::run_dir::ENV_FILE);
    let env_json = env_path
        .is_file()
        .then(|| read(&env_path).map(|b| String::from_utf8_lossy(&b).into_owned()))
        .transpose()?;
    let resume = match &args.resume_from {
        Some(dir) => {
            let env_steps = checkpoint_step(dir)?;
            let mut files = Vec::new();
            for &slot in &slots {
                files.push((slot, read(&dir.join(actor_file(slot)))?));
            }
            Some(ResumeFiles { env_steps, files })
        }
        None => None,
    };
    Ok(Assignment {
        run_id: args.run_id.clone(),
        attempt: 0,
        slots,
        config_toml,
        env_json,
        run_plan,
        mode: args.mode,
        actors: args.actors,
        slack: args.slack,
        resume,
    })
}

/// The step T of checkpoint directory `dir` (`checkpoints/<T>`).
pub(crate) fn checkpoint_step(dir: &Path) -> Result<u64, GatewayError> {
    dir.file_name()
        .and_then(|n| n.to_str())
        .and_then(|n| n.parse().ok())
        .ok_or_else(|| {
            GatewayError::Failed(format!(
                "{}: not a checkpoint directory (checkpoints/<step>)",
                dir.display()
            ))
        })
}

/// One message of a worker's stream, in order.
fn deliver(
    gate: &Gate,
    opts: &HeadOptions,
    slots: &mut [SlotOut],
    consumers: usize,
    from: u64,
    item: Item,
) -> Result<(), GatewayError> {
    let (name, slot) = {
        let st = lock(&gate.state);
        let name = st
            .workers
            .get(&from)
            .map(|w| w.name.clone())
            .unwrap_or_default();
        let slot = match &item {
            Item::Transitions { slot, .. }
            | Item::Stats { slot, .. }
            | Item::CheckpointFile { slot, .. }
            | Item::SlotFailed { slot, .. }
            | Item::Log { slot, .. } => *slot,
            Item::Bye => {
                drop(st);
                let mut st = lock(&gate.state);
                st.said_bye.insert(from);
                tracing::info!("worker {name}: every actor exited, goodbye");
                return Ok(());
            }
            Item::Control { .. } | Item::Finished => {
                tracing::warn!("worker {name} sent a head's item");
                return Ok(());
            }
        };
        match st.slot_index(slot) {
            Some(i) if st.owner[i] == Some(from) => (name, slot),
            _ => {
                drop(st);
                lock(&gate.state).fail(format!(
                    "worker {name} sent data of actor {slot}, which it does not hold"
                ));
                return Ok(());
            }
        }
    };
    let i = usize::from(slot - opts.local_actors);
    let out = &mut slots[i];
    match item {
        Item::Transitions {
            actor_seq,
            meta,
            rows,
            ..
        } => {
            if actor_seq != out.next_actor_seq {
                lock(&gate.state).fail(format!(
                    "actor {slot} on {name}: batch {actor_seq} arrived, {} expected (a transition was lost or doubled)",
                    out.next_actor_seq
                ));
                return Ok(());
            }
            if !out.consumers_ready {
                out.real
                    .wait_for_subscribers(consumers, Duration::from_secs(120))
                    .map_err(RuntimeError::from)?;
                out.consumers_ready = true;
            }
            out.real
                .send_rows(&rows, meta)
                .map_err(RuntimeError::from)?;
            out.next_actor_seq += 1;
            out.transitions += 1;
        }
        Item::Stats { record, .. } => {
            if out.stats.subscribers() == 0 {
                out.stats
                    .wait_for_subscribers(1, Duration::from_secs(60))
                    .map_err(RuntimeError::from)?;
            }
            out.stats.send(&record).map_err(RuntimeError::from)?;
        }
        Item::CheckpointFile {
            env_steps, bytes, ..
        } => {
            let dir = checkpoint::dir_for(&opts.service.run_dir, env_steps);
            write_atomically(&dir.join(actor_file(slot)), &bytes)?;
            tracing::info!(
                "checkpoint after step {env_steps}: wrote actor {slot}'s file from {name}"
            );
        }
        Item::SlotFailed { reason, .. } => {
            lock(&gate.state).fail(format!("actor {slot} on {name} failed: {reason}"));
        }
        Item::Log { text, .. } => {
            let dir = opts.service.run_dir.join("logs").join(sanitize(&name));
            append(&dir, &format!("actor-{slot}.log"), &text)?;
        }
        Item::Control { .. } | Item::Finished | Item::Bye => unreachable!("handled above"),
    }
    Ok(())
}

/// `name` usable as a directory name.
fn sanitize(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .take(64)
        .collect();
    if s.is_empty() || s.starts_with('.') {
        format!("worker{s}")
    } else {
        s
    }
}

fn append(dir: &Path, file: &str, text: &str) -> Result<(), GatewayError> {
    use std::io::Write;
    let io = |path: PathBuf| move |source| GatewayError::Io { path, source };
    std::fs::create_dir_all(dir).map_err(io(dir.to_path_buf()))?;
    let path = dir.join(file);
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(io(path.clone()))?;
    f.write_all(text.as_bytes()).map_err(io(path))
}

/// Write `bytes` to `path` (its directory made first) the way checkpoint files are written:
/// a crash leaves the old file or the new one, never half of one.
pub(crate) fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), GatewayError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| GatewayError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    Ok(checkpoint::write_atomically(path, bytes)?)
}

/// The to-workers thread: control commands and weights of the remote slots.
fn to_workers(
    gate: &Gate,
    args: &ServiceArgs,
    pipeline: &'static PipelineSpec,
    dims: Dims,
    first: u16,
) -> Result<(), GatewayError> {
    let mut run = RunIpc::new(&args.run_id, &args.ipc_root)?;
    configure_run(&mut run);
    let (kind, hash, len) = actor_weights(pipeline, &dims);
    let mut control = Vec::new();
    let mut weights = Vec::new();
    let mut nodes = Vec::new();
    for slot in first..args.actors {
        let node = run.node::<ipc::Service>(Role::Actor, slot)?;
        control.push(ControlSubscriber::create(&node)?);
        weights.push(WeightsSubscriber::create(&node, kind, hash, len)?);
        nodes.push(node);
    }
    let mut waiter = Waiter::new().map_err(RuntimeError::from)?;
    for (c, w) in control.iter().zip(&weights) {
        waiter.attach(c).attach(w);
    }
    while !gate.stopping() {
        if waiter
            .wait(Duration::from_millis(200))
            .map_err(RuntimeError::from)?
            == WaitOutcome::Terminate
        {
            break;
        }
        for (i, sub) in control.iter().enumerate() {
            let slot = first + i as u16;
            let me = ProducerId::new(Role::Actor, slot);
            while let Some(m) = sub.receive().map_err(RuntimeError::from)? {
                if m.msg.is_for(me) {
                    forward_control(gate, slot, m.msg)?;
                }
            }
        }
        let mut newest = None;
        for w in &weights {
            if let Some(s) = w.receive_latest().map_err(RuntimeError::from)? {
                if newest.as_ref().is_none_or(|(v, _)| s.version() > *v) {
                    let h = s.header();
                    let msg = WeightsMsg {
                        kind,
                        version: s.version(),
                        counters: WeightsCounters {
                            env_steps: h.env_steps,
                            sac_updates: h.sac_updates,
                            model_trainings: h.model_trainings,
                        },
                        params: s.params().to_vec(),
                        sent_ns: h.send_time_ns,
                    };
                    newest = Some((s.version(), msg));
                }
            }
        }
        if let Some((version, msg)) = newest {
            publish_weights(gate, version, msg)?;
        }
    }
    Ok(())
}

fn publish_weights(gate: &Gate, version: u64, msg: WeightsMsg) -> Result<(), GatewayError> {
    let mut st = lock(&gate.state);
    if st.weights.as_ref().is_some_and(|(v, _)| *v >= version) {
        return Ok(());
    }
    let bytes = Arc::new(encode(&Envelope {
        version: PROTOCOL_VERSION,
        session: st.me,
        body: Body::Weights(Box::new(msg)),
    }));
    if st.weights.is_none() {
        tracing::info!("first weights: version {version}");
    }
    st.weights = Some((version, bytes.clone()));
    let now = Instant::now();
    let sessions: Vec<u64> = st.workers.keys().copied().collect();
    for s in sessions {
        st.workers[&s].put(bytes.to_vec())?;
        if let Some(seen) = st.weights_seen.get_mut(&s) {
            seen.1 = Some(now);
        }
    }
    Ok(())
}

/// Send `msg` to the worker holding `slot`, or keep it until one does.
fn forward_control(gate: &Gate, slot: u16, msg: ControlMsg) -> Result<(), GatewayError> {
    let st = lock(&gate.state);
    let i = st.slot_index(slot).expect("a remote slot");
    let stop = msg.stop_reason();
    let (mut st, ok) = wait_until(
        &gate.space,
        st,
        |st| match st.owner[i] {
            Some(w) => st.workers.get(&w).is_none_or(|p| !p.window_full(64)),
            None => true,
        },
        |st| st.failure.is_some() || gate.quit.load(Ordering::Relaxed),
    );
    if !ok {
        return Ok(());
    }
    if stop.is_some() {
        st.stopped[i] = stop;
    }
    match st.owner[i].and_then(|w| st.workers.contains_key(&w).then_some(w)) {
        Some(w) => {
            st.workers
                .get_mut(&w)
                .expect("checked")
                .send_item(Item::Control { slot, msg })?;
        }
        None => st.pending[i].push_back(msg),
    }
    Ok(())
}

/// The heartbeat thread.
fn heartbeat(gate: &Gate, timeout: Duration, run_dir: &Path) {
    let mut silenced = std::collections::HashSet::new();
    let mut live: Option<LiveHosts> = None;
    while !gate.stopping() {
        std::thread::sleep(HEARTBEAT_PERIOD);
        let mut st = lock(&gate.state);
        let now = Instant::now();
        let latest = st.weights.clone();
        let sessions: Vec<u64> = st.workers.keys().copied().collect();
        for s in sessions {
            let seen = st.weights_seen.get(&s).copied().unwrap_or((0, None));
            let w = st.workers.get_mut(&s).expect("listed");
            let silent = now.duration_since(w.last_heard);
            let name = w.name.clone();
            if silent > timeout {
                let why = format!(
                    "worker {name} silent for {:.0} s (--worker-timeout): its actors' state is taken for lost",
                    silent.as_secs_f64()
                );
                st.fail(why);
                break;
            }
            // The link is the only way between the hosts: while it is down the run waits.
            if silent > SILENCE_WARNING && silenced.insert(s) {
                tracing::warn!(
                    "worker {name}: nothing heard for {:.1} s",
                    silent.as_secs_f64()
                );
            } else if silent < HEARTBEAT_PERIOD * 2 && silenced.remove(&s) {
                tracing::info!("worker {name}: heard again");
            }
            let w = st.workers.get_mut(&s).expect("listed");
            let mut r = w.heartbeat(latest.as_ref().map_or(0, |(v, _)| *v));
            if r.is_ok() {
                r = w.resend_due(now);
            }
            // A newer snapshot it missed (sent at most once a second).
            if let Some((v, bytes)) = &latest {
                let stale = seen.0 < *v
                    && seen
                        .1
                        .is_none_or(|t| now.duration_since(t) > Duration::from_secs(1));
                if r.is_ok() && stale {
                    r = w.put(bytes.to_vec());
                    if let Some(x) = st.weights_seen.get_mut(&s) {
                        x.1 = Some(now);
                    }
                }
            }
            if let Err(e) = r {
                tracing::warn!("heartbeat: {e}");
            }
        }
        let now_live = live_hosts(&st, &silenced);
        drop(st);
        if live.as_ref() != Some(&now_live) {
            if let Err(e) = now_live.write(run_dir) {
                tracing::warn!("writing {}: {e}", mbpo_runtime::LIVE_HOSTS_FILE);
            }
            live = Some(now_live);
        }
    }
}

/// Who holds the remote slots now (for the supervisor's progress line).
fn live_hosts(st: &Shared, silenced: &std::collections::HashSet<u64>) -> LiveHosts {
    let mut workers: Vec<LiveWorker> = st
        .workers
        .iter()
        .map(|(session, w)| LiveWorker {
            name: w.name.clone(),
            actors: (0..st.owner.len())
                .filter(|&i| st.owner[i] == Some(*session))
                .map(|i| st.first_slot + i as u16)
                .collect(),
            silent: silenced.contains(session),
        })
        .collect();
    workers.sort_by(|a, b| a.actors.cmp(&b.actors));
    LiveHosts {
        remote_slots: st.owner.len() as u16,
        workers,
    }
}
