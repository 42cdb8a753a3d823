//! What each role had reached when the run ended, whatever ended it.
//!
//! A role sends its `Done` record (real transitions, work, lags, IPC time) only once its work
//! is done. A run that is stopped (Ctrl-C, `--steps` reached by a checkpoint), fails or is
//! rolled back ends before that, and its summary would report zeros for what happened. So the
//! coordinator also follows the records every role sends while it works -- progress, episodes,
//! learner rows, trained models, rollout batches, barrier pauses -- and keeps, per role, the
//! furthest counters they show. A role that sent `Done` is reported from it; any other from
//! here (lower bounds: a role may have done a little more since its last record).

use std::collections::BTreeMap;

use mbpo_train::Schedule;
use mbpo_wire::{BarrierReport, ProducerId, Role, Stats};

/// The counters of one role so far, in the units of its `Done` record.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Counters {
    /// Actors: local env steps taken. Consumers: real transitions received.
    pub real: u64,
    /// Learner: SAC updates. Model trainer: trainings. Rollout generator: imagined batches.
    /// Evaluator: evaluations. Actors: episodes finished.
    pub work: u64,
}

/// The furthest counters each role's records show.
#[derive(Debug, Clone)]
pub struct Reached {
    schedule: Schedule,
    actors: u16,
    by_role: BTreeMap<ProducerId, Counters>,
}

impl Reached {
    /// For a run of `schedule` with `actors` actors.
    pub fn new(schedule: Schedule, actors: u16) -> Self {
        Self {
            schedule,
            actors,
            by_role: BTreeMap::new(),
        }
    }

    /// Follow one record of `from`.
    pub fn see(&mut self, from: ProducerId, stats: &Stats) {
        let Some(role) = from.role() else {
            return;
        };
        let (real, work) = match (role, stats) {
            (Role::Actor, Stats::Progress(p)) => (Some(self.local_step(from, p.env_steps)), None),
            (Role::Actor, Stats::Episode(e)) => {
                let episodes = self.get(from).work + 1;
                (Some(self.local_step(from, e.env_steps)), Some(episodes))
            }
            (Role::Learner, Stats::Progress(p)) => (Some(p.env_steps), Some(p.sac_updates)),
            (Role::Learner, Stats::Learner(row)) => (Some(row.env_steps), Some(row.sac_updates)),
            (Role::ModelTrainer, Stats::Model(m)) => (Some(m.rows), Some(m.version)),
            // The k-th batch is the k-th train point's, made from its t − 1 real transitions.
            (Role::RolloutGenerator, Stats::Rollout(r)) => (
                Some(r.env_steps),
                Some(self.schedule.train_points_upto(r.env_steps + 1)),
            ),
            (Role::Evaluator, Stats::Eval(_)) => (None, Some(self.get(from).work + 1)),
            // A pause reports the exact counter: an actor's local steps, the trainings of the
            // model trainer, the batches of the rollout generator.
            (Role::Actor, Stats::Barrier(BarrierReport::Paused(steps))) => (Some(*steps), None),
            (
                Role::ModelTrainer | Role::RolloutGenerator,
                Stats::Barrier(BarrierReport::Paused(k)),
            ) => (None, Some(*k)),
            _ => (None, None),
        };
        let c = self.by_role.entry(from).or_default();
        c.real = c.real.max(real.unwrap_or(0));
        c.work = c.work.max(work.unwrap_or(0));
    }

    /// Continue a resumed run from its checkpoint after `env_steps` with `model_trainings`,
    /// and the learner's last report `(env steps, SAC updates)` its book holds.
    pub fn resume_at(&mut self, env_steps: u64, model_trainings: u64, learner: (u64, u64)) {
        for index in 0..self.actors {
            let actor = ProducerId::new(Role::Actor, index);
            let steps = crate::actor_steps(env_steps, self.actors, index);
            let c = self.by_role.entry(actor).or_default();
            c.real = c.real.max(steps);
        }
        let trainer = self
            .by_role
            .entry(ProducerId::new(Role::ModelTrainer, 0))
            .or_default();
        trainer.work = trainer.work.max(model_trainings);
        let l = self
            .by_role
            .entry(ProducerId::new(Role::Learner, 0))
            .or_default();
        (l.real, l.work) = (l.real.max(learner.0), l.work.max(learner.1));
    }

    /// The counters of `from` so far (zero if it sent nothing).
    pub fn get(&self, from: ProducerId) -> Counters {
        self.by_role.get(&from).copied().unwrap_or_default()
    }

    /// Actor `from`'s local step of global step `g` (steps are dealt round-robin).
    fn local_step(&self, from: ProducerId, g: u64) -> u64 {
        let n = u64::from(self.actors.max(1));
        let index = u64::from(from.index());
        match g > index {
            true => (g - index - 1) / n + 1,
            false => 0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_train::ExperimentConfig;
    use mbpo_wire::{EpisodeEnd, LearnerRow, ModelTrained, Progress, RolloutBranch};

    fn schedule() -> Schedule {
        let mut cfg = ExperimentConfig {
            algo: mbpo_train::Algo::MBPO,
            ..Default::default()
        };
        cfg.mbpo.init_random_steps = 100;
        cfg.mbpo.model_train_freq = 50;
        Schedule::of(&cfg)
    }

    #[test]
    fn every_role_keeps_the_furthest_counters_its_records_show() {
        let mut r = Reached::new(schedule(), 2);
        let actor1 = ProducerId::new(Role::Actor, 1);
        // Actor 1 of 2 takes global steps 2, 4, 6, ...: global 40 is its 20th.
        let progress = |g| {
            Stats::Progress(Progress {
                env_steps: g,
                ..Default::default()
            })
        };
        r.see(actor1, &progress(40));
        r.see(actor1, &progress(10)); // older records never lower a counter
        let episode = EpisodeEnd {
            env_steps: 42,
            episode_return: 1.0,
            version: 0,
        };
        r.see(actor1, &Stats::Episode(episode));
        assert_eq!(r.get(actor1), Counters { real: 21, work: 1 });
        r.see(actor1, &Stats::Barrier(BarrierReport::Paused(30)));
        assert_eq!(r.get(actor1).real, 30);

        let learner = ProducerId::new(Role::Learner, 0);
        let row = LearnerRow {
            env_steps: 200,
            sac_updates: 4000,
            critic_loss: 0.0,
            actor_loss: 0.0,
            alpha: 0.1,
            entropy: 0.0,
            q_mean: 0.0,
            consistency_loss: f32::NAN,
            reward_loss: f32::NAN,
            rollout_length: 1,
            model_buffer: 0,
            model_version: 2,
        };
        r.see(learner, &Stats::Learner(row));
        assert_eq!(
            r.get(learner),
            Counters {
                real: 200,
                work: 4000
            }
        );

        let trainer = ProducerId::new(Role::ModelTrainer, 0);
        let model = ModelTrained {
            rows: 150,
            version: 2,
            holdout_mse: 0.1,
            epochs: 5,
            seconds: 1.0,
        };
        r.see(trainer, &Stats::Model(model));
        assert_eq!(r.get(trainer), Counters { real: 150, work: 2 });

        // Train points at 101, 151, 201 (warm-up 100, every 50): the batch of step 151 is the
        // second.
        let rollouts = ProducerId::new(Role::RolloutGenerator, 0);
        let batch = RolloutBranch {
            env_steps: 150,
            model_version: 2,
            policy_version: 150,
            rows: 400,
            length: 1,
            seconds: 0.1,
        };
        r.see(rollouts, &Stats::Rollout(batch));
        assert_eq!(r.get(rollouts), Counters { real: 150, work: 2 });
    }

    #[test]
    fn a_resumed_run_starts_from_its_checkpoint() {
        let mut r = Reached::new(schedule(), 3);
        r.resume_at(10, 4, (9, 90));
        let steps: Vec<u64> = (0..3)
            .map(|i| r.get(ProducerId::new(Role::Actor, i)).real)
            .collect();
        assert_eq!(steps, [4, 3, 3]);
        assert_eq!(r.get(ProducerId::new(Role::ModelTrainer, 0)).work, 4);
        let learner = r.get(ProducerId::new(Role::Learner, 0));
        assert_eq!(learner, Counters { real: 9, work: 90 });
    }
}
