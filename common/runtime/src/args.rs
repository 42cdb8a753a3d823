//! The command line every service takes from the launcher, and the hand-off modes.

use std::path::PathBuf;

/// How hand-offs between processes are sequenced.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum Mode {
    /// Zero slack: every hand-off waits for exactly the version the sequential algorithm uses;
    /// with one actor the run equals `mbpo train --mode sequential` bit for bit.
    Lockstep,
    /// Bounded slack (--policy-lag, --update-buffer, --model-lag): acting, model training,
    /// rollouts and SAC updates overlap.
    Pipelined,
}

impl Mode {
    /// Lower-case name (as on the command line).
    pub fn name(self) -> &'static str {
        match self {
            Mode::Lockstep => "lockstep",
            Mode::Pipelined => "pipelined",
        }
    }
}

/// The error buffers of pipelined mode (all zero in lockstep).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::Args, serde::Serialize, serde::Deserialize)]
pub struct Slack {
    /// Pipelined: policy versions (env steps) an actor's policy may lag behind the step it takes.
    #[arg(long, default_value_t = 2)]
    pub policy_lag: u64,
    /// Pipelined: how many SAC updates the learner's count may be ahead of or behind G times
    /// the real env steps it has taken in (so it can keep updating while the next transition
    /// is on its way, and catch up after a model training).
    #[arg(long, default_value_t = 40)]
    pub update_buffer: u64,
    /// Pipelined: env steps the learner may consume past a train point before the rollouts
    /// branched for it must have arrived (model staleness of the data it trains on).
    #[arg(long, default_value_t = 25)]
    pub model_lag: u64,
}

impl Slack {
    /// No slack at all (lockstep).
    pub const ZERO: Slack = Slack {
        policy_lag: 0,
        update_buffer: 0,
        model_lag: 0,
    };
    /// The slack in force in `mode`.
    pub fn effective(self, mode: Mode) -> Slack {
        match mode {
            Mode::Lockstep => Slack::ZERO,
            Mode::Pipelined => self,
        }
    }
}

/// The command line the supervisor gives every service.
#[derive(Debug, Clone, clap::Args)]
pub struct ServiceArgs {
    /// Run directory holding the resolved `config.toml`.
    #[arg(long)]
    pub run_dir: PathBuf,
    /// Run id (selects the run's iceoryx2 prefix and service names).
    #[arg(long)]
    pub run_id: String,
    /// Base directory of the run's iceoryx2 root path (keep it short).
    #[arg(long, default_value = "/tmp/mbpo-ipc")]
    pub ipc_root: PathBuf,
    /// Index of this process within its role.
    #[arg(long, default_value_t = 0)]
    pub index: u16,
    /// Hand-off mode.
    #[arg(long, value_enum, default_value = "lockstep")]
    pub mode: Mode,
    /// Number of (training) actors in the run.
    #[arg(long, default_value_t = 1)]
    pub actors: u16,
    /// The error buffers of pipelined mode.
    #[command(flatten)]
    pub slack: Slack,
    /// Continue from this checkpoint directory (`<run-dir>/checkpoints/<T>`; `mbpo run --resume`).
    #[arg(long)]
    pub resume_from: Option<PathBuf>,
    /// An actor on a worker host: its one consumer is the host's gateway (`mbpo join`), which
    /// carries its transitions to the head's consumers.
    #[arg(long)]
    pub behind_gateway: bool,
}

/// `mbpo join`'s arguments (a worker host's gateway, `mbpo-gateway join`): here rather than in
/// the gateway's binary so that `mbpo docs` can write them into the command reference without
/// `mbpo` linking the network stack.
#[derive(Debug, clap::Args)]
pub struct JoinArgs {
    /// The head's endpoint, e.g. tcp/10.0.0.1:7447 (tls/... with credentials).
    pub head: String,
    /// Actors to offer.
    #[arg(long, default_value_t = 1)]
    pub actors: u16,
    /// Actors per core of this host (instead of --actors).
    #[arg(long)]
    pub actors_per_core: Option<u16>,
    /// Roles besides actors to offer, by process name, comma-separated: `evaluator`, for a
    /// head started with `mbpo run --remote-roles evaluator` (`--actors 0 --roles evaluator`
    /// offers the evaluator alone).
    #[arg(long, value_delimiter = ',', value_name = "ROLE")]
    pub roles: Vec<String>,
    /// Credentials directory (`mbpo certs`, the worker's part).
    #[arg(long)]
    pub credentials: Option<PathBuf>,
    /// This worker's name in the head's logs and summary (default: host name).
    #[arg(long)]
    pub name: Option<String>,
    /// Directory for the actors' local files.
    #[arg(long)]
    pub dir: Option<PathBuf>,
    /// Base directory of this host's iceoryx2 root.
    #[arg(long, default_value = "/tmp/mbpo-ipc")]
    pub ipc_root: PathBuf,
    /// Seconds the head may be silent before this worker stops its actors and joins again
    /// (keep it above the head's --worker-timeout, 30 s, so the head gives up first).
    #[arg(long, default_value_t = 60.0)]
    pub head_timeout: f64,
}

/// `mbpo certs`'s arguments (`mbpo-gateway certs`).
#[derive(Debug, clap::Args)]
pub struct CertsArgs {
    /// Directory to create them in: DIR/head and DIR/worker (a CA, a certificate each, a
    /// password).
    #[arg(long)]
    pub out: PathBuf,
}
