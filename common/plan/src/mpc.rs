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
use serde::{Deserialize, Serialize};

/// Everything of an [`Mpc`] that carries from one env step to the next: what a checkpoint
/// keeps so that a resumed run plans exactly as an uninterrupted one.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MpcState {
    /// The planner's warm start ([`Planner::warm_start`]).
    pub warm_start: Option<Vec<f32>>,
    /// The open-loop plan being executed (open loop only; `H x A`).
    pub plan: Vec<f32>,
    /// Index of the open-loop plan's next action (H: plan anew).
    pub cursor: usize,
    /// Plans made so far.
    pub plans: u64,
}

/// A planner run as a controller.
pub struct Mpc {
    planner: Box<dyn Planner>,
    open_loop: bool,
    /// The open-loop plan being executed, and the index of its next action.
    plan: Vec<f32>,
    cursor: usize,
    plans: u64,
    /// Iterations per plan since this controller was made.
    iterations: IterationCount,
}

/// Iterations per plan: fewest, most, their sum and the plans counted.
#[derive(Debug, Clone, Copy)]
struct IterationCount {
    fewest: usize,
    most: usize,
    sum: u64,
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
            iterations: IterationCount {
                fewest: usize::MAX,
                most: 0,
                sum: 0,
                plans: 0,
            },
        }
    }

    /// Iterations per plan since this controller was made (a resumed one: since the resume):
    /// fewest, mean, most; `None` before the first plan. Below the planner's `iterations` when
    /// its time budget (`budget_ms`) cut plans short.
    pub fn iterations_per_plan(&self) -> Option<(usize, f64, usize)> {
        let c = &self.iterations;
        (c.plans > 0).then(|| (c.fewest, c.sum as f64 / c.plans as f64, c.most))
    }

    fn count_iterations(&mut self) {
        let k = self.planner.iterations_done();
        let c = &mut self.iterations;
        (c.fewest, c.most) = (c.fewest.min(k), c.most.max(k));
        (c.sum, c.plans) = (c.sum + k as u64, c.plans + 1);
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
            self.count_iterations();
            return Ok(true);
        }
        let planned = self.cursor >= self.planner.horizon();
        if planned {
            self.planner.reset();
            let plan = self.planner.plan(model, obs, rng)?;
            self.plan.copy_from_slice(plan);
            self.cursor = 0;
            self.plans += 1;
            self.count_iterations();
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

    /// The state a checkpoint keeps (allocates).
    pub fn state(&self) -> MpcState {
        MpcState {
            warm_start: self.planner.warm_start().map(<[f32]>::to_vec),
            plan: self.plan.clone(),
            cursor: self.cursor,
            plans: self.plans,
        }
    }

    /// Continue from the [`Mpc::state`] of a controller of the same config; a state of another
    /// shape is an error naming what does not fit.
    pub fn restore(&mut self, state: MpcState) -> Result<(), PlanError> {
        if state.plan.len() != self.plan.len() || state.cursor > self.planner.horizon() {
            return Err(PlanError::Dims(format!(
                "mpc state: a plan of {} values at action {}, this controller plans {} values \
                 over {} steps",
                state.plan.len(),
                state.cursor,
                self.plan.len(),
                self.planner.horizon()
            )));
        }
        self.planner.set_warm_start(state.warm_start.as_deref())?;
        self.plan = state.plan;
        self.cursor = state.cursor;
        self.plans = state.plans;
        Ok(())
    }
}
