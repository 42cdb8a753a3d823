//! Per-run isolation: an iceoryx2 [`Config`] with the run's own prefix and root path, node
//! creation, and removal of stale and leftover resources.
//!
//! POSIX shared-memory names ignore iceoryx2's root path (they all live in `/dev/shm`), so two
//! runs on one host are kept apart by `global.prefix`, derived here from a hash of the run id
//! and the base directory (`mbpo<10 hex>_`). Files (service descriptions, node records, event sockets) go under
//! `<base_dir>/<prefix>/`. Every process of a run builds the same [`RunIpc`] from the run id and
//! base directory it was given, so they agree on both.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Duration;

use iceoryx2::config::Config;
use iceoryx2::node::{Node, NodeBuilder, NodeState, NodeView};
use iceoryx2::prelude::{CallbackProgression, FileName, NodeName, SemanticString};
use iceoryx2::service::Service;

use crate::error::{CleanupError, NodeCreateError, RunIpcError};
use crate::names::{valid_run_id, Channel, ProducerId, Role};

/// Directory where Linux exposes POSIX shared memory objects.
pub const SHM_DIR: &str = "/dev/shm";

/// Longest root path we accept: event sockets are `<root><prefix><port id, up to 39
/// digits>.event` (measured) and a unix socket path holds at most 107 bytes.
const MAX_ROOT_LEN: usize = 48;

/// Resource limits of one channel's services. Every process of a run must use the same values:
/// iceoryx2 treats them as minimum requirements when it opens an existing service and refuses
/// a service created with smaller ones (an `Incompatible...`/`DoesNotSupport...` error).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ChannelQos {
    /// Publishers that may exist at once (live ones; dead ones are cleaned up).
    pub max_publishers: usize,
    /// Subscribers that may exist at once.
    pub max_subscribers: usize,
    /// Nodes that may open the service at once.
    pub max_nodes: usize,
    /// Samples queued per subscriber before a publisher blocks (reliable channels) or
    /// overwrites (weights).
    pub buffer_size: usize,
    /// Samples one subscriber may hold at once.
    pub max_borrowed: usize,
    /// Samples one publisher may have loaned at once.
    pub max_loaned: usize,
}

impl ChannelQos {
    /// The default limits of `channel` (see the table in the crate docs).
    pub const fn default_for(channel: Channel) -> Self {
        let (max_publishers, max_subscribers, max_nodes, buffer_size) = match channel {
            // Actors (scaled per core, plus restarts) -> model trainer, rollout generator,
            // learner, and a monitor.
            Channel::Real => (16, 6, 32, 16),
            // Rollout generator -> learner; batches can be 100k rows, keep the chunk count low.
            Channel::Imagined => (2, 2, 8, 4),
            // Learner -> actors, rollout generator, supervisor.
            Channel::Policy => (2, 24, 32, 1),
            // Model trainer -> rollout generator, supervisor.
            Channel::Model => (2, 8, 16, 1),
            // Everyone -> supervisor.
            Channel::Stats => (32, 2, 40, 256),
            // Supervisor -> everyone, and acknowledgements back. The queue holds a barrier's
            // Pause, cut and Resume plus the coordinator's resend of Pause and cut for each
            // subscriber that joins during the barrier (at most 32): a role still starting
            // (waiting for its own consumers) reads none of them yet, and a full queue would
            // block the coordinator.
            Channel::Control => (32, 32, 40, 2 * 32 + 8),
        };
        ChannelQos {
            max_publishers,
            max_subscribers,
            max_nodes,
            buffer_size,
            max_borrowed: 2,
            max_loaned: 2,
        }
    }
}

/// What a run's ports need to know about the run.
#[derive(Debug, Clone)]
pub(crate) struct RunShared {
    pub run_id: String,
    pub run_hash: u64,
    pub config: Config,
    pub qos: [ChannelQos; 6],
    pub stall_timeout: Option<Duration>,
}

impl RunShared {
    pub fn qos(&self, c: Channel) -> ChannelQos {
        self.qos[(c.tag() - 1) as usize]
    }
}

/// The iceoryx2 environment of one run.
#[derive(Debug, Clone)]
pub struct RunIpc {
    shared: Arc<RunShared>,
    prefix: String,
    root: PathBuf,
}

/// What [`RunIpc::remove_stale_nodes`] found.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct StaleCleanup {
    /// Nodes of live processes.
    pub alive: usize,
    /// Dead nodes whose resources were removed.
    pub removed: usize,
    /// Dead nodes whose resources could not be removed (see the log).
    pub failed: usize,
    /// Nodes in an undefined or inaccessible state.
    pub other: usize,
}

impl RunIpc {
    /// The environment of run `run_id`, with the iceoryx2 root path `<base_dir>/<prefix>/`.
    ///
    /// `base_dir` must be short (the root path is limited to 48 bytes because event sockets
    /// live under it); `/tmp/mbpo-ipc` is a good choice.
    pub fn new(run_id: &str, base_dir: impl AsRef<Path>) -> Result<Self, RunIpcError> {
        if !valid_run_id(run_id) {
            return Err(RunIpcError::InvalidRunId(run_id.to_string()));
        }
        let run_hash = run_hash(run_id);
        // The prefix also depends on the base directory: the same run id under two base
        // directories (two checkouts, two users) must not share /dev/shm names either.
        let base = base_dir.as_ref();
        let place = format!("{run_id}\0{}", base.display());
        let prefix = format!(
            "mbpo{:010x}_",
            mbpo_core::rng::fnv1a(place.as_bytes()) & 0xff_ffff_ffff
        );
        let run = Self::with_prefix(run_id, run_hash, prefix, base)?;
        std::fs::create_dir_all(&run.root).map_err(|source| RunIpcError::Io {
            path: format!("{}/", run.root.display()),
            source,
        })?;
        Ok(run)
    }

    /// The environment with iceoryx2 prefix `prefix` and root path `<base>/<prefix>/` (not
    /// created here: cleaning up another run must not recreate its directory).
    fn with_prefix(
        run_id: &str,
        run_hash: u64,
        prefix: String,
        base: &Path,
    ) -> Result<Self, RunIpcError> {
        let root = base.join(prefix.trim_end_matches('_'));
        let root_str = format!("{}/", root.display());
        if root_str.len() > MAX_ROOT_LEN {
            return Err(RunIpcError::RootPathTooLong {
                path: root_str.clone(),
                len: root_str.len(),
                max: MAX_ROOT_LEN,
            });
        }
        let mut config = Config::default();
        config.global.prefix =
            FileName::new(prefix.as_bytes()).map_err(|e| RunIpcError::Config {
                what: "prefix",
                value: prefix.clone(),
                cause: format!("{e:?}"),
            })?;
        let root_path =
            iceoryx2::prelude::Path::new(root_str.as_bytes()).map_err(|e| RunIpcError::Config {
                what: "root path",
                value: root_str.clone(),
                cause: format!("{e:?}"),
            })?;
        config.global.set_root_path(&root_path);
        Ok(Self {
            shared: Arc::new(RunShared {
                run_id: run_id.to_string(),
                run_hash,
                config,
                qos: Channel::ALL.map(ChannelQos::default_for),
                stall_timeout: None,
            }),
            prefix,
            root,
        })
    }

    /// Replace the limits of `channel`. Every process of the run must make the same change.
    pub fn set_qos(&mut self, channel: Channel, qos: ChannelQos) -> &mut Self {
        Arc::make_mut(&mut self.shared).qos[(channel.tag() - 1) as usize] = qos;
        self
    }

    /// Make reliable publishers give up (with [`crate::PublishError::Stalled`]) when a
    /// subscriber has not made room for `timeout`. `None` (the default) waits for ever: a
    /// consumer that trains for minutes is normal backpressure, not an error.
    pub fn set_stall_timeout(&mut self, timeout: Option<Duration>) -> &mut Self {
        Arc::make_mut(&mut self.shared).stall_timeout = timeout;
        self
    }

    /// The limits of `channel`.
    pub fn qos(&self, channel: Channel) -> ChannelQos {
        self.shared.qos(channel)
    }
    /// The run id.
    pub fn run_id(&self) -> &str {
        &self.shared.run_id
    }
    /// 64-bit hash of the run id, stamped in every header.
    pub fn run_hash(&self) -> u64 {
        self.shared.run_hash
    }
    /// The iceoryx2 `global.prefix` of the run (also the prefix of its `/dev/shm` files).
    pub fn prefix(&self) -> &str {
        &self.prefix
    }
    /// The iceoryx2 root path of the run.
    pub fn root_path(&self) -> &Path {
        &self.root
    }
    /// The iceoryx2 configuration of the run (for tools such as `iox2` and for tests).
    pub fn config(&self) -> &Config {
        &self.shared.config
    }
    /// The service name of `channel` in this run.
    pub fn service_name(&self, channel: Channel) -> String {
        channel.service_name(&self.shared.run_id)
    }

    /// A node for process `(role, index)` of this run, named `<role>-<index>`. SIGINT and
    /// SIGTERM are captured from here on (see [`crate::termination_requested`]).
    pub fn node<S: Service>(&self, role: Role, index: u16) -> Result<WireNode<S>, NodeCreateError> {
        let producer = ProducerId::new(role, index);
        let name = format!("{}-{}", role.name(), index);
        let node_name = NodeName::new(&name).map_err(|e| NodeCreateError::InvalidName {
            name: name.clone(),
            cause: format!("{e:?}"),
        })?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&self.shared.config)
            .create::<S>()
            .map_err(|source| NodeCreateError::Iceoryx {
                name: name.clone(),
                root: self.root.display().to_string(),
                source,
            })?;
        // Installs iceoryx2's SIGINT/SIGTERM capture now rather than at the first wait.
        let _ = crate::termination_requested();
        Ok(WireNode {
            node: Arc::new(node),
            run: self.shared.clone(),
            producer,
            name,
        })
    }

    /// Remove the resources of this run's nodes whose processes died (crash, SIGKILL). Call it
    /// at start-up, before creating ports; nodes of live processes are left alone.
    pub fn remove_stale_nodes<S: Service>(&self) -> Result<StaleCleanup, CleanupError> {
        let mut report = StaleCleanup::default();
        let mut dead = Vec::new();
        Node::<S>::list(&self.shared.config, |state| {
            match state {
                NodeState::Alive(_) => report.alive += 1,
                NodeState::Dead(view) => dead.push(view),
                NodeState::Inaccessible(_) | NodeState::Undefined(_) => report.other += 1,
            }
            CallbackProgression::Continue
        })?;
        for view in dead {
            let id = format!("{:?}", view.id());
            match view.blocking_remove_stale_resources(Duration::from_secs(2)) {
                Ok(()) => report.removed += 1,
                Err(e) => {
                    tracing::warn!(node = %id, error = ?e, "cannot remove the resources of a dead node");
                    report.failed += 1;
                }
            }
        }
        Ok(report)
    }

    /// Record this process as the run's launcher (`<root>/launcher`: pid and start time), so
    /// that [`RunIpc::remove_dead_runs`] of a later launcher knows at once when it is gone.
    pub fn mark_launcher(&self) -> std::io::Result<()> {
        let me = std::process::id();
        let start = process_start_ticks(me).unwrap_or(0);
        std::fs::create_dir_all(&self.root)?;
        std::fs::write(self.root.join(LAUNCHER_FILE), format!("{me} {start}\n"))
    }

    /// Remove what other runs left under `base_dir` once every one of their nodes is known
    /// dead (a node of unknown state, e.g. another user's, counts as alive). A run without any
    /// node counts as dead only when its launcher is known gone ([`RunIpc::mark_launcher`]) or,
    /// if it has no launcher file, when its root path is at least `min_age` old (a run starting
    /// this moment has no node yet). A launcher killed with SIGKILL cannot clean up after
    /// itself, so the next one on the host does.
    /// Returns the root paths removed. A run that cannot be inspected or removed is logged and
    /// skipped: someone else's leftovers never stop a launch.
    pub fn remove_dead_runs<S: Service>(
        base_dir: impl AsRef<Path>,
        min_age: Duration,
    ) -> Vec<PathBuf> {
        let base = base_dir.as_ref();
        let Ok(entries) = std::fs::read_dir(base) else {
            return Vec::new();
        };
        let mut removed = Vec::new();
        for entry in entries.flatten() {
            let name = entry.file_name().to_string_lossy().into_owned();
            let is_run_root = name.len() == 14
                && name.starts_with("mbpo")
                && name[4..].bytes().all(|b| b.is_ascii_hexdigit());
            let old_enough = entry
                .metadata()
                .and_then(|m| m.modified())
                .is_ok_and(|t| t.elapsed().is_ok_and(|age| age >= min_age));
            if !is_run_root {
                continue;
            }
            let launcher_alive = launcher_alive(&entry.path());
            if launcher_alive == Some(true) {
                continue;
            }
            let Ok(run) = Self::with_prefix(&name, 0, format!("{name}_"), base) else {
                continue;
            };
            let launcher_gone = launcher_alive == Some(false);
            match run.dead_nodes_if_all_dead::<S>() {
                Ok(Some(dead)) if dead > 0 || launcher_gone || old_enough => {}
                Ok(_) => continue,
                Err(e) => {
                    tracing::warn!(run = %run.root.display(), error = %e, "cannot inspect a run's nodes; left as it is");
                    continue;
                }
            }
            match run.remove_all::<S>() {
                Ok(_) => removed.push(run.root),
                Err(e) => {
                    tracing::warn!(run = %run.root.display(), error = %e, "cannot remove a dead run's leftovers")
                }
            }
        }
        removed
    }

    /// The number of this run's nodes when every one is known dead (none alive, none of
    /// unknown state); `None` otherwise.
    fn dead_nodes_if_all_dead<S: Service>(&self) -> Result<Option<usize>, CleanupError> {
        let (mut dead, mut all_dead) = (0, true);
        Node::<S>::list(&self.shared.config, |state| {
            match state {
                NodeState::Dead(_) => dead += 1,
                _ => all_dead = false,
            }
            CallbackProgression::Continue
        })?;
        Ok(all_dead.then_some(dead))
    }

    /// Names of the live nodes of this run.
    pub fn alive_nodes<S: Service>(&self) -> Result<Vec<String>, CleanupError> {
        let mut alive = Vec::new();
        Node::<S>::list(&self.shared.config, |state| {
            if let NodeState::Alive(view) = state {
                alive.push(match view.details() {
                    Some(d) => format!("{} (pid {})", d.name().as_str(), d.process_id().value()),
                    None => format!("{:?}", view.id()),
                });
            }
            CallbackProgression::Continue
        })?;
        Ok(alive)
    }

    /// Remove everything the run left: dead nodes' resources, then every `/dev/shm` object with
    /// the run's prefix, then the root path. Refuses while a node of the run is alive.
    /// Returns the number of files removed.
    pub fn remove_all<S: Service>(&self) -> Result<usize, CleanupError> {
        let alive = self.alive_nodes::<S>()?;
        if !alive.is_empty() {
            return Err(CleanupError::NodesStillAlive(alive));
        }
        self.remove_stale_nodes::<S>()?;
        let mut removed = 0;
        for path in self.shm_files() {
            match std::fs::remove_file(&path) {
                Ok(()) => removed += 1,
                Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
                Err(source) => {
                    return Err(CleanupError::Io {
                        path: path.display().to_string(),
                        source,
                    })
                }
            }
        }
        removed += count_files(&self.root);
        match std::fs::remove_dir_all(&self.root) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
            Err(source) => {
                return Err(CleanupError::Io {
                    path: self.root.display().to_string(),
                    source,
                })
            }
        }
        Ok(removed)
    }

    /// Every resource of the run that still exists: `/dev/shm` objects with the run's prefix
    /// and files under its root path. Empty after [`RunIpc::remove_all`].
    pub fn leftovers(&self) -> Vec<PathBuf> {
        let mut out = self.shm_files();
        list_files(&self.root, &mut out);
        out
    }

    fn shm_files(&self) -> Vec<PathBuf> {
        let mut out = Vec::new();
        if let Ok(rd) = std::fs::read_dir(SHM_DIR) {
            for e in rd.flatten() {
                if e.file_name().to_string_lossy().starts_with(&self.prefix) {
                    out.push(e.path());
                }
            }
        }
        out.sort();
        out
    }
}

/// The file in a run's root path naming its launcher.
const LAUNCHER_FILE: &str = "launcher";

/// Whether the launcher recorded under `root` still runs (`None`: no readable record). A pid
/// is taken for the same process only with the same start time (pids are reused).
fn launcher_alive(root: &Path) -> Option<bool> {
    let text = std::fs::read_to_string(root.join(LAUNCHER_FILE)).ok()?;
    let mut fields = text.split_whitespace().map(str::parse::<u64>);
    let (Some(Ok(pid)), Some(Ok(start))) = (fields.next(), fields.next()) else {
        return None;
    };
    let pid = u32::try_from(pid).ok()?;
    Some(process_start_ticks(pid).is_some_and(|s| s == start))
}

/// Start time of process `pid` in clock ticks since boot (`/proc/<pid>/stat` field 22), or
/// `None` if there is no such process (a zombie counts as gone).
fn process_start_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // Fields after the command name (which may hold spaces) start at field 3, the state.
    let rest = &stat[stat.rfind(')')? + 2..];
    let mut fields = rest.split_whitespace();
    if fields.next()? == "Z" {
        return None;
    }
    fields.nth(18)?.parse().ok()
}

fn list_files(dir: &Path, out: &mut Vec<PathBuf>) {
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            let p = e.path();
            if e.file_type().map(|t| t.is_dir()).unwrap_or(false) {
                list_files(&p, out);
            } else {
                out.push(p);
            }
        }
    }
}

fn count_files(dir: &Path) -> usize {
    let mut v = Vec::new();
    list_files(dir, &mut v);
    v.len()
}

/// 64-bit hash of a run id, stamped in every header.
pub fn run_hash(run_id: &str) -> u64 {
    mbpo_core::rng::fnv1a(run_id.as_bytes())
}

/// A process's node in a run: creates the run's ports.
#[derive(Debug)]
pub struct WireNode<S: Service = iceoryx2::service::ipc::Service> {
    pub(crate) node: Arc<Node<S>>,
    pub(crate) run: Arc<RunShared>,
    pub(crate) producer: ProducerId,
    name: String,
}

impl<S: Service> WireNode<S> {
    /// The producer id stamped on everything this node publishes.
    pub fn producer(&self) -> ProducerId {
        self.producer
    }
    /// The node name, `<role>-<index>`.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The run id.
    pub fn run_id(&self) -> &str {
        &self.run.run_id
    }
    /// The run hash.
    pub fn run_hash(&self) -> u64 {
        self.run.run_hash
    }
    /// The underlying iceoryx2 node (for diagnostics; services should not need it).
    pub fn iceoryx_node(&self) -> &Node<S> {
        &self.node
    }
}
