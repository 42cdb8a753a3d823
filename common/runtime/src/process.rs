//! One service: its config, the sizes of what it sends, its run IPC and node ([`Process`]), and
//! how a service process starts and ends ([`init_service_process`], [`exit_code`]).

use std::path::Path;

use mbpo_sac::TanhGaussianActor;
use mbpo_train::{ExperimentConfig, Schedule};
use mbpo_wire::{Channel, RunIpc, Transport, WireNode};

use crate::args::{Mode, ServiceArgs, Slack};
use crate::error::ensure_protocol;
use crate::pipeline::{self, PipelineSpec, RoleKind};
use crate::run_plan::{actor_net, Dims, ResolvedRun};
use crate::{Result, RuntimeError};

/// Logs to stderr (the launcher redirects it to `<run-dir>/logs/<process>.log`).
pub fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(false)
        .try_init();
}

/// What a service *process* does before its loop: log to stderr, and exit when its launcher
/// dies. The launcher starts services in their own process group (so a Ctrl-C reaches only it);
/// should it die without stopping them, SIGTERM makes them exit too. (Roles running as threads
/// of one process skip this.)
pub fn init_service_process() {
    init_logging();
    mbpo_train::cpu::log_cpu_kernels();
    // SAFETY: prctl(PR_SET_PDEATHSIG) only sets a flag of this process.
    unsafe { libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) };
}

/// Load `<run_dir>/config.toml`, the config the launcher resolved and validated (parsed, not
/// validated again: see [`crate::run_plan`]).
pub fn load_config(run_dir: &Path) -> Result<ExperimentConfig> {
    load_run(run_dir).map(|(cfg, _)| cfg)
}

/// The run plan and the config of the run in `run_dir`. The plan first: its algorithm may be
/// one only the launcher's program registered, which the config names.
pub fn load_run(run_dir: &Path) -> Result<(ExperimentConfig, ResolvedRun)> {
    let plan = ResolvedRun::read(run_dir)?;
    if let Some(row) = &plan.algorithm {
        row.make_known()?;
    }
    let path = run_dir.join("config.toml");
    let cfg = ExperimentConfig::load_resolved(&path)
        .map_err(|source| RuntimeError::Config { path, source })?;
    Ok((cfg, plan))
}

/// One service: its config, run IPC and node.
pub struct Process<S: Transport> {
    /// The resolved config.
    pub cfg: ExperimentConfig,
    /// When things happen in the run.
    pub schedule: Schedule,
    /// Dimensions and layouts.
    pub dims: Dims,
    /// The run's iceoryx2 environment.
    pub run: RunIpc,
    /// This process's node.
    pub node: WireNode<S>,
    /// Hand-off mode.
    pub mode: Mode,
    /// Slack in force (zero in lockstep).
    pub slack: Slack,
    /// The arguments it was started with.
    pub args: ServiceArgs,
    /// How the run's algorithm runs as a pipeline.
    pub pipeline: &'static PipelineSpec,
}

impl<S: Transport> Process<S> {
    /// Load the config, open the run and create the node of role `kind` (index `args.index`);
    /// refused when the run's algorithm has no such role (a launcher started the wrong one).
    pub fn open(args: &ServiceArgs, kind: RoleKind) -> Result<Self> {
        let (cfg, plan) = load_run(&args.run_dir)?;
        let pipeline = pipeline::spec(cfg.algo)?;
        ensure_protocol!(
            pipeline.has(kind),
            "a {} run has no {kind:?} role: its roles are {:?}",
            pipeline.algo,
            pipeline.roles(1).iter().map(|r| r.kind).collect::<Vec<_>>()
        );
        let role = kind.wire_role();
        ensure_protocol!(
            (plan.mode, plan.actors) == (args.mode, args.actors),
            "started with --mode {} --actors {}, but the run plan says {} and {}",
            args.mode.name(),
            args.actors,
            plan.mode.name(),
            plan.actors
        );
        let dims = plan.dims;
        let mut run = RunIpc::new(&args.run_id, &args.ipc_root)?;
        configure_run(&mut run);
        let node = run.node::<S>(role, args.index)?;
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
            schedule: Schedule::of(&cfg),
            cfg,
            dims,
            run,
            node,
            mode: args.mode,
            slack: args.slack.effective(args.mode),
            args: args.clone(),
            pipeline,
        })
    }
    /// How many subscribers an actor's transitions need before its first send: the run's
    /// consumers, or on a worker host the one gateway.
    pub fn real_consumers(&self) -> usize {
        match self.args.behind_gateway {
            true => 1,
            false => self.pipeline.real_consumers(),
        }
    }
    /// How many subscribers of the control channel an evaluator's acknowledgements wait for:
    /// every role of the run (its own included), or on a worker host itself and the gateway
    /// (which forwards them to the head, where the gateway's stand-in waits for the run's).
    pub fn control_subscribers(&self) -> usize {
        match self.args.behind_gateway {
            true => 2,
            false => self
                .pipeline
                .subscribers(Channel::Control, self.args.actors),
        }
    }
    /// A fresh SAC actor network of the run (architecture only).
    pub fn actor_net(&self) -> TanhGaussianActor {
        actor_net(&self.cfg, self.dims.obs, self.dims.act)
    }
}

/// The pids a service's log names, oldest first: every start of a service logs a line ending
/// `pid N)` ([`Process::open`]); a restarted service appends to the same log. Tools that watch
/// a run (`mbpo chaos`, the tests) read them here, next to the line that writes them.
pub fn pids_in_log(text: &str) -> Vec<i32> {
    text.match_indices(", pid ")
        .filter_map(|(i, _)| {
            let rest = &text[i + 6..];
            rest[..rest.find(')').unwrap_or(rest.len())]
                .trim()
                .parse()
                .ok()
        })
        .collect()
}

/// Live processes whose command line mentions `needle` (a run id: what a run left running),
/// as `pid: command line`; cargo's own processes are left out.
pub fn processes_mentioning(needle: &str) -> Vec<String> {
    let mut out = Vec::new();
    for e in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        if let Ok(cmd) = std::fs::read(e.path().join("cmdline")) {
            let cmd = String::from_utf8_lossy(&cmd).replace('\0', " ");
            if cmd.contains(needle) && !cmd.contains("cargo") {
                out.push(format!("{}: {cmd}", e.file_name().to_string_lossy()));
            }
        }
    }
    out
}

/// Make the per-run channel limits every process of a run uses (they must agree): a deep real
/// transition queue, so a consumer busy training does not stall the actors at once.
pub fn configure_run(run: &mut RunIpc) {
    let mut q = mbpo_wire::ChannelQos::default_for(mbpo_wire::Channel::Real);
    q.buffer_size = 1024;
    // A consumer keeps the transitions it may not take yet in shared memory (`RealInbox`): a
    // lockstep consumer the one or two past its next step or train point, a pipelined learner
    // about its policy lag times the actors. More are copied out (`RealInbox::spilled`).
    q.max_borrowed = 64;
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

/// A service's exit code: success, or the error (with its causes) logged and failure. Every
/// service `main` ends with it, so a failing service always leaves its reason in its log.
pub fn exit_code<E: std::error::Error + 'static>(
    result: std::result::Result<(), E>,
) -> std::process::ExitCode {
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
pub fn error_chain(err: &(dyn std::error::Error + 'static)) -> String {
    let mut text = String::new();
    let mut cause = Some(err);
    while let Some(c) = cause {
        let part = c.to_string();
        cause = c.source();
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
    fn the_pids_of_every_start_are_read_back_in_order() {
        let log = "x INFO learner-0 of run r (Pendulum-v1 mbpo, seed 0, 500 steps, mode lockstep, pid 41)\n\
                   y WARN something else, pid unknown)\n\
                   z INFO learner-0 of run r (Pendulum-v1 mbpo, seed 0, 500 steps, mode lockstep, pid 977)\n";
        assert_eq!(pids_in_log(log), [41, 977]);
        assert!(pids_in_log("").is_empty());
    }

    #[derive(Debug, thiserror::Error)]
    #[error("{what}")]
    struct Outer {
        what: &'static str,
        #[source]
        source: Box<dyn std::error::Error + 'static>,
    }

    #[test]
    fn an_error_chain_says_each_cause_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let err = Outer {
            what: "evaluating run",
            source: Box::new(mbpo_train::checkpoint::CheckpointError::Io {
                path: "run/checkpoints/1/learner".into(),
                source: io,
            }),
        };
        assert_eq!(
            error_chain(&err),
            "evaluating run: checkpoint run/checkpoints/1/learner: no such file"
        );
        // A cause that merely ends the message's last word is still said.
        let err = Outer {
            what: "not found",
            source: "found".into(),
        };
        assert_eq!(error_chain(&err), "not found: found");
    }

    #[test]
    fn actors_deal_the_steps_round_robin() {
        let mut seen: Vec<u64> = (0..3)
            .flat_map(|i| (1..=actor_steps(10, 3, i)).map(move |t| global_step(t, 3, i)))
            .collect();
        seen.sort();
        assert_eq!(seen, (1..=10).collect::<Vec<_>>());
    }
}
