//! `mbpo-actor`: acts in the real environment with the newest policy it is allowed to use and
//! publishes every transition (reliable, sequence-numbered). With `--eval` it is the
//! evaluation actor: deterministic policy, stream `eval.env`, evaluating policy version t at
//! the sequential evaluation points.
//!
//! Lockstep: the actor of global step t waits for policy version exactly t − 1. Pipelined: any
//! version ≥ t − 1 − policy_lag. The step loop is `acting.rs`, shared with MPC's planning
//! actors (`planning.rs`).

use std::time::Duration;

use mbpo_core::rng::stream;
use mbpo_core::{Rng, TransitionSink};
use mbpo_envs::Env;
use mbpo_sac::ActorPolicy;
use mbpo_train::actor::{Behaviour, EnvActor};
use mbpo_train::roles::ActorRole;
use mbpo_train::TrainError;
use mbpo_wire::*;

use super::acting::{ActingRole, Finish};
use super::eval_points::EvalPoints;
use crate::barrier::{self, ActorCheckpoint, EvaluatorCheckpoint};
use crate::error::ensure_protocol;
use crate::serving::{AtCut, Cx, Step, Worker};
use crate::{Result, *};

/// The SAC actor on the shared step loop: it acts with the learner's policy; step g needs
/// version g − 1 (pipelined: at least g − 1 − `policy_lag`).
pub struct PolicyActing {
    role: ActorRole,
    policy_lag: u64,
}

impl ActingRole for PolicyActing {
    const ROLE: RoleKind = RoleKind::Actor;
    const WEIGHTS: WeightsKind = WeightsKind::Policy;
    type Checkpoint = ActorCheckpoint;

    fn new<S: Transport>(s: &Process<S>) -> Result<Self> {
        Ok(Self {
            role: ActorRole::new(&s.cfg, s.args.index as u64)?,
            policy_lag: s.slack.policy_lag,
        })
    }

    fn checkpoint(&self, steps: u64) -> ActorCheckpoint {
        ActorCheckpoint {
            role: self.role.checkpoint(),
            steps,
        }
    }
    fn restore(&mut self, state: ActorCheckpoint) -> Result<u64> {
        self.role.restore(state.role)?;
        Ok(state.steps)
    }
    fn take_newest<S: Transport>(&mut self, policy: &WeightsSubscriber<S>, _: &Dims) -> Result<()> {
        if let Some(w) = policy.receive_latest()? {
            let version = policy_version_of(w.version());
            self.role.set_policy_params(w.params(), version);
        }
        Ok(())
    }
    fn sequential_version(&self, g: u64) -> u64 {
        g - 1
    }
    fn oldest_allowed(&self, g: u64) -> u64 {
        (g - 1).saturating_sub(self.policy_lag)
    }
    fn holds(&self, version: u64) -> bool {
        self.role.has_policy(version)
    }
    fn version(&self) -> u64 {
        self.role.policy_version()
    }
    fn env_actor(&self) -> &EnvActor {
        self.role.env_actor()
    }
    fn act_into(
        &mut self,
        behaviour: Behaviour,
        sink: &mut dyn TransitionSink,
    ) -> std::result::Result<(), TrainError> {
        self.role.act_into(behaviour, sink)
    }
    fn finish(&mut self) -> Finish {
        Finish {
            work: self.role.env_actor().episodes,
            median_step_seconds: 0.0,
            log: String::new(),
        }
    }
}

/// The evaluator's ports: the policy it evaluates, and the acknowledgements it sends the
/// learner (lockstep).
pub struct EvaluatorPorts<S: Transport> {
    acks: ControlPublisher<S>,
    policy: WeightsSubscriber<S>,
}

type EvalCx<'a, S> = Cx<'a, S, EvaluatorPorts<S>>;

/// The evaluator on the serving loop: one step evaluates the next eval point t once policy
/// version t arrived.
pub struct Evaluator {
    env: Box<dyn Env>,
    rng: Rng,
    policy: ActorPolicy,
    version: u64,
    /// Evaluations done and the next eval point.
    points: EvalPoints,
}

impl<S: Transport> Worker<S> for Evaluator {
    const KIND: RoleKind = RoleKind::Evaluator;
    type Ports = EvaluatorPorts<S>;
    type Checkpoint = EvaluatorCheckpoint;

    fn ports(s: &Process<S>) -> Result<EvaluatorPorts<S>> {
        let d = s.dims;
        Ok(EvaluatorPorts {
            acks: ControlPublisher::<S>::create(&s.node)?,
            policy: WeightsSubscriber::create(
                &s.node,
                WeightsKind::Policy,
                d.policy_hash,
                d.policy_len,
            )?,
        })
    }
    fn connect(s: &Process<S>, control: &ControlInbox<S>, p: &EvaluatorPorts<S>) -> Result<()> {
        wait_for_control_subscribers(s, control, &p.acks)
    }
    fn attach<'a>(p: &'a EvaluatorPorts<S>, waiter: &mut Waiter<'a, S>) {
        waiter.attach(&p.policy);
    }
    fn new(cx: &EvalCx<'_, S>) -> Result<Self> {
        let (cfg, d) = (&cx.s.cfg, cx.s.dims);
        Ok(Self {
            env: cfg.make_env()?,
            rng: stream(cfg.seed, "eval.env", 0),
            policy: ActorPolicy::new(cx.s.actor_net(), vec![0.0; d.policy_len], true),
            version: 0,
            points: EvalPoints::after(&cx.s.schedule, 0, 0),
        })
    }
    fn restore(&mut self, state: EvaluatorCheckpoint, cx: &EvalCx<'_, S>) -> Result<()> {
        (self.rng, self.version) = (state.rng, state.version);
        self.points = EvalPoints::after(&cx.s.schedule, state.evals, state.env_steps);
        Ok(())
    }
    fn step(&mut self, cx: &EvalCx<'_, S>) -> Result<Step> {
        let Some(t) = self.points.next else {
            return Ok(Step::Finished);
        };
        if let Some(h) = cx
            .ports
            .policy
            .receive_latest_into(&mut self.policy.params)?
        {
            self.version = policy_version_of(h.version);
        }
        if self.version < t {
            return Ok(Step::Waiting);
        }
        let (cfg, version) = (&cx.s.cfg, self.version);
        if cx.s.mode == Mode::Lockstep {
            ensure_protocol!(
                version == t,
                "lockstep evaluator expected policy version {t}, got {version}"
            );
            // The learner publishes version t + 1 only after this: no version is skipped.
            send_ack(&cx.ports.acks, ProducerId::new(Role::Learner, 0), t)?;
        }
        let (env, rng) = (self.env.as_mut(), &mut self.rng);
        let ret = mbpo_train::eval::evaluate(&mut self.policy, env, cfg.eval.episodes, rng)?;
        cx.stats.report(EvalResult {
            env_steps: t,
            policy_version: version,
            model_version: 0,
            mean_return: ret,
            episodes: cfg.eval.episodes as u32,
        })?;
        tracing::info!("eval after step {t} (policy version {version}): {ret:.2}");
        self.points.evaluated(&cx.s.schedule, t);
        Ok(Step::Worked)
    }
    fn done_so_far(&self) -> u64 {
        self.points.evals
    }
    /// At the cut every eval point ≤ T is evaluated.
    fn at_cut(
        &mut self,
        cut: barrier::Cut,
        _: &EvalCx<'_, S>,
    ) -> Result<AtCut<EvaluatorCheckpoint>> {
        if self.points.behind(cut) {
            return Ok(AtCut::Work);
        }
        Ok(AtCut::Write(EvaluatorCheckpoint {
            rng: self.rng.clone(),
            version: self.version,
            evals: self.points.evals,
            env_steps: cut.env_steps,
        }))
    }
    fn finish(&mut self, cx: &EvalCx<'_, S>) -> Result<()> {
        self.points.report_done(cx.stats)
    }
    fn waiting_for(&self) -> String {
        let t = self.points.next.unwrap_or_default();
        format!("policy version {t} to evaluate")
    }
}

/// An evaluator sends acknowledgements on the control channel: wait until every role's
/// control subscriber is there ([`Process::control_subscribers`], this evaluator's own
/// included, which confirms only when asked to: same thread).
pub(crate) fn wait_for_control_subscribers<S: Transport>(
    s: &Process<S>,
    control: &ControlInbox<S>,
    acks: &ControlPublisher<S>,
) -> Result<()> {
    control.sub.update_connections();
    acks.wait_for_subscribers(s.control_subscribers(), Duration::from_secs(120))?;
    Ok(())
}
