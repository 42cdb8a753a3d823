//! The head's to-workers thread: for every remote slot it subscribes what the slot's role
//! subscribes on the head (control commands addressed to it, and the weights it acts with)
//! and forwards them to the worker holding the slot. Control for a slot no worker holds yet
//! waits in that slot's queue; weights are latest values, sent to every worker.

use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use mbpo_runtime::remote::weights_channel;
use mbpo_runtime::run_plan::Slot;
use mbpo_runtime::{configure_run, Dims, PipelineSpec, RuntimeError, ServiceArgs};
use mbpo_wire::*;

use super::state::Gate;
use crate::peer::{lock, wait_until};
use crate::protocol::{encode, Body, Envelope, Item, WeightsMsg, PROTOCOL_VERSION};
use crate::{actor_weights, GatewayError};

/// One remote slot's subscribers on the head.
struct SlotIn {
    slot: Slot,
    me: ProducerId,
    control: ControlSubscriber<ipc::Service>,
    weights: Option<WeightsSubscriber<ipc::Service>>,
    _node: WireNode<ipc::Service>,
}

/// The to-workers thread: control commands and weights of the remote slots.
pub(crate) fn to_workers(
    gate: &Gate,
    args: &ServiceArgs,
    pipeline: &'static PipelineSpec,
    dims: Dims,
    slots: &[Slot],
) -> Result<(), GatewayError> {
    let mut run = RunIpc::new(&args.run_id, &args.ipc_root)?;
    configure_run(&mut run);
    let (kind, hash, len) = actor_weights(pipeline, &dims);
    let channel = weights_channel(pipeline);
    let mut ins = Vec::new();
    for &slot in slots {
        let node = run.node::<ipc::Service>(slot.kind.wire_role(), slot.index)?;
        let weights = match slot.kind.subscribes(channel) {
            true => Some(WeightsSubscriber::create(&node, kind, hash, len)?),
            false => None,
        };
        ins.push(SlotIn {
            slot,
            me: node.producer(),
            control: ControlSubscriber::create(&node)?,
            weights,
            _node: node,
        });
    }
    let mut waiter = Waiter::new().map_err(RuntimeError::from)?;
    for s in &ins {
        waiter.attach(&s.control);
        if let Some(w) = &s.weights {
            waiter.attach(w);
        }
    }
    while !gate.stopping() {
        let woke = waiter.wait(Duration::from_millis(200));
        if woke.map_err(RuntimeError::from)? == WaitOutcome::Terminate {
            break;
        }
        for s in &ins {
            while let Some(m) = s.control.receive().map_err(RuntimeError::from)? {
                if m.msg.is_for(s.me) {
                    forward_control(gate, s.slot, m.msg)?;
                }
            }
        }
        if let Some((version, msg)) = newest_weights(&ins, kind)? {
            publish_weights(gate, version, msg)?;
        }
    }
    Ok(())
}

/// The newest snapshot any slot's subscriber holds, as a message for the workers.
fn newest_weights(
    ins: &[SlotIn],
    kind: WeightsKind,
) -> Result<Option<(u64, WeightsMsg)>, GatewayError> {
    let mut newest: Option<(u64, WeightsMsg)> = None;
    for w in ins.iter().filter_map(|s| s.weights.as_ref()) {
        let Some(s) = w.receive_latest().map_err(RuntimeError::from)? else {
            continue;
        };
        if newest.as_ref().is_some_and(|(v, _)| s.version() <= *v) {
            continue;
        }
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
    Ok(newest)
}

/// Send a snapshot newer than the last to every worker (encoded once).
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
fn forward_control(gate: &Gate, slot: Slot, msg: ControlMsg) -> Result<(), GatewayError> {
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
            let peer = st.workers.get_mut(&w).expect("checked");
            peer.send_item(Item::Control { slot, msg })?;
        }
        None => st.pending[i].push_back(msg),
    }
    Ok(())
}
