//! `mbpo-model-trainer`: keeps its own copy of the real data and, at every train point t,
//! trains the ensemble and publishes model version v (latest value, one flat `[f32]`, see
//! `ModelWireLayout`).
//!
//! Lockstep: trains on exactly the first t − 1 real transitions (transition t may already have
//! arrived; it is held back). Pipelined: trains on every transition received by then (≥ t − 1).
//! In an MPC run (algo = "mpc") the same loop feeds the planning actors; in lockstep it also
//! waits for the planning evaluator's acknowledgements before replacing a model version.

use std::time::{Duration, Instant};

use mbpo_model::TrainReport;
use mbpo_train::roles::{ModelSnapshot, ModelTrainerRole};
use mbpo_train::Schedule;
use mbpo_wire::*;

use crate::barrier::{self, ModelTrainerCheckpoint};
use crate::{Result, *};

/// The model trainer's service loop.
pub fn run<S: Transport>(args: &ServiceArgs) -> Result<()> {
    let s = Process::<S>::open(args, RoleKind::ModelTrainer)?;
    let (cfg, d) = (&s.cfg, s.dims);
    let control = ControlInbox::create(&s.node)?;
    let stats_pub = StatsPublisher::<S>::create(&s.node)?;
    let real = TransitionSubscriber::create(&s.node, Channel::Real, d.rows())?;
    let model_pub = WeightsPublisher::create(
        &s.node,
        WeightsKind::Model,
        d.model.layout_hash,
        d.model.len(),
    )?;
    stats_pub.wait_for_subscribers(1, Duration::from_secs(60))?;
    let mut waiter = Waiter::new()?;
    waiter.attach(&control.sub).attach(&real).attach(&model_pub);

    let mut role = ModelTrainerRole::new(cfg, d.obs, d.act)?;
    let schedule = s.schedule;
    let mut inbox = RealInbox::new(d.rows());
    let mut flat = Vec::with_capacity(d.model.len());
    let file = barrier::FileTarget::new(
        &args.run_dir,
        barrier::file::MODEL_TRAINER,
        barrier::kind::MODEL_TRAINER,
    );
    // Planners act on the models: they are republished on resume, and (lockstep) each waits
    // for the evaluations of the model before it.
    let plans = s.pipeline.plans();
    let mut prev_train_point = 0;
    if let Some(dir) = &args.resume_from {
        let state: ModelTrainerCheckpoint = file.read(dir)?;
        role.restore(state.role)?;
        inbox.resume_at(role.real_received());
        if plans && role.version() > 0 {
            // The planners' checkpoints hold no model: they plan on this version again. (MBPO:
            // no republish, the rollout generator's checkpoint holds this model version.)
            d.model.encode(&role.snapshot().weights, &mut flat)?;
            let counters = WeightsCounters {
                env_steps: role.real_received(),
                sac_updates: 0,
                model_trainings: role.version(),
            };
            model_pub.publish(&flat, role.version(), counters)?;
            // The evaluator acknowledged every eval point ≤ T before the cut (those messages
            // went with the stopped processes): only later ones are waited for.
            let last = schedule.nth_train_point(role.version()).unwrap_or(0);
            prev_train_point = last.max(role.real_received() + 1);
        }
    }
    let mut version = role.version();
    let at_cut = |role: &mut ModelTrainerRole, cut: barrier::Cut| {
        let state = ModelTrainerCheckpoint {
            role: role.checkpoint(),
        };
        barrier::write_and_await_resume(&waiter, &control, &stats_pub, &file, cut, &state)
    };
    let gate = barrier::DataGate::new(&waiter, &control, &stats_pub, &real, s.mode, at_cut);
    let mut train_points = (1..=cfg.steps)
        .filter(|&t| schedule.train_point(t).is_some())
        .skip(version as usize)
        .peekable();
    while let Some(&t) = train_points.peek() {
        if !gate.wait_for_real(&mut inbox, &mut role, t - 1, version)? {
            return Ok(());
        }
        let n = match s.mode {
            Mode::Lockstep => (t - 1 - inbox.taken()) as usize,
            Mode::Pipelined => inbox.pending(),
        };
        inbox.take(n, &mut role);
        tracing::info!(
            "training model v{} for step {t} on {} transitions",
            version + 1,
            role.real_received()
        );
        let started = Instant::now();
        let abandon = s.pipeline.abandons_training_on_stop(s.mode);
        let Some((snapshot, report)) = train(&mut role, abandon, &control, version)? else {
            // Back to the gate, which serves the barrier (a resumed run trains again) or stops.
            tracing::info!(
                "model training for step {t} abandoned after {:.1} s: the run is stopping",
                started.elapsed().as_secs_f64()
            );
            continue;
        };
        train_points.next();
        let seconds = started.elapsed().as_secs_f64();
        version = snapshot.version;
        // The same number the sequential metrics row shows.
        let mse = report.elite_holdout_mse();
        // Stats before weights: whoever sees a later consequence of this model finds its record.
        stats_pub.report(ModelTrained {
            rows: role.real_received(),
            version,
            holdout_mse: mse,
            epochs: report.epochs as u32,
            seconds: seconds as f32,
        })?;
        if plans && s.mode == Mode::Lockstep {
            if !wait_for_mpc_eval_acks(&schedule, &waiter, &control, prev_train_point, t, version)?
            {
                return Ok(());
            }
            prev_train_point = t;
        }
        d.model.encode(&snapshot.weights, &mut flat)?;
        let counters = WeightsCounters {
            env_steps: role.real_received(),
            sac_updates: 0,
            model_trainings: version,
        };
        model_pub.publish(&flat, version, counters)?;
        tracing::info!(
            "model v{version} trained for step {t} on {} transitions: {} epochs, holdout mse {mse:.5}, {seconds:.2} s{}",
            role.real_received(),
            report.epochs,
            report.termination.map(|t| format!("; {t}")).unwrap_or_default()
        );
    }
    // Take the rest so that no actor blocks and the counts are complete.
    let total = cfg.steps;
    if !gate.wait_for_real(&mut inbox, &mut role, total, version)? {
        return Ok(());
    }
    let lost = real.stats().missing;
    stats_pub.report(Done {
        real: inbox.received(),
        lost,
        real_spilled: inbox.spilled(),
        work: version,
        ..Default::default()
    })?;
    tracing::info!(
        "done: {} real transitions received, {lost} lost, {version} trainings",
        inbox.received()
    );
    gate.idle_until_stop(&mut inbox, &mut role, Some(version))
}

/// Train on the role's data, abandoning the training after the epoch under way (`None`; the
/// role is as before it) when the process is stopped, or -- pipelined MBPO -- when a
/// checkpoint barrier the run stops after (Ctrl-C) does not need it: a training can take
/// minutes, and the cut then holds the `done` trainings completed (the resumed run trains
/// again, on at least as much data: pipelined runs train on whatever has arrived). A periodic
/// barrier lets the training finish, since the run goes on with it; lockstep must hold every
/// training of the train points ≤ T, and an MPC evaluator needs the model of every eval point
/// ≤ T (`Barrier::take_cut`).
fn train<S: Transport>(
    role: &mut ModelTrainerRole,
    abandon_at_stop_barrier: bool,
    control: &ControlInbox<S>,
    done: u64,
) -> Result<Option<(ModelSnapshot, TrainReport)>> {
    let mut poll_error = None;
    let trained = role.train_unless(|| {
        if let Err(e) = control.poll() {
            poll_error = Some(e);
            return true;
        }
        control.stopped()
            || (abandon_at_stop_barrier && control.pause_to_stop() && barrier::holds(control, done))
    })?;
    match poll_error {
        Some(e) => Err(e),
        None => Ok(trained),
    }
}

/// MPC lockstep: before model `version` replaces `version − 1` (weights are latest-value), wait
/// until the evaluator acknowledged every eval point in [prev_train_point, t) — the points the
/// sequential run evaluates with `version − 1`. Returns false on stop.
fn wait_for_mpc_eval_acks<S: Transport>(
    schedule: &Schedule,
    waiter: &Waiter<'_, S>,
    control: &ControlInbox<S>,
    prev_train_point: u64,
    t: u64,
    version: u64,
) -> Result<bool> {
    if version <= 1 {
        return Ok(true);
    }
    let mut pending: Vec<u64> = (prev_train_point..t)
        .filter(|&e| schedule.is_eval_point(e))
        .collect();
    let what = format!(
        "the evaluator's acknowledgement of model v{} at steps {pending:?}",
        version - 1
    );
    wait_for(waiter, control, &|| what.clone(), || {
        pending.retain(|&e| !control.take_ack(e));
        Ok(pending.is_empty())
    })
}
