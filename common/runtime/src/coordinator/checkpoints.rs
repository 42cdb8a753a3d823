//! The coordinator's side of pipeline checkpoints (protocol in `crate::barrier`):
//! start a barrier (periodically, or on SIGINT/SIGTERM for a clean stop), turn the processes'
//! pause reports into the cut, and write its own file and `COMPLETE` once every file is in.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;
use std::time::Instant;

use crate::barrier::{self, Cut};
use crate::pipeline::{self, PipelineSpec};
use crate::{Mode, Result, RuntimeError, Slack};
use mbpo_train::checkpoint;
use mbpo_train::Algo;
use mbpo_train::Schedule;
use mbpo_wire::BarrierReport;
use mbpo_wire::{ProducerId, Role};
use serde::{Deserialize, Serialize};

use crate::barrier::RunBook;

/// The launcher's file of a checkpoint: how the pipeline ran (a checkpoint of `mbpo train` has
/// none: one actor, and the mode and slack `mbpo run --resume` is given).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SupervisorCheckpoint {
    /// Hand-off mode of the run (a resumed run keeps it).
    pub mode: Mode,
    /// Actors of the run (one file each; a resumed run keeps the count).
    pub actors: u16,
    /// Slack of the run.
    pub slack: Slack,
}

/// A complete checkpoint to resume from, every file checked.
#[derive(Debug, Clone)]
pub struct ResumePoint {
    /// Its directory.
    pub dir: std::path::PathBuf,
    /// Its env step T.
    pub env_steps: u64,
    /// The launcher's file (`None`: written by `mbpo train`, one actor).
    pub supervisor: Option<SupervisorCheckpoint>,
    /// The run's book.
    pub book: RunBook,
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
    /// Pause reports the cut needs ([`pipeline::pausing_processes`]).
    pausing: usize,
    /// Files the processes write (every file of the checkpoint but the supervisor's).
    files: usize,
    /// Warnings logged about a slow barrier.
    pub warnings: u32,
    /// Control subscribers counted just before the barrier's messages last went out: one that
    /// appears later (a role still starting when Ctrl-C came) has not got them.
    pub control_subscribers: usize,
    pipeline: &'static PipelineSpec,
}

/// A barrier is reported as slow after this long (and every as long again).
pub const BARRIER_WARN_AFTER: std::time::Duration = std::time::Duration::from_secs(60);

impl Barrier {
    /// A barrier over `pipeline` with `actors` actors.
    pub fn new(pipeline: &'static PipelineSpec, actors: u16, stop_after: bool) -> Self {
        Self {
            started: Instant::now(),
            stop_after,
            paused: BTreeMap::new(),
            cut: None,
            written: BTreeSet::new(),
            pausing: pipeline::pausing_processes(pipeline, actors),
            files: pipeline.roles(actors).len(),
            warnings: 0,
            control_subscribers: 0,
            pipeline,
        }
    }

    /// The cut, once sent.
    pub fn cut(&self) -> Option<Cut> {
        self.cut
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
    /// rollout generator had done, and at least those of the train points ≤ T (a training
    /// under way for one is finished) -- except when the run stops after this barrier and its
    /// trainer abandons a training under way
    /// ([`PipelineSpec::abandons_training_on_stop`]; one can take minutes): the resumed run
    /// does it again, and K is what was done.
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
        let abandons = self.pipeline.abandons_training_on_stop(mode) && self.stop_after;
        let model_trainings = if abandons {
            done
        } else {
            schedule.train_points_upto(env_steps).max(done)
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

/// Write the run book, the launcher's file and `COMPLETE`, then prune per the config's
/// `checkpoint.keep` and `checkpoint.keep_every`.
pub fn finish(
    run: &Path,
    pipeline: &PipelineSpec,
    cut: Cut,
    state: &SupervisorCheckpoint,
    book: &RunBook,
    keep: &mbpo_train::config::CheckpointConfig,
) -> Result<()> {
    let dir = checkpoint::dir_for(run, cut.env_steps);
    checkpoint::write(
        &dir.join(barrier::file::RUN_BOOK),
        barrier::kind::RUN_BOOK,
        book,
    )?;
    checkpoint::write(
        &dir.join(barrier::file::SUPERVISOR),
        barrier::kind::SUPERVISOR,
        state,
    )?;
    let files = pipeline::pipeline_files(pipeline, state.actors);
    let names: Vec<&str> = files.iter().map(|(name, _)| name.as_str()).collect();
    checkpoint::mark_complete(&dir, cut.env_steps, &names)?;
    checkpoint::prune(run, keep.keep, keep.keep_every)?;
    Ok(())
}

/// The newest complete checkpoint of `run` (of a run of `algo`, by either command), every file
/// checked (header, kind and checksum). A checkpoint of `mbpo train` has no launcher's file
/// and one actor.
pub fn latest_verified(run: &Path, algo: Algo) -> Result<ResumePoint> {
    let pipeline = pipeline::spec(algo)?;
    let Some((dir, manifest)) = checkpoint::latest(run)? else {
        return Err(RuntimeError::Resume(format!(
            "{} has no complete checkpoint (nothing under {}); start a new run instead",
            run.display(),
            checkpoint::root(run).display()
        )));
    };
    let sup_path = dir.join(barrier::file::SUPERVISOR);
    let supervisor: Option<SupervisorCheckpoint> = match sup_path.is_file() {
        true => Some(checkpoint::read(&sup_path, barrier::kind::SUPERVISOR)?),
        false => None,
    };
    let actors = supervisor.map_or(1, |s| s.actors);
    let files = match supervisor {
        Some(_) => pipeline::pipeline_files(pipeline, actors),
        None => pipeline::role_files(pipeline, actors),
    };
    for (name, kind) in files {
        let path = dir.join(&name);
        if !path.is_file() {
            return Err(RuntimeError::Resume(format!(
                "{} holds no {name} file: it is not a checkpoint of an {} run with {actors} actor(s)",
                dir.display(),
                algo.name()
            )));
        }
        checkpoint::verify(&path, kind)?;
    }
    let book = checkpoint::read(&dir.join(barrier::file::RUN_BOOK), barrier::kind::RUN_BOOK)?;
    Ok(ResumePoint {
        dir,
        env_steps: manifest.env_steps,
        supervisor,
        book,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_train::ExperimentConfig;

    /// Actor 0 paused after `t` steps, the model trainer after 1 training (the second, for step
    /// 651 of train points 401, 651, ..., not done), the rollout generator after 1 branch.
    fn barrier_at(algo: Algo, t: u64, stop_after: bool) -> (Barrier, Schedule) {
        let mut cfg = ExperimentConfig {
            algo,
            ..Default::default()
        };
        cfg.mbpo.init_random_steps = 400;
        cfg.mbpo.model_train_freq = 250;
        cfg.mpc.init_random_steps = 400;
        cfg.mpc.model_train_freq = 250;
        let mut b = Barrier::new(pipeline::spec(algo).unwrap(), 1, stop_after);
        b.on_report(ProducerId::new(Role::Actor, 0), BarrierReport::Paused(t));
        b.on_report(
            ProducerId::new(Role::ModelTrainer, 0),
            BarrierReport::Paused(1),
        );
        if algo == Algo::MBPO {
            b.on_report(
                ProducerId::new(Role::RolloutGenerator, 0),
                BarrierReport::Paused(1),
            );
        }
        (b, Schedule::of(&cfg))
    }

    #[test]
    fn only_a_pipelined_mbpo_stop_cuts_without_the_trainings_up_to_t() {
        let cases = [
            // (algo, mode, stop after the barrier, K at T = 651)
            (Algo::MBPO, Mode::Pipelined, true, 1),
            (Algo::MBPO, Mode::Pipelined, false, 2),
            (Algo::MBPO, Mode::Lockstep, true, 2),
            (Algo::MPC, Mode::Pipelined, true, 2),
        ];
        for (algo, mode, stop_after, k) in cases {
            let (mut b, schedule) = barrier_at(algo, 650, stop_after);
            let cut = b.take_cut(&schedule, mode).unwrap();
            assert_eq!((cut.env_steps, cut.model_trainings), (650, 1));
            let (mut b, schedule) = barrier_at(algo, 651, stop_after);
            let cut = b.take_cut(&schedule, mode).unwrap();
            let case = format!("{algo:?} {mode:?} stop {stop_after}");
            assert_eq!((cut.env_steps, cut.model_trainings), (651, k), "{case}");
            assert!(b.take_cut(&schedule, mode).is_none(), "a cut is taken once");
        }
    }
}
