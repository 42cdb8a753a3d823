//! The worker's heartbeat thread: liveness both ways, resends, the role processes (one that
//! ends without being told to is reported, and the head restarts the pipeline from its
//! checkpoint) and their logs, the head (silent for `--head-timeout`: the roles stop and the
//! worker joins again), and the last `Bye` once the run is over and every role exited.

use std::path::Path;
use std::time::Instant;

use super::attempt::end_attempt;
use super::state::{Attempt, Gate};
use super::WorkerOptions;
use crate::peer::{lock, HEARTBEAT_PERIOD};
use crate::protocol::Item;

/// The heartbeat thread.
pub(crate) fn heartbeat(gate: &Gate, opts: &WorkerOptions) {
    while !gate.quitting() {
        std::thread::sleep(HEARTBEAT_PERIOD);
        let mut st = lock(&gate.state);
        let now = Instant::now();
        let weights = st.weights_have;
        let mut items = st.attempt.as_mut().map(watch_roles).unwrap_or_default();
        // The run is over and every role has exited: their last log lines, then Bye.
        let all_exited = st
            .attempt
            .as_ref()
            .is_some_and(|a| a.procs.iter().all(|p| p.reported));
        if st.finished && all_exited && st.bye_sent.is_none() {
            if let Some(a) = st.attempt.as_mut() {
                items.extend(new_logs(a));
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
                "the head is silent for {:.0} s (--head-timeout): stopping the roles and joining again",
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

/// The roles' new log lines, and a report of each role that exited without being told to.
fn watch_roles(a: &mut Attempt) -> Vec<Item> {
    let mut items = new_logs(a);
    for p in a.procs.iter_mut().filter(|p| !p.reported) {
        let Ok(Some(status)) = p.child.try_wait() else {
            continue;
        };
        p.reported = true;
        if !(status.success() && p.told_to_stop) {
            let reason = format!(
                "its process ended ({status}) without being told to stop; log tail:\n{}",
                tail(&p.log, 15)
            );
            tracing::error!("{}: {reason}", p.slot);
            items.push(Item::SlotFailed {
                slot: p.slot,
                reason,
            });
        }
    }
    items
}

/// Each role's log text written since the last look.
fn new_logs(a: &mut Attempt) -> Vec<Item> {
    let logs = a.procs.iter_mut().filter_map(|p| {
        let text = new_log_text(&p.log, &mut p.log_offset)?;
        Some(Item::Log { slot: p.slot, text })
    });
    logs.collect()
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
