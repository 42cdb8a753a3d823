//! Scoring candidate action sequences by trajectory sampling (Chua et al. 2018, §5, TS∞).
//!
//! Every candidate sequence is replicated over P particles; particle p is bound to one model
//! member for the whole horizon (TS∞: the member stands for one hypothesis about the dynamics,
//! the per-step Gaussian noise for the aleatoric part). All candidates × particles are one batch
//! of rows, so each model step is one batched prediction (one GEMM per layer per member chunk):
//!
//! ```text
//! rows r = c·P + p                (candidate-major; N·P rows)
//! s_0^r = s                       (the real observation)
//! for t in 0..H:  (r_t, s_{t+1}) ~ model(s_t, a_t^c, member(p))
//! R(c) = 1/P Σ_p Σ_t [not terminated before t]·r_t
//! ```
//!
//! The particle → member binding is a fresh balanced random assignment per plan (members are
//! dealt round-robin to a shuffled particle order), shared by all candidates: candidates are
//! compared under the same hypotheses (common random numbers), which sharpens the ranking.

use crate::error::PlanError;
use crate::model::PlanningModel;
use mbpo_core::rng::shuffle;
use mbpo_core::Rng;

/// Buffers and the particle binding of trajectory sampling.
#[derive(Debug, Clone, Default)]
pub struct TrajectorySampler {
    particles: usize,
    /// Member slot of each particle.
    particle_member: Vec<usize>,
    /// Member slot of each row (`particle_member` tiled over candidates).
    row_member: Vec<usize>,
    obs: Vec<f32>,
    next_obs: Vec<f32>,
    act: Vec<f32>,
    reward: Vec<f32>,
    alive: Vec<bool>,
    done: Vec<bool>,
    total: Vec<f64>,
}

impl TrajectorySampler {
    /// A sampler with `particles` particles per candidate.
    pub fn new(particles: usize) -> Self {
        Self {
            particles: particles.max(1),
            ..Self::default()
        }
    }

    /// Particles per candidate.
    pub fn particles(&self) -> usize {
        self.particles
    }

    /// Member slot of each particle (after [`TrajectorySampler::bind_particles`]).
    pub fn particle_members(&self) -> &[usize] {
        &self.particle_member
    }

    /// A fresh random particle → member binding (see [`deal_members`]).
    pub fn bind_particles(&mut self, members: usize, rng: &mut Rng) {
        deal_members(self.particles, members, rng, &mut self.particle_member);
    }

    /// Mean return over particles of each of the `n` candidate sequences in `seqs`
    /// (`n x H x A`, row-major) from observation `obs0`, written to `returns` (`n`).
    /// Non-finite returns become −∞ so they are never preferred.
    #[allow(clippy::too_many_arguments)]
    pub fn evaluate(
        &mut self,
        model: &mut dyn PlanningModel,
        obs0: &[f32],
        seqs: &[f32],
        n: usize,
        horizon: usize,
        rng: &mut Rng,
        returns: &mut [f32],
    ) -> Result<(), PlanError> {
        let (o, a, p) = (model.obs_dim(), model.act_dim(), self.particles);
        if obs0.len() != o || seqs.len() != n * horizon * a || returns.len() != n {
            return Err(PlanError::Dims(format!(
                "evaluate: obs {} (expected {o}), sequences {} (expected {n} x {horizon} x {a}), returns {} (expected {n})",
                obs0.len(),
                seqs.len(),
                returns.len()
            )));
        }
        if self.particle_member.len() != p {
            self.bind_particles(model.members(), rng);
        }
        let rows = n * p;
        self.resize(rows, o, a);
        for r in 0..rows {
            self.obs[r * o..(r + 1) * o].copy_from_slice(obs0);
            self.row_member[r] = self.particle_member[r % p];
        }
        self.alive[..rows].fill(true);
        self.total[..rows].fill(0.0);
        for t in 0..horizon {
            // a_t of candidate c on each of its P rows.
            for c in 0..n {
                let a_t = &seqs[(c * horizon + t) * a..(c * horizon + t + 1) * a];
                for r in c * p..(c + 1) * p {
                    self.act[r * a..(r + 1) * a].copy_from_slice(a_t);
                }
            }
            model.step(
                &self.obs[..rows * o],
                &self.act[..rows * a],
                &self.row_member[..rows],
                rng,
                &mut self.reward[..rows],
                &mut self.next_obs[..rows * o],
            )?;
            self.accumulate(model, rows, o, a)?;
            std::mem::swap(&mut self.obs, &mut self.next_obs);
        }
        for (c, ret) in returns.iter_mut().enumerate() {
            let sum: f64 = self.total[c * p..(c + 1) * p].iter().sum();
            let mean = (sum / p as f64) as f32;
            *ret = if mean.is_finite() {
                mean
            } else {
                f32::NEG_INFINITY
            };
        }
        Ok(())
    }

    /// Add step rewards of live rows; a row that terminates keeps the reward of its last
    /// transition and nothing after it (mbrl-lib's `evaluate_action_sequences`).
    fn accumulate(
        &mut self,
        model: &mut dyn PlanningModel,
        rows: usize,
        o: usize,
        a: usize,
    ) -> Result<(), PlanError> {
        model.terminated(
            &self.obs[..rows * o],
            &self.act[..rows * a],
            &self.next_obs[..rows * o],
            rows,
            &mut self.done[..rows],
        )?;
        for r in 0..rows {
            if !self.alive[r] {
                continue;
            }
            self.total[r] += self.reward[r] as f64;
            if self.done[r] {
                self.alive[r] = false;
            }
        }
        Ok(())
    }

    fn resize(&mut self, rows: usize, o: usize, a: usize) {
        // Grow only: a steady state of equal-sized calls allocates nothing.
        let grow = |v: &mut Vec<f32>, len: usize| {
            if v.len() < len {
                v.resize(len, 0.0);
            }
        };
        grow(&mut self.obs, rows * o);
        grow(&mut self.next_obs, rows * o);
        grow(&mut self.act, rows * a);
        grow(&mut self.reward, rows);
        if self.row_member.len() < rows {
            self.row_member.resize(rows, 0);
            self.alive.resize(rows, true);
            self.done.resize(rows, false);
            self.total.resize(rows, 0.0);
        }
    }
}

/// Deal `members` model members to `particles` particles: particle p gets slot `perm[p] mod M`
/// for a random permutation, so every member carries ⌊P/M⌋ or ⌈P/M⌉ particles.
pub fn deal_members(particles: usize, members: usize, rng: &mut Rng, out: &mut Vec<usize>) {
    out.clear();
    out.extend((0..particles).map(|p| p % members.max(1)));
    shuffle(rng, out);
}
