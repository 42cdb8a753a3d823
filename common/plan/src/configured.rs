//! [`build`]: the planner a config names. Kept apart from the [`Planner`] interface, which
//! every planner implements, so that the interface does not depend on the planners.

use crate::cem::Cem;
use crate::config::{PlannerConfig, PlannerKind};
use crate::error::PlanError;
use crate::grad::GradientPlanner;
use crate::mppi::Mppi;
use crate::planner::Planner;
use crate::random::RandomShooting;

/// The planner `cfg.kind` for actions of width `act_dim`.
pub fn build(cfg: &PlannerConfig, act_dim: usize) -> Result<Box<dyn Planner>, PlanError> {
    cfg.validate()?;
    if act_dim == 0 {
        return Err(PlanError::Dims(
            "actions must have at least one dimension".into(),
        ));
    }
    Ok(match cfg.kind {
        PlannerKind::Random => Box::new(RandomShooting::new(cfg, act_dim)),
        PlannerKind::Cem => Box::new(Cem::new(cfg, act_dim)),
        PlannerKind::Mppi => Box::new(Mppi::new(cfg, act_dim)),
        PlannerKind::Grad => Box::new(GradientPlanner::new(cfg, act_dim)),
    })
}
