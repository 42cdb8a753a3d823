//! A worker host's gateway (`mbpo join`): joins a head, runs the roles it is given (actors,
//! the evaluator) as local processes on the worker's own iceoryx2, and carries their channels
//! over the link.
//!
//! The roles are the ordinary binaries of the role table with `--behind-gateway` (their only
//! consumer is this gateway). Three threads:
//! * **main** receives from the head: the assignment (config, plan, slots, checkpoint files;
//!   [`attempt`]), control commands (republished to each role), weight snapshots (republished
//!   when newer), and acknowledgements;
//! * **to-head** ([`to_head`]), one per attempt, sleeps on what the roles publish --
//!   transitions, reports, control messages -- and puts it into the reliable stream (a role's
//!   checkpoint file goes before the report that it was written); a full window makes it, and
//!   so the roles, wait;
//! * **heartbeat** ([`heartbeat`]) sends heartbeats and the roles' new log lines, resends a
//!   stalled stream, watches the role processes and the head.
//!
//! A head whose session changes has restarted (a new attempt of the pipeline): the worker
//! stops its roles, forgets the old stream, and joins again; the new assignment brings the
//! checkpoint its roles resume from.

mod attempt;
mod heartbeat;
mod state;
mod to_head;

use std::path::PathBuf;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mbpo_runtime::RuntimeError;
use mbpo_wire::*;
use zenoh::Wait;

use self::attempt::{end_attempt, start_attempt, LocalOut};
use self::state::Gate;
use crate::link::Accept;
use crate::peer::{lock, publisher, Peer};
use crate::protocol::{decode, encode, Body, Envelope, Item, WeightsMsg, PROTOCOL_VERSION};
use crate::session::{self, NetOptions, Side};
use crate::GatewayError;

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
    /// Roles besides actors offered, by process name (`evaluator`).
    pub roles: Vec<String>,
    /// This worker's name (host name by default).
    pub name: String,
    /// Where the roles' run directory and logs go.
    pub dir: PathBuf,
    /// Base directory of the local iceoryx2 root.
    pub ipc_root: PathBuf,
    /// Where the role binaries (`mbpo-actor`) are.
    pub bin_dir: PathBuf,
    /// A head silent this long is taken for gone: stop the roles and join again.
    pub head_timeout: Duration,
}

/// How a worker's run ended.
#[derive(Debug, Clone, Default, serde::Serialize)]
pub struct WorkerReport {
    /// The head's run id.
    pub run_id: String,
    /// The roles run in the last attempt, by process name (`actor-1`, `evaluator`).
    pub slots: Vec<String>,
    /// Attempts joined (a head restart is a new one).
    pub attempts: u32,
    /// Transition batches sent in the last attempt.
    pub batches_sent: u64,
    /// Messages of the stream sent more than once.
    pub resent: u64,
    /// Weight snapshots published to the roles.
    pub weights_applied: u64,
    /// Latency of a weight snapshot from its publisher on the head to this host's shared
    /// memory, milliseconds: median and 99th percentile (host clocks must agree).
    pub weights_latency_ms_p50: f64,
    /// See `weights_latency_ms_p50`.
    pub weights_latency_ms_p99: f64,
}

/// Join the head at `opts.net.endpoint` and run roles for it until its run ends.
pub fn run_worker(opts: &WorkerOptions) -> Result<WorkerReport, GatewayError> {
    let session = session::open(Side::Worker, &opts.net)?;
    let me = session::new_session_id();
    let to_head = publisher(&session, session::worker_to_head(me))?;
    let sub = session
        .declare_subscriber(session::head_to_worker(me))
        .wait()
        .map_err(|e| GatewayError::Zenoh(format!("subscribing: {e}")))?;
    let offer = match opts.roles.is_empty() {
        true => String::new(),
        false => format!(" and {}", opts.roles.join(", ")),
    };
    tracing::info!(
        "worker {} ({me:016x}): joining {} with {} actor(s){offer} (pid {})",
        opts.name,
        opts.net.endpoint,
        opts.actors,
        std::process::id()
    );
    let gate = Arc::new(Gate::new(me));
    let heart = {
        let (gate, opts) = (gate.clone(), opts.clone());
        std::thread::Builder::new()
            .name("heartbeat".into())
            .spawn(move || heartbeat::heartbeat(&gate, &opts))
            .map_err(|e| GatewayError::Failed(format!("starting a thread: {e}")))?
    };
    let mut main = Main {
        gate: &gate,
        to_head: &to_head,
        opts,
        report: WorkerReport::default(),
        latencies: Vec::new(),
        local: None,
        last_hello: None,
    };
    let result = main.receive(&sub);
    let mut report = main.finish_report();
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

type HeadSubscriber =
    zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>;

/// The main thread's own.
struct Main<'a> {
    gate: &'a Arc<Gate>,
    to_head: &'a Arc<zenoh::pubsub::Publisher<'static>>,
    opts: &'a WorkerOptions,
    report: WorkerReport,
    /// Weight snapshots' latencies, ms.
    latencies: Vec<f64>,
    /// The current attempt's ports.
    local: Option<LocalOut>,
    last_hello: Option<Instant>,
}

impl Main<'_> {
    /// The report with the weights' latency percentiles.
    fn finish_report(&mut self) -> WorkerReport {
        let mut report = std::mem::take(&mut self.report);
        let l = &mut self.latencies;
        report.weights_applied = l.len() as u64;
        l.sort_by(f64::total_cmp);
        let pct = |q: f64| {
            let i = ((l.len() as f64 - 1.0) * q).round() as usize;
            l.get(i).copied().unwrap_or(0.0)
        };
        (report.weights_latency_ms_p50, report.weights_latency_ms_p99) = (pct(0.5), pct(0.99));
        report
    }

    fn receive(&mut self, sub: &HeadSubscriber) -> Result<(), GatewayError> {
        let started = Instant::now();
        let mut next_complaint = Duration::from_secs(5);
        let mut refused_logged: Option<String> = None;
        loop {
            if termination_requested() {
                tracing::info!("stopped by a signal");
                return Ok(());
            }
            if self.over()? {
                return Ok(());
            }
            self.say_hello(started, &mut next_complaint)?;
            // A role that subscribed after the last snapshot gets it only when the publisher
            // looks for new subscribers (iceoryx2 delivers history then), and the head sends
            // no newer one while the run waits for this very role.
            if let Some(out) = &self.local {
                let r = out.weights.update_connections();
                r.map_err(RuntimeError::from)?;
            }
            let sample = match sub.recv_timeout(Duration::from_millis(100)) {
                Ok(Some(s)) => s,
                Ok(None) => continue,
                Err(e) => return Err(GatewayError::Zenoh(format!("receiving: {e}"))),
            };
            match decode(&sample.payload().to_bytes()) {
                Ok(env) => self.handle(env, &mut refused_logged)?,
                Err(e) => tracing::warn!("dropped a message from the head: {e}"),
            }
        }
    }

    /// Whether the worker is done: a failure (error), the run over and our Bye delivered (or
    /// 5 s after it). A rolled-back attempt is left here for the next one.
    fn over(&mut self) -> Result<bool, GatewayError> {
        let st = lock(&self.gate.state);
        if let Some(why) = &st.failure {
            return Err(GatewayError::Failed(why.clone()));
        }
        // After our Bye: end once the head has it (or has gone: it ends on our Bye).
        if let Some(t) = st.bye_sent {
            let acked = st.head.as_ref().is_none_or(|p| p.outstanding() == 0);
            if acked || t.elapsed() > Duration::from_secs(5) {
                tracing::info!("the run is over and every role stopped: the worker ends");
                return Ok(true);
            }
        }
        let rolled_back = st
            .attempt
            .as_ref()
            .is_some_and(|a| a.rolled_back_and_stopped());
        drop(st);
        if rolled_back {
            self.leave();
        }
        Ok(false)
    }

    /// Not a member: say hello every [`HELLO_PERIOD`], and say it when nobody answers.
    fn say_hello(
        &mut self,
        started: Instant,
        next_complaint: &mut Duration,
    ) -> Result<(), GatewayError> {
        let st = lock(&self.gate.state);
        if st.attempt.is_some() {
            return Ok(());
        }
        let waited = started.elapsed();
        if st.head.is_none() && waited > *next_complaint {
            tracing::warn!(
                "no answer from the head at {} after {:.0} s: is `mbpo run --listen` running there, is the address reachable, and are this worker's credentials (--credentials) the run's?",
                self.opts.net.endpoint,
                waited.as_secs_f64()
            );
            *next_complaint = waited * 2;
        }
        if self.last_hello.is_some_and(|t| t.elapsed() <= HELLO_PERIOD) {
            return Ok(());
        }
        let hello = encode(&Envelope {
            version: PROTOCOL_VERSION,
            session: st.me,
            body: Body::Hello {
                worker: self.opts.name.clone(),
                actors: self.opts.actors,
                roles: self.opts.roles.clone(),
            },
        });
        self.to_head
            .put(hello)
            .wait()
            .map_err(|e| GatewayError::Zenoh(format!("sending hello: {e}")))?;
        self.last_hello = Some(Instant::now());
        Ok(())
    }

    fn handle(
        &mut self,
        env: Envelope,
        refused_logged: &mut Option<String>,
    ) -> Result<(), GatewayError> {
        let head = env.session;
        // A head we do not know: a new attempt (or the first). Its Refused counts too: a new
        // head answers the heartbeats of a worker still in the old attempt with one (its old
        // gateway crashed and never told us), and waiting for --head-timeout instead would
        // hold the whole run for a minute.
        let current = lock(&self.gate.state).head.as_ref().map(|p| p.session);
        if current.is_some_and(|c| c != head) {
            tracing::warn!(
                "the head restarted (session {head:016x}): stopping the roles, joining again"
            );
            self.leave();
        }
        match env.body {
            Body::Welcome(assignment) => {
                if lock(&self.gate.state).attempt.is_some() {
                    return Ok(()); // a repeated Welcome
                }
                *refused_logged = None;
                self.report.attempts += 1;
                self.report.run_id = assignment.run_id.clone();
                self.report.slots = assignment.slots.iter().map(|s| s.name()).collect();
                let pubr = self.to_head.clone();
                let out = start_attempt(self.gate, self.opts, head, *assignment, pubr)?;
                self.local = Some(out);
            }
            Body::Refused { reason } => {
                if refused_logged.as_deref() != Some(reason.as_str()) {
                    tracing::warn!("the head refused this worker: {reason}; trying again");
                    *refused_logged = Some(reason);
                }
                let st = lock(&self.gate.state);
                if st.head.as_ref().is_some_and(|p| p.session == head) {
                    drop(st);
                    self.leave();
                }
            }
            Body::Data { seq, item } => self.data(head, seq, item)?,
            Body::Ack { next } | Body::Heartbeat { next, .. } => {
                let mut st = lock(&self.gate.state);
                if let Some(p) = st.head.as_mut().filter(|p| p.session == head) {
                    p.last_heard = Instant::now();
                    if p.acked(next) > 0 {
                        self.gate.space.notify_all();
                    }
                }
            }
            Body::Weights(w) => self.weights(head, *w)?,
            Body::Hello { .. } => tracing::warn!("a worker's hello reached a worker"),
        }
        Ok(())
    }

    /// Message `seq` of the head's stream: delivered in order, then acknowledged.
    fn data(&mut self, head: u64, seq: u64, item: Item) -> Result<(), GatewayError> {
        let Some(out) = self.local.as_mut().filter(|l| l.head == head) else {
            return Ok(()); // before our Welcome: it comes again
        };
        let accept = {
            let mut st = lock(&self.gate.state);
            let Some(p) = st.head.as_mut() else {
                return Ok(());
            };
            p.last_heard = Instant::now();
            p.accept(seq)
        };
        if accept == Accept::Deliver {
            deliver(self.gate, out, item)?;
        }
        let mut st = lock(&self.gate.state);
        match st.head.as_mut() {
            Some(p) => p.acknowledge(accept),
            None => Ok(()),
        }
    }

    /// A snapshot from the head: published to the roles when newer, its latency kept.
    fn weights(&mut self, head: u64, w: WeightsMsg) -> Result<(), GatewayError> {
        let Some(out) = self.local.as_mut().filter(|l| l.head == head) else {
            return Ok(());
        };
        let (sent_ns, version) = (w.sent_ns, w.version);
        if !apply_weights(self.gate, out, w)? {
            return Ok(());
        }
        if out.weights_seen == 0 {
            tracing::info!("first weights: version {version}");
        }
        out.weights_seen += 1;
        if self.latencies.len() < 1_000_000 {
            let now = mbpo_wire::schema::now_ns();
            self.latencies
                .push(now.saturating_sub(sent_ns) as f64 / 1e6);
        }
        Ok(())
    }

    /// Leave the current attempt (the head restarted, refused us or rolled back).
    fn leave(&mut self) {
        self.local = None;
        self.last_hello = None;
        let attempt = {
            let mut st = lock(&self.gate.state);
            self.report.resent += st.head.take().map_or(0, |p| p.resent());
            st.attempt.take()
        };
        if let Some(a) = attempt {
            end_attempt(a, self.gate);
        }
    }
}

/// Publish `w` to the roles if it is newer than what they have; true if it was.
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
            if !out.roles_listening {
                out.control
                    .wait_for_subscribers(out.control_subscribers, Duration::from_secs(120))
                    .map_err(RuntimeError::from)?;
                out.roles_listening = true;
            }
            if let Some(why) = msg.stop_reason() {
                let mut st = lock(&gate.state);
                if let Some(a) = st.attempt.as_mut() {
                    let told = a.procs.iter_mut().filter(|p| p.slot == slot);
                    told.for_each(|p| p.told_to_stop = true);
                    if why == StopReason::RollBack && a.rolled_back.is_none() {
                        tracing::info!(
                            "the head rolls back to its newest checkpoint: stopping the roles, then joining the next attempt"
                        );
                        a.rolled_back = Some(Instant::now());
                    }
                }
            }
            // Each role gets its own copy, addressed to it.
            msg.target = ProducerId::new(slot.kind.wire_role(), slot.index).0;
            out.control.send(&msg).map_err(RuntimeError::from)?;
        }
        Item::Finished => lock(&gate.state).finished = true,
        other => tracing::warn!("the head sent a worker's item: {other:?}"),
    }
    Ok(())
}
