//! The planning actor and the planning evaluator (algo = "mpc"): model predictive control on the
//! ensemble the model trainer publishes, instead of a SAC policy.
//!
//! Acting (`actor-i`): warm-up steps are uniform; from then on, global step g plans on model
//! version ≥ `train_points_upto(g − model_lag)` (lockstep: exactly `train_points_upto(g)`, the
//! version the sequential `train_mpc` plans with), executes the first action and publishes the
//! transition to the model trainer (data aggregation).
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

use mbpo_model::ProbabilisticEnsemble;
use mbpo_train::actor::Behaviour;
use mbpo_train::mpc_roles::{PlanningActorRole, PlanningEvaluator};
use mbpo_train::Schedule;
use mbpo_wire::*;

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

/// A planning actor's service loop (`s`: its opened process).
pub fn act<S: Transport>(args: &ServiceArgs) -> Result<()> {
    let s = Process::<S>::open(args, RoleKind::PlanningActor)?;
    let args = &s.args;
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::<S>::create(&s.node)?;
    let model = WeightsSubscriber::create(
        &s.node,
        WeightsKind::Model,
        d.model.layout_hash,
        d.model.len(),
    )?;
    let real = TransitionPublisher::create(&s.node, Channel::Real, d.rows(), 1)?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    // The model trainer is the only consumer of real data in an MPC run.
    real.wait_for_subscribers(s.real_consumers(), Duration::from_secs(120))?;
    let mut waiter = Waiter::new()?;
    waiter.attach(&control.sub).attach(&model);

    let mut role = PlanningActorRole::new(cfg, args.index as u64)?;
    let schedule = s.schedule;
    let mut lag = SlackTracker::default();
    let mut plan_seconds = Vec::new();
    let mut last_progress = Instant::now();
    let steps = actor_steps(cfg.steps, args.actors, args.index);
    let file = barrier::FileTarget::new(
        &args.run_dir,
        barrier::actor_file(args.index),
        barrier::kind::PLANNING_ACTOR,
    );
    let mut first = 1;
    if let Some(dir) = &args.resume_from {
        // The model comes again from the model trainer, which republishes its version.
        let state: PlanningActorCheckpoint = file.read(dir)?;
        role.restore(state.role)?;
        first = state.steps + 1;
    }
    // At the cut: write the state after `done` local steps, wait for the resume.
    let write_at = |role: &PlanningActorRole, done: u64, cut| {
        let state = PlanningActorCheckpoint {
            role: role.checkpoint(),
            steps: done,
        };
        barrier::write_and_await_resume(&waiter, &control, &stats_pub, &file, cut, &state)
    };
    // At a barrier: report the steps done, then as above.
    let at_barrier = |role: &PlanningActorRole, done: u64| -> Result<bool> {
        match barrier::report_paused(&waiter, &control, &stats_pub, done)? {
            Some(cut) => write_at(role, done, cut),
            None => Ok(false),
        }
    };
    let started = Instant::now();
    let mut ipc = Duration::ZERO;
    for t in first..=steps {
        let g = global_step(t, args.actors, args.index);
        let behaviour = loop {
            control.poll()?;
            if control.stopped() {
                tracing::info!("stopped before step {g}");
                return Ok(());
            }
            if control.pause_requested() {
                if !at_barrier(&role, t - 1)? {
                    tracing::info!("stopped after the checkpoint, before step {g}");
                    return Ok(());
                }
                continue;
            }
            if schedule.is_warm_up(g) {
                break Behaviour::Uniform;
            }
            let need = needed_model(&schedule, g, s.slack.model_lag);
            let ok = wait_for(
                &waiter,
                &control,
                &|| format!("model version {need}"),
                || {
                    pull_model(&model, &d, |v, load| Ok(role.load_model(v, load)?))?;
                    Ok(role.model_version() >= need || control.pause_requested())
                },
            )?;
            if !ok {
                tracing::info!("stopped before step {g}");
                return Ok(());
            }
            if control.pause_requested() {
                continue;
            }
            let exact = schedule.train_points_upto(g);
            if s.mode == Mode::Lockstep {
                ensure_protocol!(
                    role.model_version() == exact,
                    "lockstep planning actor at step {g} got model version {} (want {exact})",
                    role.model_version()
                );
            }
            lag.see(exact as f64 - role.model_version() as f64);
            break Behaviour::Policy;
        };
        let episodes = role.env_actor().episodes;
        // The env step writes its transition straight into the sample it is sent in.
        let t0 = Instant::now();
        let mut loan = real.loan_rows(1)?;
        ipc += t0.elapsed();
        if let Err(e) = role.act_into(behaviour, &mut loan) {
            drop(loan);
            let (w, c, p) = (&waiter, &control, &stats_pub);
            return barrier::after_env_failure(w, c, p, e, g, t - 1, |cut| {
                write_at(&role, t - 1, cut)
            });
        }
        if behaviour == Behaviour::Policy {
            plan_seconds.push(role.last_plan_seconds);
        }
        let a = role.env_actor();
        if a.episodes > episodes {
            let ret = a.last_return.unwrap_or(f64::NAN);
            stats_pub.report(EpisodeEnd {
                env_steps: g,
                episode_return: ret,
                version: role.model_version(),
            })?;
        }
        let meta = TransitionMeta {
            policy_version: 0,
            model_version: role.model_version(),
            env_steps: g,
        };
        let t0 = Instant::now();
        loan.send(meta)?;
        ipc += t0.elapsed();
        // After every planned step (planning takes far longer than a record): the supervisor
        // writes the metrics row of eval point t only once every actor is past t.
        if behaviour == Behaviour::Policy || last_progress.elapsed() >= Duration::from_millis(500) {
            last_progress = Instant::now();
            stats_pub.report(Progress {
                env_steps: g,
                model_version: role.model_version(),
                ..Default::default()
            })?;
        }
    }
    let median = mbpo_core::stats::median(&mut plan_seconds);
    let (lo, hi, mean) = lag.get();
    let done = Done {
        real: steps,
        work: role.plans(),
        episodes_cut: role.env_actor().episodes_cut,
        episodes_lost: role.env_actor().episodes_lost,
        median_step_seconds: median.unwrap_or(0.0) as f32,
        slack_min: lo,
        slack_max: hi,
        slack_mean: mean,
        ipc_seconds: ipc.as_secs_f32(),
        wall_seconds: started.elapsed().as_secs_f32(),
        ..Default::default()
    };
    stats_pub.report(done)?;
    tracing::info!(
        "done: {steps} steps, {} plans (median {:.1} ms), model lag {lo}..{hi} (mean {mean:.2})",
        role.plans(),
        median.unwrap_or(0.0) * 1e3
    );
    barrier::idle_until_stop(&waiter, &control, &stats_pub, Some(steps), |cut| {
        write_at(&role, steps, cut)
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
    // Control subscribers of an MPC run: the actors, the model trainer and this evaluator.
    control.sub.update_connections();
    acks.wait_for_subscribers(args.actors as usize + 2, Duration::from_secs(120))?;
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
