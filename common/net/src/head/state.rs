//! What the head gateway's three threads share: the workers, who holds each remote slot,
//! control waiting for a slot no worker holds yet, the newest weights, and why the gateway
//! must end.

use std::collections::{HashMap, HashSet, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Instant;

use mbpo_runtime::run_plan::Slot;
use mbpo_wire::{ControlMsg, StopReason};

use crate::peer::{lock, Peer};

/// The state of the head's gateway.
pub(crate) struct Shared {
    /// Our session id.
    pub me: u64,
    /// The remote slots, in the run plan's order (actors first).
    pub slots: Vec<Slot>,
    pub workers: HashMap<u64, Peer>,
    /// Worker session holding each remote slot.
    pub owner: Vec<Option<u64>>,
    /// Control commands for slots no worker holds yet.
    pub pending: Vec<VecDeque<ControlMsg>>,
    /// Per remote slot, the Stop it was told and why: the run is over, or this attempt is
    /// rolled back and the run goes on.
    pub stopped: Vec<Option<StopReason>>,
    /// The newest weights: version and encoded envelope.
    pub weights: Option<(u64, Arc<Vec<u8>>)>,
    /// Per worker: newest weight version it has, and when we last sent it one.
    pub weights_seen: HashMap<u64, (u64, Option<Instant>)>,
    /// Why the gateway must end (a remote role's state is lost).
    pub failure: Option<String>,
    pub finished_sent: bool,
    /// Workers whose `Item::Bye` arrived.
    pub said_bye: HashSet<u64>,
}

impl Shared {
    /// Nobody holds any of `slots` yet.
    pub fn new(me: u64, slots: Vec<Slot>) -> Self {
        let n = slots.len();
        Self {
            me,
            slots,
            workers: HashMap::new(),
            owner: vec![None; n],
            pending: vec![VecDeque::new(); n],
            stopped: vec![None; n],
            weights: None,
            weights_seen: HashMap::new(),
            failure: None,
            finished_sent: false,
            said_bye: HashSet::new(),
        }
    }
    /// The position of remote slot `slot`.
    pub fn slot_index(&self, slot: Slot) -> Option<usize> {
        self.slots.iter().position(|s| *s == slot)
    }
    /// The slots worker `session` holds.
    pub fn slots_of(&self, session: u64) -> Vec<Slot> {
        let held = self.slots.iter().zip(&self.owner);
        held.filter(|(_, o)| **o == Some(session))
            .map(|(s, _)| *s)
            .collect()
    }
    /// Whether every remote slot was told to stop for `why`.
    pub fn all_stopped(&self, why: StopReason) -> bool {
        self.stopped.iter().all(|&s| s == Some(why))
    }
    /// End the gateway for `why` (the first reason counts).
    pub fn fail(&mut self, why: String) {
        if self.failure.is_none() {
            tracing::error!("{why}");
            self.failure = Some(why);
        }
    }
}

/// The shared state, the condition the threads wait on for window space, and the end.
pub(crate) struct Gate {
    pub state: Mutex<Shared>,
    pub space: Condvar,
    pub quit: AtomicBool,
}

impl Gate {
    /// A gate over `shared`.
    pub fn new(shared: Shared) -> Self {
        Self {
            state: Mutex::new(shared),
            space: Condvar::new(),
            quit: AtomicBool::new(false),
        }
    }
    /// The gateway is ending (told to, or failed).
    pub fn stopping(&self) -> bool {
        self.quit.load(Ordering::Relaxed) || lock(&self.state).failure.is_some()
    }
}
