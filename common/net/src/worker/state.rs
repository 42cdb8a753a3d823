//! What the worker gateway's threads share: the link to the head, the attempt under way (its
//! role processes, local iceoryx2 run and to-head thread), and why the worker must end.

use std::path::PathBuf;
use std::process::Child;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Condvar, Mutex};
use std::time::Instant;

use mbpo_runtime::run_plan::Slot;
use mbpo_wire::RunIpc;

use crate::peer::Peer;
use crate::protocol::Assignment;
use crate::GatewayError;

/// One role process of the attempt.
pub(crate) struct RoleProc {
    pub slot: Slot,
    pub child: Child,
    pub log: PathBuf,
    pub log_offset: u64,
    pub told_to_stop: bool,
    /// Its exit was seen (and reported if it was not told to stop).
    pub reported: bool,
}

/// One attempt: the slots of one head session.
pub(crate) struct Attempt {
    pub assignment: Assignment,
    pub run_dir: PathBuf,
    pub ipc: RunIpc,
    pub procs: Vec<RoleProc>,
    pub stop: Arc<AtomicBool>,
    pub to_head: Option<std::thread::JoinHandle<Result<u64, GatewayError>>>,
    /// When the head's supervisor rolled this attempt back (a process of the head crashed):
    /// once the roles have exited the worker leaves it and joins the next attempt.
    pub rolled_back: Option<Instant>,
}

impl Attempt {
    /// Whether it was rolled back and its roles have exited (or had 5 s to): the worker leaves
    /// it for the head's next attempt. (The old head ignores its hellos.)
    pub fn rolled_back_and_stopped(&self) -> bool {
        self.rolled_back.is_some_and(|t| {
            self.procs.iter().all(|p| p.reported) || t.elapsed() > std::time::Duration::from_secs(5)
        })
    }
}

/// The state of a worker's gateway.
pub(crate) struct Shared {
    pub me: u64,
    pub head: Option<Peer>,
    pub attempt: Option<Attempt>,
    pub finished: bool,
    /// When `Item::Bye` went into the stream.
    pub bye_sent: Option<Instant>,
    pub weights_have: u64,
    pub failure: Option<String>,
}

/// The shared state, the condition the threads wait on for window space, and the end.
pub(crate) struct Gate {
    pub state: Mutex<Shared>,
    pub space: Condvar,
    pub quit: AtomicBool,
}

impl Gate {
    /// A worker of session `me`, in no run yet.
    pub fn new(me: u64) -> Self {
        Self {
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
        }
    }
    /// The worker is ending.
    pub fn quitting(&self) -> bool {
        self.quit.load(Ordering::Relaxed)
    }
}
