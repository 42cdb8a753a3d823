//! One error enum per operation on the model.

/// Why [`crate::ProbabilisticEnsemble::train`] rejected its data.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum TrainError {
    /// The batch's observation or action width differs from the model's.
    #[error("training data has obs_dim {found_obs} / act_dim {found_act}, the model has {obs_dim} / {act_dim}")]
    Dims {
        /// Model observation width.
        obs_dim: usize,
        /// Model action width.
        act_dim: usize,
        /// Data observation width.
        found_obs: usize,
        /// Data action width.
        found_act: usize,
    },
    /// A column of the batch is shorter than `len` rows require.
    #[error("training batch field `{field}` has {found} values, {expected} needed for {len} rows")]
    Ragged {
        /// Field name.
        field: &'static str,
        /// Values present.
        found: usize,
        /// Values needed.
        expected: usize,
        /// Rows claimed by `Batch::len`.
        len: usize,
    },
    /// Too few transitions for a non-empty holdout and training split.
    #[error("{found} transitions are too few to train on: the holdout (min(int({ratio} N), max)) and the training split must both be non-empty; need at least {required}")]
    TooFewTransitions {
        /// Transitions given.
        found: usize,
        /// Smallest usable count under the configured holdout ratio.
        required: usize,
        /// Configured holdout ratio.
        ratio: f64,
    },
    /// A value in the data is NaN or infinite.
    #[error("training data row {row} has a non-finite value in `{field}`")]
    NonFinite {
        /// Row index.
        row: usize,
        /// Field name.
        field: &'static str,
    },
}

/// Why a prediction or evaluation call was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum PredictError {
    /// An input or output slice has the wrong length for `n` samples.
    #[error("`{what}` has {found} values, {expected} needed")]
    Length {
        /// Argument name.
        what: &'static str,
        /// Values needed.
        expected: usize,
        /// Values given.
        found: usize,
    },
    /// A member index is out of range.
    #[error("member index {member} out of range (the ensemble has {members})")]
    Member {
        /// Offending index.
        member: usize,
        /// Ensemble size.
        members: usize,
    },
    /// The data's observation or action width differs from the model's.
    #[error(
        "data has obs_dim {found_obs} / act_dim {found_act}, the model has {obs_dim} / {act_dim}"
    )]
    Dims {
        /// Model observation width.
        obs_dim: usize,
        /// Model action width.
        act_dim: usize,
        /// Data observation width.
        found_obs: usize,
        /// Data action width.
        found_act: usize,
    },
}

/// Why [`crate::ProbabilisticEnsemble::rollout`] was rejected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum RolloutError {
    /// `start_obs` does not hold `n` observations.
    #[error("start_obs has {found} values, {n} rollouts x obs_dim {obs_dim} = {expected} needed")]
    StartObs {
        /// Rollouts requested.
        n: usize,
        /// Model observation width.
        obs_dim: usize,
        /// Values needed.
        expected: usize,
        /// Values given.
        found: usize,
    },
    /// The output buffer stores transitions of another shape.
    #[error("model buffer holds obs_dim {found_obs} / act_dim {found_act}, the model has {obs_dim} / {act_dim}")]
    BufferDims {
        /// Model observation width.
        obs_dim: usize,
        /// Model action width.
        act_dim: usize,
        /// Buffer observation width.
        found_obs: usize,
        /// Buffer action width.
        found_act: usize,
    },
    /// The batch termination rule failed.
    #[error("the termination rule failed: {0}")]
    Termination(String),
    /// No termination rule was given and the model learns none.
    #[error("no termination rule: give the task's, or build the model with learn_termination")]
    NoTerminationRule,
    /// The elites' predictions behind a masked rollout failed.
    #[error("scoring the imagined transitions for the mask: {0}")]
    Mask(PredictError),
}

/// Why parameters or weights could not be loaded into a model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ParamsError {
    /// The number of parameters differs from the model's.
    #[error("{found} parameters given, the model has {expected}")]
    Length {
        /// Model parameter count.
        expected: usize,
        /// Count given.
        found: usize,
    },
    /// The weights were produced by a model of another architecture.
    #[error("weights have layout hash {found:#018x}, this model has {expected:#018x} ({layout}); they come from a model of another architecture")]
    Layout {
        /// This model's layout hash.
        expected: u64,
        /// The weights' layout hash.
        found: u64,
        /// This model's layout, described.
        layout: String,
    },
    /// The normaliser or elite list does not fit the model.
    #[error("weights are inconsistent with the model: {0}")]
    Inconsistent(String),
}
