//! Planning in a learned latent space, after TD-MPC2 (Hansen, Su, Wang, ICLR 2024): an encoder
//! maps an observation to a latent state z normalised by SimNorm, latent dynamics predict the
//! next z from (z, a), a reward head and an ensemble of Q heads read (z, a) as two-hot
//! classifications, and a policy prior proposes actions; MPPI plans over the latent with the
//! value at the horizon.
//!
//! This crate holds the world model's pieces, each checked against finite differences:
//! * [`bench`]: what one env step costs (a plan and an update), for `mbpo bench tdmpc-step`.
//! * [`elementwise`]: Mish, LayerNorm and SimNorm, forward and backward.
//! * [`mppi`]: the planner, MPPI over latent action sequences with the value at the horizon.
//! * [`normed_mlp`]: the network every part is made of (Linear → LayerNorm → Mish layers; a
//!   Linear or SimNorm output).
//! * [`policy`]: the policy prior: sampling, the TD targets, the policy loss.
//! * [`replay`]: real transitions as episodes, sampled as H-step subsequences inside one.
//! * [`two_hot`]: symlog, two-hot encodings and their cross-entropy (rewards and values).
//! * [`update`]: one TD-MPC2 update (targets, the model's and the policy's Adam steps, Polyak).
//! * [`world_model`]: the encoder, dynamics, reward, Q and policy networks in one parameter
//!   vector, and the loss of a sampled subsequence (consistency, reward, value) with its
//!   gradient.
//!
//! Must not hold anything of the pipeline or a run directory: it is a numeric library, like
//! `mbpo-model` for the raw-state ensemble.
#![warn(missing_docs)]

pub mod bench;
pub mod elementwise;
pub mod mppi;
pub mod normed_mlp;
pub mod policy;
pub mod replay;
pub mod two_hot;
pub mod update;
pub mod world_model;

pub use normed_mlp::{Head, NormedCache, NormedMlp};
pub use replay::{EpisodeBuffer, EpisodeLinks};
pub use two_hot::{symexp, symlog, TwoHot};
pub use world_model::{LossWorkspace, Losses, Sequences, WorldModel, WorldModelConfig};
