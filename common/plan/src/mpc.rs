//! Model predictive control: plan, execute, observe, replan.
//!
//! Closed loop (MPC proper): at every env step plan from the real observation, execute the
//! first action, shift the plan by one step as the next plan's warm start. Open loop (for
//! comparison): plan once, execute all H actions without looking, then plan again from scratch;
//! it shows what replanning buys when the model is imperfect.

use crate::error::PlanError;
use crate::model::PlanningModel;
use crate::planner::Planner;
use mbpo_core::Rng;

/// A planner run as a controller.
pub struct Mpc {
    planner: Box<dyn Planner>,
    open_loop: bool,
    /// The open-loop plan being executed, and the index of its next action.
    plan: Vec<f32>,
    cursor: usize,
    plans: u64,
}

impl Mpc {
    /// Run `planner` closed loop (`open_loop` false) or open loop.
    pub fn new(planner: Box<dyn Planner>, open_loop: bool) -> Self {
        let len = planner.horizon() * planner.act_dim();
        let h = planner.horizon();
        Self {
            planner,
            open_loop,
            plan: vec![0.0; len],
            cursor: h,
            plans: 0,
        }
    }

    /// The planner.
    pub fn planner(&self) -> &dyn Planner {
        self.planner.as_ref()
    }

    /// Plans made so far.
    pub fn plans(&self) -> u64 {
        self.plans
    }

    /// The action (`act_dim`, in [−1, 1]) for the real observation `obs`; returns whether a
    /// plan was made for it.
    pub fn act(
        &mut self,
        model: &mut dyn PlanningModel,
        obs: &[f32],
        rng: &mut Rng,
        action: &mut [f32],
    ) -> Result<bool, PlanError> {
        let a = self.planner.act_dim();
        if action.len() != a || obs.len() != model.obs_dim() || model.act_dim() != a {
            return Err(PlanError::Dims(format!(
                "mpc: observation {} / action {} values for a model of {} / {} and a planner of {a}",
                obs.len(),
                action.len(),
                model.obs_dim(),
                model.act_dim()
            )));
        }
        if !self.open_loop {
            let plan = self.planner.plan(model, obs, rng)?;
            action.copy_from_slice(&plan[..a]);
            self.planner.shift(1);
            self.plans += 1;
            return Ok(true);
        }
        let planned = self.cursor >= self.planner.horizon();
        if planned {
            self.planner.reset();
            let plan = self.planner.plan(model, obs, rng)?;
            self.plan.copy_from_slice(plan);
            self.cursor = 0;
            self.plans += 1;
        }
        action.copy_from_slice(&self.plan[self.cursor * a..(self.cursor + 1) * a]);
        self.cursor += 1;
        Ok(planned)
    }

    /// A new episode: forget the warm start and any open-loop plan.
    pub fn reset(&mut self) {
        self.planner.reset();
        self.cursor = self.planner.horizon();
    }
}
