//! [`ModelConfig`]: every hyper-parameter of the dynamics model, with MBPO's values as defaults.

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// Most threads a training call may use ([`ModelConfig::threads`]).
pub const MAX_THREADS: usize = 64;

/// Hyper-parameters of the probabilistic ensemble and of its training.
///
/// Defaults are those of the MBPO code (`mbpo/models/constructor.py`, `bnn.py`), identical to
/// the PETS HalfCheetah model. Deserialises from a partial table: missing fields keep their
/// defaults, unknown fields are an error (a typo must not silently fall back to a default).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ModelConfig {
    /// Ensemble size B ("num_networks", 7).
    pub members: usize,
    /// Number of elites used for predictions ("num_elites", 5): the members with the lowest
    /// holdout MSE after each training call.
    pub elites: usize,
    /// Hidden widths ("hidden_dim", 4 x 200; Humanoid uses 400). Activation: SiLU ("swish").
    pub hidden: Vec<usize>,
    /// L2 weight decay per dense layer, input to output ("weight_decay" of each `FC`; 2.5e-5,
    /// 5e-5, 7.5e-5, 7.5e-5, 1e-4). The loss gets `wd · ½‖W‖²` per layer (TensorFlow's
    /// `l2_loss`); biases are not decayed. Length must be `hidden.len() + 1`.
    pub weight_decay: Vec<f32>,
    /// Adam learning rate (1e-3). Adam's other constants are the usual (0.9, 0.999, 1e-8).
    pub lr: f32,
    /// Minibatch rows per member per gradient step ("batch_size", 256).
    pub batch_size: usize,
    /// Fraction of each training call's data held out for early stopping ("holdout_ratio", 0.2).
    pub holdout_ratio: f64,
    /// Cap on the holdout size ("max_logging", 5000).
    pub max_holdout: usize,
    /// A member's snapshot is taken when its holdout MSE improves by more than this fraction of
    /// its best so far (0.01, the 1 % rule of `_save_best`).
    pub improvement_threshold: f32,
    /// Training stops once more than this many epochs in a row improved no member
    /// ("max_epochs_since_update", 5).
    pub max_epochs_since_update: usize,
    /// Optional cap on the epochs of one training call ("max_epochs"; MBPO: none).
    pub max_epochs: Option<usize>,
    /// Optional wall-clock cap on one training call, in seconds ("max_model_t"; MBPO: none).
    /// Checked after each epoch, so at least one epoch runs. A time cap makes training depend
    /// on machine speed, so it breaks run-to-run reproducibility; leave it unset for that.
    pub max_train_seconds: Option<f64>,
    /// Initial upper soft bound on every output log-variance ("max_logvar", 0.5).
    pub init_max_logvar: f32,
    /// Initial lower soft bound on every output log-variance ("min_logvar", −10).
    pub init_min_logvar: f32,
    /// Whether the bounds are trained (MBPO/PETS: yes; mbrl-lib and Xingyu-Lin's port freeze them).
    pub learn_logvar_bounds: bool,
    /// Coefficient of the bound regulariser `c · (Σ max_logvar − Σ min_logvar)` (0.01).
    pub logvar_bound_penalty: f32,
    /// Threads the model's training calls, sampled predictions and rollouts run on (1).
    /// Training: members are independent until the shared bounds and Adam, so each thread
    /// takes a contiguous block of members, or of half minibatches when the threads do not
    /// divide the members (7 members on 2 threads: 3½ each instead of 4 and 3); a member
    /// whose halves land on one thread runs whole, so only members that a block boundary cuts
    /// run in halves. Every sum keeps member order, so the result is bit-identical for every
    /// thread count that cuts the same members (with 7 members: 1, 4 and 7-13 cut none; 2 cuts
    /// member 3; 3 member 2; 5 and 6 members 1 and 4; 14 or more all); the ways differ in f32
    /// rounding only. Sampled predictions and rollouts give the same bits for every count.
    /// Threads beyond the units of work would have none and are not started. Not a
    /// hyper-parameter of MBPO: a machine setting (the pipeline's model trainer can use a core
    /// the learner leaves idle).
    pub threads: usize,
    /// Learn the termination rule of model rollouts with the model (a
    /// [`crate::TerminationClassifier`] trained after the ensemble on the same data). Not a key
    /// of the config file: the experiment's `termination = "learned"` sets it.
    #[serde(skip)]
    pub learn_termination: bool,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            members: 7,
            elites: 5,
            hidden: vec![200; 4],
            weight_decay: vec![2.5e-5, 5e-5, 7.5e-5, 7.5e-5, 1e-4],
            lr: 1e-3,
            batch_size: 256,
            holdout_ratio: 0.2,
            max_holdout: 5000,
            improvement_threshold: 0.01,
            max_epochs_since_update: 5,
            max_epochs: None,
            max_train_seconds: None,
            init_max_logvar: 0.5,
            init_min_logvar: -10.0,
            learn_logvar_bounds: true,
            logvar_bound_penalty: 0.01,
            threads: 1,
            learn_termination: false,
        }
    }
}

/// Why a [`ModelConfig`] cannot build a model.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ModelConfigError {
    /// `members` is zero.
    #[error("the ensemble needs at least one member (members = 0)")]
    NoMembers,
    /// `elites` is zero or exceeds `members`.
    #[error("elites must be between 1 and members ({members}), got {elites}")]
    Elites {
        /// Configured elites.
        elites: usize,
        /// Configured members.
        members: usize,
    },
    /// A hidden width is zero.
    #[error("hidden widths must be positive, got {0:?}")]
    Hidden(Vec<usize>),
    /// `weight_decay` does not have one entry per dense layer.
    #[error("weight_decay needs one value per dense layer ({layers} = hidden layers + output), got {found}")]
    WeightDecayLen {
        /// Dense layers.
        layers: usize,
        /// Values given.
        found: usize,
    },
    /// Observation or action dimension is zero.
    #[error("observation and action dimensions must be positive (obs {obs_dim}, act {act_dim})")]
    Dims {
        /// Observation dimension.
        obs_dim: usize,
        /// Action dimension.
        act_dim: usize,
    },
    /// A numeric setting is out of its range.
    #[error("{field} = {value} is out of range ({expected})")]
    OutOfRange {
        /// Field name.
        field: &'static str,
        /// Offending value.
        value: f64,
        /// What is accepted.
        expected: &'static str,
    },
}

impl ModelConfigError {
    /// The offending setting (a field of [`ModelConfig`]; `dims` for the environment's), what
    /// it accepts and the value found: what a config file's error names (`model.<field>`).
    pub fn parts(&self) -> (&'static str, String, String) {
        match self {
            Self::NoMembers => ("members", "at least 1".into(), "0".into()),
            Self::Elites { elites, members } => (
                "elites",
                format!("between 1 and members ({members})"),
                elites.to_string(),
            ),
            Self::Hidden(h) => ("hidden", "positive widths".into(), format!("{h:?}")),
            Self::WeightDecayLen { layers, found } => (
                "weight_decay",
                format!("one value per dense layer ({layers} = hidden layers + output)"),
                format!("{found} values"),
            ),
            Self::Dims { obs_dim, act_dim } => (
                "dims",
                "positive observation and action dimensions".into(),
                format!("obs {obs_dim}, act {act_dim}"),
            ),
            Self::OutOfRange {
                field,
                value,
                expected,
            } => (field, (*expected).into(), value.to_string()),
        }
    }
}

impl ModelConfig {
    /// How many of `n` transitions a training call holds out for early stopping:
    /// `min(int(holdout_ratio n), max_holdout)`, as the paper's code truncates it.
    pub fn holdout_size(&self, n: usize) -> usize {
        ((n as f64 * self.holdout_ratio) as usize).min(self.max_holdout)
    }

    /// Whether `n` transitions can be split into a non-empty holdout and a non-empty training
    /// split: the one rule for "enough data to train".
    pub fn can_train_on(&self, n: usize) -> bool {
        let h = self.holdout_size(n);
        h >= 1 && n > h
    }

    /// The fewest transitions a training call accepts (5 with the paper's holdout ratio 0.2);
    /// `usize::MAX` for settings that never split (caught by [`ModelConfig::validate`]).
    pub fn min_training_transitions(&self) -> usize {
        (2..=1_000_000)
            .find(|&n| self.can_train_on(n))
            .unwrap_or(usize::MAX)
    }

    /// Check the settings for a model with the given dimensions.
    pub fn validate(&self, obs_dim: usize, act_dim: usize) -> Result<(), ModelConfigError> {
        if obs_dim == 0 || act_dim == 0 {
            return Err(ModelConfigError::Dims { obs_dim, act_dim });
        }
        if self.members == 0 {
            return Err(ModelConfigError::NoMembers);
        }
        if self.elites == 0 || self.elites > self.members {
            return Err(ModelConfigError::Elites {
                elites: self.elites,
                members: self.members,
            });
        }
        if self.hidden.contains(&0) {
            return Err(ModelConfigError::Hidden(self.hidden.clone()));
        }
        if self.weight_decay.len() != self.hidden.len() + 1 {
            return Err(ModelConfigError::WeightDecayLen {
                layers: self.hidden.len() + 1,
                found: self.weight_decay.len(),
            });
        }
        let range = |field, value: f64, ok: bool, expected| {
            if ok {
                Ok(())
            } else {
                Err(ModelConfigError::OutOfRange {
                    field,
                    value,
                    expected,
                })
            }
        };
        range(
            "lr",
            self.lr as f64,
            self.lr >= 0.0 && self.lr.is_finite(),
            ">= 0",
        )?;
        range(
            "batch_size",
            self.batch_size as f64,
            self.batch_size > 0,
            "> 0",
        )?;
        range(
            "threads",
            self.threads as f64,
            (1..=MAX_THREADS).contains(&self.threads),
            "1 to 64",
        )?;
        range(
            "holdout_ratio",
            self.holdout_ratio,
            self.holdout_ratio > 0.0 && self.holdout_ratio < 1.0,
            "in (0, 1)",
        )?;
        range(
            "max_holdout",
            self.max_holdout as f64,
            self.max_holdout > 0,
            "> 0",
        )?;
        range(
            "init_min_logvar",
            self.init_min_logvar as f64,
            self.init_min_logvar < self.init_max_logvar,
            "< init_max_logvar",
        )?;
        for &wd in &self.weight_decay {
            range("weight_decay", wd as f64, wd >= 0.0, ">= 0")?;
        }
        if let Some(s) = self.max_train_seconds {
            range("max_train_seconds", s, s > 0.0, "> 0")?;
        }
        if let Some(e) = self.max_epochs {
            range("max_epochs", e as f64, e > 0, "> 0")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_are_mbpo_and_validate() {
        let c = ModelConfig::default();
        assert_eq!((c.members, c.elites, c.batch_size), (7, 5, 256));
        assert_eq!(c.hidden, vec![200; 4]);
        assert_eq!(c.weight_decay, vec![2.5e-5, 5e-5, 7.5e-5, 7.5e-5, 1e-4]);
        c.validate(17, 6).unwrap();
    }

    #[test]
    fn holdout_is_a_fifth_capped_at_5000() {
        let c = ModelConfig::default();
        assert_eq!(c.holdout_size(10_000), 2000);
        assert_eq!(c.holdout_size(1_000_000), 5000);
        assert_eq!(c.holdout_size(9), 1); // int(1.8)
        assert_eq!(c.holdout_size(4), 0);
        assert!(!c.can_train_on(4) && c.can_train_on(5));
        assert_eq!(c.min_training_transitions(), 5);
    }

    #[test]
    fn deserialises_a_partial_table_and_rejects_typos() {
        let c: ModelConfig =
            serde_json::from_str(r#"{"hidden": [400, 400, 400, 400], "max_epochs": 50}"#).unwrap();
        assert_eq!(c.hidden, vec![400; 4]);
        assert_eq!(c.max_epochs, Some(50));
        assert_eq!((c.members, c.lr), (7, 1e-3));
        let err = serde_json::from_str::<ModelConfig>(r#"{"hiden": [400]}"#).unwrap_err();
        assert!(err.to_string().contains("hiden"), "{err}");
    }

    #[test]
    fn bad_settings_are_named() {
        let c = ModelConfig {
            elites: 8,
            ..Default::default()
        };
        assert!(matches!(
            c.validate(3, 1),
            Err(ModelConfigError::Elites { elites: 8, .. })
        ));
        let c = ModelConfig {
            hidden: vec![64, 64],
            ..Default::default()
        };
        let err = c.validate(3, 1).unwrap_err();
        assert!(err.to_string().contains("weight_decay"), "{err}");
    }
}
