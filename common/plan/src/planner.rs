//! The [`Planner`] interface and the sequence helpers the planners share.

use crate::error::PlanError;
use crate::model::PlanningModel;
use mbpo_core::Rng;

/// An optimiser of action sequences `a_0 … a_{H−1}` (`H x A`, row-major, in [−1, 1]) that
/// maximise the model's predicted return from an observation.
///
/// Planners keep their last solution so that model predictive control can warm-start the next
/// step from it ([`Planner::shift`]).
pub trait Planner: Send {
    /// Planning horizon H.
    fn horizon(&self) -> usize;
    /// Action width A.
    fn act_dim(&self) -> usize;

    /// Plan from `obs`; the returned sequence (`H x A`) stays valid until the next call.
    fn plan(
        &mut self,
        model: &mut dyn PlanningModel,
        obs: &[f32],
        rng: &mut Rng,
    ) -> Result<&[f32], PlanError>;

    /// The model's predicted return of the last plan (mean over particles).
    fn predicted_return(&self) -> f32;

    /// The first `k` actions of the last plan were executed: shift the solution by `k` so the
    /// next plan starts from its remainder (warm start); the freed tail gets the planner's
    /// initial value.
    fn shift(&mut self, k: usize);

    /// Forget the last solution (a new episode, or open-loop replanning from scratch).
    fn reset(&mut self);

    /// What carries from one plan to the next (the warm start, as [`Planner::shift`] or
    /// [`Planner::reset`] left it), `None` when nothing does: all a checkpoint needs to
    /// continue planning exactly (everything else is rebuilt by each plan).
    fn warm_start(&self) -> Option<&[f32]>;

    /// Continue from a [`Planner::warm_start`] of a planner of the same config.
    fn set_warm_start(&mut self, warm: Option<&[f32]>) -> Result<(), PlanError>;

    /// Iterations the last plan ran: all its configured ones unless its time budget
    /// (`budget_ms`) cut it short. A planner that does not iterate ran one.
    fn iterations_done(&self) -> usize {
        1
    }
}

pub use mbpo_core::budget::Budget;

/// Copy a restored warm start `src` into `dst`, which must be as long.
pub(crate) fn restore_sequence(dst: &mut [f32], src: Option<&[f32]>) -> Result<(), PlanError> {
    match src {
        Some(s) if s.len() == dst.len() => {
            dst.copy_from_slice(s);
            Ok(())
        }
        Some(s) => Err(PlanError::Dims(format!(
            "planner warm start: {} values, this planner's horizon x actions is {}",
            s.len(),
            dst.len()
        ))),
        None => Err(PlanError::Dims(
            "planner warm start: missing (this planner always carries one)".into(),
        )),
    }
}

/// Copy `src` shifted by `k` steps of `a` values into itself, filling the tail with `fill`.
pub(crate) fn shift_sequence(seq: &mut [f32], a: usize, k: usize, fill: f32) {
    let len = seq.len();
    let k = (k * a).min(len);
    seq.copy_within(k.., 0);
    seq[len - k..].fill(fill);
}

/// Index of the largest value (first on ties); −∞/NaN never win over a finite value.
pub(crate) fn argmax(values: &[f32]) -> usize {
    let mut best = 0;
    for (i, &v) in values.iter().enumerate() {
        if v > values[best] || values[best].is_nan() {
            best = i;
        }
    }
    best
}
