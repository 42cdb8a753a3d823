//! What the services report to the coordinator, with named fields. Every [`StatsRecord`] on
//! the stats channel is one [`Stats`]; [`Stats::record`] and [`Stats::decode`] are the only
//! places that know which slot of the fixed-size record holds which field, so senders and the
//! reader cannot disagree.
//!
//! | variant | sender | when |
//! |---|---|---|
//! | [`Stats::Episode`] | actor | an episode ended (sent *before* the transition that ended it) |
//! | [`Stats::Eval`] | evaluator | after evaluating eval point t |
//! | [`Stats::Learner`] | learner | after step t at every eval point |
//! | [`Stats::Model`] | model trainer | after each training (sent *before* the weights) |
//! | [`Stats::Rollout`] | rollout generator | after each branch |
//! | [`Stats::Progress`] | everyone | progress counters for the live line |
//! | [`Stats::Done`] | everyone | the process finished its work |
//! | [`Stats::Barrier`] | pausing processes, writers | a checkpoint barrier step |
//! | [`Stats::Pacing`] | paced actors | at the end, before `Done`: their step-interval errors |

use crate::error::DecodeError;
use crate::schema::{StatsKind, StatsRecord};

/// An actor's episode ended.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EpisodeEnd {
    /// Global env step at which it ended.
    pub env_steps: u64,
    /// Undiscounted return.
    pub episode_return: f64,
    /// Policy (MBPO) or model (MPC) version the actor acted with.
    pub version: u64,
}

/// An evaluation finished.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalResult {
    /// The eval point t.
    pub env_steps: u64,
    /// Policy version evaluated (MPC: 0).
    pub policy_version: u64,
    /// Model version planned with (MPC; MBPO: 0).
    pub model_version: u64,
    /// Mean return over the episodes.
    pub mean_return: f64,
    /// Episodes evaluated.
    pub episodes: u32,
}

/// What the learner reports for the metrics row of eval point t.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearnerRow {
    /// Env step t.
    pub env_steps: u64,
    /// SAC updates so far.
    pub sac_updates: u64,
    /// The value function's loss in the last update (SAC's critics, TD-MPC2's Q heads).
    pub critic_loss: f32,
    /// The policy's loss in the last update (SAC's actor, TD-MPC2's policy prior).
    pub actor_loss: f32,
    /// Temperature α.
    pub alpha: f32,
    /// Policy entropy estimate of the last update.
    pub entropy: f32,
    /// Mean Q of the last update.
    pub q_mean: f32,
    /// TD-MPC2's latent consistency loss in the last update (SAC: NaN).
    pub consistency_loss: f32,
    /// TD-MPC2's reward loss in the last update (SAC: NaN).
    pub reward_loss: f32,
    /// Rollout length in force.
    pub rollout_length: usize,
    /// Transitions in D_model.
    pub model_buffer: usize,
    /// Model version of the newest imagined data (0: none yet).
    pub model_version: u64,
}

/// A model training finished.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ModelTrained {
    /// Real transitions trained on.
    pub rows: u64,
    /// The new model version.
    pub version: u64,
    /// Mean over elites of the final holdout MSE.
    pub holdout_mse: f64,
    /// Epochs run.
    pub epochs: u32,
    /// Wall seconds of the training.
    pub seconds: f32,
}

/// A model training under way, after one of its epochs (for the progress line: a training
/// can take minutes, and other roles may wait for it meanwhile).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ModelTraining {
    /// The train point t it trains for.
    pub env_steps: u64,
    /// The model version it will become.
    pub version: u64,
    /// Epochs done.
    pub epoch: u32,
    /// The members' mean holdout MSE after that epoch.
    pub holdout_mse: f32,
    /// Wall seconds so far.
    pub seconds: f32,
}

/// A rollout branch finished.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RolloutBranch {
    /// t − 1 of its train point t.
    pub env_steps: u64,
    /// Model version rolled out.
    pub model_version: u64,
    /// Policy version that chose the actions.
    pub policy_version: u64,
    /// Imagined transitions.
    pub rows: u32,
    /// Rollout length k.
    pub length: u32,
    /// Wall seconds of the branch.
    pub seconds: f32,
}

/// An actor's environment failed at a step (its log holds the error): nothing of that step
/// was sent, the actor waits for the checkpoint that stops the run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct EnvFailed {
    /// The run's env step that failed.
    pub env_steps: u64,
}

/// Progress counters of a process (for the live line).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Progress {
    /// Env steps taken (actors) or consumed (learner).
    pub env_steps: u64,
    /// SAC updates (learner).
    pub sac_updates: u64,
    /// Model version in use.
    pub model_version: u64,
    /// Policy version in use.
    pub policy_version: u64,
}

/// The final report of a process that finished its work.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Done {
    /// Real transitions produced (actors) or received (consumers).
    pub real: u64,
    /// Real transitions lost (sequence gaps) on the way to this consumer.
    pub lost: u64,
    /// SAC updates (learner) / model trainings (model trainer) / branches (rollout generator).
    pub work: u64,
    /// Median wall seconds per env step after the warm-up (learner), else 0.
    pub median_step_seconds: f32,
    /// Smallest and largest slack value seen (learner: updates owed `(r − warm-up)·G − u`;
    /// actor: policy lag `t − 1 − version`; rollout generator: model versions behind).
    pub slack_min: f32,
    /// See `slack_min`.
    pub slack_max: f32,
    /// Mean of the slack value.
    pub slack_mean: f32,
    /// Seconds spent inside IPC calls (send, receive, copy in/out of shared memory; not waiting).
    pub ipc_seconds: f32,
    /// Wall seconds of the process's work loop.
    pub wall_seconds: f32,
    /// Episodes its resumes cut short (actors whose environment cannot save its state).
    pub episodes_cut: u64,
    /// Episodes lost to an environment process that exited (actors of Python envs).
    pub episodes_lost: u64,
    /// Real transitions this consumer copied out of shared memory before taking them (more
    /// waited than it may hold): each was copied three times instead of twice.
    pub real_spilled: u64,
    /// Deadlines a paced actor (`actor.control_hz`) started a step after.
    pub missed_deadlines: u64,
    /// Waits of a paced actor between episodes for the weights its next step needs.
    pub rests: u64,
}

impl Done {
    /// A `Done` with the lag or slack `tracked` over the run; the rest default (set them with
    /// `Done { .., ..Done::with_slack(&t) }`).
    pub fn with_slack(tracked: &SlackTracker) -> Self {
        let (slack_min, slack_max, slack_mean) = tracked.get();
        Self {
            slack_min,
            slack_max,
            slack_mean,
            ..Default::default()
        }
    }
}

/// Counts per bin of [`PacingPart`]: the record's exact integer slots (five `u64` and the `f64`,
/// exact below 2^53).
pub const PACING_PART_BINS: usize = 6;

/// Part of a paced actor's histogram of step-interval errors `|interval − period|` (the bins
/// are `mbpo_runtime::pacer`'s): bins `first_bin..first_bin + 6`. An actor sends as many parts
/// as its histogram needs, before its `Done`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PacingPart {
    /// The histogram's bin of `counts[0]`.
    pub first_bin: u32,
    /// Intervals per bin.
    pub counts: [u64; PACING_PART_BINS],
    /// The actor's largest interval error, µs (the same in every part).
    pub max_error_us: f32,
}

/// A step of a checkpoint barrier (protocol: `mbpo_runtime::barrier`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BarrierReport {
    /// Paused with this counter (actor: local steps; model trainer: trainings; rollout
    /// generator: branches).
    Paused(u64),
    /// Wrote its file of checkpoint T.
    Written(u64),
}

/// One report on the stats channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Stats {
    /// An actor's episode ended.
    Episode(EpisodeEnd),
    /// An evaluation finished.
    Eval(EvalResult),
    /// The learner's part of a metrics row.
    Learner(LearnerRow),
    /// A model training finished.
    Model(ModelTrained),
    /// A model training under way.
    Training(ModelTraining),
    /// A rollout branch finished.
    Rollout(RolloutBranch),
    /// Progress counters.
    Progress(Progress),
    /// The process finished its work.
    Done(Done),
    /// A checkpoint barrier step.
    Barrier(BarrierReport),
    /// An actor's environment failed.
    EnvFailed(EnvFailed),
    /// Part of a paced actor's step-interval errors.
    Pacing(PacingPart),
}

// Heartbeat records: metrics[0] tells progress (0) from done (1).
const HEARTBEAT_PROGRESS: f32 = 0.0;
const HEARTBEAT_DONE: f32 = 1.0;
const HEARTBEAT_TRAINING: f32 = 2.0;
// Checkpoint records: metrics[0] tells paused (0) from written (1).
const BARRIER_PAUSED: f32 = 0.0;
const BARRIER_WRITTEN: f32 = 1.0;

fn metrics(first: &[f32]) -> [f32; 8] {
    let mut m = [0.0; 8];
    m[..first.len()].copy_from_slice(first);
    m
}

/// The record of a learner's metrics row (the two records with the most fields have a
/// function each, so [`Stats::record`] stays a table).
fn learner_record(l: &LearnerRow) -> StatsRecord {
    StatsRecord {
        kind: StatsKind::Learner as u32,
        env_steps: l.env_steps,
        sac_updates: l.sac_updates,
        policy_version: l.env_steps,
        model_version: l.model_version,
        metrics: metrics(&[
            l.critic_loss,
            l.actor_loss,
            l.alpha,
            l.entropy,
            l.q_mean,
            l.rollout_length as f32,
            l.model_buffer as f32,
            l.consistency_loss,
        ]),
        // The eight metrics are taken: the reward loss rides in the (otherwise unused) value.
        value: l.reward_loss as f64,
        ..Default::default()
    }
}

/// The record of a role's `Done` report.
fn done_record(d: &Done) -> StatsRecord {
    StatsRecord {
        kind: StatsKind::Heartbeat as u32,
        env_steps: d.real,
        sac_updates: d.work,
        model_version: d.episodes_cut,
        model_trainings: d.episodes_lost,
        policy_version: d.real_spilled,
        value: d.lost as f64,
        episode_len: d.missed_deadlines.min(u32::MAX as u64) as u32,
        metrics: metrics(&[
            HEARTBEAT_DONE,
            d.median_step_seconds,
            d.slack_min,
            d.slack_max,
            d.slack_mean,
            d.ipc_seconds,
            d.wall_seconds,
            // Exact up to 2^24 rests.
            d.rests as f32,
        ]),
    }
}

/// The record of a part of a paced actor's histogram.
fn pacing_record(p: &PacingPart) -> StatsRecord {
    let c = p.counts;
    StatsRecord {
        kind: StatsKind::Pacing as u32,
        env_steps: c[0],
        sac_updates: c[1],
        model_trainings: c[2],
        policy_version: c[3],
        model_version: c[4],
        value: c[5] as f64,
        episode_len: p.first_bin,
        metrics: metrics(&[p.max_error_us]),
    }
}

impl Stats {
    /// The fixed-size record that carries this report.
    pub fn record(&self) -> StatsRecord {
        match *self {
            Stats::Episode(e) => StatsRecord {
                kind: StatsKind::Episode as u32,
                env_steps: e.env_steps,
                policy_version: e.version,
                value: e.episode_return,
                ..Default::default()
            },
            Stats::Eval(e) => StatsRecord {
                kind: StatsKind::Eval as u32,
                env_steps: e.env_steps,
                policy_version: e.policy_version,
                model_version: e.model_version,
                value: e.mean_return,
                episode_len: e.episodes,
                ..Default::default()
            },
            Stats::Learner(l) => learner_record(&l),
            Stats::Model(m) => StatsRecord {
                kind: StatsKind::Model as u32,
                env_steps: m.rows,
                model_trainings: m.version,
                model_version: m.version,
                value: m.holdout_mse,
                metrics: metrics(&[m.epochs as f32, m.seconds]),
                ..Default::default()
            },
            Stats::Rollout(r) => StatsRecord {
                kind: StatsKind::Rollout as u32,
                env_steps: r.env_steps,
                model_version: r.model_version,
                policy_version: r.policy_version,
                metrics: metrics(&[r.rows as f32, r.length as f32, r.seconds]),
                ..Default::default()
            },
            Stats::Progress(p) => StatsRecord {
                kind: StatsKind::Heartbeat as u32,
                env_steps: p.env_steps,
                sac_updates: p.sac_updates,
                model_trainings: p.model_version,
                model_version: p.model_version,
                policy_version: p.policy_version,
                metrics: metrics(&[HEARTBEAT_PROGRESS]),
                ..Default::default()
            },
            Stats::Training(m) => StatsRecord {
                kind: StatsKind::Heartbeat as u32,
                env_steps: m.env_steps,
                model_version: m.version,
                episode_len: m.epoch,
                metrics: metrics(&[HEARTBEAT_TRAINING, m.holdout_mse, m.seconds]),
                ..Default::default()
            },
            Stats::Done(d) => done_record(&d),
            Stats::EnvFailed(f) => StatsRecord {
                kind: StatsKind::EnvFailed as u32,
                env_steps: f.env_steps,
                ..Default::default()
            },
            Stats::Pacing(p) => pacing_record(&p),
            Stats::Barrier(b) => {
                let (env_steps, phase) = match b {
                    BarrierReport::Paused(n) => (n, BARRIER_PAUSED),
                    BarrierReport::Written(t) => (t, BARRIER_WRITTEN),
                };
                StatsRecord {
                    kind: StatsKind::Checkpoint as u32,
                    env_steps,
                    metrics: metrics(&[phase]),
                    ..Default::default()
                }
            }
        }
    }

    /// The report a record carries; an unknown kind is an error naming it.
    pub fn decode(r: &StatsRecord) -> Result<Self, DecodeError> {
        let kind = r
            .stats_kind()
            .ok_or(DecodeError::UnknownStatsKind(r.kind))?;
        let m = r.metrics;
        Ok(match kind {
            StatsKind::Episode => Stats::Episode(EpisodeEnd {
                env_steps: r.env_steps,
                episode_return: r.value,
                version: r.policy_version,
            }),
            StatsKind::Eval => Stats::Eval(EvalResult {
                env_steps: r.env_steps,
                policy_version: r.policy_version,
                model_version: r.model_version,
                mean_return: r.value,
                episodes: r.episode_len,
            }),
            StatsKind::Learner => Stats::Learner(LearnerRow {
                env_steps: r.env_steps,
                sac_updates: r.sac_updates,
                critic_loss: m[0],
                actor_loss: m[1],
                alpha: m[2],
                entropy: m[3],
                q_mean: m[4],
                rollout_length: m[5] as usize,
                model_buffer: m[6] as usize,
                consistency_loss: m[7],
                reward_loss: r.value as f32,
                model_version: r.model_version,
            }),
            StatsKind::Model => Stats::Model(ModelTrained {
                rows: r.env_steps,
                version: r.model_version,
                holdout_mse: r.value,
                epochs: m[0] as u32,
                seconds: m[1],
            }),
            StatsKind::Rollout => Stats::Rollout(RolloutBranch {
                env_steps: r.env_steps,
                model_version: r.model_version,
                policy_version: r.policy_version,
                rows: m[0] as u32,
                length: m[1] as u32,
                seconds: m[2],
            }),
            StatsKind::Heartbeat => heartbeat(r),
            StatsKind::Checkpoint if m[0] == BARRIER_WRITTEN => {
                Stats::Barrier(BarrierReport::Written(r.env_steps))
            }
            StatsKind::Checkpoint => Stats::Barrier(BarrierReport::Paused(r.env_steps)),
            StatsKind::EnvFailed => Stats::EnvFailed(EnvFailed {
                env_steps: r.env_steps,
            }),
            StatsKind::Pacing => Stats::Pacing(PacingPart {
                first_bin: r.episode_len,
                counts: [
                    r.env_steps,
                    r.sac_updates,
                    r.model_trainings,
                    r.policy_version,
                    r.model_version,
                    r.value as u64,
                ],
                max_error_us: m[0],
            }),
        })
    }
}

/// A heartbeat record's report: metrics[0] tells done, a training under way and progress apart.
fn heartbeat(r: &StatsRecord) -> Stats {
    let m = r.metrics;
    match m[0] {
        phase if phase == HEARTBEAT_DONE => Stats::Done(Done {
            real: r.env_steps,
            lost: r.value as u64,
            work: r.sac_updates,
            median_step_seconds: m[1],
            slack_min: m[2],
            slack_max: m[3],
            slack_mean: m[4],
            ipc_seconds: m[5],
            wall_seconds: m[6],
            episodes_cut: r.model_version,
            episodes_lost: r.model_trainings,
            real_spilled: r.policy_version,
            missed_deadlines: r.episode_len as u64,
            rests: m[7] as u64,
        }),
        phase if phase == HEARTBEAT_TRAINING => Stats::Training(ModelTraining {
            env_steps: r.env_steps,
            version: r.model_version,
            epoch: r.episode_len,
            holdout_mse: m[1],
            seconds: m[2],
        }),
        _ => Stats::Progress(Progress {
            env_steps: r.env_steps,
            sac_updates: r.sac_updates,
            model_version: r.model_version,
            policy_version: r.policy_version,
        }),
    }
}

macro_rules! into_stats {
    ($($ty:ident => $variant:ident),*) => {$(
        impl From<$ty> for Stats {
            fn from(v: $ty) -> Self {
                Stats::$variant(v)
            }
        }
    )*};
}
into_stats!(EpisodeEnd => Episode, EvalResult => Eval, LearnerRow => Learner,
    ModelTrained => Model, ModelTraining => Training, RolloutBranch => Rollout, Progress => Progress, Done => Done,
    BarrierReport => Barrier, EnvFailed => EnvFailed, PacingPart => Pacing);

/// Running min / max / mean of a slack value (for [`Done`]).
#[derive(Debug, Clone, Copy)]
pub struct SlackTracker {
    min: f64,
    max: f64,
    sum: f64,
    n: u64,
}

impl Default for SlackTracker {
    fn default() -> Self {
        Self {
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
            sum: 0.0,
            n: 0,
        }
    }
}

impl SlackTracker {
    /// Record one value.
    pub fn see(&mut self, v: f64) {
        self.min = self.min.min(v);
        self.max = self.max.max(v);
        self.sum += v;
        self.n += 1;
    }
    /// (min, max, mean), zeros when nothing was seen.
    pub fn get(&self) -> (f32, f32, f32) {
        if self.n == 0 {
            return (0.0, 0.0, 0.0);
        }
        (
            self.min as f32,
            self.max as f32,
            (self.sum / self.n as f64) as f32,
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `Done` with every field set.
    fn a_done() -> Done {
        Done {
            real: 1000,
            lost: 2,
            work: 9,
            median_step_seconds: 0.5,
            slack_min: -3.0,
            slack_max: 4.0,
            slack_mean: 0.5,
            ipc_seconds: 0.125,
            wall_seconds: 12.0,
            episodes_cut: 3,
            episodes_lost: 2,
            real_spilled: 6,
            missed_deadlines: 11,
            rests: 5,
        }
    }

    /// One report of every kind, with values in every field.
    fn one_of_each() -> Vec<Stats> {
        vec![
            Stats::Episode(EpisodeEnd {
                env_steps: 200,
                episode_return: -1234.5,
                version: 199,
            }),
            Stats::Eval(EvalResult {
                env_steps: 1000,
                policy_version: 1000,
                model_version: 3,
                mean_return: -150.25,
                episodes: 5,
            }),
            Stats::Learner(LearnerRow {
                env_steps: 400,
                sac_updates: 3000,
                critic_loss: 1.5,
                actor_loss: -2.5,
                alpha: 0.125,
                entropy: -0.75,
                q_mean: 10.0,
                consistency_loss: 0.625,
                reward_loss: 0.375,
                rollout_length: 3,
                model_buffer: 40_000,
                model_version: 2,
            }),
            Stats::Model(ModelTrained {
                rows: 650,
                version: 4,
                holdout_mse: 0.0125,
                epochs: 87,
                seconds: 2.5,
            }),
            Stats::Training(ModelTraining {
                env_steps: 1000,
                version: 5,
                epoch: 12,
                holdout_mse: 0.0375,
                seconds: 4.25,
            }),
            Stats::Rollout(RolloutBranch {
                env_steps: 250,
                model_version: 1,
                policy_version: 248,
                rows: 400,
                length: 1,
                seconds: 0.25,
            }),
            Stats::Progress(Progress {
                env_steps: 5,
                sac_updates: 7,
                model_version: 1,
                policy_version: 4,
            }),
            Stats::Done(a_done()),
            Stats::Barrier(BarrierReport::Paused(0)),
            Stats::Barrier(BarrierReport::Paused(7)),
            Stats::Barrier(BarrierReport::Written(1200)),
            Stats::EnvFailed(EnvFailed { env_steps: 50 }),
            Stats::Pacing(PacingPart {
                first_bin: 12,
                counts: [1 << 40, 2, 0, 3, 4, (1 << 52) + 1],
                max_error_us: 1250.5,
            }),
        ]
    }

    #[test]
    fn every_report_round_trips_through_its_record() {
        for s in one_of_each() {
            assert_eq!(Stats::decode(&s.record()).unwrap(), s, "{s:?}");
        }
    }

    #[test]
    fn an_unknown_kind_is_an_error_that_names_it() {
        let r = StatsRecord {
            kind: 99,
            ..Default::default()
        };
        let e = Stats::decode(&r).unwrap_err();
        assert!(e.to_string().contains("99"), "{e}");
    }
}
