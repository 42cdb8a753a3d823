//! D_model in a checkpoint as the branches that filled it, done again on restore.
//!
//! MBPO's model buffer holds the newest `retain_epochs · epoch_length / model_train_freq`
//! branches of M · model_train_freq k-step rollouts: 359 MB of the 397 MB checkpoint at Hopper
//! 100k (k = 15), 1 GB for Ant at 50k (k = 10), rewritten every 1000 env steps. What made those
//! rows is a few MB per branch: the model, the policy and the `rollout` stream it started from,
//! how much of D_env it drew its start states from (D_env only grows, so that is a prefix of
//! today's) and its epoch (k). Rollouts are deterministic, so a checkpoint of the single-process
//! trainer keeps those inputs ([`BranchInputs`]) instead of the rows, and a restore does the
//! branches again, newest first, putting each row in its slot until the buffer is full.
//!
//! Each branch's rows carry a digest. A build that rounds differently (another GEMM kernel)
//! computes other rows from the same inputs: the restore then continues with them and warns,
//! as the run is no longer bit for bit the uninterrupted one (it is the same algorithm on the
//! same data). The rows are stored as before (a [`ReplaySnapshot`]) whenever the inputs do not
//! cover them: in the multi-process pipeline (the learner never sees the model's weights),
//! after a restore until enough branches were recorded again, or once D_env wrapped.

use crate::error::TrainError;
use mbpo_core::{Batch, ReplayBuffer, ReplaySnapshot, Rng};
use mbpo_model::ModelWeights;
use serde::{Deserialize, Serialize};
use std::collections::VecDeque;

/// Everything one branch of rollouts needs to be done again, and what it produced.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BranchInputs {
    /// The epoch it branched in (k = rollout_length(epoch)).
    pub epoch: usize,
    /// Real transitions in D_env when it drew its start states (the first ones of D_env).
    pub d_env_rows: u64,
    /// The model it rolled out in.
    pub model: ModelWeights,
    /// The policy that acted.
    pub policy: Vec<f32>,
    /// The `rollout` stream before the branch.
    pub rng: Rng,
    /// Imagined transitions it added to D_model.
    pub rows: usize,
    /// [`Batch::digest`] of those rows.
    pub digest: u64,
}

/// D_model's rows as the newest branches that produced them, oldest first: the buffer holds the
/// last `len` of their rows.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DModelBranches {
    /// Rows the buffer held.
    pub len: usize,
    /// The branches, oldest first; their rows add up to at least `len`.
    pub branches: Vec<BranchInputs>,
}

/// The newest branches whose rows are still in D_model (the learner keeps it beside D_model).
#[derive(Debug, Clone, Default)]
pub struct BranchLog {
    branches: VecDeque<BranchInputs>,
    rows: usize,
}

impl BranchLog {
    /// A branch just added to D_model (of `capacity` rows now): keep it, and forget the oldest
    /// ones while the newer ones alone fill the buffer.
    pub fn record(&mut self, inputs: BranchInputs, capacity: usize) {
        self.rows += inputs.rows;
        self.branches.push_back(inputs);
        while let Some(oldest) = self.branches.front() {
            if self.rows - oldest.rows < capacity {
                break;
            }
            self.rows -= oldest.rows;
            self.branches.pop_front();
        }
    }

    /// Rows were added without their inputs (a pipeline's imagined batch): the log no longer
    /// describes the buffer until the branches recorded from now on fill it.
    pub fn forget(&mut self) {
        self.branches.clear();
        self.rows = 0;
    }

    /// The branches behind the newest `len` rows of D_model, if this log has them all and each
    /// can be done again from `d_env` (which must not have wrapped since).
    pub fn covering(&self, len: usize, d_env: &ReplayBuffer) -> Option<DModelBranches> {
        let d_env_whole = d_env.pushed() <= d_env.capacity() as u64;
        (len > 0 && self.rows >= len && d_env_whole).then(|| DModelBranches {
            len,
            branches: self.branches.iter().cloned().collect(),
        })
    }

    /// Continue from a restored checkpoint's branches (taken over, not copied).
    pub fn restore(branches: DModelBranches) -> Self {
        Self {
            rows: branches.branches.iter().map(|b| b.rows).sum(),
            branches: branches.branches.into(),
        }
    }
}

/// D_model rebuilt by [`DModelBranches::replay`].
pub struct Replayed {
    /// The buffer, in `layout`'s slots.
    pub buffer: ReplayBuffer,
    /// Branches whose rows differ from what the run had (another build's rounding).
    pub differing: usize,
}

impl DModelBranches {
    /// Do every branch again with `do_branch` (the rollout generator's
    /// `RolloutRole::replay`, on `obs_dim`/`act_dim` rows), newest first, and lay the newest
    /// `len` rows out in `layout`'s slots (its capacity, write position and push count; its own
    /// rows are not read).
    pub fn replay(
        &self,
        (obs_dim, act_dim): (usize, usize),
        layout: &ReplaySnapshot,
        mut do_branch: impl FnMut(&BranchInputs) -> Result<Batch, TrainError>,
    ) -> Result<Replayed, TrainError> {
        let bad = |e: String| {
            TrainError::Config(format!(
                "cannot do D_model's {} branches again: {e}",
                self.branches.len()
            ))
        };
        let recorded: usize = self.branches.iter().map(|b| b.rows).sum();
        if self.len == 0 || recorded < self.len {
            return Err(bad(format!(
                "their {recorded} rows do not cover the {} the buffer held",
                self.len
            )));
        }
        // Newest branch first, each row straight to its slot: only one branch's rows are
        // held besides the buffer, and a branch whose rows were all overwritten is not done.
        let mut fill = ReplayBuffer::fill_from_newest(layout, obs_dim, act_dim, self.len)
            .map_err(|e| bad(e.0))?;
        let mut differing = 0;
        for (i, inputs) in self.branches.iter().enumerate().rev() {
            let rows = do_branch(inputs)?;
            if rows.len != inputs.rows || rows.digest() != inputs.digest {
                differing += 1;
                tracing::warn!(
                    "D_model branch {} of {} (epoch {}) done again gives other rows than the \
                     run had ({} rows against {}): this build rounds differently from the one \
                     that wrote the checkpoint, so the run continues with the same algorithm \
                     on the same data, no longer bit for bit the uninterrupted one",
                    i + 1,
                    self.branches.len(),
                    inputs.epoch,
                    rows.len,
                    inputs.rows
                );
            }
            if fill.prepend(&rows) == 0 {
                break;
            }
        }
        // Fewer rows than the run had: this build's rollouts end elsewhere.
        let buffer = fill.finish().map_err(|e| {
            bad(format!(
                "{} (resume with the build that wrote the checkpoint)",
                e.0
            ))
        })?;
        Ok(Replayed { buffer, differing })
    }
}
