//! What the pipeline's service binaries (`mbpo-actor`, `mbpo-model-trainer`,
//! `mbpo-rollout-generator`, `mbpo-sac-learner`) and the supervisor (`mbpo run`) share, so
//! that no two processes can disagree:
//!
//! * [`ServiceArgs`]: the command line every service takes from the supervisor;
//! * [`Mode`] and [`Slack`]: lockstep (zero slack) or pipelined (bounded slack) hand-offs;
//! * [`Process`]: config, run IPC and node of one process; [`Dims`]: sizes and layout hashes
//!   of everything that crosses shared memory;
//! * [`ModelWireLayout`]: how a [`ModelWeights`] crosses as one flat `[f32]`;
//! * [`stats`]: the meaning of every [`StatsRecord`] a service sends;
//! * [`RealInbox`] (real transitions held back until a role may see them) and
//!   [`ControlInbox`] (stop requests, evaluation acknowledgements, checkpoint barriers);
//! * [`barrier`]: checkpoints of the running pipeline (the barrier protocol and the files).

pub mod barrier;
pub mod stats;

use std::cell::{Cell, RefCell};
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;
use mbpo_core::rng::stream;
use mbpo_core::Batch;
use mbpo_model::{InputNormalizer, ModelWeights, ProbabilisticEnsemble};
use mbpo_sac::TanhGaussianActor;
use mbpo_train::ExperimentConfig;
use mbpo_wire::{
    ipc, ControlCommand, ControlMsg, ControlPublisher, ControlSubscriber, ProducerId, Role,
    RowLayout, RunIpc, TransitionSubscriber, WaitOutcome, Waiter, WireNode,
};

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
    /// Pipelined: SAC updates the learner may run ahead of or behind G per env step.
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
    #[command(flatten)]
    pub slack: Slack,
    /// Continue from this checkpoint directory (`<run-dir>/checkpoints/<T>`; `mbpo run --resume`).
    #[arg(long)]
    pub resume_from: Option<PathBuf>,
}

/// Logs to stderr (the supervisor redirects it to `<run-dir>/logs/<process>.log`).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(false)
        .try_init();
}

/// Load `<run_dir>/config.toml` (written by the supervisor).
pub fn load_config(run_dir: &Path) -> anyhow::Result<ExperimentConfig> {
    let path = run_dir.join("config.toml");
    ExperimentConfig::load(&path).with_context(|| format!("loading {}", path.display()))
}

/// Sizes and layout hashes of everything that crosses shared memory in a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dims {
    /// Observation width.
    pub obs: usize,
    /// Action width.
    pub act: usize,
    /// `ParamLayout::hash` of the SAC actor.
    pub policy_hash: u64,
    /// Floats in a policy snapshot.
    pub policy_len: usize,
    /// How model snapshots are laid out.
    pub model: ModelWireLayout,
}

impl Dims {
    /// The dimensions of the run configured by `cfg`.
    pub fn of(cfg: &ExperimentConfig) -> anyhow::Result<Self> {
        let env = mbpo_envs::make(&cfg.env)?;
        let (obs, act) = (env.obs_dim(), env.act_dim());
        let net = TanhGaussianActor::new(
            obs,
            act,
            &cfg.sac.hidden,
            cfg.sac.log_std_min,
            cfg.sac.log_std_max,
        );
        Ok(Self {
            obs,
            act,
            policy_hash: net.layout().hash(),
            policy_len: net.num_params(),
            model: ModelWireLayout::of(cfg, obs, act)?,
        })
    }
    /// The transition row layout.
    pub fn rows(&self) -> RowLayout {
        RowLayout::new(self.obs, self.act)
    }
    /// A fresh actor network (architecture only).
    pub fn actor_net(&self, cfg: &ExperimentConfig) -> TanhGaussianActor {
        TanhGaussianActor::new(
            self.obs,
            self.act,
            &cfg.sac.hidden,
            cfg.sac.log_std_min,
            cfg.sac.log_std_max,
        )
    }
}

/// A model snapshot ([`ModelWeights`]) as one flat `[f32]`:
///
/// ```text
/// [ θ (n_params, ParamLayout order) | normaliser mean (obs+act) | normaliser std (obs+act) | elites (as f32) ]
/// ```
///
/// The header's layout hash is the ensemble's `ParamLayout::hash`; the lengths of the other
/// parts follow from the config (obs+act inputs, `model.elites` elites), so a mismatch in any
/// of them changes the total length and is rejected by the subscriber.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModelWireLayout {
    /// `ParamLayout::hash` of the ensemble.
    pub layout_hash: u64,
    /// Floats of θ.
    pub n_params: usize,
    /// Model input width (obs + act).
    pub in_dim: usize,
    /// Number of elites.
    pub elites: usize,
}

impl ModelWireLayout {
    /// The layout for `cfg`'s ensemble on `obs`/`act` dimensions.
    pub fn of(cfg: &ExperimentConfig, obs: usize, act: usize) -> anyhow::Result<Self> {
        // Architecture only; the stream is never used for anything else.
        let model = ProbabilisticEnsemble::new(
            obs,
            act,
            cfg.model.clone(),
            &mut stream(cfg.seed, "wire.model-shape", 0),
        )
        .map_err(|e| anyhow::anyhow!("model config: {e}"))?;
        Ok(Self {
            layout_hash: model.layout().hash(),
            n_params: model.params().len(),
            in_dim: obs + act,
            elites: cfg.model.elites,
        })
    }
    /// Total floats.
    pub fn len(&self) -> usize {
        self.n_params + 2 * self.in_dim + self.elites
    }
    /// Never empty.
    pub fn is_empty(&self) -> bool {
        false
    }
    /// Write `w` into `out` (resized to [`ModelWireLayout::len`]).
    pub fn encode(&self, w: &ModelWeights, out: &mut Vec<f32>) -> anyhow::Result<()> {
        anyhow::ensure!(
            w.layout_hash == self.layout_hash
                && w.params.len() == self.n_params
                && w.normalizer.mean.len() == self.in_dim
                && w.normalizer.std.len() == self.in_dim
                && w.elites.len() == self.elites,
            "model weights do not match the wire layout {self:?}"
        );
        out.clear();
        out.extend_from_slice(&w.params);
        out.extend_from_slice(&w.normalizer.mean);
        out.extend_from_slice(&w.normalizer.std);
        out.extend(w.elites.iter().map(|&e| e as f32));
        Ok(())
    }
    /// Read weights back from `flat`.
    pub fn decode(&self, flat: &[f32]) -> anyhow::Result<ModelWeights> {
        anyhow::ensure!(
            flat.len() == self.len(),
            "model snapshot has {} floats, the layout needs {}",
            flat.len(),
            self.len()
        );
        let (p, rest) = flat.split_at(self.n_params);
        let (mean, rest) = rest.split_at(self.in_dim);
        let (std, elites) = rest.split_at(self.in_dim);
        Ok(ModelWeights {
            layout_hash: self.layout_hash,
            params: p.to_vec(),
            normalizer: InputNormalizer {
                mean: mean.to_vec(),
                std: std.to_vec(),
            },
            elites: elites.iter().map(|&e| e as usize).collect(),
        })
    }
}

/// One service process: its config, run IPC and node.
pub struct Process {
    /// The resolved config.
    pub cfg: ExperimentConfig,
    /// Dimensions and layouts.
    pub dims: Dims,
    /// The run's iceoryx2 environment.
    pub run: RunIpc,
    /// This process's node.
    pub node: WireNode<ipc::Service>,
    /// Hand-off mode.
    pub mode: Mode,
    /// Slack in force (zero in lockstep).
    pub slack: Slack,
}

impl Process {
    /// Load the config, open the run and create the node of `(role, args.index)`.
    pub fn start(args: &ServiceArgs, role: Role) -> anyhow::Result<Self> {
        init_logging();
        // The supervisor starts services in their own process group (so a Ctrl-C reaches only
        // it); should it die without stopping them, SIGTERM makes them exit too.
        // SAFETY: prctl(PR_SET_PDEATHSIG) only sets a flag of this process.
        unsafe { libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) };
        let cfg = load_config(&args.run_dir)?;
        let dims = Dims::of(&cfg)?;
        let mut run = RunIpc::new(&args.run_id, &args.ipc_root)?;
        configure_run(&mut run);
        let node = run.node::<ipc::Service>(role, args.index)?;
        tracing::info!(
            "{} of run {} ({} {}, seed {}, {} steps, mode {}, pid {})",
            node.name(),
            args.run_id,
            cfg.env,
            cfg.algo.name(),
            cfg.seed,
            cfg.steps,
            args.mode.name(),
            std::process::id()
        );
        Ok(Self {
            cfg,
            dims,
            run,
            node,
            mode: args.mode,
            slack: args.slack.effective(args.mode),
        })
    }
}

/// Stop requests and acknowledgements addressed to this process.
pub struct ControlInbox {
    /// The subscriber (attach it to the process's [`Waiter`]).
    pub sub: ControlSubscriber<ipc::Service>,
    me: ProducerId,
    stop: Cell<bool>,
    acked: RefCell<BTreeSet<u64>>,
    pause: Cell<bool>,
    /// The barrier under way ends in a stop (SIGINT/SIGTERM).
    pause_to_stop: Cell<bool>,
    cut: Cell<Option<barrier::Cut>>,
    resume: Cell<bool>,
}

impl ControlInbox {
    /// Subscribe to the run's control channel as `node`.
    pub fn create(node: &WireNode<ipc::Service>) -> anyhow::Result<Self> {
        Ok(Self {
            sub: ControlSubscriber::create(node)?,
            me: node.producer(),
            stop: Cell::new(false),
            acked: RefCell::new(BTreeSet::new()),
            pause: Cell::new(false),
            pause_to_stop: Cell::new(false),
            cut: Cell::new(None),
            resume: Cell::new(false),
        })
    }
    /// Read pending control messages.
    pub fn poll(&self) -> anyhow::Result<()> {
        while let Some(m) = self.sub.receive()? {
            if !m.msg.is_for(self.me) {
                continue;
            }
            match m.msg.control_command() {
                Some(ControlCommand::Stop) => self.stop.set(true),
                Some(ControlCommand::Ack) => {
                    self.acked.borrow_mut().insert(m.msg.step);
                }
                Some(ControlCommand::Pause) => {
                    self.pause.set(true);
                    if m.msg.request_id == barrier::PAUSE_TO_STOP {
                        self.pause_to_stop.set(true);
                    }
                }
                Some(ControlCommand::Checkpoint) => {
                    self.pause.set(true);
                    self.cut.set(Some(barrier::Cut {
                        env_steps: m.msg.step,
                        model_trainings: m.msg.request_id,
                    }));
                }
                Some(ControlCommand::Resume) => {
                    self.pause.set(false);
                    self.pause_to_stop.set(false);
                    self.cut.set(None);
                    self.resume.set(true);
                }
                None => {}
            }
        }
        Ok(())
    }
    /// True once a Stop for this process arrived, or SIGINT/SIGTERM.
    pub fn stopped(&self) -> bool {
        self.stop.get() || mbpo_wire::termination_requested()
    }
    /// True when an acknowledgement for `step` arrived (consumes it).
    pub fn take_ack(&self, step: u64) -> bool {
        self.acked.borrow_mut().remove(&step)
    }
    /// Count `step` as acknowledged (a resumed learner: the evaluator acknowledged the eval
    /// point of the checkpoint before it was written).
    pub fn assume_ack(&self, step: u64) {
        self.acked.borrow_mut().insert(step);
    }
    /// True while a checkpoint barrier is under way (from its Pause to its Resume).
    pub fn pause_requested(&self) -> bool {
        self.pause.get()
    }
    /// True while the checkpoint barrier under way is one the run stops after: work the
    /// cut does not need may then be abandoned rather than finished (a periodic checkpoint
    /// lets it finish, as the run goes on with it).
    pub fn pause_to_stop(&self) -> bool {
        self.pause_to_stop.get()
    }
    /// The cut of the checkpoint barrier under way, once the supervisor sent it.
    pub fn cut(&self) -> Option<barrier::Cut> {
        self.cut.get()
    }
    /// True when the supervisor said "resume" after a checkpoint (consumes it).
    pub fn take_resume(&self) -> bool {
        self.resume.replace(false)
    }
}

/// Tell `target` that step `step` was handled (the evaluator's "I copied policy version t").
pub fn send_ack(
    control: &ControlPublisher<ipc::Service>,
    target: ProducerId,
    step: u64,
) -> anyhow::Result<()> {
    let msg = ControlMsg {
        request_id: step,
        step,
        command: ControlCommand::Ack as u32,
        target: target.0,
        status: 0,
        acked_command: 0,
    };
    control.send(&msg)?;
    Ok(())
}

/// Sleep in `waiter` until `ready` returns true (`Ok(true)`), or a stop/termination arrives
/// (`Ok(false)`). `ready` is evaluated after every wake-up; it drains the subscribers it needs.
pub fn wait_for(
    waiter: &Waiter<'_, ipc::Service>,
    control: &ControlInbox,
    what: &dyn Fn() -> String,
    mut ready: impl FnMut() -> anyhow::Result<bool>,
) -> anyhow::Result<bool> {
    let start = Instant::now();
    let mut next_warn = Duration::from_secs(60);
    loop {
        control.poll()?;
        if control.stopped() {
            return Ok(false);
        }
        if ready()? {
            return Ok(true);
        }
        if waiter.wait(Duration::from_secs(1))? == WaitOutcome::Terminate {
            return Ok(false);
        }
        if start.elapsed() >= next_warn {
            tracing::warn!("still waiting after {:?} for {}", start.elapsed(), what());
            next_warn += Duration::from_secs(60);
        }
    }
}

/// Sleep until the supervisor says stop (or SIGINT/SIGTERM): a finished service stays alive
/// so that everything it sent is consumed before its ports go away.
pub fn wait_for_stop(
    waiter: &Waiter<'_, ipc::Service>,
    control: &ControlInbox,
) -> anyhow::Result<()> {
    wait_for(waiter, control, &|| "the supervisor's stop".into(), || {
        Ok(false)
    })?;
    Ok(())
}

/// Real transitions received but not yet handed to the role: lockstep roles must see exactly
/// the first t − 1 transitions at a train point although transition t may already be here.
pub struct RealInbox {
    layout: RowLayout,
    rows: Vec<f32>,
    start: usize,
    received: u64,
    taken: u64,
}

impl RealInbox {
    /// An empty inbox for rows of `layout`.
    pub fn new(layout: RowLayout) -> Self {
        Self {
            layout,
            rows: Vec::new(),
            start: 0,
            received: 0,
            taken: 0,
        }
    }
    /// Move every pending batch of `sub` into the inbox; returns the rows added.
    pub fn pull(&mut self, sub: &TransitionSubscriber<ipc::Service>) -> anyhow::Result<usize> {
        let mut n = 0;
        while let Some(b) = sub.receive()? {
            if self.start > 0 && self.start * 2 >= self.rows.len() {
                self.rows.drain(..self.start);
                self.start = 0;
            }
            self.rows.extend_from_slice(b.rows());
            n += b.n_rows();
        }
        self.received += n as u64;
        Ok(n)
    }
    /// A resumed consumer: the first `n` rows of the run were received and taken before the
    /// checkpoint it continues from.
    pub fn resume_at(&mut self, n: u64) {
        self.received = n;
        self.taken = n;
    }
    /// Rows received so far (taken or not).
    pub fn received(&self) -> u64 {
        self.received
    }
    /// Rows handed out so far.
    pub fn taken(&self) -> u64 {
        self.taken
    }
    /// Rows waiting.
    pub fn pending(&self) -> usize {
        (self.rows.len() - self.start) / self.layout.width()
    }
    /// Hand out the next `n` rows (at most [`RealInbox::pending`]) into `out`.
    pub fn take(&mut self, n: usize, out: &mut Batch) {
        let n = n.min(self.pending());
        let w = self.layout.width();
        self.layout
            .unpack_into(&self.rows[self.start..self.start + n * w], out);
        self.start += n * w;
        self.taken += n as u64;
    }
}

/// Eval points of a run: after step t when t % every == 0 or t == steps (as `train_mbpo`);
/// MPC runs skip the points of the warm-up, where there is no model to plan with (as `train_mpc`).
pub fn is_eval_point(cfg: &ExperimentConfig, t: u64) -> bool {
    let warm_up = cfg.algo == mbpo_train::Algo::Mpc && t <= cfg.mpc.init_random_steps;
    !warm_up && (t.is_multiple_of(cfg.eval.every) || t == cfg.steps)
}

/// Binary names of the services, as installed next to `mbpo`.
pub const BINARIES: [&str; 4] = [
    "mbpo-actor",
    "mbpo-model-trainer",
    "mbpo-rollout-generator",
    "mbpo-sac-learner",
];

/// Policy versions cross the wire shifted by one (`WeightsPublisher` versions start at 1,
/// policy versions at 0 = the initial parameters).
pub fn policy_wire_version(version: u64) -> u64 {
    version + 1
}

/// The policy version of a wire version (see [`policy_wire_version`]).
pub fn policy_version_of(wire_version: u64) -> u64 {
    wire_version.saturating_sub(1)
}

/// Number of train points t' ≤ `t` (model trainings before env step `t` included).
pub fn train_points_upto(schedule: &mbpo_train::roles::Schedule, t: u64) -> u64 {
    if t <= schedule.init_random_steps {
        0
    } else {
        (t - schedule.init_random_steps - 1) / schedule.model_train_freq + 1
    }
}

/// Make the per-run channel limits every process of a run uses (they must agree): a deep real
/// transition queue, so a consumer busy training does not stall the actors at once.
pub fn configure_run(run: &mut RunIpc) {
    let mut q = mbpo_wire::ChannelQos::default_for(mbpo_wire::Channel::Real);
    q.buffer_size = 1024;
    run.set_qos(mbpo_wire::Channel::Real, q);
}

/// Steps taken by actor `index` of `actors` when the run has `steps` real steps in total.
pub fn actor_steps(steps: u64, actors: u16, index: u16) -> u64 {
    let n = actors.max(1) as u64;
    steps / n + u64::from((index as u64) < steps % n)
}

/// Global env step of actor `index`'s local step `t` (1-based): steps are dealt round-robin.
pub fn global_step(t: u64, actors: u16, index: u16) -> u64 {
    (t - 1) * actors.max(1) as u64 + index as u64 + 1
}

/// A service's exit code: success, or the error (with its context chain) logged and failure.
/// Every service `main` ends with it, so a failing service always leaves its reason in its log.
pub fn exit_code(result: anyhow::Result<()>) -> std::process::ExitCode {
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!("{}", error_chain(&e));
            std::process::ExitCode::FAILURE
        }
    }
}

/// `err` and its causes joined by ": ", like anyhow's `{:#}`, but without a cause whose text
/// the message already ends with: many errors print their source themselves (`"checkpoint
/// <path>: {source}"`), and `{:#}` would then say "No such file or directory" twice.
pub fn error_chain(err: &anyhow::Error) -> String {
    let mut text = String::new();
    for cause in err.chain() {
        let part = cause.to_string();
        if text == part || text.ends_with(&format!(": {part}")) {
            continue;
        }
        if !text.is_empty() {
            text.push_str(": ");
        }
        text.push_str(&part);
    }
    text
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_error_chain_says_each_cause_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let err = anyhow::Error::new(mbpo_train::checkpoint::CheckpointError::Io {
            path: "run/checkpoints/1/learner".into(),
            source: io,
        })
        .context("evaluating run");
        assert_eq!(
            error_chain(&err),
            "evaluating run: checkpoint run/checkpoints/1/learner: no such file"
        );
        assert_eq!(format!("{err:#}").matches("no such file").count(), 2);
        // A cause that merely ends the message's last word is still said.
        let err = anyhow::anyhow!("found").context("not found");
        assert_eq!(error_chain(&err), "not found: found");
    }

    #[test]
    fn model_weights_round_trip_through_the_flat_layout() {
        let mut cfg = ExperimentConfig::default();
        cfg.model.members = 3;
        cfg.model.elites = 2;
        cfg.model.hidden = vec![8, 8];
        cfg.model.weight_decay = vec![1e-5, 1e-5, 1e-5];
        let l = ModelWireLayout::of(&cfg, 3, 1).unwrap();
        let w = ModelWeights {
            layout_hash: l.layout_hash,
            params: (0..l.n_params).map(|i| i as f32 * 0.5).collect(),
            normalizer: InputNormalizer {
                mean: vec![1.0, 2.0, 3.0, 4.0],
                std: vec![0.5, 0.25, 2.0, 1.0],
            },
            elites: vec![2, 0],
        };
        let mut flat = Vec::new();
        l.encode(&w, &mut flat).unwrap();
        assert_eq!(flat.len(), l.len());
        assert_eq!(l.decode(&flat).unwrap(), w);
        assert!(l.decode(&flat[1..]).is_err());
    }
}
