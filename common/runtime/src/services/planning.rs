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

use std::time::{Duration, Instant};

use mbpo_core::TransitionSink;
use mbpo_model::ProbabilisticEnsemble;
use mbpo_train::actor::{Behaviour, EnvActor};
use mbpo_train::mpc_roles::{PlanningActorRole, PlanningEvaluator};
use mbpo_train::{Schedule, TrainError};
use mbpo_wire::*;

use super::acting::{self, ActingRole, Finish};
use crate::barrier::{self, PlanningActorCheckpoint, PlanningEvaluatorCheckpoint};
use crate::error::ensure_protocol;
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
struct ModelActing {
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
        Finish {
            work: plans,
            median_step_seconds: median as f32,
            log: format!("{plans} plans (median {:.1} ms), ", median * 1e3),
        }
    }
}

/// A planning actor's service loop.
pub fn act<S: Transport>(args: &ServiceArgs) -> Result<()> {
    acting::act(args, |s: &Process<S>| {
        Ok(ModelActing {
            role: PlanningActorRole::new(&s.cfg, args.index as u64)?,
            schedule: s.schedule,
            model_lag: s.slack.model_lag,
            plan_seconds: Vec::new(),
        })
    })
}

/// The planning evaluator's service loop (`s`: its opened process).
pub fn evaluate<S: Transport>(args: &ServiceArgs) -> Result<()> {
    let s = Process::<S>::open(args, RoleKind::PlanningEvaluator)?;
    let args = &s.args;
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::<S>::create(&s.node)?;
    let acks = ControlPublisher::<S>::create(&s.node)?;
    let model = WeightsSubscriber::create(
        &s.node,
        WeightsKind::Model,
        d.model.layout_hash,
        d.model.len(),
    )?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    // Every role's control subscriber (the role table's count, this evaluator's included).
    control.sub.update_connections();
    let subscribers = s.pipeline.subscribers(Channel::Control, args.actors);
    acks.wait_for_subscribers(subscribers, Duration::from_secs(120))?;
    let mut waiter = Waiter::new()?;
    waiter.attach(&control.sub).attach(&model);

    let mut evaluator = PlanningEvaluator::new(cfg)?;
    let schedule = s.schedule;
    let trainer = ProducerId::new(Role::ModelTrainer, 0);
    let mut evals = 0;
    let mut after = 0;
    let file = barrier::FileTarget::new(
        &args.run_dir,
        barrier::file::EVALUATOR,
        barrier::kind::PLANNING_EVALUATOR,
    );
    if let Some(dir) = &args.resume_from {
        let state: PlanningEvaluatorCheckpoint = file.read(dir)?;
        evaluator.restore(state.role);
        (evals, after) = (state.evals, state.env_steps);
    }
    // Unlike a policy version, the model of eval point t can exist before the actors reach t,
    // so the evaluator may have evaluated points after the cut T by the time it learns T. Its
    // file must hold the state after T: the state before each evaluation no cut covers yet is
    // kept, and a cut writes the one before its first eval point after T (those evaluations
    // are done again on resume, with the same streams).
    let mut before_eval: Vec<(u64, PlanningEvaluatorCheckpoint)> = Vec::new();
    let write_at = |before_eval: &mut Vec<(u64, PlanningEvaluatorCheckpoint)>,
                    now: PlanningEvaluatorCheckpoint,
                    cut: barrier::Cut| {
        let mut state = before_eval
            .iter()
            .find(|(t, _)| *t > cut.env_steps)
            .map_or(now, |(_, s)| s.clone());
        state.env_steps = cut.env_steps;
        before_eval.retain(|(t, _)| *t > cut.env_steps);
        barrier::write_and_await_resume(&waiter, &control, &stats_pub, &file, cut, &state)
    };
    let state_now = |evaluator: &PlanningEvaluator, evals: u64| PlanningEvaluatorCheckpoint {
        role: evaluator.checkpoint(),
        evals,
        env_steps: 0,
    };
    for t in (after + 1..=cfg.steps).filter(|&t| schedule.is_eval_point(t)) {
        let need = schedule.train_points_upto(t);
        let mut acknowledged = false;
        let ret = loop {
            // Wait for model version `need`, writing the checkpoint of a cut before t meanwhile.
            // (Lockstep keeps a model once copied: the trainer may publish need + 1 as soon as
            // t is acknowledged, and an evaluation of t abandoned at a barrier is done again
            // with version need.)
            loop {
                let ok = wait_for(
                    &waiter,
                    &control,
                    &|| format!("model version {need} to evaluate step {t}"),
                    || {
                        if s.mode == Mode::Pipelined || evaluator.model_version() < need {
                            pull_model(&model, &d, |v, load| Ok(evaluator.load_model(v, load)?))?;
                        }
                        Ok(evaluator.model_version() >= need
                            || control.cut().is_some_and(|c| c.env_steps < t))
                    },
                )?;
                if !ok {
                    return Ok(());
                }
                match control.cut() {
                    Some(cut) if cut.env_steps < t => {
                        let now = state_now(&evaluator, evals);
                        if !write_at(&mut before_eval, now, cut)? {
                            return Ok(());
                        }
                    }
                    _ => break,
                }
            }
            before_eval.push((t, state_now(&evaluator, evals)));
            if s.mode == Mode::Lockstep {
                ensure_protocol!(
                    evaluator.model_version() == need,
                    "lockstep evaluator at step {t} expected model version {need}, got {}",
                    evaluator.model_version()
                );
                // The model trainer publishes version need + 1 only after this (once per
                // eval point, also when an abandoned evaluation of t is done again).
                if !acknowledged {
                    send_ack(&acks, trainer, t)?;
                    acknowledged = true;
                }
            }
            let started = Instant::now();
            // A cut before t (or a stop) abandons the evaluation: the barrier would otherwise
            // wait for an evaluation it discards (t is evaluated again after the cut).
            let mut poll_error = None;
            let ret = evaluator.evaluate_unless(cfg.eval.episodes, || {
                if let Err(e) = control.poll() {
                    poll_error = Some(e);
                    return true;
                }
                control.stopped() || control.cut().is_some_and(|c| c.env_steps < t)
            })?;
            if let Some(e) = poll_error {
                return Err(e);
            }
            match ret {
                Some(ret) => {
                    let seconds = started.elapsed().as_secs_f64();
                    break (ret, seconds);
                }
                None => {
                    // Back to the state before t, as if t had not been started.
                    let (_, before) = before_eval.pop().expect("pushed before evaluating t");
                    evaluator.restore(before.role);
                    tracing::info!(
                        "eval after step {t} abandoned after {:.1} s for the checkpoint barrier",
                        started.elapsed().as_secs_f64()
                    );
                    if control.stopped() {
                        return Ok(());
                    }
                }
            }
        };
        let (ret, seconds) = ret;
        stats_pub.report(EvalResult {
            env_steps: t,
            policy_version: 0,
            model_version: evaluator.model_version(),
            mean_return: ret,
            episodes: cfg.eval.episodes as u32,
        })?;
        tracing::info!(
            "eval after step {t} (model version {}): {ret:.2} in {seconds:.1} s",
            evaluator.model_version()
        );
        evals += 1;
    }
    stats_pub.report(Done {
        work: evals,
        ..Default::default()
    })?;
    barrier::idle_until_stop(&waiter, &control, &stats_pub, None, |cut| {
        write_at(&mut before_eval, state_now(&evaluator, evals), cut)
    })
}
