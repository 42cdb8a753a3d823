//! The meaning of every [`StatsRecord`] a service sends to the supervisor. Writers and the
//! reader use these functions only, so they cannot disagree.
//!
//! | kind | sender | when | fields |
//! |---|---|---|---|
//! | `Episode` | actor | an episode ended (sent *before* the transition that ended it) | `value` return, `episode_len`, `env_steps` |
//! | `Eval` | evaluator | after evaluating policy version t (MPC: model version) | `value` mean return, `env_steps` t, `policy_version` (MPC: `model_version`) |
//! | `Learner` | learner | after step t at every eval point | see [`LearnerRow`] |
//! | `Model` | model trainer | after each training (sent *before* the weights) | `value` mean elite holdout MSE, `env_steps` real rows trained on, `model_version` |
//! | `Rollout` | rollout generator | after each branch | `metrics` = [rows, k, seconds] |
//! | `Heartbeat` | everyone | progress (`metrics[0]` = 0) or done (`metrics[0]` = 1, see [`Done`]) | counters |
//! | `Checkpoint` | everyone | a checkpoint barrier step (see [`BarrierReport`], `crate::barrier`) | `env_steps` counter or T, `metrics[0]` phase |

use mbpo_sac::SacStats;
use mbpo_wire::{StatsKind, StatsRecord};

/// What the learner reports for the metrics row of eval point t.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LearnerRow {
    /// Env step t.
    pub env_steps: u64,
    /// SAC updates so far.
    pub sac_updates: u64,
    /// Statistics of the last update.
    pub stats: SacStats,
    /// Temperature α.
    pub alpha: f32,
    /// Rollout length in force.
    pub rollout_length: usize,
    /// Transitions in D_model.
    pub model_buffer: usize,
    /// Model version of the newest imagined data (0: none yet).
    pub model_version: u64,
}

impl LearnerRow {
    /// Encode.
    pub fn record(&self) -> StatsRecord {
        StatsRecord {
            kind: StatsKind::Learner as u32,
            env_steps: self.env_steps,
            sac_updates: self.sac_updates,
            policy_version: self.env_steps,
            model_version: self.model_version,
            value: 0.0,
            metrics: [
                self.stats.critic_loss,
                self.stats.actor_loss,
                self.alpha,
                self.stats.entropy,
                self.stats.q_mean,
                self.rollout_length as f32,
                self.model_buffer as f32,
                0.0,
            ],
            ..Default::default()
        }
    }
    /// Decode.
    pub fn from_record(r: &StatsRecord) -> Self {
        let m = r.metrics;
        Self {
            env_steps: r.env_steps,
            sac_updates: r.sac_updates,
            stats: SacStats {
                critic_loss: m[0],
                actor_loss: m[1],
                alpha_loss: 0.0,
                alpha: m[2],
                entropy: m[3],
                q_mean: m[4],
            },
            alpha: m[2],
            rollout_length: m[5] as usize,
            model_buffer: m[6] as usize,
            model_version: r.model_version,
        }
    }
}

/// An evaluation result.
pub fn eval(env_steps: u64, policy_version: u64, mean_return: f64, episodes: usize) -> StatsRecord {
    StatsRecord {
        kind: StatsKind::Eval as u32,
        env_steps,
        policy_version,
        value: mean_return,
        episode_len: episodes as u32,
        ..Default::default()
    }
}

/// An evaluation of MPC with model version `model_version` (algo = "mpc": no policy).
pub fn eval_model(
    env_steps: u64,
    model_version: u64,
    mean_return: f64,
    episodes: usize,
) -> StatsRecord {
    StatsRecord {
        model_version,
        ..eval(env_steps, 0, mean_return, episodes)
    }
}

/// A model training: `holdout_mse` is the mean over elites of the final holdout MSE (as the
/// sequential metrics row computes it), `rows` the real transitions trained on.
pub fn model(
    rows: u64,
    version: u64,
    holdout_mse: f64,
    epochs: usize,
    seconds: f64,
) -> StatsRecord {
    StatsRecord {
        kind: StatsKind::Model as u32,
        env_steps: rows,
        model_trainings: version,
        model_version: version,
        value: holdout_mse,
        metrics: [epochs as f32, seconds as f32, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        ..Default::default()
    }
}

/// A rollout branch.
pub fn rollout(
    env_steps: u64,
    model_version: u64,
    policy_version: u64,
    rows: usize,
    k: usize,
    seconds: f64,
) -> StatsRecord {
    StatsRecord {
        kind: StatsKind::Rollout as u32,
        env_steps,
        model_version,
        policy_version,
        metrics: [
            rows as f32,
            k as f32,
            seconds as f32,
            0.0,
            0.0,
            0.0,
            0.0,
            0.0,
        ],
        ..Default::default()
    }
}

/// Progress of a process (for the live line).
pub fn progress(
    env_steps: u64,
    sac_updates: u64,
    model_version: u64,
    policy_version: u64,
) -> StatsRecord {
    StatsRecord {
        kind: StatsKind::Heartbeat as u32,
        env_steps,
        sac_updates,
        model_trainings: model_version,
        model_version,
        policy_version,
        ..Default::default()
    }
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
}

impl Done {
    /// Encode.
    pub fn record(&self) -> StatsRecord {
        StatsRecord {
            kind: StatsKind::Heartbeat as u32,
            env_steps: self.real,
            sac_updates: self.work,
            value: self.lost as f64,
            metrics: [
                1.0,
                self.median_step_seconds,
                self.slack_min,
                self.slack_max,
                self.slack_mean,
                self.ipc_seconds,
                self.wall_seconds,
                0.0,
            ],
            ..Default::default()
        }
    }
    /// Decode, if `r` is a done record.
    pub fn from_record(r: &StatsRecord) -> Option<Self> {
        (r.stats_kind() == Some(StatsKind::Heartbeat) && r.metrics[0] == 1.0).then(|| Self {
            real: r.env_steps,
            lost: r.value as u64,
            work: r.sac_updates,
            median_step_seconds: r.metrics[1],
            slack_min: r.metrics[2],
            slack_max: r.metrics[3],
            slack_mean: r.metrics[4],
            ipc_seconds: r.metrics[5],
            wall_seconds: r.metrics[6],
        })
    }
}

/// Running min / max / mean of a slack value.
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

/// A step of a checkpoint barrier ([`StatsKind::Checkpoint`]; protocol in `crate::barrier`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BarrierReport {
    /// Paused with this counter (actor: local steps; model trainer: trainings; rollout
    /// generator: branches). `metrics[0]` = 0.
    Paused(u64),
    /// Wrote its file of checkpoint T. `metrics[0]` = 1.
    Written(u64),
}

impl BarrierReport {
    /// Encode.
    pub fn record(self) -> StatsRecord {
        let (env_steps, phase) = match self {
            BarrierReport::Paused(n) => (n, 0.0),
            BarrierReport::Written(t) => (t, 1.0),
        };
        let mut metrics = [0.0; 8];
        metrics[0] = phase;
        StatsRecord {
            kind: StatsKind::Checkpoint as u32,
            env_steps,
            metrics,
            ..Default::default()
        }
    }
    /// Decode, if `r` is a checkpoint record.
    pub fn from_record(r: &StatsRecord) -> Option<Self> {
        (r.stats_kind() == Some(StatsKind::Checkpoint)).then(|| {
            if r.metrics[0] == 1.0 {
                BarrierReport::Written(r.env_steps)
            } else {
                BarrierReport::Paused(r.env_steps)
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn barrier_reports_round_trip_and_other_kinds_are_not_reports() {
        for r in [
            BarrierReport::Paused(0),
            BarrierReport::Paused(7),
            BarrierReport::Written(1200),
        ] {
            assert_eq!(BarrierReport::from_record(&r.record()), Some(r));
        }
        assert_eq!(BarrierReport::from_record(&progress(5, 0, 0, 4)), None);
    }
}
