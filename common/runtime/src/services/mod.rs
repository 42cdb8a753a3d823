//! Every role's service loop, generic over the transport: a binary under `services/` runs one
//! of them in its own process (`ipc::Service`); a test can run them all as threads of one
//! process (`local::Service`).

mod acting;
pub mod actor;
pub mod learner;
pub mod model_trainer;
pub mod planning;
pub mod rollout;

use mbpo_wire::Transport;

use crate::{Result, RoleKind, ServiceArgs};

/// The service loop of role `kind` on transport `S` (the one place that maps a role to its
/// loop: the service binaries and the in-process pipeline both ask here).
pub fn service_loop<S: Transport>(kind: RoleKind) -> fn(&ServiceArgs) -> Result<()> {
    match kind {
        RoleKind::Learner => learner::run::<S>,
        RoleKind::ModelTrainer => model_trainer::run::<S>,
        RoleKind::RolloutGenerator => rollout::run::<S>,
        RoleKind::Evaluator => actor::evaluate::<S>,
        RoleKind::Actor => actor::act::<S>,
        RoleKind::PlanningEvaluator => planning::evaluate::<S>,
        RoleKind::PlanningActor => planning::act::<S>,
    }
}
