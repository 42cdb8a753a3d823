//! Turning the services' stats records into `metrics.csv` rows, progress and the summary.
//!
//! The row of eval point t is written once the evaluator's `Eval` record and the learner's
//! `Learner` record for t are in. Everything else the row needs was sent *before* the learner's
//! record could be (episode records precede their transition, model records precede their
//! weights), and the collector drains every queue before writing, so in lockstep the row
//! equals the sequential one.

use std::collections::BTreeMap;
use std::time::Instant;

use mbpo_train::progress::{training_note, Progress};
use mbpo_train::run_dir::MetricsRow;
use mbpo_train::{ExperimentConfig, RunDir, Summary};
use mbpo_wire::{Done, LearnerRow, ModelTraining, ProducerId, Role, Stats};
use serde::Serialize;

use super::reached::Reached;
use super::RunPlan;
use crate::pacer::IntervalErrors;

/// Real transitions: produced, received by each consumer, lost.
#[derive(Debug, Clone, Default, Serialize)]
pub struct RealCounts {
    /// Produced by all actors.
    pub produced: u64,
    /// Received, per consumer.
    pub received: BTreeMap<String, u64>,
    /// Lost (sequence gaps), summed over consumers.
    pub lost: u64,
    /// Copied out of shared memory before the consumer took them (it held as many as it may),
    /// per consumer. 0: every real transition was copied twice on its way to it, by the
    /// actor's env step into shared memory and from there into its D_env.
    pub spilled: BTreeMap<String, u64>,
}

/// A slack value's range over the run, with the bounds the run's rate limits keep it in.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Range {
    /// Smallest.
    pub min: f32,
    /// Largest.
    pub max: f32,
    /// Mean.
    pub mean: f32,
    /// The lowest value the rate limits allow (`None`: not bounded below by one).
    pub lowest_allowed: Option<f32>,
    /// The highest value the rate limits allow (`None`: not bounded above by one).
    pub highest_allowed: Option<f32>,
}

impl Range {
    /// This range with the allowed bounds `-below..=highest` (the limits are buffers around 0).
    fn allowed(self, below: Option<u64>, highest: Option<u64>) -> Self {
        Self {
            lowest_allowed: below.map(|v| 0.0 - v as f32),
            highest_allowed: highest.map(|v| v as f32),
            ..self
        }
    }
}

/// The ratios the rate limiters hold.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Ratios {
    /// SAC updates per env step after the warm-up (target: G).
    pub updates_per_env_step: f64,
    /// The same when the last actor finished: what the policy the actors acted with had of
    /// G (below G when paced actors do not wait for the learner, `actor.catch_up = "never"`;
    /// the learner does the rest after them). `None` for MPC or a run whose actors did not
    /// finish.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub updates_per_env_step_while_acting: Option<f64>,
    /// G.
    pub target_updates_per_env_step: usize,
    /// Updates owed when the learner consumed a step, `(r − warm-up)·G − u`, in
    /// [−update_buffer, G + update_buffer] (lockstep: [0, G]): the learner consumes a step only
    /// while it owes at most `update_buffer` updates, then owes G more; it updates only while
    /// it is less than `update_buffer` ahead.
    pub learner_updates_owed: Range,
    /// Policy lag of the actors, `g − 1 − version` at global step g, at most policy_lag; below
    /// 0 when other actors are ahead (a version counts every actor's transitions). MPC: model
    /// versions behind the exact one, `train_points(g) − version` (bounded through model_lag in
    /// env steps, not in versions).
    pub actor_policy_lag: Range,
    /// Policy lag of the rollouts, `t − 1 − version` at train point t, in [−model_lag,
    /// policy_lag]: they wait for version t − 1 − policy_lag, and the learner consumes at most
    /// model_lag steps past a train point before its imagined batch.
    pub rollout_policy_lag: Range,
    /// Imagined batches (one per model training: M · model_train_freq rollouts each).
    pub rollout_batches: u64,
    /// Model trainings.
    pub model_trainings: u64,
}

/// Time a process spent inside IPC calls (sending, receiving, copying weights and rows in and
/// out of shared memory; sleeping in a wait is not counted).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct IpcShare {
    /// Seconds inside IPC calls.
    pub ipc_seconds: f64,
    /// Wall seconds of the work loop.
    pub wall_seconds: f64,
    /// `ipc_seconds / wall_seconds`.
    pub share: f64,
}

/// `summary.json` of `mbpo run`: the fields of `mbpo train`'s summary plus the pipeline's.
#[derive(Debug, Clone, Serialize)]
pub struct PipelineSummary {
    /// The same fields as the sequential mode.
    #[serde(flatten)]
    pub summary: Summary,
    /// `lockstep` or `pipelined`.
    pub mode: String,
    /// Actors.
    pub actors: u16,
    /// Run id (iceoryx2 services `mbpo/<run id>/...`).
    pub run_id: String,
    /// Real transitions.
    pub real_transitions: RealCounts,
    /// Ratios.
    pub ratios: Ratios,
    /// IPC cost per process that measures it (learner, actors).
    pub ipc: BTreeMap<String, IpcShare>,
    /// Process restarts.
    pub restarts: u32,
    /// iceoryx2 files removed at the end.
    pub ipc_files_removed: usize,
    /// iceoryx2 files left behind (should be empty).
    pub ipc_leftovers: Vec<String>,
    /// Worker hosts of a multi-host run (`hosts.json`, written by the head's gateway): per
    /// worker its actors, transitions, attempts and restarts.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hosts: Option<serde_json::Value>,
    /// Paced actors (`actor.control_hz`): their deadlines missed and rests, summed.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub pacing: Option<Pacing>,
}

/// What the paced actors of a run report.
#[derive(Debug, Clone, Default, Serialize)]
pub struct Pacing {
    /// Steps a second each actor was asked for.
    pub control_hz: f64,
    /// When the actors could wait for the learner (`actor.catch_up`).
    pub catch_up: mbpo_train::CatchUp,
    /// Steps started after their deadline, all actors.
    pub missed_deadlines: u64,
    /// Waits between episodes for the weights the next step needs, all actors.
    pub rests_between_episodes: u64,
    /// Intervals between consecutive steps measured, all actors (a rest starts a new grid:
    /// the wait is not an interval).
    pub intervals: u64,
    /// `|interval − period|`, µs, measured where each step starts (after the pacer's sleep):
    /// upper bounds of the median and the 99th percentile (bin edges of the histogram, or the
    /// largest error when smaller), and the largest.
    pub interval_error_us: ErrorQuantiles,
    /// The histogram of `|interval − period|`: steps per bin (log-spaced, `pacing.png`).
    pub histogram: Vec<HistogramBin>,
}

/// Quantiles of an error, µs.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct ErrorQuantiles {
    /// At most this (the median's bin).
    pub p50: f64,
    /// At most this (the 99th percentile's bin).
    pub p99: f64,
    /// The largest.
    pub max: f64,
}

/// One bin of a histogram.
#[derive(Debug, Clone, Default, Serialize)]
pub struct HistogramBin {
    /// What it holds, e.g. `20 us..50 us`.
    pub bin: String,
    /// Steps in it.
    pub steps: u64,
}

impl Pacing {
    /// The report of the actors paced per `cfg` with `intervals`, their missed deadlines and
    /// rests.
    fn of(cfg: &ExperimentConfig, intervals: &IntervalErrors, missed: u64, rests: u64) -> Self {
        let histogram = intervals.labelled().into_iter();
        Self {
            control_hz: cfg.actor.control_hz,
            catch_up: cfg.actor.catch_up,
            missed_deadlines: missed,
            rests_between_episodes: rests,
            intervals: intervals.total(),
            interval_error_us: ErrorQuantiles {
                p50: intervals.quantile_us(0.5),
                p99: intervals.quantile_us(0.99),
                max: intervals.max_ns as f64 / 1e3,
            },
            histogram: histogram
                .map(|(bin, steps)| HistogramBin { bin, steps })
                .collect(),
        }
    }
}

/// The collector's bookkeeping, what a checkpoint keeps of it: every row ≤ T is written by
/// then, or its evaluation kept in `unwritten_evals`, so a resumed run continues its rows,
/// episode count, best return and clock.
pub use mbpo_train::run_files::RunBook;

/// What the supervisor knows about the run.
pub struct Collector {
    cfg: ExperimentConfig,
    pipeline: &'static crate::pipeline::PipelineSpec,
    mode: String,
    actors: u16,
    run_id: String,
    slack: crate::Slack,
    eval_points: Vec<u64>,
    evals: BTreeMap<u64, f64>,
    learner: BTreeMap<u64, LearnerRow>,
    done: BTreeMap<ProducerId, Done>,
    /// MPC: the last global step each actor reported (`u64::MAX` once done).
    actor_steps: BTreeMap<ProducerId, u64>,
    /// What each role's records show it reached (for a run that ends before its `Done`).
    pub reached: Reached,
    /// Rows, returns, counters: what a checkpoint keeps.
    pub book: RunBook,
    /// `eval.stop_when_solved`, fed each row's return in order (set by the coordinator).
    pub solved_rule: Option<mbpo_train::SolvedRule>,
    /// The eval point whose row solved the run, short of its last step.
    pub solved_at: Option<u64>,
    /// The model training under way as its last report showed it, the learner's SAC updates
    /// then, and whether they had not moved since the report before (the learner waits).
    training: Option<(ModelTraining, u64, bool)>,
    /// The paced actors' step-interval errors, put together from their parts (this attempt's:
    /// a resumed run's summary has the intervals since the resume).
    intervals: IntervalErrors,
    /// The learner's SAC updates when the last actor sent `Done` (this attempt's).
    updates_when_acting_ended: Option<u64>,
}

impl Collector {
    /// For the run `cfg` of `plan`.
    pub fn new(cfg: &ExperimentConfig, plan: &RunPlan) -> Self {
        Self {
            cfg: cfg.clone(),
            pipeline: plan.pipeline,
            mode: plan.mode.name().into(),
            actors: plan.actors,
            run_id: plan.run_id.clone(),
            slack: plan.slack.effective(plan.mode),
            eval_points: mbpo_train::Schedule::of(cfg).eval_points().collect(),
            evals: BTreeMap::new(),
            learner: BTreeMap::new(),
            done: BTreeMap::new(),
            actor_steps: BTreeMap::new(),
            reached: Reached::new(mbpo_train::Schedule::of(cfg), plan.actors),
            book: RunBook::start(),
            solved_rule: None,
            solved_at: None,
            training: None,
            intervals: IntervalErrors::default(),
            updates_when_acting_ended: None,
        }
    }

    /// Eval points ≤ `t` whose row is not written yet.
    fn rows_unwritten_upto(&self, t: u64) -> impl Iterator<Item = u64> + '_ {
        self.eval_points[self.book.next_row.min(self.eval_points.len())..]
            .iter()
            .copied()
            .take_while(move |&p| p <= t)
    }

    /// What a checkpoint after step `t` still lacks, counted in eval points ≤ t: MBPO, their
    /// rows (the learner and evaluator are past t at the cut, so every row ≤ t can be
    /// written); MPC, their evaluations (a row also waits for every actor to pass its step,
    /// and pipelined actors can be behind the cut's step: those rows come after the resume).
    pub fn missing_at_cut(&self, t: u64) -> usize {
        let unwritten = self.rows_unwritten_upto(t);
        if self.rows_from_evaluations() {
            unwritten.filter(|p| !self.evals.contains_key(p)).count()
        } else {
            unwritten.count()
        }
    }

    /// The book of a checkpoint after step `t` at `elapsed` wall seconds (with its
    /// evaluations whose rows are not written yet).
    pub fn book_at(&self, t: u64, elapsed: f64) -> RunBook {
        let unwritten_evals = self
            .rows_unwritten_upto(t)
            .filter_map(|p| {
                let version = self.learner.get(&p).map_or(0, |r| r.model_version);
                Some((p, *self.evals.get(&p)?, version))
            })
            .collect();
        RunBook {
            unwritten_evals,
            elapsed_seconds: elapsed,
            ..self.book.clone()
        }
    }

    /// Continue from a checkpoint's book. The next row is the first eval point after the last
    /// row written: a run extended past its old end (`--resume RUN --steps N`) has other eval
    /// points than the run that wrote the book (the old last step was one), so a row count
    /// would skip one.
    pub fn restore(&mut self, mut book: RunBook) {
        let last_written = book.last_row.1;
        book.next_row = self.eval_points.partition_point(|&p| p <= last_written);
        // The pipeline's step times are the learner's own (a book of `mbpo train` has them).
        book.step_seconds.clear();
        for &(t, ret, version) in &book.unwritten_evals {
            self.evals.insert(t, ret);
            if self.rows_from_evaluations() {
                self.learner.insert(t, planning_row(t, version));
            }
        }
        self.book = book;
    }

    /// Take one report (barrier reports go to the supervisor's barrier and [`Reached`]).
    pub fn on_stats(&mut self, from: ProducerId, stats: Stats) {
        self.reached.see(from, &stats);
        match stats {
            Stats::Episode(e) => self.book.episodes.push((e.env_steps, e.episode_return)),
            Stats::Eval(e) => {
                self.evals.insert(e.env_steps, e.mean_return);
                if self.rows_from_evaluations() {
                    let row = planning_row(e.env_steps, e.model_version);
                    self.learner.insert(e.env_steps, row);
                }
            }
            Stats::Learner(row) => {
                self.book.progress = (row.env_steps, row.sac_updates, row.model_version);
                self.learner.insert(row.env_steps, row);
            }
            Stats::Model(m) => {
                self.book.models.insert(m.version, m.holdout_mse);
                if self.training.is_some_and(|(t, ..)| t.version <= m.version) {
                    self.training = None;
                }
            }
            Stats::Training(m) => {
                let updates = self.book.progress.1;
                let stalled = self
                    .training
                    .is_some_and(|(before, u, _)| before.version == m.version && u == updates);
                self.training = Some((m, updates, stalled));
            }
            Stats::Pacing(part) => self.intervals.add_part(&part),
            Stats::Rollout(_) | Stats::Barrier(_) | Stats::EnvFailed(_) => {}
            Stats::Done(d) => {
                tracing::info!("{from} finished: {d:?}");
                if from.role() == Some(Role::Actor) {
                    self.actor_steps.insert(from, u64::MAX);
                }
                self.done.insert(from, d);
                if from.role() == Some(Role::Actor) && self.all_actors_done() {
                    self.updates_when_acting_ended = Some(self.book.progress.1);
                }
            }
            Stats::Progress(p) if from.role() == Some(Role::Learner) => {
                self.book.progress = (p.env_steps, p.sac_updates, p.model_version)
            }
            // MPC has no learner: the actors' progress is the run's.
            Stats::Progress(p)
                if self.rows_from_evaluations() && from.role() == Some(Role::Actor) =>
            {
                self.actor_steps.insert(from, p.env_steps);
                if p.env_steps > self.book.progress.0 {
                    self.book.progress = (p.env_steps, 0, p.model_version)
                }
            }
            Stats::Progress(_) => {}
        }
    }

    /// Every actor of the run sent its `Done`.
    fn all_actors_done(&self) -> bool {
        let done = self.done.keys().filter(|p| p.role() == Some(Role::Actor));
        done.count() == usize::from(self.actors)
    }

    /// MPC: every actor reported a step after which its next one is past `t` (its episodes
    /// ending at steps ≤ t are in: an actor sends them before its progress).
    fn actors_past(&self, t: u64) -> bool {
        let n = self.actors as u64;
        self.actor_steps.len() == self.actors as usize
            && self.actor_steps.values().all(|&g| g.saturating_add(n) > t)
    }

    /// Env steps consumed by the learner (last report).
    pub fn env_steps(&self) -> u64 {
        self.book.progress.0
    }

    /// Every actor sent its Done record (all real transitions exist).
    pub fn actors_done(&self, actors: u16) -> bool {
        let done = self.done.keys().filter(|p| p.role() == Some(Role::Actor));
        done.count() == actors as usize
    }

    /// True when every process reported done.
    pub fn all_done(&self, actors: u16) -> bool {
        self.done.len() == self.pipeline.roles(actors).len()
    }

    /// The run has no learner (MPC): its rows come from the evaluations of model versions and
    /// its progress from the actors.
    fn rows_from_evaluations(&self) -> bool {
        !self.pipeline.has_learner()
    }

    /// Write the rows whose records are all in.
    pub fn write_rows(&mut self, run: &mut RunDir, started: Instant) -> std::io::Result<()> {
        while let Some(&t) = self.eval_points.get(self.book.next_row) {
            let (Some(&ret), Some(lr)) = (self.evals.get(&t), self.learner.get(&t).copied()) else {
                break;
            };
            let done: Vec<&(u64, f64)> = self.book.episodes.iter().filter(|e| e.0 <= t).collect();
            let train_return = done.iter().max_by_key(|e| e.0).map(|e| e.1);
            let updated = lr.sac_updates > 0;
            // A figure a learner does not have (SAC's α for TD-MPC2, the world model's losses
            // for SAC) comes as NaN: an empty cell.
            let some = |v: f32| (updated && v.is_finite()).then_some(v as f64);
            let model = (lr.model_version > 0)
                .then(|| self.book.models.get(&lr.model_version).copied())
                .flatten();
            if self.rows_from_evaluations() && model.is_none() && lr.model_version > 0 {
                break; // the model record arrives before its weights; wait for it
            }
            if self.rows_from_evaluations() && !self.actors_past(t) {
                // The evaluator may plan for t before the actors get there (the model of t
                // is older than step t): the row waits for their episodes up to t.
                break;
            }
            let no_learner = self.rows_from_evaluations();
            let now = started.elapsed().as_secs_f64();
            let dt = (now - self.book.last_row.0).max(1e-9);
            let sps = (t - self.book.last_row.1) as f64 / dt;
            let ups = lr.sac_updates.saturating_sub(self.book.last_row_updates) as f64 / dt;
            let row = MetricsRow {
                env_steps: t,
                episodes: done.len() as u64,
                eval_return: ret,
                train_return,
                sac_updates: lr.sac_updates,
                critic_loss: some(lr.critic_loss),
                actor_loss: some(lr.actor_loss),
                alpha: (!no_learner && lr.alpha.is_finite()).then_some(lr.alpha as f64),
                entropy: some(lr.entropy),
                q_mean: some(lr.q_mean),
                consistency_loss: some(lr.consistency_loss),
                reward_loss: some(lr.reward_loss),
                model_holdout_mse: model,
                rollout_length: model
                    .filter(|_| !no_learner)
                    .map(|_| lr.rollout_length as f64),
                model_buffer: model
                    .filter(|_| !no_learner)
                    .map(|_| lr.model_buffer as f64),
                wall_seconds: now,
                env_steps_per_sec: sps,
                updates_per_sec: ups,
            };
            run.write_metrics(&row)?;
            tracing::info!(
                "step {t}: eval {ret:.1}, {} updates, alpha {:.3}, {sps:.1} steps/s",
                lr.sac_updates,
                lr.alpha
            );
            self.book.wrote_row(t, ret, now, lr.sac_updates);
            let solved = self.solved_rule.as_mut().is_some_and(|r| r.see(ret));
            if solved && t < self.cfg.steps && self.solved_at.is_none() {
                self.solved_at = Some(t);
            }
        }
        Ok(())
    }

    /// Hand the learner's progress and the last evaluation to the progress bar / lines.
    pub fn show_progress(&self, progress: &mut Progress) {
        let (steps, updates, model) = self.book.progress;
        progress.set_model_version(model);
        let notes = [self.acting_note(), self.training_note()];
        let notes: Vec<String> = notes.into_iter().flatten().collect();
        progress.set_activity((!notes.is_empty()).then(|| notes.join("; ")));
        if let Some(r) = self.book.last_eval {
            progress.set_eval(r);
        }
        progress.update(steps, updates);
    }

    /// How far paced actors that never wait (`actor.catch_up = "never"`) have acted, when it
    /// is past what the learner consumed: the progress line counts consumed steps, and
    /// without this a user would see "0.0 env steps/s" while the actors step on the clock.
    fn acting_note(&self) -> Option<String> {
        let acts_freely = self.cfg.actor.control_hz > 0.0
            && self.cfg.actor.catch_up == mbpo_train::CatchUp::Never;
        let acted = self.book.episodes.iter().map(|&(t, _)| t).max()?;
        (acts_freely && acted > self.book.progress.0).then(|| match self.all_actors_done() {
            true => format!(
                "the actors are done ({} steps), the learner catches up",
                self.cfg.steps
            ),
            false => format!("the actors at step {acted}"),
        })
    }

    /// The model training under way, in words, and whether the learner waits for it (its
    /// SAC updates stood still between the training's last two reports: it needs the
    /// rollouts of the new model, or the actors need a policy the learner cannot make yet).
    fn training_note(&self) -> Option<String> {
        let (m, _, stalled) = self.training?;
        let seconds = m.seconds as f64;
        let mut note = training_note(m.version, m.epoch as usize, m.holdout_mse, seconds);
        if stalled && self.pipeline.has_learner() {
            note.push_str("; the learner waits for it");
        }
        Some(note)
    }

    /// The summary; `env_steps_to_target` is read off the run's metrics
    /// (`RunDir::env_steps_to_target`). Every status reports what the roles reached: a role
    /// that sent `Done` from it, any other from its last records ([`Reached`]).
    pub fn summary(
        &self,
        status: &str,
        policy_sha256: String,
        started: Instant,
        env_steps_to_target: Option<u64>,
    ) -> PipelineSummary {
        let tally = self.tally();
        // The algorithm's warm-up and ratio (TD-MPC2's burst of updates at the end of its
        // seed steps is not per step).
        let schedule = mbpo_train::Schedule::of(&self.cfg);
        let mut ratios = tally.ratios;
        let after_warmup = tally
            .real
            .produced
            .saturating_sub(schedule.init_random_steps);
        if after_warmup > 0 {
            let per_env_step = |updates: u64| {
                updates.saturating_sub(schedule.burst_updates) as f64 / after_warmup as f64
            };
            let acting = self
                .updates_when_acting_ended
                .filter(|_| self.pipeline.has_learner());
            ratios.updates_per_env_step_while_acting = acting.map(per_env_step);
            ratios.updates_per_env_step = per_env_step(tally.sac_updates);
        }
        PipelineSummary {
            summary: Summary {
                algo: self.cfg.algo.name().into(),
                env: self.cfg.env.clone(),
                seed: self.cfg.seed,
                env_steps: self.book.last_row.1.max(tally.real.produced),
                sac_updates: tally.sac_updates,
                final_eval_return: self.book.final_return,
                best_eval_return: self.book.best_return,
                target_return: self.cfg.target_return(),
                env_steps_to_target,
                policy_sha256,
                wall_seconds: started.elapsed().as_secs_f64(),
                median_seconds_per_env_step: tally.median,
                // `completed`, `stopped` (checkpointed, resumable), `failed` or `interrupted`.
                status: status.into(),
                episodes_cut_by_resume: tally.episodes_cut,
                episodes_lost_to_env_exit: tally.episodes_lost,
            },
            mode: self.mode.clone(),
            actors: self.actors,
            run_id: self.run_id.clone(),
            real_transitions: tally.real,
            ratios,
            ipc: tally.ipc,
            restarts: self.book.restarts,
            ipc_files_removed: 0,
            ipc_leftovers: Vec::new(),
            hosts: None,
            pacing: (self.cfg.actor.control_hz > 0.0).then(|| {
                Pacing::of(
                    &self.cfg,
                    &self.intervals,
                    tally.missed_deadlines,
                    tally.rests,
                )
            }),
        }
    }

    /// Every role of the run with its counters: its `Done` record, or (`false`) one made of
    /// what its records showed.
    fn final_counters(&self) -> Vec<(ProducerId, Done, bool)> {
        let roles = self.pipeline.roles(self.actors).into_iter();
        roles
            .map(|r| ProducerId::new(r.kind.wire_role(), r.index))
            .map(|who| match self.done.get(&who) {
                Some(d) => (who, *d, true),
                None => {
                    let c = self.reached.get(who);
                    let d = Done {
                        real: c.real,
                        work: c.work,
                        ..Done::default()
                    };
                    (who, d, false)
                }
            })
            .collect()
    }

    /// The roles' counters added up.
    fn tally(&self) -> Tally {
        let mut t = Tally::new(&self.cfg);
        let counters = self.final_counters();
        let finished_actors = counters
            .iter()
            .filter(|(who, _, done)| *done && who.role() == Some(Role::Actor))
            .count();
        for (who, d, finished) in &counters {
            if *finished && d.wall_seconds > 0.0 {
                t.ipc.insert(who.to_string(), IpcShare::of(d));
            }
            match who.role() {
                Some(Role::Actor) => {
                    t.real.produced += d.real;
                    t.episodes_cut += d.episodes_cut;
                    t.episodes_lost += d.episodes_lost;
                    t.missed_deadlines += d.missed_deadlines;
                    t.rests += d.rests;
                    if *finished {
                        self.add_actor_timing(&mut t, d, finished_actors);
                    }
                }
                Some(r @ (Role::ModelTrainer | Role::RolloutGenerator | Role::Learner)) => {
                    t.real.received.insert(r.name().to_string(), d.real);
                    t.real.lost += d.lost;
                    t.real.spilled.insert(r.name().to_string(), d.real_spilled);
                    self.add_consumer(&mut t, r, d, *finished);
                }
                _ => {}
            }
        }
        if t.actor_lag.min.is_finite() {
            // A paced actor never waits inside an episode (docs/src/real-time.md): `--policy-lag`
            // bounds its lag only at an episode's first step, so no bound is claimed for it.
            let paced = self.cfg.actor.control_hz > 0.0;
            let highest =
                (!self.rows_from_evaluations() && !paced).then_some(self.slack.policy_lag);
            t.ratios.actor_policy_lag = t.actor_lag.allowed(None, highest);
        }
        t
    }

    /// A finished actor's planning time (MPC) and policy lag; the lag's mean is over the
    /// `finished` actors.
    fn add_actor_timing(&self, t: &mut Tally, d: &Done, finished: usize) {
        if self.rows_from_evaluations() && d.median_step_seconds > 0.0 {
            // Median planning time of an MPC step (the slowest actor's).
            let m = d.median_step_seconds as f64;
            t.median = Some(t.median.map_or(m, |x: f64| x.max(m)));
        }
        t.actor_lag.min = t.actor_lag.min.min(d.slack_min);
        t.actor_lag.max = t.actor_lag.max.max(d.slack_max);
        t.actor_lag.mean += d.slack_mean / finished as f32;
    }

    /// What a consumer of real data adds: its work and (once finished) its lags.
    fn add_consumer(&self, t: &mut Tally, role: Role, d: &Done, finished: bool) {
        let range = Range {
            min: d.slack_min,
            max: d.slack_max,
            mean: d.slack_mean,
            ..Default::default()
        };
        match role {
            Role::Learner => {
                t.sac_updates = d.work;
                if finished {
                    t.median =
                        (d.median_step_seconds > 0.0).then_some(d.median_step_seconds as f64);
                    let (buffer, g) = (self.slack.update_buffer, self.cfg.mbpo.updates_per_step);
                    t.ratios.learner_updates_owed =
                        range.allowed(Some(buffer), Some(g as u64 + buffer));
                }
            }
            Role::RolloutGenerator => {
                if finished {
                    let (model_lag, policy_lag) = (self.slack.model_lag, self.slack.policy_lag);
                    t.ratios.rollout_policy_lag = range.allowed(Some(model_lag), Some(policy_lag));
                }
                t.ratios.rollout_batches = d.work;
            }
            _ => t.ratios.model_trainings = d.work,
        }
    }
}

/// The roles' counters added up for the summary.
struct Tally {
    real: RealCounts,
    ratios: Ratios,
    sac_updates: u64,
    episodes_cut: u64,
    episodes_lost: u64,
    missed_deadlines: u64,
    rests: u64,
    median: Option<f64>,
    actor_lag: Range,
    ipc: BTreeMap<String, IpcShare>,
}

impl Tally {
    fn new(cfg: &ExperimentConfig) -> Self {
        Self {
            real: RealCounts::default(),
            ratios: Ratios {
                target_updates_per_env_step: mbpo_train::Schedule::of(cfg).updates_per_step
                    as usize,
                ..Default::default()
            },
            sac_updates: 0,
            episodes_cut: 0,
            episodes_lost: 0,
            missed_deadlines: 0,
            rests: 0,
            median: None,
            actor_lag: Range {
                min: f32::INFINITY,
                max: f32::NEG_INFINITY,
                ..Default::default()
            },
            ipc: BTreeMap::new(),
        }
    }
}

impl IpcShare {
    /// The share of a role's `Done` record.
    fn of(d: &Done) -> Self {
        let (ipc_seconds, wall_seconds) = (d.ipc_seconds as f64, d.wall_seconds as f64);
        Self {
            ipc_seconds,
            wall_seconds,
            share: ipc_seconds / wall_seconds,
        }
    }
}

/// MPC has no learner: the evaluator's model version of eval point `t` stands in for the
/// learner's row.
fn planning_row(t: u64, model_version: u64) -> LearnerRow {
    LearnerRow {
        env_steps: t,
        sac_updates: 0,
        critic_loss: 0.0,
        actor_loss: 0.0,
        alpha: f32::NAN,
        entropy: 0.0,
        q_mean: 0.0,
        consistency_loss: f32::NAN,
        reward_loss: f32::NAN,
        rollout_length: 0,
        model_buffer: 0,
        model_version,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_wire::ModelTrained;

    fn book(unwritten_evals: Vec<(u64, f64, u64)>) -> RunBook {
        RunBook {
            next_row: 8,
            unwritten_evals,
            ..RunBook::start()
        }
    }

    #[test]
    fn an_extended_run_writes_the_row_of_every_new_eval_point() {
        // Written by a 500-step run: rows 200, 400 and its last step 500 (3 rows).
        let written = RunBook {
            next_row: 3,
            last_row: (1.0, 500),
            ..RunBook::start()
        };
        // Extended to 700 steps: eval points 200, 400, 600, 700; the next row is 600's.
        let mut cfg = ExperimentConfig {
            steps: 700,
            ..Default::default()
        };
        cfg.eval.every = 200;
        cfg.mbpo.init_random_steps = 100;
        let mut collector = mbpo_collector(&mut cfg);
        assert_eq!(collector.eval_points, [200, 400, 600, 700]);
        collector.restore(written);
        assert_eq!(collector.eval_points[collector.book.next_row], 600);
    }

    /// The collector of a pipelined MBPO run of `cfg` with one actor.
    fn mbpo_collector(cfg: &mut ExperimentConfig) -> Collector {
        cfg.algo = mbpo_train::Algo::MBPO;
        let plan = RunPlan {
            pipeline: crate::pipeline::spec(cfg.algo).unwrap(),
            run_id: "test".into(),
            mode: crate::Mode::Pipelined,
            actors: 1,
            slack: crate::Slack::ZERO,
        };
        Collector::new(cfg, &plan)
    }

    fn learner_at(env_steps: u64, sac_updates: u64) -> Stats {
        Stats::Progress(mbpo_wire::Progress {
            env_steps,
            sac_updates,
            ..Default::default()
        })
    }

    #[test]
    fn the_progress_line_shows_a_training_under_way_and_whether_the_learner_waits() {
        let mut c = mbpo_collector(&mut ExperimentConfig::default());
        let learner = ProducerId::new(Role::Learner, 0);
        let trainer = ProducerId::new(Role::ModelTrainer, 0);
        let training = |epoch, seconds| {
            Stats::Training(ModelTraining {
                env_steps: 651,
                version: 2,
                epoch,
                holdout_mse: 0.0114,
                seconds,
            })
        };
        assert_eq!(c.training_note(), None);
        c.on_stats(learner, learner_at(660, 5000));
        c.on_stats(trainer, training(199, 4.0));
        let note = c.training_note().unwrap();
        assert_eq!(
            note,
            "training model v2: epoch 199, holdout mse 0.0114, 4 s"
        );
        // The learner's updates stood still between two reports of the training: it waits.
        c.on_stats(trainer, training(797, 14.0));
        assert!(c
            .training_note()
            .unwrap()
            .ends_with("14 s; the learner waits for it"));
        // It moves again; once the model is trained, the note goes.
        c.on_stats(learner, learner_at(670, 5200));
        c.on_stats(trainer, training(900, 15.0));
        assert!(!c.training_note().unwrap().contains("waits"));
        let trained = ModelTrained {
            rows: 650,
            version: 2,
            holdout_mse: 0.01,
            epochs: 950,
            seconds: 15.5,
        };
        c.on_stats(trainer, Stats::Model(trained));
        assert_eq!(c.training_note(), None);
    }

    #[test]
    fn a_resume_keeps_the_rows_before_the_first_unwritten_evaluation() {
        assert_eq!(book(Vec::new()).rows_upto(913), 913);
        // Rows 900 and later were written after the checkpoint by the abandoned attempt (or
        // not at all): the resumed run writes them from the book.
        let held = book(vec![(900, -1133.3, 9), (1000, -1200.0, 10)]);
        assert_eq!(held.rows_upto(1013), 899);
    }
}
