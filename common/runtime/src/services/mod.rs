//! Every role of the pipeline as a worker on the one serving loop (`crate::serving`), generic
//! over the transport: a binary under `services/` serves one in its own process
//! (`ipc::Service`); a test can serve them all as threads of one process (`local::Service`).

mod acting;
pub mod actor;
mod data;
mod eval_points;
pub mod latent;
pub mod learner;
pub mod model_trainer;
pub mod planning;
pub mod rollout;
pub mod world_model;

use mbpo_wire::Transport;

use crate::serving::serve;
use crate::{Result, RoleKind, ServiceArgs};

/// What a role's process (or thread) runs: `serving::serve` of its worker.
pub type ServiceLoop = fn(&ServiceArgs) -> Result<()>;

/// The service loop of role `kind` on transport `S` (the one place that maps a role to its
/// worker: the service binaries and the in-process pipeline both ask here).
pub fn service_loop<S: Transport>(kind: RoleKind) -> ServiceLoop {
    use acting::Acting;
    match kind {
        RoleKind::Learner => serve::<S, learner::Learner<S>>,
        RoleKind::ModelTrainer => serve::<S, model_trainer::ModelTrainer<S>>,
        RoleKind::RolloutGenerator => serve::<S, rollout::RolloutGenerator<S>>,
        RoleKind::Evaluator => serve::<S, actor::Evaluator>,
        RoleKind::Actor => serve::<S, Acting<S, actor::PolicyActing>>,
        RoleKind::PlanningEvaluator => serve::<S, planning::ModelEvaluator>,
        RoleKind::PlanningActor => serve::<S, Acting<S, planning::ModelActing>>,
        RoleKind::WorldModelLearner => serve::<S, world_model::WorldModelLearnerWorker<S>>,
        RoleKind::LatentEvaluator => serve::<S, latent::LatentEvaluator>,
        RoleKind::LatentActor => serve::<S, Acting<S, latent::LatentActing>>,
    }
}
