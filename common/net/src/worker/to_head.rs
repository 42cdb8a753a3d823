//! The to-head thread of one attempt: it subscribes, on the worker's iceoryx2, what the
//! attempt's roles publish (real transitions, reports, control messages) and puts it into the
//! reliable stream to the head. A role's checkpoint file goes before the report that it was
//! written; a full window makes the thread, and so the roles, wait.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use mbpo_runtime::run_plan::Slot;
use mbpo_runtime::{configure_run, Dims, RuntimeError};
use mbpo_train::checkpoint;
use mbpo_wire::*;

use super::state::Gate;
use crate::peer::{lock, wait_until};
use crate::protocol::Item;
use crate::GatewayError;

/// Where the thread reads and what it serves.
pub(crate) struct ToHead {
    pub run_dir: PathBuf,
    pub ipc_root: PathBuf,
    pub local_id: String,
    pub dims: Dims,
    pub slots: Vec<Slot>,
}

/// The local subscribers: what the roles publish.
struct Ports {
    real: TransitionSubscriber<ipc::Service>,
    stats: StatsSubscriber<ipc::Service>,
    control: ControlSubscriber<ipc::Service>,
    _node: WireNode<ipc::Service>,
}

/// Serve until `stop`: transitions, reports and control messages of the roles into the
/// stream. `ready` gets the outcome of creating the subscribers, before any role starts (so
/// nothing a role sends is lost). Returns the transition batches sent.
pub(crate) fn to_head_loop(
    gate: &Gate,
    stop: &AtomicBool,
    to: &ToHead,
    ready: mpsc::Sender<Result<(), String>>,
) -> Result<u64, GatewayError> {
    let ports = match open(to) {
        Ok(p) => {
            let _ = ready.send(Ok(()));
            p
        }
        Err(e) => {
            let _ = ready.send(Err(e.to_string()));
            return Err(e);
        }
    };
    let mut waiter = Waiter::new().map_err(RuntimeError::from)?;
    waiter
        .attach(&ports.real)
        .attach(&ports.stats)
        .attach(&ports.control);
    let send = |item: Item, bytes: usize| send(gate, stop, item, bytes);
    let mut batches = 0u64;
    while !stop.load(Ordering::Relaxed) && !gate.quitting() {
        let woke = waiter.wait(Duration::from_millis(200));
        if woke.map_err(RuntimeError::from)? == WaitOutcome::Terminate {
            break;
        }
        let Some(n) = transitions(&ports, to, &send)? else {
            break;
        };
        batches += n;
        if !reports(&ports, to, &send)? || !control(&ports, to, &send)? {
            break;
        }
    }
    Ok(batches)
}

fn open(to: &ToHead) -> Result<Ports, GatewayError> {
    let mut ipc = RunIpc::new(&to.local_id, &to.ipc_root)?;
    configure_run(&mut ipc);
    let node = ipc.node::<ipc::Service>(Role::Tool, 0)?;
    Ok(Ports {
        real: TransitionSubscriber::create(&node, Channel::Real, to.dims.rows())?,
        stats: StatsSubscriber::create(&node)?,
        control: ControlSubscriber::create(&node)?,
        _node: node,
    })
}

/// Put `item` (about `bytes`) into the stream once the window has room; false when the
/// attempt or the worker ends first.
fn send(gate: &Gate, stop: &AtomicBool, item: Item, bytes: usize) -> Result<bool, GatewayError> {
    let st = lock(&gate.state);
    let (mut st, ok) = wait_until(
        &gate.space,
        st,
        |st| st.head.as_ref().is_some_and(|p| !p.window_full(bytes)),
        |st| stop.load(Ordering::Relaxed) || gate.quitting() || st.head.is_none(),
    );
    if ok {
        st.head.as_mut().expect("checked").send_item(item)?;
    }
    Ok(ok)
}

type Send<'a> = dyn Fn(Item, usize) -> Result<bool, GatewayError> + 'a;

/// The slot of the attempt that `producer` is.
fn slot_of(to: &ToHead, producer: ProducerId) -> Result<Slot, GatewayError> {
    let (role, index) = (producer.role(), producer.index());
    let found = role.and_then(|r| to.slots.iter().find(|s| s.is(r, index)));
    found.copied().ok_or_else(|| {
        GatewayError::Failed(format!(
            "a process of this host published as {producer}, which is none of the attempt's roles"
        ))
    })
}

/// Every transition batch waiting; `None` when the stream ended.
fn transitions(ports: &Ports, to: &ToHead, send: &Send<'_>) -> Result<Option<u64>, GatewayError> {
    let mut n = 0;
    while let Some(batch) = ports.real.receive().map_err(RuntimeError::from)? {
        let h = *batch.header();
        let item = Item::Transitions {
            slot: slot_of(to, batch.producer())?,
            actor_seq: h.seq,
            meta: TransitionMeta {
                policy_version: h.policy_version,
                model_version: h.model_version,
                env_steps: h.env_steps,
            },
            rows: batch.rows().to_vec(),
        };
        drop(batch);
        let bytes = 64 + 4 * to.dims.rows().width() * h.n_rows as usize;
        if !send(item, bytes)? {
            return Ok(None);
        }
        n += 1;
    }
    Ok(Some(n))
}

/// Every report waiting, a checkpoint file before the report that it was written.
fn reports(ports: &Ports, to: &ToHead, send: &Send<'_>) -> Result<bool, GatewayError> {
    while let Some(m) = ports.stats.receive().map_err(RuntimeError::from)? {
        let slot = slot_of(to, m.producer())?;
        if let Ok(Stats::Barrier(BarrierReport::Written(t))) = Stats::decode(&m.msg) {
            let path = checkpoint::dir_for(&to.run_dir, t).join(slot.name());
            let bytes = crate::files::read(&path)?;
            let n = bytes.len();
            let file = Item::CheckpointFile {
                slot,
                env_steps: t,
                bytes,
            };
            if !send(file, n)? {
                return Ok(false);
            }
        }
        if !send(
            Item::Stats {
                slot,
                record: m.msg,
            },
            160,
        )? {
            return Ok(false);
        }
    }
    Ok(true)
}

/// Every control message a role published (the evaluator's acknowledgements); the commands
/// this gateway itself forwards to the roles are left out.
fn control(ports: &Ports, to: &ToHead, send: &Send<'_>) -> Result<bool, GatewayError> {
    while let Some(m) = ports.control.receive().map_err(RuntimeError::from)? {
        if m.producer().role() == Some(Role::Supervisor) {
            continue;
        }
        let slot = slot_of(to, m.producer())?;
        if !send(Item::ControlFrom { slot, msg: m.msg }, 64)? {
            return Ok(false);
        }
    }
    Ok(true)
}
