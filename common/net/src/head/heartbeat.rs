//! The head's heartbeat thread: liveness both ways, resending stalled streams and newer
//! weights a worker missed, failing the gateway when a worker is silent for
//! `--worker-timeout`, and `hosts-live.json` on every change of who holds the slots.

use std::collections::HashSet;
use std::path::Path;
use std::time::{Duration, Instant};

use mbpo_runtime::hosts::LiveHosts;

use super::account::live_hosts;
use super::state::{Gate, Shared};
use crate::peer::{lock, HEARTBEAT_PERIOD};

/// A worker silent this long is logged (the run waits for it meanwhile).
const SILENCE_WARNING: Duration = Duration::from_secs(2);

/// The heartbeat thread.
pub(crate) fn heartbeat(gate: &Gate, timeout: Duration, run_dir: &Path) {
    let mut silenced = HashSet::new();
    let mut live: Option<LiveHosts> = None;
    while !gate.stopping() {
        std::thread::sleep(HEARTBEAT_PERIOD);
        let mut st = lock(&gate.state);
        let sessions: Vec<u64> = st.workers.keys().copied().collect();
        for s in sessions {
            if !beat(&mut st, s, timeout, &mut silenced) {
                break;
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

/// One worker's beat: fail a worker silent past `timeout` (false), say when it goes quiet or
/// is heard again, send the heartbeat, what its stream needs again and a snapshot it missed.
fn beat(st: &mut Shared, s: u64, timeout: Duration, silenced: &mut HashSet<u64>) -> bool {
    let now = Instant::now();
    let latest = st.weights.clone();
    let seen = st.weights_seen.get(&s).copied().unwrap_or((0, None));
    let w = st.workers.get_mut(&s).expect("listed");
    let silent = now.duration_since(w.last_heard);
    let name = w.name.clone();
    if silent > timeout {
        st.fail(format!(
            "worker {name} silent for {:.0} s (--worker-timeout): its roles' state is taken for lost",
            silent.as_secs_f64()
        ));
        return false;
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
    true
}
