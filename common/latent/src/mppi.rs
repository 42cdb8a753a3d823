//! TD-MPC2's planner: MPPI over action sequences in the latent space (Hansen et al. 2024,
//! §3.2). From z₀ = h(o), candidate sequences of H actions -- `policy_samples` from the policy
//! prior rolled through the latent dynamics, the rest drawn from N(μ, σ²) -- are scored by the
//! model's return estimate Σ_t γᵗ R(z_t, a_t) + γᴴ Q̄(z_H, π(z_H)); μ and σ move to the
//! score-weighted mean and spread of the best `elites` (weights exp(τ · (v − max v))), for
//! `iterations` rounds. The action taken is the first of one elite drawn by weight, plus
//! N(0, σ₀²) noise when exploring. μ is kept, shifted by a step, to start the next plan.

use mbpo_core::budget::Budget;
use mbpo_core::rng::{normal_f32, uniform_f64, Rng};

use crate::normed_mlp::NormedCache;
use crate::policy::PolicyWorkspace;
use crate::world_model::{concat_rows, WorldModel};

/// MPPI's settings (TD-MPC2's defaults).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MppiConfig {
    /// Candidate sequences per iteration.
    pub samples: usize,
    /// Of them, rolled out by the policy prior.
    pub policy_samples: usize,
    /// The best sequences the distribution moves to.
    pub elites: usize,
    /// Rounds per plan.
    pub iterations: usize,
    /// σ's bounds.
    pub min_std: f32,
    /// See `min_std`.
    pub max_std: f32,
    /// τ of the elites' weights.
    pub temperature: f32,
    /// Wall-clock budget of one plan: iterations stop before one that would overrun it (the
    /// first always runs; at most `iterations`). `None`: every iteration runs.
    pub budget: Option<std::time::Duration>,
    /// Multiply in bf16 on AMX where the CPU has it (inputs rounded to bf16, sums in f32):
    /// the candidates' scores move by the rounding, the plan's cost drops (see
    /// `mbpo_nn::gemm::bf16`). Elsewhere, and when false, every product is f32.
    pub bf16: bool,
}

impl Default for MppiConfig {
    fn default() -> Self {
        Self {
            samples: 512,
            policy_samples: 24,
            elites: 64,
            iterations: 6,
            min_std: 0.05,
            max_std: 2.0,
            temperature: 0.5,
            budget: None,
            bf16: false,
        }
    }
}

/// A planner's state and buffers (sized once).
pub struct LatentMppi {
    cfg: MppiConfig,
    horizon: usize,
    act: usize,
    latent: usize,
    /// μ and σ, H x act; μ is the warm start of the next plan.
    mean: Vec<f32>,
    std: Vec<f32>,
    /// Candidates, sample-major: samples x H x act.
    actions: Vec<f32>,
    values: Vec<f32>,
    z: Vec<f32>,
    za: Vec<f32>,
    noise: Vec<f32>,
    dynamics: NormedCache,
    reward: NormedCache,
    q: [NormedCache; 2],
    policy: PolicyWorkspace,
    order: Vec<usize>,
    weights: Vec<f32>,
    iterations_done: usize,
    /// Whether the forward caches multiply in bf16 ([`MppiConfig::bf16`] where AMX runs).
    bf16: bool,
}

impl LatentMppi {
    /// A planner for `model` with `cfg`.
    pub fn new(model: &WorldModel, cfg: MppiConfig) -> Self {
        let (h, a, z, n) = (
            model.cfg.horizon,
            model.act_dim(),
            model.cfg.latent,
            cfg.samples,
        );
        assert!(
            cfg.policy_samples < n && cfg.elites <= n,
            "policy samples and elites fit in the samples"
        );
        let mut planner = Self {
            cfg,
            horizon: h,
            act: a,
            latent: z,
            mean: vec![0.0; h * a],
            std: vec![cfg.max_std; h * a],
            actions: vec![0.0; n * h * a],
            values: vec![0.0; n],
            z: vec![0.0; n * z],
            za: vec![0.0; n * (z + a)],
            noise: vec![0.0; n * a],
            dynamics: NormedCache::new(&model.dynamics, n),
            reward: NormedCache::new(&model.reward, n),
            q: [NormedCache::new(&model.q, n), NormedCache::new(&model.q, n)],
            policy: PolicyWorkspace::new(model, n),
            order: (0..n).collect(),
            weights: vec![0.0; cfg.elites],
            iterations_done: 0,
            bf16: false,
        };
        planner.dynamics.forward_only();
        planner.reward.forward_only();
        planner.q.iter_mut().for_each(NormedCache::forward_only);
        planner.policy.policy_cache().forward_only();
        if cfg.bf16 {
            planner.bf16 = planner.dynamics.use_bf16(&model.dynamics)
                && planner.reward.use_bf16(&model.reward)
                && planner.q.iter_mut().all(|c| c.use_bf16(&model.q))
                && planner.policy.policy_cache().use_bf16(&model.policy);
        }
        planner
    }

    /// Whether this planner's products are bf16 on AMX (asked for, and the CPU has it).
    pub fn multiplies_in_bf16(&self) -> bool {
        self.bf16
    }

    /// The bf16 copies of the weights from `params` (each plan: the actor's parameters change
    /// between plans; packing was 3 % of a bf16 plan's time on walker-walk's 1M preset).
    fn pack_bf16(&mut self, model: &WorldModel, params: &[f32]) {
        self.dynamics
            .pack_bf16(&model.dynamics, &params[model.dynamics_range()]);
        self.reward
            .pack_bf16(&model.reward, &params[model.reward_range()]);
        for (k, cache) in self.q.iter_mut().enumerate() {
            cache.pack_bf16(&model.q, &params[model.q_head_range(k % model.cfg.q_heads)]);
        }
        self.policy
            .policy_cache()
            .pack_bf16(&model.policy, &params[model.policy_range()]);
    }

    /// Forget the warm start (a new episode).
    pub fn reset(&mut self) {
        self.mean.fill(0.0);
    }

    /// Plan from the latent `z0` and write the action into `action`; `explore` adds
    /// N(0, σ₀²) to it.
    pub fn plan(
        &mut self,
        model: &WorldModel,
        params: &[f32],
        z0: &[f32],
        explore: bool,
        rng: &mut Rng,
        action: &mut [f32],
    ) {
        let (h, a) = (self.horizon, self.act);
        // Warm start: last plan's μ shifted by one step, a fresh σ.
        self.mean.copy_within(a.., 0);
        self.mean[(h - 1) * a..].fill(0.0);
        self.std.fill(self.cfg.max_std);
        let budget = Budget::start(self.cfg.budget);
        if self.bf16 {
            self.pack_bf16(model, params);
        }
        self.policy_rollouts(model, params, z0, rng);
        self.iterations_done = 0;
        while self.iterations_done < self.cfg.iterations && budget.allows(self.iterations_done) {
            self.sample_around_mean(rng);
            self.estimate_values(model, params, z0, rng);
            self.refit(h * a);
            self.iterations_done += 1;
        }
        // The first action of one elite drawn by weight.
        let mut u = uniform_f64(rng) as f32;
        let pick = (0..self.cfg.elites)
            .find(|&i| {
                u -= self.weights[i];
                u <= 0.0
            })
            .unwrap_or(self.cfg.elites - 1);
        let chosen = self.order[pick] * h * a;
        for (j, out) in action[..a].iter_mut().enumerate() {
            let noise = match explore {
                true => self.std[j] * normal_f32(rng),
                false => 0.0,
            };
            *out = (self.actions[chosen + j] + noise).clamp(-1.0, 1.0);
        }
    }

    /// The first `policy_samples` candidates: the policy prior rolled through the dynamics.
    fn policy_rollouts(&mut self, model: &WorldModel, params: &[f32], z0: &[f32], rng: &mut Rng) {
        let (h, a, z, n) = (self.horizon, self.act, self.latent, self.cfg.policy_samples);
        for row in self.z[..n * z].chunks_exact_mut(z) {
            row.copy_from_slice(z0);
        }
        let dynamics = &params[model.dynamics_range()];
        for t in 0..h {
            self.noise[..n * a]
                .iter_mut()
                .for_each(|e| *e = normal_f32(rng));
            let acts = model.sample_policy_rows(
                params,
                &self.z[..n * z],
                &self.noise[..n * a],
                n,
                &mut self.policy,
            );
            for (i, act) in acts.chunks_exact(a).enumerate() {
                self.actions[(i * h + t) * a..(i * h + t + 1) * a].copy_from_slice(act);
            }
            if t + 1 < h {
                concat_rows(&self.z[..n * z], z, acts, a, &mut self.za[..n * (z + a)]);
                let next = model.dynamics.forward(
                    dynamics,
                    &self.za[..n * (z + a)],
                    n,
                    &mut self.dynamics,
                );
                self.z[..n * z].copy_from_slice(next);
            }
        }
    }

    /// The other candidates: clamp(μ + σ·ε, −1, 1).
    fn sample_around_mean(&mut self, rng: &mut Rng) {
        let ha = self.horizon * self.act;
        let first = self.cfg.policy_samples * ha;
        for (k, x) in self.actions[first..].iter_mut().enumerate() {
            let j = k % ha;
            *x = (self.mean[j] + self.std[j] * normal_f32(rng)).clamp(-1.0, 1.0);
        }
    }

    /// Each candidate's Σ_t γᵗ R(z_t, a_t) + γᴴ Q̄(z_H, π(z_H)) into `values`.
    fn estimate_values(&mut self, model: &WorldModel, params: &[f32], z0: &[f32], rng: &mut Rng) {
        let (h, a, z, n) = (self.horizon, self.act, self.latent, self.cfg.samples);
        let (bins, gamma) = (model.cfg.two_hot.bins, model.cfg.discount);
        for row in self.z.chunks_exact_mut(z) {
            row.copy_from_slice(z0);
        }
        self.values.fill(0.0);
        let mut discount = 1.0;
        for t in 0..h {
            for i in 0..n {
                let (zi, ai) = (
                    &self.z[i * z..(i + 1) * z],
                    &self.actions[(i * h + t) * a..(i * h + t + 1) * a],
                );
                self.za[i * (z + a)..i * (z + a) + z].copy_from_slice(zi);
                self.za[i * (z + a) + z..(i + 1) * (z + a)].copy_from_slice(ai);
            }
            let logits =
                model
                    .reward
                    .forward(&params[model.reward_range()], &self.za, n, &mut self.reward);
            for (v, l) in self.values.iter_mut().zip(logits.chunks_exact(bins)) {
                *v += discount * model.cfg.two_hot.decode(l);
            }
            let next = model.dynamics.forward(
                &params[model.dynamics_range()],
                &self.za,
                n,
                &mut self.dynamics,
            );
            self.z.copy_from_slice(next);
            discount *= gamma;
        }
        // The value at the horizon: the mean of two Q heads at (z_H, a ~ π(z_H)).
        self.noise.iter_mut().for_each(|e| *e = normal_f32(rng));
        let acts = model.sample_policy_rows(params, &self.z, &self.noise, n, &mut self.policy);
        concat_rows(&self.z, z, acts, a, &mut self.za);
        for (k, cache) in self.q.iter_mut().enumerate() {
            let logits = model.q.forward(
                &params[model.q_head_range(k % model.cfg.q_heads)],
                &self.za,
                n,
                cache,
            );
            for (v, l) in self.values.iter_mut().zip(logits.chunks_exact(bins)) {
                *v += discount * 0.5 * model.cfg.two_hot.decode(l);
            }
        }
    }

    /// μ, σ ← the weighted mean and spread of the elites; their weights into `weights`.
    fn refit(&mut self, ha: usize) {
        let values = &self.values;
        self.order
            .sort_unstable_by(|&i, &j| values[j].total_cmp(&values[i]));
        let elites = &self.order[..self.cfg.elites];
        let best = values[elites[0]];
        for (w, &i) in self.weights.iter_mut().zip(elites) {
            *w = (self.cfg.temperature * (values[i] - best)).exp();
        }
        let total: f32 = self.weights.iter().sum();
        self.weights.iter_mut().for_each(|w| *w /= total);
        for j in 0..ha {
            let at = |i: usize| self.actions[i * ha + j];
            let mean: f32 = elites
                .iter()
                .zip(&self.weights)
                .map(|(&i, w)| w * at(i))
                .sum();
            let var: f32 = elites
                .iter()
                .zip(&self.weights)
                .map(|(&i, w)| w * (at(i) - mean).powi(2))
                .sum();
            self.mean[j] = mean;
            self.std[j] = var.sqrt().clamp(self.cfg.min_std, self.cfg.max_std);
        }
    }

    /// Iterations the last plan ran: `iterations` unless its budget cut it short.
    pub fn iterations_done(&self) -> usize {
        self.iterations_done
    }

    /// The plan's current mean action sequence (H x act).
    pub fn mean(&self) -> &[f32] {
        &self.mean
    }

    /// Continue from a checkpoint's warm start ([`LatentMppi::mean`]); one of another
    /// horizon or action width is refused.
    pub fn set_mean(&mut self, mean: &[f32]) -> Result<(), String> {
        if mean.len() != self.mean.len() {
            return Err(format!(
                "a plan of {} values, this planner's is {} (horizon x action width)",
                mean.len(),
                self.mean.len()
            ));
        }
        self.mean.copy_from_slice(mean);
        Ok(())
    }

    /// The return estimate of each candidate of the last iteration.
    pub fn values(&self) -> &[f32] {
        &self.values
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::world_model::tests::small_config;
    use mbpo_core::rng::stream;

    fn model() -> (WorldModel, Vec<f32>, Vec<f32>) {
        let model = WorldModel::new(3, 2, small_config());
        let mut params = vec![0.0; model.num_params()];
        model.init(&mut params, &mut stream(7, "test.mppi", 0));
        // Heads that say something: away from the init's zero reward and Q outputs.
        for (i, p) in params.iter_mut().enumerate() {
            *p += 0.3 * ((i as f32) * 0.37).sin();
        }
        let z0: Vec<f32> = {
            let mut g = stream(8, "test.mppi.z0", 0);
            let raw: Vec<f32> = (0..model.cfg.latent).map(|_| normal_f32(&mut g)).collect();
            let mut s = vec![0.0; raw.len()];
            crate::elementwise::simnorm_forward(&raw, &mut s);
            s
        };
        (model, params, z0)
    }

    fn mean_candidate_value(iterations: usize) -> f32 {
        let (model, params, z0) = model();
        let cfg = MppiConfig {
            samples: 128,
            policy_samples: 8,
            elites: 16,
            iterations,
            ..Default::default()
        };
        let mut mppi = LatentMppi::new(&model, cfg);
        let mut action = [0.0; 2];
        mppi.plan(
            &model,
            &params,
            &z0,
            false,
            &mut stream(9, "test.mppi.plan", 0),
            &mut action,
        );
        assert!(action.iter().all(|a| (-1.0..=1.0).contains(a)));
        mppi.values().iter().sum::<f32>() / mppi.values().len() as f32
    }

    #[test]
    fn iterations_move_the_candidates_to_higher_estimated_returns() {
        let (one, six) = (mean_candidate_value(1), mean_candidate_value(6));
        assert!(
            six > one,
            "mean candidate value after 6 iterations {six}, after 1 {one}"
        );
    }

    #[test]
    fn a_budget_cuts_the_iterations_and_none_runs_them_all() {
        let (model, params, z0) = model();
        let plan = |budget: Option<std::time::Duration>| {
            let cfg = MppiConfig {
                samples: 64,
                policy_samples: 4,
                elites: 8,
                iterations: 50,
                budget,
                ..Default::default()
            };
            let mut mppi = LatentMppi::new(&model, cfg);
            let mut action = [0.0; 2];
            let rng = &mut stream(11, "test.mppi.budget", 0);
            mppi.plan(&model, &params, &z0, false, rng, &mut action);
            mppi.iterations_done()
        };
        assert_eq!(plan(None), 50);
        // A budget spent before the first iteration still runs one.
        assert_eq!(plan(Some(std::time::Duration::from_nanos(1))), 1);
        let some = plan(Some(std::time::Duration::from_micros(300)));
        assert!((1..50).contains(&some), "{some} iterations in 0.3 ms");
    }

    #[test]
    fn a_plan_is_a_function_of_its_seed() {
        let (model, params, z0) = model();
        let plan = |seed: u64| {
            let mut mppi = LatentMppi::new(
                &model,
                MppiConfig {
                    samples: 64,
                    policy_samples: 4,
                    elites: 8,
                    ..Default::default()
                },
            );
            let mut a = [0.0; 2];
            mppi.plan(
                &model,
                &params,
                &z0,
                true,
                &mut stream(seed, "test.mppi.plan", 0),
                &mut a,
            );
            (a, mppi.mean().to_vec())
        };
        assert_eq!(plan(1), plan(1));
        assert_ne!(plan(1).0, plan(2).0);
    }

    /// One iteration's values of the same candidates (same seed) in `bf16` or f32.
    fn first_iteration_values(bf16: bool) -> (bool, Vec<f32>) {
        let (model, params, z0) = model();
        let cfg = MppiConfig {
            samples: 96,
            policy_samples: 8,
            elites: 16,
            iterations: 1,
            bf16,
            ..Default::default()
        };
        let mut mppi = LatentMppi::new(&model, cfg);
        let rng = &mut stream(12, "test.mppi.bf16", 0);
        mppi.plan(&model, &params, &z0, false, rng, &mut [0.0; 2]);
        (mppi.multiplies_in_bf16(), mppi.values().to_vec())
    }

    #[test]
    fn bf16_products_score_the_candidates_as_f32_does_up_to_their_rounding() {
        let (on_amx, bf16) = first_iteration_values(true);
        let (f32_ran_as_f32, exact) = first_iteration_values(false);
        assert!(!f32_ran_as_f32, "precision f32 never multiplies in bf16");
        if !on_amx {
            eprintln!("skipped: this CPU or kernel has no AMX bf16 (the planner stays f32)");
            assert_eq!(bf16, exact, "without AMX a bf16 request plans in f32");
            return;
        }
        let spread = exact.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        let worst = bf16
            .iter()
            .zip(&exact)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(
            bf16 != exact,
            "the bf16 products ran (their rounding shows)"
        );
        // bf16 keeps 8 significant bits: values within a few percent of their range.
        assert!(
            worst <= 0.03 * spread,
            "largest difference {worst} against values up to {spread}"
        );
        // And the ranking the elites come from is nearly the same.
        let top = |v: &[f32]| {
            let mut order: Vec<usize> = (0..v.len()).collect();
            order.sort_by(|&i, &j| v[j].total_cmp(&v[i]));
            order[..16].to_vec()
        };
        let (a, b) = (top(&bf16), top(&exact));
        let shared = a.iter().filter(|i| b.contains(i)).count();
        eprintln!("bf16 against f32: largest difference {worst} (values up to {spread}), {shared} of 16 elites shared");
        assert!(shared >= 12, "{shared} of the 16 elites shared");
    }
}
