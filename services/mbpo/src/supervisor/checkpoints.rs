//! The supervisor's side of pipeline checkpoints (protocol in `mbpo_service_kit::barrier`):
//! start a barrier (periodically, or on SIGINT/SIGTERM for a clean stop), turn the processes'
//! pause reports into the cut, and write its own file and `COMPLETE` once every file is in.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::time::Instant;

use mbpo_service_kit::barrier::{self, Cut};
use mbpo_service_kit::stats::BarrierReport;
use mbpo_service_kit::{train_points_upto, Mode, Slack};
use mbpo_train::checkpoint;
use mbpo_train::roles::Schedule;
use mbpo_train::Algo;
use mbpo_wire::{ProducerId, Role};
use serde::{Deserialize, Serialize};

use super::collect::CollectorBook;

/// The supervisor's file of a checkpoint.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SupervisorCheckpoint {
    /// Hand-off mode of the run (a resumed run keeps it).
    pub mode: Mode,
    /// Actors of the run (one file each; a resumed run keeps the count).
    pub actors: u16,
    /// Slack of the run.
    pub slack: Slack,
    /// Metrics bookkeeping.
    pub book: CollectorBook,
    /// Wall seconds of the run so far (the clock continues from here).
    pub elapsed_seconds: f64,
}

/// One checkpoint barrier under way.
pub struct Barrier {
    /// When it started (for the log).
    pub started: Instant,
    /// Stop the run once the checkpoint is complete (SIGINT/SIGTERM) instead of resuming.
    pub stop_after: bool,
    paused: BTreeMap<ProducerId, u64>,
    cut: Option<Cut>,
    written: BTreeSet<ProducerId>,
    /// Pause reports the cut needs ([`barrier::pausing_processes`]).
    pausing: usize,
    /// Files the processes write (every file of the checkpoint but the supervisor's).
    files: usize,
    /// Warnings logged about a slow barrier.
    pub warnings: u32,
}

/// A barrier is reported as slow after this long (and every as long again).
pub const BARRIER_WARN_AFTER: std::time::Duration = std::time::Duration::from_secs(60);

impl Barrier {
    /// A barrier over a pipeline running `algo` with `actors` actors.
    pub fn new(algo: Algo, actors: u16, stop_after: bool) -> Self {
        Self {
            started: Instant::now(),
            stop_after,
            paused: BTreeMap::new(),
            cut: None,
            written: BTreeSet::new(),
            pausing: barrier::pausing_processes(algo, actors),
            files: barrier::pipeline_files(algo, actors).len() - 1,
            warnings: 0,
        }
    }

    /// Take one report.
    pub fn on_report(&mut self, from: ProducerId, report: BarrierReport) {
        match report {
            BarrierReport::Paused(n) => {
                self.paused.insert(from, n);
            }
            BarrierReport::Written(t) => {
                if self.cut.is_some_and(|c| c.env_steps == t) {
                    self.written.insert(from);
                } else {
                    tracing::warn!("{from} wrote checkpoint {t}, expected {:?}", self.cut);
                }
            }
        }
    }

    /// The cut, once every actor, the model trainer and the rollout generator (MBPO) paused
    /// (and not yet sent): T = the actors' steps summed; K = the trainings the model trainer or
    /// rollout generator had done. Lockstep, K is at least the trainings of the train points ≤ T
    /// (it equals the sequential run, so a training under way for a point ≤ T is finished);
    /// pipelined, the trainer abandons a training under way at a pause (it can take minutes)
    /// and does it again after the barrier, so K is what was done.
    pub fn take_cut(&mut self, schedule: &Schedule, mode: Mode) -> Option<Cut> {
        if self.cut.is_some() || self.paused.len() < self.pausing {
            return None;
        }
        let of = |role: Role| {
            self.paused
                .iter()
                .filter(move |(p, _)| p.role() == Some(role))
                .map(|(_, &n)| n)
        };
        let env_steps: u64 = of(Role::Actor).sum();
        let done = of(Role::ModelTrainer)
            .chain(of(Role::RolloutGenerator))
            .max();
        let done = done.unwrap_or(0);
        let model_trainings = match mode {
            Mode::Lockstep => train_points_upto(schedule, env_steps).max(done),
            Mode::Pipelined => done,
        };
        let cut = Cut {
            env_steps,
            model_trainings,
        };
        self.cut = Some(cut);
        Some(cut)
    }

    /// The cut once every process wrote its file.
    pub fn complete(&self) -> Option<Cut> {
        (self.written.len() == self.files)
            .then_some(self.cut)
            .flatten()
    }

    /// What the barrier still waits for (for a warning when it takes long).
    pub fn waiting_for(&self) -> String {
        match self.cut {
            None => format!("pause reports: {} of {}", self.paused.len(), self.pausing),
            Some(c) => format!(
                "checkpoint files of step {}: {} of {}",
                c.env_steps,
                self.written.len(),
                self.files
            ),
        }
    }
}

/// Write the supervisor's file and `COMPLETE`, then keep the newest `keep` checkpoints.
pub fn finish(
    run: &Path,
    algo: Algo,
    cut: Cut,
    state: &SupervisorCheckpoint,
    keep: usize,
) -> anyhow::Result<()> {
    let dir = checkpoint::dir_for(run, cut.env_steps);
    checkpoint::write(
        &dir.join(barrier::file::SUPERVISOR),
        barrier::kind::SUPERVISOR,
        state,
    )?;
    let files = barrier::pipeline_files(algo, state.actors);
    let names: Vec<&str> = files.iter().map(|(name, _)| name.as_str()).collect();
    checkpoint::mark_complete(&dir, cut.env_steps, &names)?;
    checkpoint::prune(run, keep)?;
    Ok(())
}

/// The newest complete checkpoint of `run` (a pipeline running `algo`), every file checked
/// (header, kind and checksum), and the supervisor's state in it.
pub fn latest_verified(
    run: &Path,
    algo: Algo,
) -> anyhow::Result<(std::path::PathBuf, u64, SupervisorCheckpoint)> {
    let Some((dir, manifest)) = checkpoint::latest(run)? else {
        anyhow::bail!(
            "{} has no complete checkpoint (nothing under {}); start a new run instead",
            run.display(),
            checkpoint::root(run).display()
        );
    };
    let sup_path = dir.join(barrier::file::SUPERVISOR);
    if !sup_path.is_file() {
        anyhow::bail!(
            "{} is not a checkpoint of `mbpo run` (no {} file); resume it with `mbpo train --resume`",
            dir.display(),
            barrier::file::SUPERVISOR
        );
    }
    let state: SupervisorCheckpoint = checkpoint::read(&sup_path, barrier::kind::SUPERVISOR)?;
    for (name, kind) in barrier::pipeline_files(algo, state.actors) {
        checkpoint::verify(&dir.join(&name), kind)?;
    }
    Ok((dir, manifest.env_steps, state))
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_train::ExperimentConfig;

    /// Actor 0 paused after 650 steps, the model trainer after 1 training (the second, for step
    /// 651 of train points 401, 651, ..., abandoned), the rollout generator after 1 branch.
    fn barrier_at_650() -> (Barrier, Schedule) {
        let mut cfg = ExperimentConfig::default();
        cfg.mbpo.init_random_steps = 400;
        cfg.mbpo.model_train_freq = 250;
        let mut b = Barrier::new(Algo::Mbpo, 1, true);
        b.on_report(ProducerId::new(Role::Actor, 0), BarrierReport::Paused(650));
        b.on_report(
            ProducerId::new(Role::ModelTrainer, 0),
            BarrierReport::Paused(1),
        );
        b.on_report(
            ProducerId::new(Role::RolloutGenerator, 0),
            BarrierReport::Paused(1),
        );
        (b, Schedule::of(&cfg))
    }

    #[test]
    fn a_lockstep_cut_holds_every_training_up_to_t_and_a_pipelined_one_what_was_done() {
        let (mut lockstep, schedule) = barrier_at_650();
        let cut = lockstep.take_cut(&schedule, Mode::Lockstep).unwrap();
        assert_eq!((cut.env_steps, cut.model_trainings), (650, 1));
        let (mut pipelined, _) = barrier_at_650();
        let cut = pipelined.take_cut(&schedule, Mode::Pipelined).unwrap();
        assert_eq!((cut.env_steps, cut.model_trainings), (650, 1));
        // Step 651 done by the actor: lockstep needs the training of 651 (finished in the
        // barrier); pipelined holds the one training done.
        for (mode, k) in [(Mode::Lockstep, 2), (Mode::Pipelined, 1)] {
            let (mut b, _) = barrier_at_650();
            b.on_report(ProducerId::new(Role::Actor, 0), BarrierReport::Paused(651));
            let cut = b.take_cut(&schedule, mode).unwrap();
            assert_eq!((cut.env_steps, cut.model_trainings), (651, k), "{mode:?}");
            assert!(b.take_cut(&schedule, mode).is_none(), "a cut is taken once");
        }
    }
}
