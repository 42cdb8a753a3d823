//! `mbpo-model-trainer`: keeps its own copy of the real data and, at every train point t,
//! trains the ensemble and publishes model version v (latest value, one flat `[f32]`, see
//! `ModelWireLayout`).
//!
//! Lockstep: trains on exactly the first t − 1 real transitions (transition t may already have
//! arrived; it is held back). Pipelined: trains on every transition received by then (≥ t − 1).
//! In an MPC run (algo = "mpc") the same worker feeds the planning actors; in lockstep it also
//! waits for the planning evaluator's acknowledgements before replacing a model version.

use std::time::{Duration, Instant};

use mbpo_model::TrainReport;
use mbpo_train::roles::{ModelSnapshot, ModelTrainerRole};
use mbpo_train::Schedule;
use mbpo_wire::*;

use super::data;
use crate::barrier::{self, ModelTrainerCheckpoint};
use crate::serving::{AtCut, Cx, Step, Worker};
use crate::{Result, *};

/// The model trainer's ports.
pub struct Ports<S: Transport> {
    real: TransitionSubscriber<S>,
    model: WeightsPublisher<S>,
}

type TrainerCx<'a, S> = Cx<'a, S, Ports<S>>;

/// The model trainer on the serving loop.
pub struct ModelTrainer<S: Transport> {
    role: ModelTrainerRole,
    inbox: RealInbox<S>,
    /// The encoded weights (reused).
    flat: Vec<f32>,
    /// MPC lockstep: the train point of the model version last published (its eval points
    /// are acknowledged before the next version replaces it).
    prev_train_point: u64,
}

impl<S: Transport> Worker<S> for ModelTrainer<S> {
    const KIND: RoleKind = RoleKind::ModelTrainer;
    type Ports = Ports<S>;
    type Checkpoint = ModelTrainerCheckpoint;

    fn ports(s: &Process<S>) -> Result<Ports<S>> {
        let d = s.dims;
        Ok(Ports {
            real: TransitionSubscriber::create(&s.node, Channel::Real, d.rows())?,
            model: WeightsPublisher::create(
                &s.node,
                WeightsKind::Model,
                d.model.layout_hash,
                d.model.len(),
            )?,
        })
    }
    fn attach<'a>(p: &'a Ports<S>, waiter: &mut Waiter<'a, S>) {
        waiter.attach(&p.real).attach(&p.model);
    }
    fn new(cx: &TrainerCx<'_, S>) -> Result<Self> {
        let d = cx.s.dims;
        Ok(Self {
            role: ModelTrainerRole::new(&cx.s.cfg, d.obs, d.act)?,
            inbox: RealInbox::new(d.rows()),
            flat: Vec::with_capacity(d.model.len()),
            prev_train_point: 0,
        })
    }
    fn restore(&mut self, state: ModelTrainerCheckpoint, cx: &TrainerCx<'_, S>) -> Result<()> {
        self.role.restore(state.role)?;
        self.inbox.resume_at(self.role.real_received());
        // Planners act on the models: the planners' checkpoints hold no model, so they plan on
        // this version again. (MBPO: no republish, the rollout generator's checkpoint holds
        // this model version.)
        if cx.s.pipeline.acts_on_models() && self.role.version() > 0 {
            let snapshot = self.role.snapshot();
            self.publish(cx, &snapshot)?;
            // The evaluator acknowledged every eval point ≤ T before the cut (those messages
            // went with the stopped processes): only later ones are waited for.
            let last =
                cx.s.schedule
                    .nth_train_point(self.role.version())
                    .unwrap_or(0);
            self.prev_train_point = last.max(self.role.real_received() + 1);
        }
        Ok(())
    }
    fn step(&mut self, cx: &TrainerCx<'_, S>) -> Result<Step> {
        let s = cx.s;
        let version = self.role.version();
        let Some(t) = s.schedule.nth_train_point(version + 1) else {
            return data::the_rest(s, &cx.ports.real, &mut self.inbox, &mut self.role);
        };
        if !data::pull(
            s.mode,
            &cx.ports.real,
            &mut self.inbox,
            &mut self.role,
            t - 1,
        )? {
            return Ok(Step::Waiting);
        }
        data::take_for(s.mode, &mut self.inbox, &mut self.role, t);
        tracing::info!(
            "training model v{} for step {t} on {} transitions",
            version + 1,
            self.role.real_received()
        );
        let started = Instant::now();
        let abandon = s.pipeline.abandons_training_on_stop(s.mode);
        let watch = Watch {
            stats: cx.stats,
            t,
            version: version + 1,
        };
        let arriving = (&cx.ports.real, &mut self.inbox);
        let trained = train(
            &mut self.role,
            abandon,
            cx.control,
            version,
            watch,
            arriving,
        )?;
        let Some((snapshot, report)) = trained else {
            // The loop serves the barrier next (a resumed run trains again) or stops.
            tracing::info!(
                "model training for step {t} abandoned after {:.1} s: the run is stopping",
                started.elapsed().as_secs_f64()
            );
            return Ok(Step::Worked);
        };
        let seconds = started.elapsed().as_secs_f64();
        self.trained(cx, t, &snapshot, &report, seconds)
    }
    fn done_so_far(&self) -> u64 {
        self.role.version()
    }
    fn at_cut(
        &mut self,
        cut: barrier::Cut,
        cx: &TrainerCx<'_, S>,
    ) -> Result<AtCut<ModelTrainerCheckpoint>> {
        if self.role.version() < cut.model_trainings {
            return Ok(AtCut::Work);
        }
        if !data::take_upto_cut(&cx.ports.real, &mut self.inbox, &mut self.role, cut)? {
            return Ok(AtCut::Wait);
        }
        Ok(AtCut::Write(ModelTrainerCheckpoint {
            role: self.role.checkpoint(),
        }))
    }
    fn finish(&mut self, cx: &TrainerCx<'_, S>) -> Result<()> {
        let lost = cx.ports.real.stats().missing;
        let version = self.role.version();
        cx.stats.report(Done {
            real: self.inbox.received(),
            lost,
            real_spilled: self.inbox.spilled(),
            work: version,
            ..Default::default()
        })?;
        tracing::info!(
            "done: {} real transitions received, {lost} lost, {version} trainings",
            self.inbox.received()
        );
        Ok(())
    }
    fn waiting_for(&self) -> String {
        let v = self.role.version() + 1;
        format!(
            "the real transitions of model v{v} ({} received)",
            self.inbox.received()
        )
    }
}

impl<S: Transport> ModelTrainer<S> {
    /// After training model `snapshot` for step `t`: its record, then (MPC lockstep: once the
    /// evaluations of the version it replaces are acknowledged) the weights.
    fn trained(
        &mut self,
        cx: &TrainerCx<'_, S>,
        t: u64,
        snapshot: &ModelSnapshot,
        report: &TrainReport,
        seconds: f64,
    ) -> Result<Step> {
        let version = snapshot.version;
        let rows = self.role.real_received();
        // The same number the sequential metrics row shows.
        let mse = report.elite_holdout_mse();
        // Stats before weights: whoever sees a later consequence of this model finds its record.
        cx.stats.report(ModelTrained {
            rows,
            version,
            holdout_mse: mse,
            epochs: report.epochs as u32,
            seconds: seconds as f32,
        })?;
        if cx.s.pipeline.acts_on_models() && cx.s.mode == Mode::Lockstep {
            let from = self.prev_train_point;
            if !wait_for_mpc_eval_acks(&cx.s.schedule, cx.waiter, cx.control, from, t, version)? {
                // Stopped: the loop sees it next.
                return Ok(Step::Worked);
            }
            self.prev_train_point = t;
        }
        self.publish(cx, snapshot)?;
        tracing::info!(
            "model v{version} trained for step {t} on {rows} transitions: {} epochs, holdout mse {mse:.5}, {seconds:.2} s{}",
            report.epochs,
            report.termination.map(|t| format!("; {t}")).unwrap_or_default()
        );
        Ok(Step::Worked)
    }

    /// Publish `snapshot` as its version, with the transitions it was trained on.
    fn publish(&mut self, cx: &TrainerCx<'_, S>, snapshot: &ModelSnapshot) -> Result<()> {
        cx.s.dims.model.encode(&snapshot.weights, &mut self.flat)?;
        let counters = WeightsCounters {
            env_steps: self.role.real_received(),
            sac_updates: 0,
            model_trainings: snapshot.version,
        };
        cx.ports
            .model
            .publish(&self.flat, snapshot.version, counters)?;
        Ok(())
    }
}

/// Train on the role's data, abandoning the training after the epoch under way (`None`; the
/// role is as before it) when the process is stopped, or -- pipelined MBPO -- when a
/// checkpoint barrier the run stops after (Ctrl-C) does not need it: a training can take
/// minutes, and the cut then holds the `done` trainings completed (the resumed run trains
/// again, on at least as much data: pipelined runs train on whatever has arrived). A periodic
/// barrier lets the training finish, since the run goes on with it; lockstep must hold every
/// training of the train points ≤ T, and an MPC evaluator needs the model of every eval point
/// ≤ T (`Barrier::take_cut`). Real transitions arriving meanwhile are received after every
/// epoch into `arriving`'s inbox (not into the data being trained on): a training may last
/// minutes, and the actors must not block on a full queue (a paced actor least of all).
fn train<S: Transport>(
    role: &mut ModelTrainerRole,
    abandon_at_stop_barrier: bool,
    control: &ControlInbox<S>,
    done: u64,
    watch: Watch<'_, S>,
    arriving: (&TransitionSubscriber<S>, &mut RealInbox<S>),
) -> Result<Option<(ModelSnapshot, TrainReport)>> {
    let mut poll_error = None;
    let mut last_shown = Instant::now();
    let (real, inbox) = arriving;
    let trained = role.train_watched(|epoch| {
        if last_shown.elapsed() >= SHOW_TRAINING_EVERY {
            last_shown = Instant::now();
            watch.show(epoch);
        }
        if let Err(e) = control.poll().and_then(|()| inbox.receive(real).map(drop)) {
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

/// How often a training under way reports its epoch to the coordinator's progress line (a
/// record a second at most: an epoch on a small D_env takes milliseconds).
const SHOW_TRAINING_EVERY: Duration = Duration::from_secs(1);

/// Where a training's epochs are shown: the run's stats, as training `version` for step `t`.
struct Watch<'a, S: Transport> {
    stats: &'a StatsPublisher<S>,
    t: u64,
    version: u64,
}

impl<S: Transport> Watch<'_, S> {
    /// Report the training's epoch; a report that cannot be sent is only logged (the progress
    /// line misses one update, the training goes on).
    fn show(&self, epoch: &mbpo_model::EpochProgress) {
        let record = ModelTraining {
            env_steps: self.t,
            version: self.version,
            epoch: epoch.epoch as u32,
            holdout_mse: epoch.holdout_mse,
            seconds: epoch.seconds as f32,
        };
        if let Err(e) = self.stats.report(record) {
            tracing::debug!("training progress not sent: {e}");
        }
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
