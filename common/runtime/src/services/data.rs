//! Real data of a worker that keeps its own D_env (model trainer, rollout generator): what it
//! takes as transitions arrive, before a training or branch, and at a checkpoint cut.
//!
//! The role takes real transitions as they arrive: in lockstep the first `upto` (those its next
//! training or branch sees), pipelined all of them (it works on whatever has arrived). It reads
//! its D_env only when it works, so this equals taking them then, and nothing it may see waits
//! in shared memory.

use mbpo_core::TransitionSink;
use mbpo_wire::{TransitionSubscriber, Transport};

use crate::barrier::Cut;
use crate::error::ensure_protocol;
use crate::serving::Step;
use crate::{Mode, Process, RealInbox, Result};

/// Receive what arrived into `inbox`, the role taking what it may see; true once the first
/// `need` transitions of the run have been received.
pub fn pull<S: Transport>(
    mode: Mode,
    real: &TransitionSubscriber<S>,
    inbox: &mut RealInbox<S>,
    role: &mut dyn TransitionSink,
    need: u64,
) -> Result<bool> {
    let upto = match mode {
        Mode::Lockstep => need,
        Mode::Pipelined => u64::MAX,
    };
    inbox.pull(real, upto, role)?;
    Ok(inbox.received() >= need)
}

/// After its last train point, the worker of process `s` takes the rest of the run's real
/// transitions, so that no actor blocks and its counts are complete: finished once all arrived.
pub fn the_rest<S: Transport>(
    s: &Process<S>,
    real: &TransitionSubscriber<S>,
    inbox: &mut RealInbox<S>,
    role: &mut dyn TransitionSink,
) -> Result<Step> {
    let all = pull(s.mode, real, inbox, role, s.cfg.steps)?;
    Ok(if all { Step::Finished } else { Step::Waiting })
}

/// Before the work of train point `t`: lockstep takes exactly the first t − 1 transitions,
/// pipelined every one received.
pub fn take_for<S: Transport>(
    mode: Mode,
    inbox: &mut RealInbox<S>,
    role: &mut dyn TransitionSink,
    t: u64,
) {
    let n = match mode {
        Mode::Lockstep => (t - 1 - inbox.taken()) as usize,
        Mode::Pipelined => inbox.pending(),
    };
    inbox.take(n, role);
}

/// At the cut the role holds every transition ≤ T: take those not taken yet once all have
/// arrived (false: not yet). More than T is a protocol error: the actors are paused.
pub fn take_upto_cut<S: Transport>(
    real: &TransitionSubscriber<S>,
    inbox: &mut RealInbox<S>,
    role: &mut dyn TransitionSink,
    cut: Cut,
) -> Result<bool> {
    let t = cut.env_steps;
    inbox.pull(real, t, role)?;
    if inbox.received() < t {
        return Ok(false);
    }
    ensure_protocol!(
        inbox.received() == t,
        "checkpoint after step {t}: {} real transitions arrived although the actors are paused",
        inbox.received()
    );
    inbox.take((t - inbox.taken()) as usize, role);
    Ok(true)
}
