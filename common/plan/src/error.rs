//! Errors of planning.

use mbpo_model::{PredictError, RolloutError};

/// Why a plan could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PlanError {
    /// The model rejected a prediction (lengths, member index).
    #[error("model prediction: {0}")]
    Predict(#[from] PredictError),
    /// The termination rule failed (a Python rule's exception, a model without a learned rule).
    #[error("termination rule: {0}")]
    Termination(#[from] RolloutError),
    /// A member slot outside the model's members.
    #[error("member slot {member} out of range: the model has {members} members to plan with")]
    Member {
        /// The slot asked for.
        member: usize,
        /// Members available.
        members: usize,
    },
    /// Observation, action or buffer dimensions disagree.
    #[error("{0}")]
    Dims(String),
    /// The gradient planner needs a model with input gradients.
    #[error(
        "the gradient planner needs a differentiable model (mean_step_recorded/mean_step_backward)"
    )]
    NotDifferentiable,
    /// A planner setting is out of range.
    #[error("planner setting `{key}` must be {expected}, found {found}")]
    Config {
        /// Dotted key, e.g. `cem.elites`.
        key: String,
        /// The allowed range, in words.
        expected: String,
        /// The value found.
        found: String,
    },
}
