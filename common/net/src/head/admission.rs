//! Who runs what: a worker's Hello is answered with the free slots it offers to run and
//! everything needed to run them (the run's config, plan and, when resuming, the slots'
//! checkpoint files), or with the reason it is refused.

use std::time::Instant;

use mbpo_runtime::run_plan::Slot;
use mbpo_wire::StopReason;
use zenoh::Wait;

use super::state::{Gate, Shared};
use super::HeadOptions;
use crate::files::{checkpoint_step, read};
use crate::peer::{lock, publisher, Peer};
use crate::protocol::{encode, Assignment, Body, Envelope, Item, ResumeFiles, PROTOCOL_VERSION};
use crate::session;
use crate::GatewayError;

/// What a worker's Hello offers: `actors` actor slots and the roles named `roles`.
pub(crate) struct Offer {
    pub worker: String,
    pub actors: u16,
    pub roles: Vec<String>,
}

impl Offer {
    /// The free slots (positions in `st.slots`) it takes: actors up to its count, and every
    /// other role it names.
    fn takes(&self, st: &Shared) -> Vec<usize> {
        let free = (0..st.slots.len()).filter(|&i| st.owner[i].is_none());
        let (mut actors, mut take) = (0, Vec::new());
        for i in free {
            let slot = st.slots[i];
            let wanted = match slot.kind.is_actor() {
                true => actors < self.actors,
                false => self.roles.contains(&slot.name()),
            };
            if wanted {
                actors += u16::from(slot.kind.is_actor());
                take.push(i);
            }
        }
        take
    }
    /// Why it is refused: no free slot is one it offers to run.
    fn refusal(&self, st: &Shared) -> String {
        let free: Vec<String> = (0..st.slots.len())
            .filter(|&i| st.owner[i].is_none())
            .map(|i| st.slots[i].name())
            .collect();
        let offers = match self.roles.is_empty() {
            true => format!("{} actor(s)", self.actors),
            false => format!("{} actor(s) and {}", self.actors, self.roles.join(", ")),
        };
        match free.is_empty() {
            true => "the run's remote slots are all taken".into(),
            false => format!(
                "no free slot is one this worker offers ({offers}); free: {} (`mbpo join --actors N --roles NAME`)",
                free.join(", ")
            ),
        }
    }
}

/// Say `reason` to worker `to`, which is not (or no longer) admitted.
pub(crate) fn refuse(
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
pub(crate) fn admit(
    gate: &Gate,
    session: &zenoh::Session,
    opts: &HeadOptions,
    from: u64,
    offer: Offer,
) -> Result<(), GatewayError> {
    let mut st = lock(&gate.state);
    if st.stopped.contains(&Some(StopReason::RollBack)) {
        // This attempt is over: the worker's hello is for the next one.
        return Ok(());
    }
    if let Some(w) = st.workers.get_mut(&from) {
        // Our Welcome was lost: it comes again below from the stored assignment.
        w.last_heard = Instant::now();
    } else if !join(&mut st, session, from, &offer)? {
        drop(st);
        let reason = offer.refusal(&lock(&gate.state));
        tracing::warn!("refused worker {}: {reason}", offer.worker);
        return refuse(session, gate, from, &reason);
    }
    if st.failure.is_some() {
        return Ok(());
    }
    let slots = st.slots_of(from);
    let assignment = assignment(opts, slots.clone())?;
    st.workers[&from].send_now(Body::Welcome(Box::new(assignment)))?;
    // Control that waited for these slots, in order.
    for slot in slots {
        let i = st.slot_index(slot).expect("an owned slot");
        while let Some(msg) = st.pending[i].pop_front() {
            let peer = st.workers.get_mut(&from).expect("just admitted");
            peer.send_item(Item::Control { slot, msg })?;
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

/// Make `from` a member holding the free slots it offers; false if there are none. A worker
/// of a known name with a new session restarted: its roles' state is lost (the gateway fails).
fn join(
    st: &mut Shared,
    session: &zenoh::Session,
    from: u64,
    offer: &Offer,
) -> Result<bool, GatewayError> {
    let worker = &offer.worker;
    if let Some(old) = st.workers.values().find(|w| w.name == *worker) {
        let why = format!(
            "worker {worker} restarted (session {:016x} -> {from:016x}): its roles' state since the last checkpoint is gone",
            old.session
        );
        st.fail(why);
        return Ok(true);
    }
    let take = offer.takes(st);
    if take.is_empty() {
        return Ok(false);
    }
    let pubr = publisher(session, session::head_to_worker(from))?;
    let mut peer = Peer::new(st.me, from, worker.clone(), pubr);
    peer.last_heard = Instant::now();
    let names: Vec<String> = take.iter().map(|&i| st.slots[i].name()).collect();
    tracing::info!("worker {worker} ({from:016x}) joined: {}", names.join(", "));
    for &i in &take {
        st.owner[i] = Some(from);
    }
    st.workers.insert(from, peer);
    st.weights_seen.insert(from, (0, None));
    Ok(true)
}

/// What a worker needs to run `slots`: the run's config and plan and, when resuming, their
/// files.
fn assignment(opts: &HeadOptions, slots: Vec<Slot>) -> Result<Assignment, GatewayError> {
    let args = &opts.service;
    let text = |p: &std::path::Path| read(p).map(|b| String::from_utf8_lossy(&b).into_owned());
    let config_toml = text(&args.run_dir.join("config.toml"))?;
    let run_plan = text(&args.run_dir.join(mbpo_runtime::run_plan::RUN_PLAN_FILE))?;
    let env_path = args.run_dir.join(mbpo_train::run_dir::ENV_FILE);
    let env_json = env_path.is_file().then(|| text(&env_path)).transpose()?;
    let resume = match &args.resume_from {
        Some(dir) => {
            let env_steps = checkpoint_step(dir)?;
            let mut files = Vec::new();
            for &slot in &slots {
                files.push((slot, read(&dir.join(slot.name()))?));
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
