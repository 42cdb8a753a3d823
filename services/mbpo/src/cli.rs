//! Command-line definitions (clap derive).

use clap::{Args, Parser, Subcommand};

/// MBPO (model-based policy optimization) as a pipelined multi-process system.
#[derive(Debug, Parser)]
#[command(name = "mbpo", version, about)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

impl ChaosArgs {
    /// The plan of `mbpo chaos`: these arguments, run with this `mbpo` executable.
    pub fn plan(&self) -> anyhow::Result<mbpo_bench::chaos::ChaosPlan> {
        let mbpo = std::env::current_exe()
            .map_err(|e| anyhow::anyhow!("finding the mbpo executable: {e}"))?;
        Ok(mbpo_bench::chaos::ChaosPlan {
            config: self.source.config.clone(),
            overrides: self.source.overrides.clone(),
            steps: self.steps,
            runs: self.runs,
            kills: self.kills,
            mode: self.mode,
            actors: self.actors,
            max_delay_seconds: self.max_delay_seconds,
            kill_seed: self.kill_seed,
            kill_supervisor: self.kill_supervisor,
            out: self.out.clone(),
            ipc_root: self.ipc_root.clone(),
            mbpo,
        })
    }
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Train in a single process (SAC baseline; MBPO sequential reference).
    Train(TrainArgs),
    /// Run MBPO as a multi-process pipeline (actors, model trainer, rollout generator, SAC
    /// learner over iceoryx2 shared memory), supervised by this process.
    Run(RunArgs),
    /// Run actors (and other roles) for a head on another host (`mbpo run --listen E
    /// --remote-actors M` there): `mbpo join tcp/<head>:7447 [--actors N | --actors-per-core K]
    /// [--roles evaluator] [--credentials DIR]`. Checks its arguments, then runs `mbpo-gateway
    /// join` with them.
    Join(mbpo_runtime::args::JoinArgs),
    /// Make credentials for a multi-host run: `mbpo certs --out DIR` writes DIR/head and
    /// DIR/worker (a CA, a certificate each, a password); runs `mbpo-gateway certs`.
    Certs(mbpo_runtime::args::CertsArgs),
    /// Environment tools: list environments, replay an action sequence.
    #[command(subcommand)]
    Env(EnvCommand),
    /// Experiment configs: print the resolved config.
    #[command(subcommand)]
    Config(ConfigCommand),
    /// Evaluate the newest checkpointed policy of a run: mean and std of the return over
    /// deterministic episodes (one JSON line).
    Eval(EvalArgs),
    /// Plot learning curves (mean and min..max over seeds, one colour per group) to a PNG, and
    /// the training losses (critic, actor, alpha, model holdout MSE) to `<out stem>-losses.png`.
    Plot(PlotArgs),
    /// Micro-benchmarks that print one JSON object per line.
    #[command(subcommand)]
    Bench(mbpo_bench::command::BenchCommand),
    /// Chaos: run the pipeline several times with `--restart on-failure`, SIGKILL random
    /// processes at random times, and report per run whether it completed with nothing lost
    /// and nothing left behind (lockstep: on the sequential run's policy). One JSON line per
    /// run and one for all; `<out>/chaos.json`.
    Chaos(ChaosArgs),
    /// Write the book's reference pages from the code: the configuration reference (every
    /// key's doc comment, type and default) and this command reference (every command's
    /// `--help`).
    Docs(DocsArgs),
}

#[derive(Debug, Args)]
pub struct DocsArgs {
    /// Directory of the pages.
    #[arg(long, default_value = "docs/src/reference")]
    pub out: std::path::PathBuf,
    /// Write nothing; fail when a page there differs from what the code generates.
    #[arg(long)]
    pub check: bool,
}

#[derive(Debug, Args)]
pub struct ChaosArgs {
    #[command(flatten)]
    pub source: ConfigSource,
    /// Total real env steps of each run (overrides the config's `steps`). Set
    /// `checkpoint.every` well below it (`--set checkpoint.every=100`): a kill waits for a
    /// checkpoint, and a restart resumes from the newest one.
    #[arg(long)]
    pub steps: Option<u64>,
    /// Runs.
    #[arg(long, default_value_t = 5)]
    pub runs: u64,
    /// SIGKILLs per run (each once the previous restart is up).
    #[arg(long, default_value_t = 2)]
    pub kills: u32,
    /// Hand-off mode.
    #[arg(long, value_enum, default_value = "pipelined")]
    pub mode: mbpo_runtime::Mode,
    /// Training actors.
    #[arg(long, default_value_t = 1)]
    pub actors: u16,
    /// Kill points are uniform over the run's first 80 % of env steps (as the newest checkpoint
    /// shows them); a kill then comes a uniform random 0..this many seconds later.
    #[arg(long, default_value_t = 0.5)]
    pub max_delay_seconds: f64,
    /// Seed of the kill schedule (which process, when).
    #[arg(long, default_value_t = 0)]
    pub kill_seed: u64,
    /// SIGKILL `mbpo run` itself instead of one of its processes, then continue the run with
    /// `mbpo run --resume`: each kill reports how long the run's processes outlived it and what
    /// shared memory it left, and the resumed run must complete and clean that up.
    #[arg(long)]
    pub kill_supervisor: bool,
    /// Output directory: the runs and `chaos.json`.
    #[arg(long, default_value = "runs/chaos")]
    pub out: std::path::PathBuf,
    /// Base directory of the runs' iceoryx2 files (as `mbpo run --ipc-root`; keep it short).
    #[arg(long, default_value = "/tmp/mbpo-ipc")]
    pub ipc_root: std::path::PathBuf,
}

#[derive(Debug, Subcommand)]
pub enum ConfigCommand {
    /// Print the config a run would use (file, then every --set, validated) as TOML. The
    /// environment is made once to check it exists (a `gym:` id starts its Python process);
    /// what it is goes to the log on stderr.
    Show(ConfigShowArgs),
}

#[derive(Debug, Args)]
pub struct ConfigShowArgs {
    #[command(flatten)]
    pub source: ConfigSource,
    /// Do not make the environment (print the config without checking that `env` exists).
    #[arg(long)]
    pub no_env_check: bool,
}

/// Where a config comes from: a file (or the defaults) and `--set` overrides.
#[derive(Debug, Args, Clone)]
pub struct ConfigSource {
    /// Experiment config (TOML); defaults are used for keys it does not set.
    #[arg(long)]
    pub config: Option<std::path::PathBuf>,
    /// Override one key, e.g. `--set sac.gamma=0.98 --set sac.hidden=[64,64]` (TOML values;
    /// anything else is a string). Applied in order, after the file.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
}

#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Run directory (with config.toml and checkpoints/).
    pub run: std::path::PathBuf,
    /// Deterministic evaluation episodes.
    #[arg(long, default_value_t = 10)]
    pub episodes: usize,
    /// Seed of the start states (stream `eval.cli` of this seed).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

#[derive(Debug, Subcommand)]
pub enum EnvCommand {
    /// List the environments with their observation and action dimensions.
    List,
    /// Step an environment from a given state through given actions; one JSON line per step.
    Replay(ReplayArgs),
}

#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// Environment id, e.g. Pendulum-v1 (see `mbpo env list`).
    #[arg(long)]
    pub env: String,
    /// Start state, comma-separated (Pendulum: theta,thetadot; MountainCar: position,velocity;
    /// MuJoCo tasks: qpos then qvel, see `mbpo env list`).
    #[arg(long, allow_hyphen_values = true)]
    pub state: String,
    /// Actions, comma-separated, act_dim values per step.
    #[arg(long, allow_hyphen_values = true)]
    pub actions: String,
}

/// The flags every training command shares.
#[derive(Debug, Args, Clone)]
pub struct CommonTrainArgs {
    #[command(flatten)]
    pub source: ConfigSource,
    /// Run seed (overrides the config's `seed`).
    #[arg(long)]
    pub seed: Option<u64>,
    /// Total real env steps (overrides the config's `steps`).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Run directory (default: runs/<algo>-<env>-s<seed>, or the first free `-2`, `-3`, ...
    /// after it when that holds an earlier run).
    #[arg(long)]
    pub out: Option<std::path::PathBuf>,
    /// Delete the earlier run in `--out` (checkpoints, logs, results) and start afresh;
    /// without it, a fresh run into a directory holding a run is refused.
    #[arg(long, requires = "out")]
    pub overwrite: bool,
}

#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Algorithm (overrides the config's `algo`).
    #[arg(long, value_parser = ["sac", "mbpo", "mpc"])]
    pub algo: Option<String>,
    /// Environment id (overrides the config's `env`).
    #[arg(long)]
    pub env: Option<String>,
    /// Execution mode: `sequential` runs every role in this one process (the reference the
    /// multi-process pipeline, `mbpo run`, is tested against).
    #[arg(long, value_parser = ["sequential"], default_value = "sequential")]
    pub mode: String,
    /// Continue the run in this directory from its newest complete checkpoint, with the
    /// config it was started with (`--steps` may extend it; no other overrides).
    #[arg(long, value_name = "RUN_DIR", conflicts_with_all = ["algo", "env", "config", "overrides", "seed", "out", "overwrite"])]
    pub resume: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub common: CommonTrainArgs,
}

#[derive(Debug, Args)]
pub struct PlotArgs {
    /// Run directories (each with a metrics.csv); runs named <group>-s<seed> are grouped.
    #[arg(required = true)]
    pub runs: Vec<std::path::PathBuf>,
    /// metrics.csv column to plot against env_steps.
    #[arg(long, default_value = "eval_return")]
    pub column: String,
    /// Output PNG (the loss panels go to `<stem>-losses.png` next to it).
    #[arg(long, default_value = "curves.png")]
    pub out: std::path::PathBuf,
    /// Plot title.
    #[arg(long, default_value = "learning curves")]
    pub title: String,
    /// Env steps between the columns of the markdown table of eval returns written next to the
    /// PNG (`<stem>.md`: each seed, the median, the MBPO paper's curve where there is one).
    #[arg(long, default_value_t = 10_000, value_parser = clap::value_parser!(u64).range(1..))]
    pub table_every: u64,
    /// A published curve file to draw and tabulate beside the runs, `FILE` or `LABEL=FILE`
    /// (repeatable): tdmpc2's `results/<method>/<task>.csv` (`step,reward,seed`) or SimbaV2's
    /// `results/baseline/<method>.csv` (the rows of the runs' task); mean ± std over its seeds.
    #[arg(long = "peer", value_name = "[LABEL=]FILE")]
    pub peers: Vec<String>,
}

/// How a crashed service process is handled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum RestartPolicy {
    /// A crash fails the run.
    Never,
    /// Restart the pipeline from its newest checkpoint (every process: a consistent cut) up to
    /// `--max-restarts` times per process, then fail.
    OnFailure,
}

#[derive(Debug, Clone, Args)]
pub struct RunArgs {
    /// Continue the run in this directory from its newest complete checkpoint, with its config,
    /// mode, actors and slack (`--steps` may extend it). An MBPO run checkpointed by `mbpo
    /// train` continues with one actor in the `--mode` given (lockstep: bit for bit).
    #[arg(long, value_name = "RUN_DIR", conflicts_with_all = ["config", "overrides", "seed", "out", "overwrite"])]
    pub resume: Option<std::path::PathBuf>,
    #[command(flatten)]
    pub common: CommonTrainArgs,
    /// Hand-off mode: `lockstep` equals `mbpo train --mode sequential` bit for bit (one actor);
    /// `pipelined` overlaps the processes within bounded slack.
    #[arg(long, value_enum, default_value = "pipelined")]
    pub mode: mbpo_runtime::Mode,
    /// Number of environment actors (lockstep needs exactly 1).
    #[arg(long, default_value_t = 1)]
    pub actors: u16,
    /// Actors per CPU core (overrides --actors: K x available cores).
    #[arg(long)]
    pub actors_per_core: Option<u16>,
    #[command(flatten)]
    pub slack: mbpo_runtime::Slack,
    /// Base directory of the run's iceoryx2 files (kept short: unix socket paths live under it).
    #[arg(long, default_value = "/tmp/mbpo-ipc")]
    pub ipc_root: std::path::PathBuf,
    /// What to do when a service process crashes.
    #[arg(long, value_enum, default_value = "never")]
    pub restart: RestartPolicy,
    /// Restarts allowed per process with `--restart on-failure`.
    #[arg(long, default_value_t = 3)]
    pub max_restarts: u32,
    /// Pin process i to CPU i mod ncpu (sched_setaffinity). A paced actor under real-time
    /// priority (`actor.realtime_priority`) pins itself to a core of its own, which the other
    /// processes keep off while another core is left.
    #[arg(long)]
    pub pin_cpus: bool,
    /// No live progress bar: log a plain progress line every 10 s instead.
    #[arg(long)]
    pub quiet: bool,
    /// Steps a second each actor takes, on a clock (`actor.control_hz`; pipelined runs): inside
    /// an episode an actor acts with the newest weights it holds, between episodes it waits for
    /// those its next step needs. Its log ends with its missed deadlines.
    #[arg(
        long,
        value_name = "HZ",
        conflicts_with = "resume",
        allow_negative_numbers = true
    )]
    pub control_hz: Option<f64>,
    #[command(flatten)]
    pub remote: RemoteArgs,
}

impl RunArgs {
    /// The actors on this host, slots `0..local_actors()` (once `actors` counts the remote
    /// ones too): the one place the split is computed; the run plan records it.
    pub fn local_actors(&self) -> u16 {
        self.actors - self.remote.remote_actors
    }
}

/// Roles on other hosts: `mbpo run --listen E --remote-actors M [--remote-roles evaluator]`
/// here, `mbpo join E` there.
#[derive(Debug, Clone, Args)]
pub struct RemoteArgs {
    /// Admit roles of worker hosts (`mbpo join ENDPOINT`) on this Zenoh endpoint, e.g.
    /// tcp/127.0.0.1:7447; an address beyond this host needs --credentials. Give it with
    /// --remote-actors, --remote-roles or both.
    #[arg(long, value_name = "ENDPOINT")]
    pub listen: Option<String>,
    /// Actor slots for worker hosts, besides the --actors on this host (the run has both).
    #[arg(long, default_value_t = 0, requires = "listen")]
    pub remote_actors: u16,
    /// Roles besides actors that run on a worker host, by process name, comma-separated:
    /// `evaluator` (e.g. on the robot's own computer). The worker offers it with `mbpo join
    /// --roles evaluator`; a role the gateways cannot carry (the learner, the model trainer)
    /// is refused with the channel they do not carry.
    #[arg(long, value_delimiter = ',', value_name = "ROLE", requires = "listen")]
    pub remote_roles: Vec<String>,
    /// Credentials directory made by `mbpo certs` (its `head` part).
    #[arg(long, value_name = "DIR", requires = "listen")]
    pub credentials: Option<std::path::PathBuf>,
    /// Seconds a worker may be silent before its actors' state is taken for lost (the run then
    /// restarts from its newest checkpoint with --restart on-failure, or fails).
    #[arg(long, default_value_t = 30.0, requires = "listen")]
    pub worker_timeout: f64,
}
