//! The planning actor and the planning evaluator (algo = "mpc"): model predictive control on the
//! ensemble the model trainer publishes, instead of a SAC policy.
//!
//! Acting (`actor-i`): warm-up steps are uniform; from then on, global step g plans on model
//! version ≥ `train_points_upto(g − model_lag)` (lockstep: exactly `train_points_upto(g)`, the
//! version the sequential `train_mpc` plans with), executes the first action and publishes the
//! transition to the model trainer (data aggregation). Its step loop is `acting.rs`, shared
//! with SAC's actor.
//!
//! Evaluating (`evaluator`): at every eval point t after the warm-up, evaluates MPC episodes with
//! model version ≥ `train_points_upto(t)`. In lockstep it acknowledges to the model trainer that
//! it copied that version; the model trainer publishes the next version only after the
//! acknowledgements of every eval point that uses the current one (weights are latest-value, so
//! this is what keeps a version from being overwritten unseen).
//!
//! Checkpoints (`mbpo_runtime::barrier`): an actor pauses between steps like the SAC actor
//! and writes its env, streams and the controller's warm start (not the model: a resumed model
//! trainer publishes its version again). The evaluator writes its streams as they were before
//! its first eval point after the cut (it may have gone past the cut, see `evaluate`). The
//! list of states it keeps for that holds one entry per eval point not yet covered by a cut.

use std::time::Instant;

use mbpo_core::TransitionSink;
use mbpo_model::ProbabilisticEnsemble;
use mbpo_train::actor::{Behaviour, EnvActor};
use mbpo_train::mpc_roles::{PlanningActorRole, PlanningEvaluator};
use mbpo_train::{Schedule, TrainError};
use mbpo_wire::*;

use super::acting::{ActingRole, Finish};
use super::actor::wait_for_control_subscribers;
use super::eval_points::EvalPoints;
use crate::barrier::{self, PlanningActorCheckpoint, PlanningEvaluatorCheckpoint};
use crate::error::ensure_protocol;
use crate::serving::{AtCut, Cx, Step, Worker};
use crate::{Result, *};

/// The model version the sequential run plans with at step `g`, minus the allowed lag.
fn needed_model(schedule: &Schedule, g: u64, model_lag: u64) -> u64 {
    schedule
        .train_points_upto(g.saturating_sub(model_lag))
        .max(1)
}

/// Load the newest published model, if there is one, with `load(version, loader)` (the
/// role's `load_model`: one copy out of shared memory); returns its version.
fn pull_model<S: Transport>(
    model: &WeightsSubscriber<S>,
    d: &Dims,
    load: impl FnOnce(u64, &dyn Fn(&mut ProbabilisticEnsemble) -> Result<()>) -> Result<()>,
) -> Result<Option<u64>> {
    let Some(w) = model.receive_latest()? else {
        return Ok(None);
    };
    let loader = |m: &mut ProbabilisticEnsemble| Ok(d.model.load_into(w.params(), m)?);
    load(w.version(), &loader)?;
    Ok(Some(w.version()))
}

/// The planning actor on the shared step loop: it plans on the model trainer's ensemble; step g
/// needs the version the sequential run plans with (pipelined: that of step g − `model_lag`).
pub struct ModelActing {
    role: PlanningActorRole,
    schedule: Schedule,
    model_lag: u64,
    /// Wall seconds of every plan, for the median in `Done`.
    plan_seconds: Vec<f64>,
}

impl ActingRole for ModelActing {
    const ROLE: RoleKind = RoleKind::PlanningActor;
    const WEIGHTS: WeightsKind = WeightsKind::Model;
    type Checkpoint = PlanningActorCheckpoint;

    fn new<S: Transport>(s: &Process<S>) -> Result<Self> {
        Ok(Self {
            role: PlanningActorRole::new(&s.cfg, s.args.index as u64)?,
            schedule: s.schedule,
            model_lag: s.slack.model_lag,
            plan_seconds: Vec::new(),
        })
    }

    fn checkpoint(&self, steps: u64) -> PlanningActorCheckpoint {
        PlanningActorCheckpoint {
            role: self.role.checkpoint(),
            steps,
        }
    }
    fn restore(&mut self, state: PlanningActorCheckpoint) -> Result<u64> {
        // The model comes again from the model trainer, which republishes its version.
        self.role.restore(state.role)?;
        Ok(state.steps)
    }
    fn take_newest<S: Transport>(&mut self, model: &WeightsSubscriber<S>, d: &Dims) -> Result<()> {
        pull_model(model, d, |v, load| Ok(self.role.load_model(v, load)?))?;
        Ok(())
    }
    fn sequential_version(&self, g: u64) -> u64 {
        self.schedule.train_points_upto(g)
    }
    fn oldest_allowed(&self, g: u64) -> u64 {
        needed_model(&self.schedule, g, self.model_lag)
    }
    fn holds(&self, version: u64) -> bool {
        self.role.model_version() >= version
    }
    fn version(&self) -> u64 {
        self.role.model_version()
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
    /// After every planned step (planning takes far longer than a record): the supervisor
    /// writes the metrics row of eval point t only once every actor is past t.
    fn after_step(&mut self, behaviour: Behaviour) -> bool {
        let planned = behaviour == Behaviour::Policy;
        if planned {
            self.plan_seconds.push(self.role.last_plan_seconds);
        }
        planned
    }
    fn finish(&mut self) -> Finish {
        let median = mbpo_core::stats::median(&mut self.plan_seconds).unwrap_or(0.0);
        let plans = self.role.plans();
        let iterations = match self.role.iterations_per_plan() {
            Some((lo, mean, hi)) => format!(", iterations per plan {lo}..{hi} (mean {mean:.1})"),
            None => String::new(),
        };
        Finish {
            work: plans,
            median_step_seconds: median as f32,
            log: format!(
                "{plans} plans (median {:.1} ms{iterations}), ",
                median * 1e3
            ),
        }
    }
}

/// The planning evaluator's ports: the models it plans on, and the acknowledgements it sends
/// the model trainer (lockstep).
pub struct EvaluatorPorts<S: Transport> {
    acks: ControlPublisher<S>,
    model: WeightsSubscriber<S>,
}

type EvalCx<'a, S> = Cx<'a, S, EvaluatorPorts<S>>;

/// The planning evaluator on the serving loop: one step evaluates the next eval point t once
/// model version `train_points_upto(t)` arrived (or abandons it for a cut before t).
///
/// Unlike a policy version, the model of eval point t can exist before the actors reach t, so
/// the evaluator may have evaluated points after the cut T by the time it learns T. Its file
/// must hold the state after T: the state before each evaluation no cut covers yet is kept
/// (`before_eval`), and a cut writes the one before its first eval point after T (those
/// evaluations are done again on resume, with the same streams).
pub struct ModelEvaluator {
    evaluator: PlanningEvaluator,
    /// Evaluations done and the next eval point.
    points: EvalPoints,
    /// Lockstep: the next eval point was acknowledged (once, also when an abandoned
    /// evaluation of it is done again).
    acknowledged: bool,
    before_eval: Vec<(u64, PlanningEvaluatorCheckpoint)>,
}

impl<S: Transport> Worker<S> for ModelEvaluator {
    const KIND: RoleKind = RoleKind::PlanningEvaluator;
    type Ports = EvaluatorPorts<S>;
    type Checkpoint = PlanningEvaluatorCheckpoint;

    fn ports(s: &Process<S>) -> Result<EvaluatorPorts<S>> {
        let d = s.dims;
        Ok(EvaluatorPorts {
            acks: ControlPublisher::<S>::create(&s.node)?,
            model: WeightsSubscriber::create(
                &s.node,
                WeightsKind::Model,
                d.model.layout_hash,
                d.model.len(),
            )?,
        })
    }
    fn connect(s: &Process<S>, control: &ControlInbox<S>, p: &EvaluatorPorts<S>) -> Result<()> {
        wait_for_control_subscribers(s, control, &p.acks)
    }
    fn attach<'a>(p: &'a EvaluatorPorts<S>, waiter: &mut Waiter<'a, S>) {
        waiter.attach(&p.model);
    }
    fn new(cx: &EvalCx<'_, S>) -> Result<Self> {
        Ok(Self {
            evaluator: PlanningEvaluator::new(&cx.s.cfg)?,
            points: EvalPoints::after(&cx.s.schedule, 0, 0),
            acknowledged: false,
            before_eval: Vec::new(),
        })
    }
    fn restore(&mut self, state: PlanningEvaluatorCheckpoint, cx: &EvalCx<'_, S>) -> Result<()> {
        self.evaluator.restore(state.role);
        self.points = EvalPoints::after(&cx.s.schedule, state.evals, state.env_steps);
        Ok(())
    }
    fn step(&mut self, cx: &EvalCx<'_, S>) -> Result<Step> {
        let Some(t) = self.points.next else {
            return Ok(Step::Finished);
        };
        // Lockstep keeps a model once copied: the trainer may publish need + 1 as soon as t is
        // acknowledged, and an evaluation of t abandoned at a barrier is done again with
        // version need.
        let need = cx.s.schedule.train_points_upto(t);
        if cx.s.mode == Mode::Pipelined || self.evaluator.model_version() < need {
            let evaluator = &mut self.evaluator;
            pull_model(&cx.ports.model, &cx.s.dims, |v, load| {
                Ok(evaluator.load_model(v, load)?)
            })?;
        }
        if self.evaluator.model_version() < need {
            return Ok(Step::Waiting);
        }
        self.before_eval.push((t, self.state_now()));
        if cx.s.mode == Mode::Lockstep {
            ensure_protocol!(
                self.evaluator.model_version() == need,
                "lockstep evaluator at step {t} expected model version {need}, got {}",
                self.evaluator.model_version()
            );
            // The model trainer publishes version need + 1 only after this.
            if !self.acknowledged {
                send_ack(&cx.ports.acks, ProducerId::new(Role::ModelTrainer, 0), t)?;
                self.acknowledged = true;
            }
        }
        self.evaluate(cx, t)?;
        Ok(Step::Worked)
    }
    fn done_so_far(&self) -> u64 {
        self.points.evals
    }
    fn at_cut(
        &mut self,
        cut: barrier::Cut,
        _: &EvalCx<'_, S>,
    ) -> Result<AtCut<PlanningEvaluatorCheckpoint>> {
        if self.points.behind(cut) {
            return Ok(AtCut::Work);
        }
        let mut state = self
            .before_eval
            .iter()
            .find(|(t, _)| *t > cut.env_steps)
            .map_or_else(|| self.state_now(), |(_, s)| s.clone());
        state.env_steps = cut.env_steps;
        self.before_eval.retain(|(t, _)| *t > cut.env_steps);
        Ok(AtCut::Write(state))
    }
    fn finish(&mut self, cx: &EvalCx<'_, S>) -> Result<()> {
        self.points.report_done(cx.stats)
    }
    fn waiting_for(&self) -> String {
        format!(
            "the model to evaluate step {}",
            self.points.next.unwrap_or_default()
        )
    }
}

impl ModelEvaluator {
    /// Its state now, as a checkpoint (the cut's step is set when written).
    fn state_now(&self) -> PlanningEvaluatorCheckpoint {
        PlanningEvaluatorCheckpoint {
            role: self.evaluator.checkpoint(),
            evals: self.points.evals,
            env_steps: 0,
        }
    }

    /// Evaluate eval point `t`. A cut before t (or a stop) abandons the evaluation: the barrier
    /// would otherwise wait for an evaluation it discards (t is evaluated again after the cut,
    /// from the state before it).
    fn evaluate<S: Transport>(&mut self, cx: &EvalCx<'_, S>, t: u64) -> Result<()> {
        let (cfg, control) = (&cx.s.cfg, cx.control);
        let started = Instant::now();
        let mut poll_error = None;
        let ret = self.evaluator.evaluate_unless(cfg.eval.episodes, || {
            if let Err(e) = control.poll() {
                poll_error = Some(e);
                return true;
            }
            control.stopped() || control.cut().is_some_and(|c| c.env_steps < t)
        })?;
        if let Some(e) = poll_error {
            return Err(e);
        }
        let seconds = started.elapsed().as_secs_f64();
        let Some(ret) = ret else {
            let (_, before) = self.before_eval.pop().expect("pushed before evaluating t");
            self.evaluator.restore(before.role);
            tracing::info!(
                "eval after step {t} abandoned after {seconds:.1} s for the checkpoint barrier"
            );
            return Ok(());
        };
        let model_version = self.evaluator.model_version();
        cx.stats.report(EvalResult {
            env_steps: t,
            policy_version: 0,
            model_version,
            mean_return: ret,
            episodes: cfg.eval.episodes as u32,
        })?;
        tracing::info!(
            "eval after step {t} (model version {model_version}): {ret:.2} in {seconds:.1} s"
        );
        self.points.evaluated(&cx.s.schedule, t);
        self.acknowledged = false;
        Ok(())
    }
}
