//! The arguments of `mbpo bench ...` (clap derive; `mbpo`'s command line flattens
//! [`BenchCommand`] in).
#![allow(missing_docs)] // the fields' docs are the commands' --help

use clap::builder::TypedValueParser as _;
use clap::{Args, Subcommand};

#[derive(Debug, Subcommand)]
pub enum BenchCommand {
    /// Single-thread faer f32 GEMM GFLOP/s for the shapes the networks use (the roofline).
    Gemm(BenchTime),
    /// Environment steps per second, per environment, single thread.
    Env(EnvBenchArgs),
    /// One SAC update (obs 17, act 6, 2x256, batch 256: HalfCheetah dims).
    SacUpdate(SacUpdateArgs),
    /// One dynamics-model training epoch over 10k transitions (7 x 4x200, HalfCheetah dims).
    ModelTrain(ModelBenchArgs),
    /// 100k one-step model rollouts (7 x 4x200, HalfCheetah dims).
    ModelRollout(ModelBenchArgs),
    /// Learning benchmark: a training config over several seeds -> <out>/learning-<env>.json.
    Learning(LearningArgs),
    /// Where an MBPO run's time goes at given sizes of D_env: continue a run from its kept
    /// checkpoints and time each phase per env step -> <out>/breakdown-<env>.json.
    Breakdown(BreakdownArgs),
    /// What an MBPO run's critic and model believe against the real environment at its kept
    /// checkpoints: Q against real soft returns, on-policy model error against holdout,
    /// imagined data against real -> <out>/diagnose-<run>.json.
    Diagnose(DiagnoseArgs),
    /// What checkpointing an MBPO run costs: its kept checkpoint restored and written again
    /// into a scratch directory, encoding (the training loop waits) and checksum + write +
    /// fsync (the writer's thread) timed apart.
    Checkpoint(CheckpointBenchArgs),
    /// Milliseconds per MPC planning step with a randomly initialised ensemble.
    PlanLatency(PlanLatencyArgs),
    /// Milliseconds per TD-MPC2 env step: one latent MPPI plan and one update (batch 256) at
    /// TD-MPC2's defaults, random parameters, one thread.
    TdmpcStep(TdmpcStepArgs),
    /// Paced actors under load: `mbpo run --mode pipelined` at a control rate, once per
    /// real-time priority (SCHED_FIFO, and 0 for the default scheduler), with busy threads on
    /// every core; their step-interval errors, missed deadlines and realised updates per env
    /// step -> one JSON line each and <out>/realtime.json.
    Realtime(RealtimeBenchArgs),
    /// The learned termination rule against the env's own: trained on random-action
    /// transitions, tested on other episodes (precision, recall).
    Termination(TerminationBenchArgs),
}

#[derive(Debug, Args)]
pub struct TerminationBenchArgs {
    /// Environment (a built-in task with termination, e.g. Hopper-v5, or a gym: id).
    #[arg(long, default_value = "Hopper-v5")]
    pub env: String,
    /// Random-action transitions to train on.
    #[arg(long, default_value_t = 20_000)]
    pub train_steps: usize,
    /// Transitions of other episodes to test on.
    #[arg(long, default_value_t = 10_000)]
    pub test_steps: usize,
    /// Seed of the random streams.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
}

#[derive(Debug, Args)]
pub struct PlanLatencyArgs {
    /// Planner: random, cem, mppi or grad.
    #[arg(long, default_value = "cem")]
    pub planner: String,
    /// Environment (dimensions, action box, known reward).
    #[arg(long, default_value = "Pendulum-v1")]
    pub env: String,
    /// Planning horizon H.
    #[arg(long, default_value_t = 30)]
    pub horizon: usize,
    /// Candidate sequences per iteration (sequences for the gradient planner).
    #[arg(long, default_value_t = 500)]
    pub candidates: usize,
    /// Iterations per plan (Adam steps for the gradient planner).
    #[arg(long, default_value_t = 5)]
    pub iterations: usize,
    /// Particles per candidate (TS-infinity).
    #[arg(long, default_value_t = 20)]
    pub particles: usize,
    /// Ensemble members.
    #[arg(long, default_value_t = 5)]
    pub members: usize,
    /// Hidden widths, e.g. 200,200,200,200.
    #[arg(long, default_value = "200,200,200,200", value_delimiter = ',')]
    pub hidden: Vec<usize>,
    /// Plan with the model's reward head instead of the known reward.
    #[arg(long)]
    pub model_reward: bool,
    /// Timed plans (after two warm-up plans), at least 1.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..).map(|n| n as usize))]
    pub plans: usize,
}

#[derive(Debug, Args)]
pub struct TdmpcStepArgs {
    /// Observation width (walker-walk's 24 by default).
    #[arg(long, default_value_t = 24)]
    pub obs: usize,
    /// Action width.
    #[arg(long, default_value_t = 6)]
    pub act: usize,
    /// Model-size preset, "1m" or "5m".
    #[arg(long, default_value = "1m")]
    pub size: String,
    /// Timed plans and updates each (after two warm-up calls), at least 1.
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..).map(|n| n as usize))]
    pub calls: usize,
    /// Episode length of the task (its discount; DeepMind Control's 1000).
    #[arg(long, default_value_t = 1000)]
    pub episode_length: usize,
    /// Arithmetic of the plan's products: "f32", or "bf16" on AMX (f32 where the CPU has none;
    /// the line's `plan_bf16` says which ran).
    #[arg(long, default_value = "f32")]
    pub plan_precision: String,
}

#[derive(Debug, Args)]
pub struct SacUpdateArgs {
    /// Seconds of measurement.
    #[arg(long, default_value_t = 2.0)]
    pub seconds: f64,
    /// Threads one update runs on (the config's `sac.threads`).
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
    /// LayerNorm in the critics' hidden layers (`sac.critic_layer_norm`).
    #[arg(long)]
    pub critic_layer_norm: bool,
}

#[derive(Debug, Args)]
pub struct EnvBenchArgs {
    #[command(flatten)]
    pub time: BenchTime,
    /// Environment id (repeatable; default: every built-in task of this build). `gym:` ids
    /// measure a Python env through the bridge (compare with tools/gym_env_speed.py).
    #[arg(long = "env")]
    pub envs: Vec<String>,
}

#[derive(Debug, Args)]
pub struct RealtimeBenchArgs {
    /// The run's config.
    #[arg(long, default_value = "deploy/configs/pendulum.toml")]
    pub config: std::path::PathBuf,
    /// Real env steps of each run.
    #[arg(long, default_value_t = 2000)]
    pub steps: u64,
    /// Steps a second of each actor (`actor.control_hz`).
    #[arg(long, default_value_t = 50.0)]
    pub control_hz: f64,
    /// Milliseconds each env step takes at least (`actor.env_step_ms`: a simulator or robot).
    #[arg(long, default_value_t = 2.0)]
    pub env_step_ms: f64,
    /// Real-time priorities to run with, comma-separated (0: the default scheduler).
    #[arg(long, value_delimiter = ',', default_value = "10,0")]
    pub priorities: Vec<u32>,
    /// Busy threads at normal priority during each run (default: one per core): the load a
    /// shared machine adds to the learning roles'.
    #[arg(long)]
    pub load: Option<usize>,
    /// Where the runs and realtime.json go.
    #[arg(long, default_value = "runs/bench-realtime")]
    pub out: std::path::PathBuf,
}

#[derive(Debug, Args)]
pub struct BenchTime {
    /// Seconds of measurement per case.
    #[arg(long, default_value_t = 2.0)]
    pub seconds: f64,
}

#[derive(Debug, Args)]
pub struct LearningArgs {
    /// Experiment config (TOML).
    #[arg(long)]
    pub config: std::path::PathBuf,
    /// Override one key of the config (see `mbpo config show --help`).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Number of seeds (0..N), at least 1.
    #[arg(long, default_value_t = 5, value_parser = clap::value_parser!(u64).range(1..))]
    pub seeds: u64,
    /// Total real env steps per run (overrides the config).
    #[arg(long)]
    pub steps: Option<u64>,
    /// Seeds run at once. With more than one, each gets one core (the config's `sac.threads`
    /// and `model.threads` become 1); with 1, a run keeps the config's threads.
    #[arg(long, default_value_t = 2)]
    pub threads: usize,
    /// Results directory.
    #[arg(long, default_value = "results")]
    pub out: std::path::PathBuf,
    /// Env-step budgets, comma-separated (e.g. 20000,50000): report each seed's eval return at
    /// the last evaluation at or before each budget, and the wall-clock seconds to get there.
    #[arg(long, value_delimiter = ',')]
    pub budgets: Vec<u64>,
    /// Run only these of the seeds 0..N, comma-separated, and write no results file: for
    /// sharing one benchmark's seeds out between processes (each its own seeds). The same
    /// command without it then writes the file, reusing the completed runs.
    #[arg(long, value_delimiter = ',')]
    pub only_seeds: Vec<u64>,
    /// A published curve file to keep beside the results (`published` of the entry: mean ± std
    /// at its points and at the budgets), `FILE` or `LABEL=FILE` (repeatable; see `mbpo plot
    /// --peer`). A rerun without it keeps the ones given before; the MBPO authors' curve is
    /// added for an MBPO run of a task they ran.
    #[arg(long = "peer", value_name = "[LABEL=]FILE")]
    pub peers: Vec<String>,
}

#[derive(Debug, Args)]
pub struct BreakdownArgs {
    /// A run directory of `mbpo train` or `mbpo bench learning` (MBPO) with complete
    /// checkpoints at the `--at` steps (`--set checkpoint.keep_every=N` keeps them).
    #[arg(long)]
    pub run: std::path::PathBuf,
    /// Env steps (real transitions) to measure at, comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "10000,25000,50000")]
    pub at: Vec<u64>,
    /// Env steps measured after each point (whole model-training periods make sense).
    #[arg(long, default_value_t = 1000)]
    pub window: u64,
    /// Override a key of the run's config, e.g. `model.threads=2` (model threads do not
    /// change results, SAC threads only their rounding; other keys measure a different run).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Also continue each point as `mbpo run --mode MODE` (lockstep or pipelined) over the
    /// same window, for its wall-clock and each process's seconds inside IPC calls.
    #[arg(long, value_enum)]
    pub pipeline: Option<mbpo_runtime::Mode>,
    /// Project the wall-clock of a run of this many env steps from the measured points.
    #[arg(long, default_value_t = 100_000)]
    pub project: u64,
    /// Results directory (`breakdown-<env>.json`; `-` for none).
    #[arg(long, default_value = "results")]
    pub out: std::path::PathBuf,
}

#[derive(Debug, Args)]
pub struct CheckpointBenchArgs {
    /// A run directory of `mbpo train` or `mbpo bench learning` (MBPO) with a complete
    /// checkpoint at `--at`.
    #[arg(long)]
    pub run: std::path::PathBuf,
    /// Env steps of the checkpoint.
    #[arg(long)]
    pub at: u64,
    /// Writes to time.
    #[arg(long, default_value_t = 3)]
    pub repeats: usize,
    /// Scratch run directory (removed after each write; default: `<run>.checkpoint-bench`,
    /// on the run's file system, whose `fsync` is the one that counts).
    #[arg(long)]
    pub scratch: Option<std::path::PathBuf>,
}

#[derive(Debug, Args)]
pub struct DiagnoseArgs {
    /// A run directory of `mbpo train` or `mbpo bench learning` (MBPO).
    #[arg(long)]
    pub run: std::path::PathBuf,
    /// Env steps of the checkpoints to diagnose, comma-separated (default: every complete
    /// checkpoint the run kept).
    #[arg(long, value_delimiter = ',')]
    pub at: Vec<u64>,
    /// Episodes of the stochastic policy played per checkpoint.
    #[arg(long, default_value_t = 5)]
    pub episodes: usize,
    /// Override a key of the run's config (threads only; other keys diagnose another run).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub overrides: Vec<String>,
    /// Results directory (`diagnose-<run>.json`; `-` for none).
    #[arg(long, default_value = "results")]
    pub out: std::path::PathBuf,
}

#[derive(Debug, Args)]
pub struct ModelBenchArgs {
    #[command(flatten)]
    pub reps: Repetitions,
    /// Threads (`model.threads`): a training call's members in blocks, a rollout's grouped
    /// chunks in runs.
    #[arg(long, default_value_t = 1)]
    pub threads: usize,
    /// Rows per member's minibatch (`model.batch_size`; the paper's 256).
    #[arg(long, default_value_t = 256)]
    pub batch_size: usize,
    /// Element-wise kernels' instruction sets to time, comma-separated (`baseline`, `avx2`,
    /// `avx512`), interleaved within each repetition; one JSON line each. Default: the widest
    /// this CPU has.
    #[arg(long, value_delimiter = ',')]
    pub simd: Vec<mbpo_nn::simd::SimdLevel>,
}

#[derive(Debug, Args)]
pub struct Repetitions {
    /// Timed repetitions after one warm-up; the best is reported.
    #[arg(long, default_value_t = 5)]
    pub repetitions: usize,
}
