//! The checkpoint file of a SAC run (`mbpo train` with `algo = "sac"`): what the SAC trainer
//! writes and resumes from, and where a run's newest policy is read from while it has not
//! completed (`policy_file`).

use crate::actor::EnvActorState;
use crate::checkpoint;
use crate::error::TrainError;
use crate::eval::EvaluatorState;
use mbpo_core::{ReplaySnapshot, Rng};
use mbpo_sac::{SacState, SacStats};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The checkpoint file of a SAC run.
pub const SAC_CHECKPOINT_FILE: &str = "sac-trainer.ckpt";
pub(crate) const SAC_CHECKPOINT_KIND: &str = "mbpo.sac-trainer";

/// Everything a SAC run needs to continue exactly.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub(crate) struct SacRunState {
    pub(crate) actor: EnvActorState,
    pub(crate) sac: SacState,
    pub(crate) replay: ReplaySnapshot,
    pub(crate) sample_rng: Rng,
    pub(crate) update_rng: Rng,
    pub(crate) stats: SacStats,
    pub(crate) evaluator: EvaluatorState,
}

/// The actor parameters stored in a SAC run's checkpoint directory.
pub fn checkpointed_actor_params(dir: &Path) -> Result<Vec<f32>, TrainError> {
    let state: SacRunState = checkpoint::read(&dir.join(SAC_CHECKPOINT_FILE), SAC_CHECKPOINT_KIND)?;
    Ok(state.sac.actor_params)
}
