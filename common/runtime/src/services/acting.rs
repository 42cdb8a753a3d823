//! The step loop every actor in the real environment shares: SAC's actor (`actor.rs`, acting
//! with the learner's policy) and MPC's planning actor (`planning.rs`, planning on the model
//! trainer's ensemble).
//!
//! One step of the worker ([`Acting`], on the serving loop) is local step t (global step g):
//! once the role holds weights it may act with at g (lockstep: exactly the sequential run's
//! version), take the env step straight into a loaned shared-memory sample, report a finished
//! episode before its transition, send the transition and report progress. The serving loop
//! pauses it between steps at a barrier. What differs between the two actors (which weights,
//! which version g needs, the checkpoint, what `Done` counts) is an [`ActingRole`].

use std::marker::PhantomData;
use std::time::{Duration, Instant};

use serde::de::DeserializeOwned;
use serde::Serialize;

use mbpo_train::actor::{Behaviour, EnvActor};
use mbpo_train::{CatchUp, TrainError};
use mbpo_wire::*;

use crate::barrier;
use crate::error::ensure_protocol;
use crate::pacer::Pacer;
use crate::serving::{AtCut, Cx, Step, Worker};
use crate::{Result, *};

/// What one kind of actor adds to the shared step loop ([`act`]).
pub trait ActingRole: Sized {
    /// The process role (its node, log and checkpoint file).
    const ROLE: RoleKind;
    /// The weights it acts with.
    const WEIGHTS: WeightsKind;
    /// Its checkpoint file's contents.
    type Checkpoint: Serialize + DeserializeOwned;

    /// Its state at the start of a run of process `s`.
    fn new<S: Transport>(s: &Process<S>) -> Result<Self>;

    /// Its state after `steps` local steps.
    fn checkpoint(&self, steps: u64) -> Self::Checkpoint;
    /// Continue from [`ActingRole::checkpoint`]; returns the local steps done.
    fn restore(&mut self, state: Self::Checkpoint) -> Result<u64>;
    /// Take the newest snapshot `weights` holds, if there is one.
    fn take_newest<S: Transport>(&mut self, weights: &WeightsSubscriber<S>, d: &Dims)
        -> Result<()>;
    /// The version global step `g` acts with in the sequential run (lockstep requires it).
    fn sequential_version(&self, g: u64) -> u64;
    /// The oldest version it may act with at `g` (pipelined: within the configured lag).
    fn oldest_allowed(&self, g: u64) -> u64;
    /// Whether it holds received weights of at least `version`.
    fn holds(&self, version: u64) -> bool;
    /// The version of the weights it acts with.
    fn version(&self) -> u64;
    /// The environment and its episode counters.
    fn env_actor(&self) -> &EnvActor;
    /// One env step whose transition goes straight into `sink`.
    fn act_into(
        &mut self,
        behaviour: Behaviour,
        sink: &mut dyn mbpo_core::TransitionSink,
    ) -> std::result::Result<(), TrainError>;
    /// After a step: whether to report progress now rather than within 500 ms.
    fn after_step(&mut self, _behaviour: Behaviour) -> bool {
        false
    }
    /// `Done.work` and `Done.median_step_seconds` when its steps are done, and the words the
    /// log line adds.
    fn finish(&mut self) -> Finish;
}

/// What an actor adds to its `Done` report and log line.
pub struct Finish {
    /// `Done.work`.
    pub work: u64,
    /// `Done.median_step_seconds`.
    pub median_step_seconds: f32,
    /// Words for the log line after "done: N steps, ".
    pub log: String,
}

/// The versions a transition or progress record carries: the acting weights' in their field.
fn stamp<R: ActingRole>(role: &R) -> (u64, u64) {
    match R::WEIGHTS {
        WeightsKind::Policy | WeightsKind::WorldModel => (role.version(), 0),
        WeightsKind::Model => (0, role.version()),
    }
}

/// The name of what `R` acts with, for messages.
fn weights_name<R: ActingRole>() -> &'static str {
    match R::WEIGHTS {
        WeightsKind::Policy => "policy",
        WeightsKind::Model => "model",
        WeightsKind::WorldModel => "world model",
    }
}

/// An actor's ports: the weights it acts with, the real transitions it sends.
pub struct Ports<S: Transport> {
    weights: WeightsSubscriber<S>,
    real: TransitionPublisher<S>,
}

type ActingCx<'a, S> = Cx<'a, S, Ports<S>>;

/// An actor of kind `R` on the serving loop.
pub struct Acting<S: Transport, R: ActingRole> {
    role: R,
    /// The next local step.
    t: u64,
    /// Its local steps in the run.
    steps: u64,
    /// What it waits for (the weights version of its next step).
    need: u64,
    lag: SlackTracker,
    last_progress: Instant,
    started: Instant,
    ipc: Duration,
    /// `actor.control_hz`: its steps' deadlines (pipelined runs only).
    pacer: Option<Pacer>,
    /// It has acted with received weights (a paced actor then keeps acting inside an episode).
    acted_with_policy: bool,
    /// A paced actor waiting for weights between episodes (its next step starts a new grid).
    resting: bool,
    transport: PhantomData<fn() -> S>,
}

impl<S: Transport, R: ActingRole> Worker<S> for Acting<S, R> {
    const KIND: RoleKind = R::ROLE;
    type Ports = Ports<S>;
    type Checkpoint = R::Checkpoint;

    fn ports(s: &Process<S>) -> Result<Ports<S>> {
        let d = s.dims;
        let (hash, len) = d.weights_layout(R::WEIGHTS);
        Ok(Ports {
            weights: WeightsSubscriber::create(&s.node, R::WEIGHTS, hash, len)?,
            real: TransitionPublisher::create(&s.node, Channel::Real, d.rows(), 1)?,
        })
    }
    /// Every consumer of real data (model trainer, and rollout generator and learner in an
    /// MBPO run; or this host's gateway): nothing sent afterwards can be lost.
    fn connect(s: &Process<S>, _: &ControlInbox<S>, p: &Ports<S>) -> Result<()> {
        p.real
            .wait_for_subscribers(s.real_consumers(), Duration::from_secs(120))?;
        Ok(())
    }
    fn attach<'a>(p: &'a Ports<S>, waiter: &mut Waiter<'a, S>) {
        waiter.attach(&p.weights);
    }
    fn new(cx: &ActingCx<'_, S>) -> Result<Self> {
        let (s, args) = (cx.s, &cx.s.args);
        let hz = s.cfg.actor.control_hz;
        crate::error::ensure_protocol!(
            hz == 0.0 || s.mode == Mode::Pipelined,
            "actor.control_hz = {hz} paces the actors of a pipelined run; lockstep takes each step with the sequential run's weights: use --mode pipelined, or actor.control_hz = 0"
        );
        Ok(Self {
            role: R::new(s)?,
            t: 1,
            steps: actor_steps(s.cfg.steps, args.actors, args.index),
            need: 0,
            lag: SlackTracker::default(),
            last_progress: Instant::now(),
            started: Instant::now(),
            ipc: Duration::ZERO,
            pacer: Pacer::new(hz),
            acted_with_policy: false,
            resting: false,
            transport: PhantomData,
        })
    }
    fn restore(&mut self, state: R::Checkpoint, _: &ActingCx<'_, S>) -> Result<()> {
        self.t = self.role.restore(state)? + 1;
        Ok(())
    }
    fn step(&mut self, cx: &ActingCx<'_, S>) -> Result<Step> {
        if self.t > self.steps {
            return Ok(Step::Finished);
        }
        let args = &cx.s.args;
        let g = global_step(self.t, args.actors, args.index);
        let Some(behaviour) = self.behaviour(cx, g)? else {
            return Ok(Step::Waiting);
        };
        self.act(cx, g, behaviour)
    }
    fn done_so_far(&self) -> u64 {
        self.t - 1
    }
    /// A paced actor waits at the cut until the run resumes: like a rest, its next step starts a
    /// new grid (the pause is not a missed deadline).
    fn at_cut(&mut self, _: barrier::Cut, _: &ActingCx<'_, S>) -> Result<AtCut<R::Checkpoint>> {
        self.resting = self.pacer.is_some();
        Ok(AtCut::Write(self.role.checkpoint(self.t - 1)))
    }
    fn finish(&mut self, cx: &ActingCx<'_, S>) -> Result<()> {
        let finish = self.role.finish();
        let (lo, hi, mean) = self.lag.get();
        let a = self.role.env_actor();
        // Before `Done`: the coordinator has every part when it writes the summary.
        for part in self.pacer.iter().flat_map(|p| p.intervals.parts()) {
            cx.stats.report(part)?;
        }
        cx.stats.report(Done {
            real: self.steps,
            work: finish.work,
            episodes_cut: a.episodes_cut,
            episodes_lost: a.episodes_lost,
            median_step_seconds: finish.median_step_seconds,
            missed_deadlines: self.pacer.as_ref().map_or(0, |p| p.missed),
            rests: self.pacer.as_ref().map_or(0, |p| p.rests),
            ipc_seconds: self.ipc.as_secs_f32(),
            wall_seconds: self.started.elapsed().as_secs_f32(),
            ..Done::with_slack(&self.lag)
        })?;
        tracing::info!(
            "done: {} steps, {}{} lag {lo}..{hi} (mean {mean:.2})",
            self.steps,
            finish.log,
            weights_name::<R>()
        );
        if let Some(p) = &self.pacer {
            let hz = 1.0 / p.period().as_secs_f64();
            let late_ms = p.worst_late_ns as f64 / 1e6;
            let e = &p.intervals;
            tracing::info!(
                "paced at {hz:.1} Hz: {} steps, {} deadlines missed (latest start {late_ms:.2} ms late), {} rests between episodes waiting for {}; step-interval error p50 <= {} us, p99 <= {} us, max {:.0} us",
                p.steps,
                p.missed,
                p.rests,
                weights_name::<R>(),
                e.quantile_us(0.5),
                e.quantile_us(0.99),
                e.max_ns as f64 / 1e3
            );
            let (late, all) = p.late_steps();
            if all > 0 {
                let first = crate::pacer::describe_late_steps(late);
                tracing::info!("{all} late steps (missed, or off by more than a tenth of the period); the first: {first}");
            }
        }
        Ok(())
    }
    fn waiting_for(&self) -> String {
        format!("{} version {}", weights_name::<R>(), self.need)
    }
}

impl<S: Transport, R: ActingRole> Acting<S, R> {
    /// How global step `g` acts: uniformly in the warm-up, else with the newest weights once
    /// they are recent enough (`None`: not yet).
    fn behaviour(&mut self, cx: &ActingCx<'_, S>, g: u64) -> Result<Option<Behaviour>> {
        if cx.s.schedule.is_warm_up(g) {
            return Ok(Some(Behaviour::Uniform));
        }
        let role = &mut self.role;
        self.need = role.oldest_allowed(g);
        role.take_newest(&cx.ports.weights, &cx.s.dims)?;
        // A paced actor does not wait inside an episode: it acts with the newest weights it
        // holds, and waits for those its step needs only between episodes -- or never, after
        // its first weights (`actor.catch_up`).
        let paced = self.pacer.is_some();
        let may_rest = match cx.s.cfg.actor.catch_up {
            CatchUp::BetweenEpisodes => !role.env_actor().mid_episode(),
            CatchUp::Never => false,
        };
        let keeps_pace = paced && self.acted_with_policy && !may_rest;
        if !role.holds(self.need) && !keeps_pace {
            self.resting = paced;
            return Ok(None);
        }
        let exact = role.sequential_version(g);
        if cx.s.mode == Mode::Lockstep {
            ensure_protocol!(
                role.version() == exact,
                "lockstep {} at step {g} got {} version {} (want {exact})",
                R::ROLE.name(cx.s.args.index),
                weights_name::<R>(),
                role.version()
            );
        }
        self.lag.see(exact as f64 - role.version() as f64);
        Ok(Some(Behaviour::Policy))
    }

    /// Take global step `g`: the env step writes its transition straight into the sample it
    /// is sent in. An environment failure is reported and ends the acting (nothing of step g
    /// was sent, so the checkpoint that stops the run holds every transition accepted).
    fn act(&mut self, cx: &ActingCx<'_, S>, g: u64, behaviour: Behaviour) -> Result<Step> {
        if let Some(pacer) = &mut self.pacer {
            if std::mem::take(&mut self.resting) {
                pacer.rest();
            }
            pacer.wait();
        }
        self.acted_with_policy |= behaviour == Behaviour::Policy;
        let episodes = self.role.env_actor().episodes;
        let t0 = Instant::now();
        let mut loan = cx.ports.real.loan_rows(1)?;
        self.ipc += t0.elapsed();
        if let Err(e) = self.role.act_into(behaviour, &mut loan) {
            drop(loan);
            let TrainError::Env(env_error) = e else {
                return Err(e.into());
            };
            tracing::error!("env step {g}: {env_error}");
            cx.stats.report(EnvFailed { env_steps: g })?;
            return Ok(Step::Failed);
        }
        let report_now = self.role.after_step(behaviour);
        let a = self.role.env_actor();
        if a.episodes > episodes {
            // Before the transition: the supervisor may rely on having every episode ≤ t.
            cx.stats.report(EpisodeEnd {
                env_steps: g,
                episode_return: a.last_return.unwrap_or(f64::NAN),
                version: self.role.version(),
            })?;
        }
        let (policy_version, model_version) = stamp(&self.role);
        let meta = TransitionMeta {
            policy_version,
            model_version,
            env_steps: g,
        };
        let t0 = Instant::now();
        loan.send(meta)?;
        self.ipc += t0.elapsed();
        if report_now || self.last_progress.elapsed() >= Duration::from_millis(500) {
            self.last_progress = Instant::now();
            cx.stats.report(Progress {
                env_steps: g,
                policy_version,
                model_version,
                ..Default::default()
            })?;
        }
        self.t += 1;
        Ok(Step::Worked)
    }
}
