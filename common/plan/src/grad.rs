//! Gradient-based planning: Adam ascent on the action sequence, backpropagating the predicted
//! return through the model (e.g. Srinivas et al. 2018 "Universal Planning Networks";
//! Chua et al.'s ensemble used as a differentiable simulator).
//!
//! The objective of sequence s is the mean over its particles of the predicted return of the
//! **mean** trajectories (each particle bound to a member, no sampling noise, so the objective
//! is a deterministic, differentiable function of the actions):
//!
//! ```text
//! J(a) = 1/P Σ_p Σ_t alive_t^p · r_t^p,    s_{t+1}^p = μ_{m(p)}(s_t^p, a_t),  s_0^p = s
//! ```
//!
//! Its gradient is one backward sweep (backpropagation through time):
//!
//! ```text
//! λ_H = 0
//! for t = H−1 … 0:   (∂J/∂s_t, ∂J/∂a_t) = backward of step t given ∂J/∂r_t = alive_t/P and λ_{t+1}
//!                    λ_t = ∂J/∂s_t
//! ∂J/∂a_t(s) = Σ_p ∂J/∂a_t of sequence s's particle rows
//! ```
//!
//! A plan runs `sequences` optimisations in parallel (the previous plan shifted by one step, the
//! rest uniform random restarts: the objective is not concave), `iterations` Adam steps each,
//! projecting onto the box after every step, and returns the best sequence seen.

use crate::config::{GradConfig, PlannerConfig};
use crate::error::PlanError;
use crate::model::PlanningModel;
use crate::planner::{argmax, restore_sequence, shift_sequence, Budget, Planner};
use crate::sampler::deal_members;
use mbpo_core::rng::uniform_range_f32;
use mbpo_core::Rng;

/// Adam's constants (Kingma & Ba 2015).
const BETA1: f32 = 0.9;
const BETA2: f32 = 0.999;
const EPS: f32 = 1e-8;

/// Adam on action sequences through a differentiable [`PlanningModel`].
#[derive(Debug, Clone)]
pub struct GradientPlanner {
    horizon: usize,
    act_dim: usize,
    particles: usize,
    cfg: GradConfig,
    particle_member: Vec<usize>,
    row_member: Vec<usize>,
    /// S x H x A: the sequences being optimised, Adam's moments, the gradient.
    seqs: Vec<f32>,
    m: Vec<f32>,
    v: Vec<f32>,
    grads: Vec<f32>,
    returns: Vec<f32>,
    /// The previous plan, shifted (warm start), and whether there is one.
    warm: Vec<f32>,
    has_warm: bool,
    best: Vec<f32>,
    best_return: f32,
    tape: Tape,
    budget: Option<std::time::Duration>,
    iterations_done: usize,
}

/// Forward values and backward scratch of one objective evaluation.
#[derive(Debug, Clone, Default)]
struct Tape {
    /// States s_0 … s_H of every row (`(H + 1) x R x O`).
    obs: Vec<f32>,
    /// Actions a_t of every row (`H x R x A`).
    act: Vec<f32>,
    reward: Vec<f32>,
    /// alive_t of every row (`H x R`): 1 until the row's episode has terminated.
    alive: Vec<f32>,
    /// Scratch: done of the previous step's transitions.
    done: Vec<bool>,
    d_reward: Vec<f32>,
    lambda: Vec<f32>,
    d_obs: Vec<f32>,
    d_act: Vec<f32>,
    total: Vec<f64>,
}

impl GradientPlanner {
    /// The gradient planner per `cfg` (`grad.*`, `horizon`, `particles`).
    pub fn new(cfg: &PlannerConfig, act_dim: usize) -> Self {
        let (h, s) = (cfg.horizon, cfg.grad.sequences);
        let len = s * h * act_dim;
        Self {
            horizon: h,
            act_dim,
            particles: cfg.particles,
            cfg: cfg.grad.clone(),
            particle_member: Vec::new(),
            row_member: Vec::new(),
            seqs: vec![0.0; len],
            m: vec![0.0; len],
            v: vec![0.0; len],
            grads: vec![0.0; len],
            returns: vec![0.0; s],
            warm: vec![0.0; h * act_dim],
            has_warm: false,
            best: vec![0.0; h * act_dim],
            best_return: f32::NEG_INFINITY,
            tape: Tape::default(),
            budget: cfg.budget(),
            iterations_done: 0,
        }
    }

    /// Bind particles to members (a fresh balanced random assignment, as trajectory sampling).
    pub fn bind_particles(&mut self, members: usize, rng: &mut Rng) {
        deal_members(self.particles, members, rng, &mut self.particle_member);
    }

    /// J and ∂J/∂a of each of the `returns.len()` sequences in `seqs` (`S x H x A`) from `obs0`
    /// (see the module docs); `grads` is `S x H x A`. Uses the current particle binding
    /// ([`GradientPlanner::bind_particles`]).
    pub fn objective_and_gradient(
        &mut self,
        model: &mut dyn PlanningModel,
        obs0: &[f32],
        seqs: &[f32],
        returns: &mut [f32],
        grads: &mut [f32],
    ) -> Result<(), PlanError> {
        let (h, a, p) = (self.horizon, self.act_dim, self.particles);
        let s = returns.len();
        let o = model.obs_dim();
        if obs0.len() != o || seqs.len() != s * h * a || grads.len() != seqs.len() {
            return Err(PlanError::Dims(format!(
                "gradient planner: obs {} (expected {o}), sequences {} and gradients {} (expected {s} x {h} x {a})",
                obs0.len(),
                seqs.len(),
                grads.len()
            )));
        }
        if self.particle_member.len() != p {
            return Err(PlanError::Dims("bind_particles was not called".into()));
        }
        let rows = s * p;
        self.row_member.clear();
        self.row_member
            .extend((0..rows).map(|r| self.particle_member[r % p]));
        self.forward(model, obs0, seqs, rows)?;
        for (c, ret) in returns.iter_mut().enumerate() {
            let sum: f64 = self.tape.total[c * p..(c + 1) * p].iter().sum();
            *ret = (sum / p as f64) as f32;
        }
        self.backward(model, rows, grads)
    }

    /// Roll every row's mean trajectory forward, recording each step in the model.
    fn forward(
        &mut self,
        model: &mut dyn PlanningModel,
        obs0: &[f32],
        seqs: &[f32],
        rows: usize,
    ) -> Result<(), PlanError> {
        let (h, a, p, o) = (self.horizon, self.act_dim, self.particles, model.obs_dim());
        let t = &mut self.tape;
        t.obs.resize((h + 1) * rows * o, 0.0);
        t.act.resize(h * rows * a, 0.0);
        t.reward.resize(rows, 0.0);
        t.alive.resize(h * rows, 0.0);
        t.done.resize(rows, false);
        t.total.clear();
        t.total.resize(rows, 0.0);
        for r in 0..rows {
            t.obs[r * o..(r + 1) * o].copy_from_slice(obs0);
        }
        for step in 0..h {
            for r in 0..rows {
                let c = r / p;
                let src = &seqs[(c * h + step) * a..(c * h + step + 1) * a];
                t.act[(step * rows + r) * a..(step * rows + r + 1) * a].copy_from_slice(src);
            }
            let (now, next) = t.obs.split_at_mut((step + 1) * rows * o);
            let s_t = &now[step * rows * o..];
            let s_next = &mut next[..rows * o];
            let a_t = &t.act[step * rows * a..(step + 1) * rows * a];
            model.mean_step_recorded(step, s_t, a_t, &self.row_member, &mut t.reward, s_next)?;
            if step > 0 {
                model.terminated(
                    &t.obs[(step - 1) * rows * o..step * rows * o],
                    &t.act[(step - 1) * rows * a..step * rows * a],
                    &t.obs[step * rows * o..(step + 1) * rows * o],
                    rows,
                    &mut t.done[..rows],
                )?;
            }
            for r in 0..rows {
                let was_alive = step == 0 || (t.alive[(step - 1) * rows + r] > 0.0 && !t.done[r]);
                t.alive[step * rows + r] = if was_alive { 1.0 } else { 0.0 };
                if was_alive {
                    t.total[r] += t.reward[r] as f64;
                }
            }
        }
        Ok(())
    }

    /// Backpropagation through time; writes ∂J/∂a summed over each sequence's particles.
    fn backward(
        &mut self,
        model: &mut dyn PlanningModel,
        rows: usize,
        grads: &mut [f32],
    ) -> Result<(), PlanError> {
        let (h, a, p, o) = (self.horizon, self.act_dim, self.particles, model.obs_dim());
        let t = &mut self.tape;
        t.lambda.clear();
        t.lambda.resize(rows * o, 0.0);
        t.d_obs.resize(rows * o, 0.0);
        t.d_act.resize(rows * a, 0.0);
        t.d_reward.resize(rows, 0.0);
        grads.fill(0.0);
        let inv_p = 1.0 / p as f32;
        for step in (0..h).rev() {
            for (d, &alive) in t
                .d_reward
                .iter_mut()
                .zip(&t.alive[step * rows..(step + 1) * rows])
            {
                *d = alive * inv_p;
            }
            model.mean_step_backward(step, &t.d_reward, &t.lambda, &mut t.d_obs, &mut t.d_act)?;
            std::mem::swap(&mut t.lambda, &mut t.d_obs);
            for r in 0..rows {
                let c = r / p;
                let g = &mut grads[(c * h + step) * a..(c * h + step + 1) * a];
                for (gj, &dj) in g.iter_mut().zip(&t.d_act[r * a..(r + 1) * a]) {
                    *gj += dj;
                }
            }
        }
        Ok(())
    }

    /// Step 1: the previous plan shifted (or zeros), then uniform random restarts; fresh Adam.
    fn initialise(&mut self, rng: &mut Rng) {
        let len = self.horizon * self.act_dim;
        if self.has_warm {
            self.seqs[..len].copy_from_slice(&self.warm);
        } else {
            self.seqs[..len].fill(0.0);
        }
        self.seqs[len..]
            .iter_mut()
            .for_each(|v| *v = uniform_range_f32(rng, -1.0, 1.0));
        self.m.fill(0.0);
        self.v.fill(0.0);
    }

    /// Step 2: one projected Adam ascent step (`k` is the 1-based step count).
    fn adam_ascent(&mut self, k: i32) {
        let lr = self.cfg.lr;
        let (c1, c2) = (1.0 - BETA1.powi(k), 1.0 - BETA2.powi(k));
        for (((x, m), v), &g) in self
            .seqs
            .iter_mut()
            .zip(&mut self.m)
            .zip(&mut self.v)
            .zip(&self.grads)
        {
            *m = BETA1 * *m + (1.0 - BETA1) * g;
            *v = BETA2 * *v + (1.0 - BETA2) * g * g;
            let step = lr * (*m / c1) / ((*v / c2).sqrt() + EPS);
            *x = (*x + step).clamp(-1.0, 1.0);
        }
    }

    /// Step 3: remember the best sequence seen so far.
    fn keep_best(&mut self) {
        let b = argmax(&self.returns);
        if self.returns[b] > self.best_return {
            let len = self.horizon * self.act_dim;
            self.best_return = self.returns[b];
            self.best
                .copy_from_slice(&self.seqs[b * len..(b + 1) * len]);
        }
    }

    /// Evaluate J and its gradient at the current sequences.
    fn evaluate(&mut self, model: &mut dyn PlanningModel, obs: &[f32]) -> Result<(), PlanError> {
        let seqs = std::mem::take(&mut self.seqs);
        let mut returns = std::mem::take(&mut self.returns);
        let mut grads = std::mem::take(&mut self.grads);
        let r = self.objective_and_gradient(model, obs, &seqs, &mut returns, &mut grads);
        self.seqs = seqs;
        self.returns = returns;
        self.grads = grads;
        r
    }
}

impl Planner for GradientPlanner {
    fn horizon(&self) -> usize {
        self.horizon
    }
    fn act_dim(&self) -> usize {
        self.act_dim
    }

    fn plan(
        &mut self,
        model: &mut dyn PlanningModel,
        obs: &[f32],
        rng: &mut Rng,
    ) -> Result<&[f32], PlanError> {
        self.bind_particles(model.members(), rng);
        self.initialise(rng);
        self.best_return = f32::NEG_INFINITY;
        // If every return diverges, the plan is the first starting sequence, never a leftover
        // of the previous plan (which no checkpoint keeps).
        let len = self.horizon * self.act_dim;
        self.best.copy_from_slice(&self.seqs[..len]);
        let budget = Budget::start(self.budget);
        self.iterations_done = 0;
        while self.iterations_done < self.cfg.iterations && budget.allows(self.iterations_done) {
            self.evaluate(model, obs)?;
            self.keep_best();
            self.iterations_done += 1;
            self.adam_ascent(self.iterations_done as i32);
        }
        self.evaluate(model, obs)?;
        self.keep_best();
        Ok(&self.best)
    }

    fn iterations_done(&self) -> usize {
        self.iterations_done
    }

    fn predicted_return(&self) -> f32 {
        self.best_return
    }

    fn shift(&mut self, k: usize) {
        self.warm.copy_from_slice(&self.best);
        shift_sequence(&mut self.warm, self.act_dim, k, 0.0);
        self.has_warm = true;
    }

    fn reset(&mut self) {
        self.has_warm = false;
    }

    fn warm_start(&self) -> Option<&[f32]> {
        self.has_warm.then_some(&self.warm[..])
    }

    fn set_warm_start(&mut self, warm: Option<&[f32]>) -> Result<(), PlanError> {
        self.has_warm = warm.is_some();
        match warm {
            Some(_) => restore_sequence(&mut self.warm, warm),
            None => Ok(()),
        }
    }
}
