//! The coordinator of a pipeline run: it owns the run directory (metrics rows, checkpoints,
//! the summary) and drives the run's protocol -- checkpoint barriers, the clean stop, the end
//! -- talking to the roles **only over the wire** (stats in, control out, the final policy
//! read off the policy channel). It never starts or watches a process: the launcher of
//! `mbpo run` does that for processes it spawned, a test for threads it started, and later a
//! remote host for processes of its own.
//!
//! A launcher's loop: sleep in a [`Waiter`] on the [`CoordinatorPorts`], hand a signal to
//! [`Coordinator::on_signal`], then [`Coordinator::pump`] (drain reports, write rows) and
//! [`Coordinator::advance`] (barriers; is the run over?); at the end [`Coordinator::send_stop`]
//! and [`Coordinator::finish`] for the summary.

pub mod checkpoints;
pub mod collect;
pub mod reached;
mod signal;

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mbpo_train::{policy_sha256, ExperimentConfig, RunDir, Schedule};
use mbpo_wire::{
    policy_wire_version, ControlCommand, ControlMsg, ControlPublisher, EnvFailed, ProducerId, Role,
    Stats, StatsSubscriber, StopReason, Transport, Waiter, WeightsKind, WeightsSubscriber,
    WireNode, CONTROL_TARGET_ALL,
};

use crate::args::{Mode, Slack};
use crate::error::ensure_protocol;
use crate::pipeline::PipelineSpec;
use crate::run_plan::Dims;
use crate::{Result, RuntimeError};
use checkpoints::{Barrier, SupervisorCheckpoint};
use collect::{Collector, PipelineSummary, RunBook};
pub use signal::{on_signal, OnSignal, RunState};

/// What a run is: its id and how its roles hand work to each other.
#[derive(Debug, Clone)]
pub struct RunPlan {
    /// How the run's algorithm runs as a pipeline.
    pub pipeline: &'static PipelineSpec,
    /// Run id (the run's iceoryx2 services `mbpo/<run id>/...`).
    pub run_id: String,
    /// Hand-off mode.
    pub mode: Mode,
    /// Training actors.
    pub actors: u16,
    /// Slack of pipelined mode (as given; zero is used in lockstep).
    pub slack: Slack,
}

/// The coordinator's ports; attach them to the launcher's [`Waiter`].
pub struct CoordinatorPorts<S: Transport> {
    /// Every role's reports.
    pub stats: StatsSubscriber<S>,
    /// The run's final "policy": the SAC actor (MBPO), or the model versions (MPC).
    pub policy: WeightsSubscriber<S>,
    /// Pause, cut, resume and stop to every role.
    pub control: ControlPublisher<S>,
}

impl<S: Transport> CoordinatorPorts<S> {
    /// The ports of the coordinator's `node` for a run of `plan`.
    pub fn create(node: &WireNode<S>, plan: &RunPlan, dims: &Dims) -> Result<Self> {
        let result = plan.pipeline.result();
        let (hash, len) = result_layout(result, dims);
        let policy = WeightsSubscriber::create(node, result, hash, len)?;
        Ok(Self {
            stats: StatsSubscriber::create(node)?,
            policy,
            control: ControlPublisher::create(node)?,
        })
    }
    /// Wake `waiter` on the reports and the final policy.
    pub fn attach<'a>(&'a self, waiter: &mut Waiter<'a, S>) {
        waiter.attach(&self.stats).attach(&self.policy);
    }
}

/// The layout hash and length of the weights a run's result is made of.
fn result_layout(result: WeightsKind, dims: &Dims) -> (u64, usize) {
    dims.weights_layout(result)
}

/// Where a run stands after [`Coordinator::advance`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Work goes on.
    Running,
    /// Every role is done and the final policy is in.
    Finished,
    /// A checkpoint the run stops after is complete.
    Stopped,
}

/// The coordinator's state (see the module docs).
pub struct Coordinator {
    cfg: ExperimentConfig,
    plan: RunPlan,
    out: PathBuf,
    schedule: Schedule,
    dims: Dims,
    /// The metrics bookkeeping.
    pub collector: Collector,
    barrier: Option<Barrier>,
    next_checkpoint: u64,
    /// Env steps of the newest complete checkpoint (the resumed one at first; 0: none).
    last_checkpoint: u64,
    final_wire: u64,
    final_params: Option<Vec<f32>>,
    finishing: bool,
    /// An actor whose environment failed, and at which env step: the run stops after the
    /// checkpoint this started.
    env_failure: Option<(ProducerId, u64)>,
    /// The run was solved and is stopping (`eval.stop_when_solved`).
    solved: bool,
}

impl Coordinator {
    /// The coordinator of the run `cfg` (of sizes `dims`) in `out`, from the start or from a
    /// checkpoint after `resume.0` env steps with book `resume.1`; `restarts` so far
    /// (`--restart on-failure`).
    pub fn new(
        cfg: &ExperimentConfig,
        dims: Dims,
        plan: RunPlan,
        out: &Path,
        resume: Option<(u64, RunBook)>,
        restarts: u32,
    ) -> Self {
        let schedule = Schedule::of(cfg);
        let mut collector = Collector::new(cfg, &plan);
        let every = cfg.checkpoint.every;
        let mut next_checkpoint = every;
        let mut last_checkpoint = 0;
        let resume_given = resume.is_some();
        if let Some((env_steps, book)) = resume {
            let trainings = book.models.keys().max().copied().unwrap_or(0);
            let learner = (book.progress.0, book.progress.1);
            collector.reached.resume_at(env_steps, trainings, learner);
            collector.restore(book);
            next_checkpoint = env_steps + every;
            last_checkpoint = env_steps;
        }
        collector.book.restarts = restarts;
        collector.solved_rule = mbpo_train::run_control::solved_rule(cfg, out, resume_given);
        let final_wire = match plan.pipeline.result() {
            WeightsKind::Model => schedule.train_points_upto(cfg.steps),
            // A learner's: one version per env step consumed.
            WeightsKind::Policy | WeightsKind::WorldModel => policy_wire_version(cfg.steps),
        };
        Self {
            dims,
            cfg: cfg.clone(),
            plan,
            out: out.to_path_buf(),
            schedule,
            collector,
            barrier: None,
            next_checkpoint,
            last_checkpoint,
            // An MPC run shorter than its warm-up trains no model: nothing to wait for.
            final_params: (final_wire == 0).then(Vec::new),
            final_wire,
            finishing: false,
            env_failure: None,
            solved: false,
        }
    }

    /// Every role sent its Done record.
    pub fn all_done(&self) -> bool {
        self.collector.all_done(self.plan.actors)
    }

    /// Take every report and the final policy that arrived, and write the rows that are
    /// complete.
    pub fn pump<S: Transport>(
        &mut self,
        ports: &CoordinatorPorts<S>,
        run: &mut RunDir,
        started: Instant,
    ) -> Result<()> {
        loop {
            match ports.stats.receive() {
                Ok(Some(r)) => match (Stats::decode(&r.msg), self.barrier.as_mut()) {
                    (Ok(Stats::Barrier(report)), Some(b)) => {
                        let counters = &mut self.collector.reached;
                        counters.see(r.producer(), &Stats::Barrier(report));
                        b.on_report(r.producer(), report)
                    }
                    (Ok(Stats::Barrier(report)), None) => {
                        tracing::warn!("{}: {report:?} outside a barrier", r.producer())
                    }
                    (Ok(Stats::EnvFailed(f)), _) => self.on_env_failure(ports, r.producer(), f)?,
                    (Ok(stats), _) => self.collector.on_stats(r.producer(), stats),
                    (Err(e), _) => tracing::warn!("stats from {}: {e}", r.producer()),
                },
                Ok(None) => break,
                Err(e) => tracing::warn!("stats: {e}"),
            }
        }
        match ports.policy.receive_latest() {
            Ok(Some(w)) if w.version() == self.final_wire => {
                self.final_params = Some(w.params().to_vec())
            }
            Ok(_) => {}
            Err(e) => tracing::warn!("policy: {e}"),
        }
        self.write_rows(run, started)
    }

    fn write_rows(&mut self, run: &mut RunDir, started: Instant) -> Result<()> {
        let out = &self.out;
        self.collector
            .write_rows(run, started)
            .map_err(|source| RuntimeError::Io {
                path: out.join("metrics.csv"),
                source,
            })
    }

    /// Drive the barrier (start a periodic one, send the cut, complete it) and tell whether
    /// the run is over. A run is over once every role is done, the final policy is in and the
    /// checkpoint of its last step is complete: extending the run (`--resume RUN --steps N`)
    /// then continues from its end, as after `mbpo train`.
    pub fn advance<S: Transport>(
        &mut self,
        ports: &CoordinatorPorts<S>,
        run: &mut RunDir,
        started: Instant,
    ) -> Result<Phase> {
        if self.start_barrier_if_due(ports)? {
            return Ok(Phase::Finished);
        }
        self.stop_if_solved(ports)?;
        let Some(cut) = self.barrier_cut_complete(ports)? else {
            return Ok(Phase::Running);
        };
        let b = self.barrier.as_ref().expect("a complete barrier");
        let (barrier_started, stop_after) = (b.started, b.stop_after);
        self.write_checkpoint(cut, run, started)?;
        tracing::info!(
            "checkpoint after step {} complete ({:.2} s barrier): {}",
            cut.env_steps,
            barrier_started.elapsed().as_secs_f64(),
            mbpo_train::checkpoint::dir_for(&self.out, cut.env_steps).display()
        );
        self.next_checkpoint = cut.env_steps + self.cfg.checkpoint.every.max(1);
        self.last_checkpoint = cut.env_steps;
        if cut.env_steps >= self.cfg.steps && self.all_done() && self.final_params.is_some() {
            // The last step's checkpoint: the run is complete (a stop asked for meanwhile
            // changes nothing).
            self.barrier = None;
            return Ok(Phase::Finished);
        }
        if stop_after {
            return Ok(Phase::Stopped);
        }
        send(
            ports,
            ControlCommand::Resume,
            cut.model_trainings,
            cut.env_steps,
        )?;
        self.barrier = None;
        Ok(Phase::Running)
    }

    /// Once a row solved the run (`eval.stop_when_solved`), stop after a checkpoint: a new
    /// barrier, or the one under way (as a first Ctrl-C does). Once only.
    fn stop_if_solved<S: Transport>(&mut self, ports: &CoordinatorPorts<S>) -> Result<()> {
        let (Some(t), Some(rule)) = (self.collector.solved_at, &self.collector.solved_rule) else {
            return Ok(());
        };
        if self.solved || self.all_done() {
            return Ok(());
        }
        self.solved = true;
        tracing::info!(
            "solved at env step {t} ({}): writing a checkpoint, then stopping",
            rule.describe()
        );
        match self.barrier.as_mut() {
            None => self.start_barrier(ports, true),
            Some(b) => {
                b.stop_after = true;
                send_pause(ports, true)
            }
        }
    }

    /// Whether the run stopped because it was solved (its status is then `solved`).
    pub fn solved(&self) -> bool {
        self.solved
    }

    /// Start a barrier when one is due: the periodic one every `checkpoint.every` env steps,
    /// or the last step's once every role is done. `true`: the run is over (done, final
    /// policy in, last step checkpointed), nothing to start.
    fn start_barrier_if_due<S: Transport>(&mut self, ports: &CoordinatorPorts<S>) -> Result<bool> {
        if self.all_done() && self.final_params.is_some() && self.barrier.is_none() {
            if self.last_checkpoint >= self.cfg.steps {
                return Ok(true);
            }
            tracing::info!("every role is done: checkpointing the last step");
            self.start_barrier(ports, false)?;
        }
        let every = self.cfg.checkpoint.every;
        if self.barrier.is_none()
            && every > 0
            && self.collector.env_steps() >= self.next_checkpoint
            && !self.all_done()
        {
            self.start_barrier(ports, false)?;
        }
        Ok(false)
    }

    /// Move the barrier under way on: its pause to late subscribers, the cut once every
    /// pausing role reported; the cut once every file is written (`None` before that, or
    /// without a barrier).
    fn barrier_cut_complete<S: Transport>(
        &mut self,
        ports: &CoordinatorPorts<S>,
    ) -> Result<Option<crate::barrier::Cut>> {
        let Some(b) = self.barrier.as_mut() else {
            return Ok(None);
        };
        resend_barrier_to_late_subscribers(ports, b)?;
        if let Some(cut) = b.take_cut(&self.schedule, self.plan.mode) {
            tracing::info!(
                "checkpoint cut: after step {} with {} model trainings",
                cut.env_steps,
                cut.model_trainings
            );
            b.control_subscribers = ports.control.subscribers();
            send_cut(ports, cut)?;
        }
        let complete = b.complete();
        let waited_long = b.started.elapsed() > checkpoints::BARRIER_WARN_AFTER * (b.warnings + 1);
        if complete.is_none() && waited_long {
            b.warnings += 1;
            tracing::warn!("checkpoint barrier still waiting for {}", b.waiting_for());
        }
        Ok(complete)
    }

    /// The run's own files of checkpoint `cut` (the launcher's state and the run book, after
    /// every row up to it), then `COMPLETE`.
    fn write_checkpoint(
        &mut self,
        cut: crate::barrier::Cut,
        run: &mut RunDir,
        started: Instant,
    ) -> Result<()> {
        self.write_rows(run, started)?;
        let missing = self.collector.missing_at_cut(cut.env_steps);
        ensure_protocol!(
            missing == 0,
            "checkpoint after step {}: the records of {missing} eval point(s) up to it are not in",
            cut.env_steps
        );
        let state = SupervisorCheckpoint {
            mode: self.plan.mode,
            actors: self.plan.actors,
            slack: self.plan.slack,
        };
        let book = self
            .collector
            .book_at(cut.env_steps, started.elapsed().as_secs_f64());
        checkpoints::finish(
            &self.out,
            self.plan.pipeline,
            cut,
            &state,
            &book,
            &self.cfg.checkpoint,
        )
    }

    /// Answer a SIGINT/SIGTERM (see [`on_signal`]); the launcher stops at once on
    /// [`OnSignal::StopNow`].
    pub fn on_signal<S: Transport>(&mut self, ports: &CoordinatorPorts<S>) -> Result<OnSignal> {
        let state = RunState {
            barrier: self.barrier.as_ref().map(|b| b.stop_after),
            all_done: self.all_done(),
            actors_done: self.collector.actors_done(self.plan.actors),
            finishing: self.finishing,
        };
        let decision = on_signal(state);
        match decision {
            OnSignal::CheckpointAndStop => {
                tracing::warn!("stopping: writing a checkpoint first (press Ctrl-C again to stop at once, without one)");
                self.start_barrier(ports, true)?;
            }
            OnSignal::StopAfterBarrier => {
                tracing::warn!(
                    "stopping after the checkpoint under way (press Ctrl-C again to stop at once)"
                );
                if let Some(b) = self.barrier.as_mut() {
                    b.stop_after = true;
                }
                send_pause(ports, true)?;
            }
            OnSignal::Finish => {
                tracing::warn!("the actors are done: finishing the run's last updates and evaluations (press Ctrl-C again to stop at once, without a checkpoint)");
                self.finishing = true;
            }
            OnSignal::StopNow => {}
        }
        Ok(decision)
    }

    /// An actor's environment failed: checkpoint what every role has (the failed step sent
    /// nothing) and stop, as after a first SIGTERM; the summary then says `failed`.
    fn on_env_failure<S: Transport>(
        &mut self,
        ports: &CoordinatorPorts<S>,
        actor: ProducerId,
        f: EnvFailed,
    ) -> Result<()> {
        tracing::error!(
            "{actor}: its environment failed at env step {}: writing a checkpoint, then stopping",
            f.env_steps
        );
        if self.env_failure.is_some() {
            return Ok(());
        }
        self.env_failure = Some((actor, f.env_steps));
        match self.barrier.as_mut() {
            None => self.start_barrier(ports, true),
            Some(b) => {
                b.stop_after = true;
                send_pause(ports, true)
            }
        }
    }

    /// Why the run stopped when an actor's environment failed (`None`: it did not).
    pub fn env_failure(&self) -> Option<String> {
        let (actor, step) = self.env_failure?;
        let kept = match self.last_checkpoint {
            0 => "no checkpoint was written".to_string(),
            t => format!("the run stopped with a checkpoint after step {t}"),
        };
        Some(format!(
            "{actor}'s environment failed at env step {step} (its error is in its log); {kept}. \
             Fix the environment, then continue the run with --resume"
        ))
    }

    /// Broadcast the Pause that starts a checkpoint barrier.
    fn start_barrier<S: Transport>(
        &mut self,
        ports: &CoordinatorPorts<S>,
        stop_after: bool,
    ) -> Result<()> {
        let mut barrier = Barrier::new(self.plan.pipeline, self.plan.actors, stop_after);
        barrier.control_subscribers = ports.control.subscribers();
        send_pause(ports, stop_after)?;
        self.barrier = Some(barrier);
        Ok(())
    }

    /// Tell every role to stop (they wait for it after their work, so nothing in flight is
    /// lost), after giving the `roles` still alive up to 2 s to be connected. `why` tells a
    /// gateway whether its remote actors leave the run or stay for the next attempt.
    pub fn send_stop<S: Transport>(
        &self,
        ports: &CoordinatorPorts<S>,
        roles: usize,
        why: StopReason,
    ) {
        let _ = ports
            .control
            .wait_for_subscribers(roles, Duration::from_secs(2));
        if let Err(e) = ports.control.send(&ControlMsg::stop(why, self.cfg.steps)) {
            tracing::warn!("sending stop: {e}");
        }
    }

    /// Env steps the learner (MPC: the actors) reported.
    pub fn env_steps(&self) -> u64 {
        self.collector.env_steps()
    }

    /// The run's summary with `status`; a completed MBPO run also leaves its final policy in
    /// `<run>/policy.ckpt`.
    pub fn finish(
        &self,
        status: &str,
        run: &mut RunDir,
        started: Instant,
    ) -> Result<PipelineSummary> {
        let result = self.plan.pipeline.result();
        // A model snapshot is θ | normaliser | elites; `train_mpc` hashes θ.
        let hashed = match result {
            WeightsKind::Model => self.dims.model.n_params,
            WeightsKind::Policy => self.dims.policy_len,
            WeightsKind::WorldModel => self.dims.world_model.len,
        };
        let params = self
            .final_params
            .as_deref()
            .map(|p| &p[..hashed.min(p.len())]);
        let sha = params.map(policy_sha256).unwrap_or_default();
        // The policy the run ended with: periodic checkpoints rarely fall on the last step.
        if let (Some(actor), "completed", WeightsKind::Policy) = (params, status, result) {
            mbpo_train::policy_file::write_final_policy(&self.out, self.env_steps(), actor)?;
        }
        let to_target = run
            .env_steps_to_target(self.cfg.target_return())
            .map_err(|source| RuntimeError::Io {
                path: self.out.join("metrics.csv"),
                source,
            })?;
        Ok(self.collector.summary(status, sha, started, to_target))
    }

    /// Roles of the run: learner, model trainer, rollout generator, evaluator and the actors
    /// (MPC: no learner or rollout generator).
    pub fn roles(&self) -> usize {
        self.plan.pipeline.roles(self.plan.actors).len()
    }
}

fn send<S: Transport>(
    ports: &CoordinatorPorts<S>,
    command: ControlCommand,
    request_id: u64,
    step: u64,
) -> Result<()> {
    let msg = ControlMsg::request(command, request_id, CONTROL_TARGET_ALL, step);
    ports.control.send(&msg)?;
    Ok(())
}

/// Send the barrier's messages again (the Pause, and the cut once sent) when a control
/// subscriber appeared since they went out: the control channel keeps no history, so a role
/// still starting when the barrier began (Ctrl-C right after `mbpo run`) never got them, and
/// the barrier would wait for its report forever. A role that has them is unchanged by them
/// again (the pause is a flag, the cut the same), and the channel delivers in order, so they
/// arrive before the Resume. A count that fell (a process gone) is followed down, so its
/// replacement counts as new.
fn resend_barrier_to_late_subscribers<S: Transport>(
    ports: &CoordinatorPorts<S>,
    b: &mut Barrier,
) -> Result<()> {
    let now = ports.control.subscribers();
    if now > b.control_subscribers {
        tracing::info!(
            "{} control subscriber(s) joined during the checkpoint barrier: sending it again",
            now - b.control_subscribers
        );
        send_pause(ports, b.stop_after)?;
        if let Some(cut) = b.cut() {
            send_cut(ports, cut)?;
        }
    }
    b.control_subscribers = now;
    Ok(())
}

/// Broadcast the barrier's cut: every role runs on to exactly "after T with K trainings".
fn send_cut<S: Transport>(ports: &CoordinatorPorts<S>, cut: crate::barrier::Cut) -> Result<()> {
    send(
        ports,
        ControlCommand::Checkpoint,
        cut.model_trainings,
        cut.env_steps,
    )
}

/// Broadcast a Pause, saying whether the run stops after the barrier (roles may then abandon
/// work the cut does not need, such as a model training under way).
fn send_pause<S: Transport>(ports: &CoordinatorPorts<S>, stop_after: bool) -> Result<()> {
    let to_stop = match stop_after {
        true => crate::barrier::PAUSE_TO_STOP,
        false => 0,
    };
    send(ports, ControlCommand::Pause, to_stop, 0)
}

/// The coordinator's node of a run.
pub fn node<S: Transport>(run: &mbpo_wire::RunIpc) -> Result<WireNode<S>> {
    Ok(run.node::<S>(Role::Supervisor, 0)?)
}
