//! What the head's gateway tells the supervisor about the worker hosts: `<run>/hosts.json`
//! (the account per host for `summary.json`) and `<run>/hosts-live.json` (who holds the remote
//! slots now, for the progress line).

use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::Duration;

use mbpo_runtime::hosts::{LiveHosts, LiveWorker};
use mbpo_runtime::run_plan::Slot;

use super::state::Shared;
use crate::files::write_atomically;
use crate::GatewayError;

/// How often a running attempt rewrites `hosts.json`.
pub(crate) const HOSTS_REWRITE: Duration = Duration::from_secs(2);

/// How often the receiving loop looks whether `hosts.json` is due (a change of the workers is
/// written at most this late).
pub(crate) const ACCOUNT_CHECK: Duration = Duration::from_millis(100);

/// Transition batches delivered per remote slot in this attempt.
pub(crate) type Batches = HashMap<Slot, u64>;

/// `<run>/hosts.json`, the account per worker host: its actors and other roles, transition
/// batches, attempts joined and restarts (attempts it ended by losing its roles' state).
///
/// The file is read once when the gateway starts (the earlier attempts' account) and this
/// attempt's part is added to that each time it is written: on every change of the workers,
/// every [`HOSTS_REWRITE`] while the attempt runs, and when the gateway ends. So writing it
/// again is harmless, and a gateway that is killed leaves its attempt in the file with counts
/// at most that old.
pub(crate) struct HostsAccount {
    path: PathBuf,
    before: serde_json::Map<String, serde_json::Value>,
}

impl HostsAccount {
    /// The account of `run_dir` as earlier attempts left it.
    pub fn load(run_dir: &Path) -> Self {
        let path = run_dir.join(mbpo_runtime::HOSTS_FILE);
        let before = std::fs::read_to_string(&path)
            .ok()
            .and_then(|t| serde_json::from_str(&t).ok())
            .unwrap_or_default();
        Self { path, before }
    }

    /// Write the earlier attempts' account plus this attempt's as it stands.
    fn write(&self, st: &Shared, counts: &Batches) -> Result<(), GatewayError> {
        let mut hosts = self.before.clone();
        for (session, w) in &st.workers {
            let slots = st.slots_of(*session);
            let batches: u64 = slots.iter().filter_map(|s| counts.get(s)).sum();
            let e = hosts.entry(w.name.clone()).or_insert_with(
                || serde_json::json!({"attempts": 0, "restarts": 0, "transition_batches": 0}),
            );
            let failed = st
                .failure
                .as_deref()
                .is_some_and(|f| f.contains(&format!("worker {} ", w.name)));
            let n = |k: &str| e[k].as_u64().unwrap_or(0);
            let (actors, roles) = split(&slots);
            *e = serde_json::json!({
                "actors": actors,
                "roles": roles,
                "attempts": n("attempts") + 1,
                "restarts": n("restarts") + u64::from(failed),
                "transition_batches": n("transition_batches") + batches,
                "resent": w.resent(),
                "duplicates_dropped": w.duplicates(),
            });
        }
        let text = serde_json::to_string_pretty(&hosts).unwrap_or_default() + "\n";
        write_atomically(&self.path, text.as_bytes())
    }

    /// [`HostsAccount::write`], a failure logged (the account must not stop the run).
    pub fn write_or_warn(&self, st: &Shared, counts: &Batches) {
        if let Err(e) = self.write(st, counts) {
            tracing::warn!("writing {}: {e}", self.path.display());
        }
    }
}

/// Actor indices and the other roles' names of `slots`.
fn split(slots: &[Slot]) -> (Vec<u16>, Vec<String>) {
    let actors = slots.iter().filter(|s| s.kind.is_actor()).map(|s| s.index);
    let roles = slots
        .iter()
        .filter(|s| !s.kind.is_actor())
        .map(|s| s.name());
    (actors.collect(), roles.collect())
}

/// Who holds the remote slots now (for the supervisor's progress line).
pub(crate) fn live_hosts(st: &Shared, silenced: &HashSet<u64>) -> LiveHosts {
    let mut workers: Vec<LiveWorker> = st
        .workers
        .iter()
        .map(|(session, w)| {
            let (actors, roles) = split(&st.slots_of(*session));
            LiveWorker {
                name: w.name.clone(),
                actors,
                roles,
                silent: silenced.contains(session),
            }
        })
        .collect();
    workers.sort_by(|a, b| (&a.actors, &a.roles).cmp(&(&b.actors, &b.roles)));
    LiveHosts {
        remote_slots: st.slots.len() as u16,
        workers,
    }
}
