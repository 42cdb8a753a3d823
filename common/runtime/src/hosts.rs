//! Which hosts a multi-host run's actors are on: the head's gateway writes the files, the
//! supervisor reads them.
//!
//! * [`HOSTS_FILE`]: the account per worker host for `summary.json` (actors, transition
//!   batches, attempts, restarts), rewritten while an attempt runs (on every change of the
//!   workers and every 2 s) and when the gateway ends it; a killed gateway's attempt is in it.
//! * [`LIVE_HOSTS_FILE`]: who holds the remote actor slots right now, rewritten on every
//!   change of membership, for the progress line.

use std::path::Path;

use serde::{Deserialize, Serialize};

/// The head's gateway's account of the worker hosts, in the run directory.
pub const HOSTS_FILE: &str = "hosts.json";

/// Who holds the remote slots now, in the run directory.
pub const LIVE_HOSTS_FILE: &str = "hosts-live.json";

/// The remote slots and the workers holding them.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct LiveHosts {
    /// Remote slots of the run, actors and other roles (held or not).
    pub remote_slots: u16,
    /// Workers holding slots, by name.
    pub workers: Vec<LiveWorker>,
}

/// One worker host's slots.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct LiveWorker {
    /// Its name (`mbpo join --name`).
    pub name: String,
    /// The actor slots it runs.
    pub actors: Vec<u16>,
    /// The other roles it runs, by process name (`evaluator`).
    #[serde(default)]
    pub roles: Vec<String>,
    /// Nothing heard from it for a while (the link may be down; the run waits for it).
    pub silent: bool,
}

impl LiveHosts {
    /// Write `<run_dir>/hosts-live.json` (a temp file renamed over it: a reader never sees half).
    pub fn write(&self, run_dir: &Path) -> std::io::Result<()> {
        let path = run_dir.join(LIVE_HOSTS_FILE);
        let tmp = path.with_extension("json.tmp");
        let text = serde_json::to_string(self).map_err(std::io::Error::other)?;
        std::fs::write(&tmp, text)?;
        std::fs::rename(tmp, path)
    }

    /// The file of `run_dir`, if the run has one that reads.
    pub fn read(run_dir: &Path) -> Option<Self> {
        let text = std::fs::read_to_string(run_dir.join(LIVE_HOSTS_FILE)).ok()?;
        serde_json::from_str(&text).ok()
    }

    /// The progress line's part, e.g. `hosts: head 1, gpu-box 2, robot-pc 0 + evaluator,
    /// 1 slot free`: each host's actors and other roles (silent workers marked `(silent)`).
    pub fn progress_text(&self, local_actors: u16) -> String {
        let mut parts = vec![format!("head {local_actors}")];
        let mut held = 0;
        for w in &self.workers {
            held += w.actors.len() + w.roles.len();
            let silent = if w.silent { " (silent)" } else { "" };
            let roles: String = w.roles.iter().map(|r| format!(" + {r}")).collect();
            parts.push(format!("{} {}{roles}{silent}", w.name, w.actors.len()));
        }
        let free = usize::from(self.remote_slots).saturating_sub(held);
        if free > 0 {
            parts.push(format!(
                "{free} slot{} free",
                if free == 1 { "" } else { "s" }
            ));
        }
        format!("hosts: {}", parts.join(", "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_progress_text_names_each_host_and_the_free_slots() {
        let mut hosts = LiveHosts {
            remote_slots: 3,
            workers: vec![LiveWorker {
                name: "gpu-box".into(),
                actors: vec![1, 2],
                roles: vec![],
                silent: false,
            }],
        };
        assert_eq!(
            hosts.progress_text(1),
            "hosts: head 1, gpu-box 2, 1 slot free"
        );
        hosts.workers[0].roles.push("evaluator".into());
        hosts.remote_slots = 4;
        assert_eq!(
            hosts.progress_text(1),
            "hosts: head 1, gpu-box 2 + evaluator, 1 slot free"
        );
        hosts.workers[0].roles.clear();
        hosts.remote_slots = 3;
        hosts.workers[0].silent = true;
        hosts.workers[0].actors.push(3);
        assert_eq!(hosts.progress_text(0), "hosts: head 0, gpu-box 3 (silent)");
    }

    #[test]
    fn the_file_round_trips_and_a_missing_one_reads_as_none() {
        let dir = std::env::temp_dir().join(format!("mbpo-live-hosts-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        assert_eq!(LiveHosts::read(&dir), None);
        let hosts = LiveHosts {
            remote_slots: 2,
            workers: vec![LiveWorker {
                name: "w".into(),
                actors: vec![4, 5],
                roles: vec!["evaluator".into()],
                silent: true,
            }],
        };
        hosts.write(&dir).unwrap();
        assert_eq!(LiveHosts::read(&dir), Some(hosts));
        std::fs::remove_dir_all(dir).unwrap();
    }
}
