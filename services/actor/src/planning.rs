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

use std::time::{Duration, Instant};

use mbpo_service_kit::{stats, *};
use mbpo_train::actor::Behaviour;
use mbpo_train::mpc::{PlanningActorRole, PlanningEvaluator};
use mbpo_train::roles::{ModelSnapshot, Schedule};
use mbpo_wire::*;

/// The model version the sequential run plans with at step `g`, minus the allowed lag.
fn needed_model(schedule: &Schedule, g: u64, model_lag: u64) -> u64 {
    train_points_upto(schedule, g.saturating_sub(model_lag)).max(1)
}

/// Load the newest published model into `set` if there is one; returns its version.
fn pull_model(
    model: &WeightsSubscriber<ipc::Service>,
    d: &Dims,
    mut set: impl FnMut(&ModelSnapshot) -> anyhow::Result<()>,
) -> anyhow::Result<Option<u64>> {
    let Some(w) = model.receive_latest()? else {
        return Ok(None);
    };
    let snapshot = ModelSnapshot {
        version: w.version(),
        weights: d.model.decode(w.params())?,
    };
    set(&snapshot)?;
    Ok(Some(snapshot.version))
}

pub fn act(args: &ServiceArgs, s: Process) -> anyhow::Result<()> {
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::create(&s.node)?;
    let model = WeightsSubscriber::create(
        &s.node,
        WeightsKind::Model,
        d.model.layout_hash,
        d.model.len(),
    )?;
    let real = TransitionPublisher::create(&s.node, Channel::Real, d.rows(), 1)?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    // The model trainer is the only consumer of real data in an MPC run.
    real.wait_for_subscribers(1, Duration::from_secs(120))?;
    let mut waiter = Waiter::new()?;
    waiter.attach(&control.sub).attach(&model);

    let mut role = PlanningActorRole::new(cfg, args.index as u64)?;
    let schedule = Schedule::of(cfg);
    let mut lag = stats::SlackTracker::default();
    let mut plan_seconds = Vec::new();
    let mut last_progress = Instant::now();
    let steps = actor_steps(cfg.steps, args.actors, args.index);
    let started = Instant::now();
    let mut ipc = Duration::ZERO;
    for t in 1..=steps {
        let g = global_step(t, args.actors, args.index);
        let behaviour = if schedule.is_warm_up(g) {
            Behaviour::Uniform
        } else {
            let need = needed_model(&schedule, g, s.slack.model_lag);
            let ok = wait_for(
                &waiter,
                &control,
                &|| format!("model version {need}"),
                || {
                    pull_model(&model, &d, |snap| Ok(role.set_model(snap)?))?;
                    Ok(role.model_version() >= need)
                },
            )?;
            if !ok {
                tracing::info!("stopped before step {g}");
                return Ok(());
            }
            let exact = train_points_upto(&schedule, g);
            if s.mode == Mode::Lockstep {
                anyhow::ensure!(
                    role.model_version() == exact,
                    "lockstep planning actor at step {g} got model version {} (want {exact})",
                    role.model_version()
                );
            }
            lag.see(exact as f64 - role.model_version() as f64);
            Behaviour::Policy
        };
        let episodes = role.env_actor().episodes;
        let rows = role.act(behaviour)?;
        if behaviour == Behaviour::Policy {
            plan_seconds.push(role.last_plan_seconds);
        }
        let a = role.env_actor();
        if a.episodes > episodes {
            let ret = a.last_return.unwrap_or(f64::NAN);
            stats_pub.send(&StatsRecord::episode(ret, 0, g, role.model_version()))?;
        }
        let meta = TransitionMeta {
            policy_version: 0,
            model_version: role.model_version(),
            env_steps: g,
        };
        let t0 = Instant::now();
        real.send_batch(&rows, meta)?;
        ipc += t0.elapsed();
        // After every planned step (planning takes far longer than a record): the supervisor
        // writes the metrics row of eval point t only once every actor is past t.
        if behaviour == Behaviour::Policy || last_progress.elapsed() >= Duration::from_millis(500) {
            last_progress = Instant::now();
            stats_pub.send(&stats::progress(g, 0, role.model_version(), 0))?;
        }
    }
    plan_seconds.sort_by(f64::total_cmp);
    let median = plan_seconds.get(plan_seconds.len() / 2).copied();
    let (lo, hi, mean) = lag.get();
    let done = stats::Done {
        real: steps,
        work: role.plans(),
        median_step_seconds: median.unwrap_or(0.0) as f32,
        slack_min: lo,
        slack_max: hi,
        slack_mean: mean,
        ipc_seconds: ipc.as_secs_f32(),
        wall_seconds: started.elapsed().as_secs_f32(),
        ..Default::default()
    };
    stats_pub.send(&done.record())?;
    tracing::info!(
        "done: {steps} steps, {} plans (median {:.1} ms), model lag {lo}..{hi} (mean {mean:.2})",
        role.plans(),
        median.unwrap_or(0.0) * 1e3
    );
    wait_for_stop(&waiter, &control)
}

pub fn evaluate(args: &ServiceArgs, s: Process) -> anyhow::Result<()> {
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::create(&s.node)?;
    let acks = ControlPublisher::create(&s.node)?;
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
    let schedule = Schedule::of(cfg);
    let trainer = ProducerId::new(Role::ModelTrainer, 0);
    let mut evals = 0;
    for t in (1..=cfg.steps).filter(|&t| is_eval_point(cfg, t)) {
        let need = train_points_upto(&schedule, t);
        let ok = wait_for(
            &waiter,
            &control,
            &|| format!("model version {need} to evaluate step {t}"),
            || {
                pull_model(&model, &d, |snap| Ok(evaluator.set_model(snap)?))?;
                Ok(evaluator.model_version() >= need)
            },
        )?;
        if !ok {
            return Ok(());
        }
        if s.mode == Mode::Lockstep {
            anyhow::ensure!(
                evaluator.model_version() == need,
                "lockstep evaluator at step {t} expected model version {need}, got {}",
                evaluator.model_version()
            );
            // The model trainer publishes version need + 1 only after this.
            send_ack(&acks, trainer, t)?;
        }
        let started = Instant::now();
        let ret = evaluator.evaluate(cfg.eval.episodes)?;
        stats_pub.send(&stats::eval_model(
            t,
            evaluator.model_version(),
            ret,
            cfg.eval.episodes,
        ))?;
        tracing::info!(
            "eval after step {t} (model version {}): {ret:.2} in {:.1} s",
            evaluator.model_version(),
            started.elapsed().as_secs_f64()
        );
        evals += 1;
    }
    stats_pub.send(
        &stats::Done {
            work: evals,
            ..Default::default()
        }
        .record(),
    )?;
    wait_for_stop(&waiter, &control)
}
