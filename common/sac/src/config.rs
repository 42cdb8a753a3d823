//! SAC hyper-parameters. Defaults are softlearning's SAC v2 as used by MBPO
//! (../shared/notes/mbpo-reference.md section 3).

use schemars::JsonSchema;
use serde::{Deserialize, Serialize};

/// Hyper-parameters of the SAC update.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SacConfig {
    /// Discount γ.
    pub gamma: f32,
    /// Polyak rate τ of the target critics (updated every step).
    pub tau: f32,
    /// Actor learning rate.
    pub actor_lr: f32,
    /// Critic learning rate.
    pub critic_lr: f32,
    /// Temperature learning rate.
    pub alpha_lr: f32,
    /// Minibatch size.
    pub batch_size: usize,
    /// Hidden widths of actor and critics (ReLU).
    pub hidden: Vec<usize>,
    /// Initial temperature α (softlearning: 1.0).
    pub init_alpha: f32,
    /// Learn α to hold the entropy at `target_entropy` (else α stays fixed).
    pub autotune_alpha: bool,
    /// Target entropy H̄; unset means −dim(A) (the action's dimension, negated).
    pub target_entropy: Option<f32>,
    /// Lower clamp of the actor's log σ.
    pub log_std_min: f32,
    /// Upper clamp of the actor's log σ.
    pub log_std_max: f32,
    /// Threads one update runs on (≥ 1; at most the batch size is used). The critics run one
    /// per thread (two at most), and one update's critic step gives the same bits for any
    /// count given the same actor; the actor's rows are split into that many shards whose
    /// gradients are added in a fixed order, so the actor's results, and through it a run's,
    /// are deterministic for a given thread count but differ in rounding between counts.
    pub threads: usize,
    /// LayerNorm after each hidden layer of the critics, before the ReLU (not in SAC or MBPO;
    /// off by default). At many updates per env step a critic's values can run away on
    /// state-actions its data never had (imagined ones, here); normalising the hidden layers
    /// bounds them (Ball et al. 2023, RLPD; Hiraoka et al. 2022, DroQ). The actor is unchanged.
    pub critic_layer_norm: bool,
}

impl Default for SacConfig {
    fn default() -> Self {
        Self {
            gamma: 0.99,
            tau: 5e-3,
            actor_lr: 3e-4,
            critic_lr: 3e-4,
            alpha_lr: 3e-4,
            batch_size: 256,
            hidden: vec![256, 256],
            init_alpha: 1.0,
            autotune_alpha: true,
            target_entropy: None,
            log_std_min: -20.0,
            log_std_max: 2.0,
            threads: 1,
            critic_layer_norm: false,
        }
    }
}
