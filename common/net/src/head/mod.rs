//! The head's gateway (`mbpo-gateway head`, started by `mbpo run --listen`): it stands in for
//! the run's remote roles on the head's iceoryx2, so the coordinator and the head's roles
//! cannot tell a remote role from a local one.
//!
//! The remote slots come from the run plan: actors `local_actors..actors` and the roles given
//! to `mbpo run --remote-roles` (the evaluator). For each it owns a node of the slot's own name
//! with the ports its role has, per channel (`mbpo_runtime::remote` says which channels
//! cross): what the role publishes -- transitions, reports, control messages -- is fed by the
//! worker's stream; what it subscribes -- control commands, the weights it acts with -- is
//! forwarded to the worker. Three threads:
//! * **main** ([`inbound`]) receives from workers: admits them ([`admission`]), publishes their
//!   roles' data under each slot's producer id, writes their checkpoint files and logs, and
//!   acknowledges (a full queue on the head holds the acknowledgements back, so the worker's
//!   roles wait: the rate limits hold across hosts);
//! * **to-workers** ([`outbound`]) sleeps on the slots' subscribers and forwards;
//! * **heartbeat** ([`heartbeat`]) sends heartbeats, resends stalled streams and newer weights,
//!   and fails the gateway when a worker is silent for `--worker-timeout`.
//!
//! Any loss of a remote role's state (its worker restarted, went silent, or reported a failed
//! process) ends the gateway with an error: the supervisor then restarts the whole pipeline
//! from its newest checkpoint (`--restart on-failure`), exactly as for a local process, and the
//! worker rejoins the new attempt, its roles resuming from their checkpoint files.
//!
//! A rollback that starts on the head (one of its own processes crashed) reaches the remote
//! roles as a Stop with [`mbpo_wire::StopReason::RollBack`]: the gateway forwards it, answers no more
//! hellos, and ends once the workers have it; the workers stop their roles and join the next
//! attempt. Only a Stop with [`mbpo_wire::StopReason::RunOver`] ends the workers
//! ([`crate::protocol::Item::Finished`]).

mod account;
mod admission;
mod heartbeat;
mod inbound;
mod outbound;
mod state;

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::Duration;

use mbpo_runtime::remote::can_run_remotely;
use mbpo_runtime::run_plan::Slot;
use mbpo_runtime::{ResolvedRun, ServiceArgs};
use zenoh::Wait;

use self::account::HostsAccount;
use self::inbound::Inbound;
use self::state::{Gate, Shared};
use crate::peer::lock;
use crate::session::{self, NetOptions, Side};
use crate::GatewayError;

/// What `mbpo-gateway head` is given.
#[derive(Debug, Clone)]
pub struct HeadOptions {
    /// The arguments every service of the run gets (`--actors` counts remote ones too).
    pub service: ServiceArgs,
    /// Where to listen, with which credentials.
    pub net: NetOptions,
    /// Actors running on the head (slots 0..local_actors); the rest are remote.
    pub local_actors: u16,
    /// A worker silent this long has lost its roles' state.
    pub worker_timeout: Duration,
}

/// The remote slots of the run's plan, checked against this gateway's arguments: it stands in
/// for actors `--local-actors..--actors` and the plan's remote roles, and there must be one.
fn remote_slots_of_plan(
    opts: &HeadOptions,
    pipeline: &mbpo_runtime::PipelineSpec,
) -> Result<(ResolvedRun, Vec<Slot>), GatewayError> {
    let args = &opts.service;
    let resolved = ResolvedRun::read(&args.run_dir)?;
    if resolved.local_actors != opts.local_actors {
        return Err(GatewayError::Failed(format!(
            "--local-actors {}, but the run plan has {} local actors",
            opts.local_actors, resolved.local_actors
        )));
    }
    let slots = resolved.remote_slots(pipeline.actor);
    if slots.is_empty() {
        return Err(GatewayError::Failed(format!(
            "--local-actors {} of --actors {} and no remote role: nothing runs on a worker",
            opts.local_actors, args.actors
        )));
    }
    for s in &slots {
        can_run_remotely(pipeline, s.kind).map_err(GatewayError::Failed)?;
    }
    Ok((resolved, slots))
}

/// Run the head's gateway until the run stops it, or a remote role's state is lost (error).
pub fn run_head(opts: &HeadOptions) -> Result<(), GatewayError> {
    let args = &opts.service;
    let cfg = mbpo_runtime::process::load_config(&args.run_dir)?;
    let pipeline = mbpo_runtime::pipeline::spec(cfg.algo)?;
    let (plan, slots) = remote_slots_of_plan(opts, pipeline)?;
    let dims = plan.dims;
    let session = session::open(Side::Head, &opts.net)?;
    let gate = Arc::new(Gate::new(Shared::new(
        session::new_session_id(),
        slots.clone(),
    )));
    let names: Vec<String> = slots.iter().map(|s| s.name()).collect();
    tracing::info!(
        "gateway of run {}: listening on {} for {} (pid {})",
        args.run_id,
        opts.net.endpoint,
        names.join(", "),
        std::process::id()
    );
    let to_workers = {
        let (gate, args) = (gate.clone(), args.clone());
        spawn("to-workers", move || {
            let r = outbound::to_workers(&gate, &args, pipeline, dims, &slots);
            if let Err(e) = &r {
                lock(&gate.state).fail(format!("forwarding to workers: {e}"));
            }
        })?
    };
    let heart = {
        let (gate, timeout, run_dir) = (gate.clone(), opts.worker_timeout, args.run_dir.clone());
        spawn("heartbeat", move || {
            heartbeat::heartbeat(&gate, timeout, &run_dir)
        })?
    };
    let account = HostsAccount::load(&args.run_dir);
    let slots = lock(&gate.state).slots.clone();
    let mut batches = Default::default();
    let result = Inbound::open(&gate, &session, opts, pipeline, dims, &slots).and_then(|mut i| {
        let r = i.run(&account);
        batches = i.batches();
        r
    });
    gate.quit.store(true, Ordering::Relaxed);
    gate.space.notify_all();
    let _ = heart.join();
    let _ = to_workers.join();
    let _ = session.close().wait();
    account.write_or_warn(&lock(&gate.state), &batches);
    result?;
    let failure = lock(&gate.state).failure.take();
    match failure {
        Some(why) => Err(GatewayError::Failed(why)),
        None => Ok(()),
    }
}

/// Start thread `name` running `f`.
fn spawn(
    name: &str,
    f: impl FnOnce() + Send + 'static,
) -> Result<std::thread::JoinHandle<()>, GatewayError> {
    std::thread::Builder::new()
        .name(name.into())
        .spawn(f)
        .map_err(|e| GatewayError::Failed(format!("starting a thread: {e}")))
}
