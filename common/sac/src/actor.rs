//! The tanh-squashed Gaussian actor.
//!
//! The MLP maps s to `[μ, log σ_raw]` (2A outputs). With log σ = clamp(log σ_raw, min, max),
//! σ = e^{log σ}, ε ~ N(0, I) and the reparameterised sample u = μ + σ ε, the action is a = tanh u
//! and its log-density is
//!
//! ```text
//! log π(a|s) = Σ_j [ −ε_j²/2 − log σ_j − ½ log 2π − log(1 − tanh² u_j) ]
//! log(1 − tanh² u) = 2 (log 2 − u − softplus(−2u))        (stable form)
//! ```
//!
//! For a loss L(a, log π) the backward pass uses ∂u/∂μ = 1, ∂u/∂log σ = σ ε,
//! ∂(−log(1 − tanh² u))/∂u = 2 tanh u = 2a and ∂ log π/∂ log σ (explicit) = −1; the clamp passes
//! no gradient outside [min, max].

use mbpo_core::rng::normal_f32;
use mbpo_core::{BatchPolicy, Rng};
use mbpo_nn::math::{exp_neg_f32, log1p_unit};
use mbpo_nn::{Activation, Init, Mlp, MlpCache, ParamLayout, WorkerPool};

const HALF_LOG_2PI: f32 = 0.918_938_5;
const LN_2: f32 = std::f32::consts::LN_2;

/// Architecture of the actor (owns no parameters).
#[derive(Debug, Clone, PartialEq)]
pub struct TanhGaussianActor {
    mlp: Mlp,
    act_dim: usize,
    log_std_min: f32,
    log_std_max: f32,
}

/// Per-batch values of one actor pass, kept for the backward pass.
#[derive(Debug, Clone, Default)]
pub struct ActorCache {
    mlp: MlpCache,
    batch: usize,
    /// Noise ε (`batch x A`).
    pub eps: Vec<f32>,
    /// σ (`batch x A`).
    pub std: Vec<f32>,
    /// Actions a = tanh u (`batch x A`).
    pub action: Vec<f32>,
    /// log π(a|s) per row.
    pub log_prob: Vec<f32>,
    /// Per-dimension terms of log π (`batch x A`), summed into `log_prob`.
    log_prob_terms: Vec<f32>,
    /// 1 where log σ_raw was inside the clamp, else 0 (`batch x A`).
    clamp_pass: Vec<f32>,
    /// ∂L/∂[μ, log σ_raw] (`batch x 2A`).
    d_out: Vec<f32>,
}

impl TanhGaussianActor {
    /// An actor for `obs_dim` observations and `act_dim` actions with ReLU hidden layers.
    pub fn new(
        obs_dim: usize,
        act_dim: usize,
        hidden: &[usize],
        log_std_min: f32,
        log_std_max: f32,
    ) -> Self {
        let mut dims = vec![obs_dim];
        dims.extend_from_slice(hidden);
        dims.push(2 * act_dim);
        Self {
            mlp: Mlp::new(&dims, Activation::Relu, Activation::Identity),
            act_dim,
            log_std_min,
            log_std_max,
        }
    }

    /// The underlying MLP.
    pub fn mlp(&self) -> &Mlp {
        &self.mlp
    }
    /// Observation width.
    pub fn obs_dim(&self) -> usize {
        self.mlp.in_dim()
    }
    /// Action width A.
    pub fn act_dim(&self) -> usize {
        self.act_dim
    }
    /// Parameter count.
    pub fn num_params(&self) -> usize {
        self.mlp.num_params()
    }
    /// Parameter names and shapes.
    pub fn layout(&self) -> &ParamLayout {
        self.mlp.layout()
    }
    /// PyTorch-default initial parameters.
    pub fn init(&self, params: &mut [f32], rng: &mut Rng) {
        self.mlp.init(params, Init::TorchDefault, rng);
    }

    /// A cache sized for `batch` rows.
    pub fn cache(&self, batch: usize) -> ActorCache {
        let a = batch * self.act_dim;
        ActorCache {
            mlp: MlpCache::new(&self.mlp, batch),
            batch,
            eps: vec![0.0; a],
            std: vec![0.0; a],
            action: vec![0.0; a],
            log_prob: vec![0.0; batch],
            log_prob_terms: vec![0.0; a],
            clamp_pass: vec![0.0; a],
            d_out: vec![0.0; 2 * a],
        }
    }

    /// Sample a ~ π(·|s) for `batch` rows (reparameterised, noise from `rng`), or the
    /// deterministic a = tanh μ when `rng` is `None`. Results are in `cache.action` and
    /// `cache.log_prob`.
    pub fn sample(
        &self,
        params: &[f32],
        obs: &[f32],
        batch: usize,
        cache: &mut ActorCache,
        rng: Option<&mut Rng>,
    ) {
        self.ensure(cache, batch);
        let eps = &mut cache.eps[..batch * self.act_dim];
        match rng {
            Some(g) => eps.iter_mut().for_each(|e| *e = normal_f32(g)),
            None => eps.fill(0.0),
        }
        self.sample_with_noise(params, obs, batch, cache);
    }

    /// [`TanhGaussianActor::sample`] with the noise ε already in `cache.eps` (`batch x A`;
    /// resize with [`TanhGaussianActor::ensure`] first). SAC's update draws the noise of all
    /// its row shards in stream order and then lets each shard sample.
    pub fn sample_with_noise(
        &self,
        params: &[f32],
        obs: &[f32],
        batch: usize,
        cache: &mut ActorCache,
    ) {
        cache.batch = batch;
        let n = batch * self.act_dim;
        let out = self.mlp.forward(params, obs, batch, &mut cache.mlp);
        let head = HeadOut {
            std: &mut cache.std[..n],
            action: &mut cache.action[..n],
            log_prob_terms: &mut cache.log_prob_terms[..n],
            clamp_pass: &mut cache.clamp_pass[..n],
        };
        let bounds = (self.log_std_min, self.log_std_max);
        mbpo_nn::simd_dispatch!(tanh_gaussian_head[out, &cache.eps[..n], self.act_dim, bounds, head]);
        // log π sums the per-dimension terms in dimension order.
        for (lp, terms) in cache.log_prob[..batch]
            .iter_mut()
            .zip(cache.log_prob_terms[..n].chunks_exact(self.act_dim))
        {
            *lp = terms.iter().fold(0.0f32, |s, &t| s + t);
        }
    }

    /// Grow `cache` to hold `batch` rows if it is smaller (keeps it otherwise).
    pub fn ensure(&self, cache: &mut ActorCache, batch: usize) {
        if cache.eps.len() < batch * self.act_dim {
            *cache = self.cache(batch);
        }
        cache.batch = batch;
    }

    /// Backward pass of the last [`TanhGaussianActor::sample`] for a loss L with
    /// `d_action` = ∂L/∂a (`batch x A`) and `d_log_prob` = ∂L/∂log π per row; writes ∂L/∂θ.
    pub fn backward(
        &self,
        params: &[f32],
        obs: &[f32],
        cache: &mut ActorCache,
        d_action: &[f32],
        d_log_prob: &[f32],
        grads: &mut [f32],
    ) {
        let a_dim = self.act_dim;
        for r in 0..cache.batch {
            let dlp = d_log_prob[r];
            for j in 0..a_dim {
                let i = r * a_dim + j;
                let a = cache.action[i];
                // ∂L/∂u through tanh and through the squashing correction of log π.
                let du = d_action[i] * (1.0 - a * a) + dlp * 2.0 * a;
                cache.d_out[r * 2 * a_dim + j] = du;
                cache.d_out[r * 2 * a_dim + a_dim + j] =
                    (du * cache.std[i] * cache.eps[i] - dlp) * cache.clamp_pass[i];
            }
        }
        self.mlp
            .backward(params, obs, &mut cache.mlp, &cache.d_out, Some(grads), None);
    }
}

/// Per-element outputs of [`tanh_gaussian_head`] (each `batch x A`).
struct HeadOut<'a> {
    std: &'a mut [f32],
    action: &'a mut [f32],
    log_prob_terms: &'a mut [f32],
    clamp_pass: &'a mut [f32],
}

/// The tanh-Gaussian head on the MLP's output rows `[μ | log σ_raw]`, element by element:
/// log σ = clamp(log σ_raw), σ = e^{log σ}, u = μ + σ ε, a = tanh u and the term of log π
/// (module docs). One exponential t = e^{−2|u|} gives both tanh|u| = (1 − t)/(1 + t) and
/// softplus(−2u) = max(−2u, 0) + ln(1 + t); all of it is branch-free and vectorises (libm's
/// `expf`, `tanhf` and `log1pf` took 2 % of an update). The tanh has an absolute error of a few
/// 1e-7, which is all that enters (a, 1 − a², 2a).
#[inline(always)]
fn tanh_gaussian_head(out: &[f32], eps: &[f32], a_dim: usize, bounds: (f32, f32), h: HeadOut) {
    let (lo, hi) = bounds;
    // De-interleave [μ | log σ_raw] rows into `action` and `std` first, so the element loop
    // below runs over flat arrays and vectorises whatever A is (A = 1 on Pendulum).
    for ((row, mu), raw) in out
        .chunks_exact(2 * a_dim)
        .zip(h.action.chunks_exact_mut(a_dim))
        .zip(h.std.chunks_exact_mut(a_dim))
    {
        mu.copy_from_slice(&row[..a_dim]);
        raw.copy_from_slice(&row[a_dim..]);
    }
    let n = h.action.len();
    // Every slice cut to exactly n: no bounds checks in the loop, so it vectorises.
    let (action, std, eps) = (&mut h.action[..n], &mut h.std[..n], &eps[..n]);
    let (terms, pass) = (&mut h.log_prob_terms[..n], &mut h.clamp_pass[..n]);
    for i in 0..n {
        let (mu, raw) = (action[i], std[i]);
        let log_std = raw.clamp(lo, hi);
        let s = exp_neg_f32(-log_std);
        let u = s.mul_add(eps[i], mu);
        let t = exp_neg_f32(2.0 * u.abs());
        let tanh_abs = (1.0 - t) / (1.0 + t);
        let softplus_m2u = (-2.0 * u).max(0.0) + log1p_unit(t);
        std[i] = s;
        action[i] = tanh_abs.copysign(u);
        terms[i] =
            -0.5 * eps[i] * eps[i] - log_std - HALF_LOG_2PI - 2.0 * (LN_2 - u - softplus_m2u);
        pass[i] = if raw >= lo && raw <= hi { 1.0 } else { 0.0 };
    }
}

/// softplus(x) = log(1 + eˣ), stable for large |x| (the tests' scalar reference).
#[cfg(test)]
fn softplus(x: f32) -> f32 {
    x.max(0.0) + (-x.abs()).exp().ln_1p()
}

/// Rows per forward pass of [`ActorPolicy::act_batch`]: large enough for full-speed GEMMs,
/// small enough that a layer's activations (rows x 256 x 4 B) stay in L2. A model rollout acts
/// on 100k states at once; one pass over all of them would stream hundreds of MB of
/// activations through memory.
pub const POLICY_CHUNK: usize = 256;

/// Most threads an [`ActorPolicy`] acts on.
pub const MAX_POLICY_THREADS: usize = 16;

/// An actor with its own parameters, usable wherever a [`BatchPolicy`] is needed (actors,
/// model rollouts, evaluation).
///
/// A batch is acted on in chunks of [`POLICY_CHUNK`] rows, on [`ActorPolicy::with_threads`]
/// threads when there are more chunks than one. The noise of the whole batch is drawn first,
/// in row order, the chunks are fixed by the batch size, and every row's action depends only
/// on its own row, so the actions are the same bits for any thread count. They are also the
/// bits of one pass over the whole batch, except in a last chunk of one or two rows, where
/// faer takes its matrix-vector or small-matrix kernels.
#[derive(Debug, Clone)]
pub struct ActorPolicy {
    /// Architecture.
    pub actor: TanhGaussianActor,
    /// Flat parameters.
    pub params: Vec<f32>,
    /// Act with tanh μ instead of sampling (evaluation).
    pub deterministic: bool,
    /// ε of the whole batch (`batch x A`).
    eps: Vec<f32>,
    /// One cache of up to [`POLICY_CHUNK`] rows per thread.
    caches: Vec<ActorCache>,
    pool: WorkerPool,
}

/// One thread's contiguous block of rows in [`ActorPolicy::act_batch`].
struct PolicyBlock<'a> {
    cache: &'a mut ActorCache,
    obs: &'a [f32],
    eps: &'a [f32],
    actions: &'a mut [f32],
}

impl ActorPolicy {
    /// A policy from an actor and its parameters, acting on the calling thread.
    pub fn new(actor: TanhGaussianActor, params: Vec<f32>, deterministic: bool) -> Self {
        assert_eq!(params.len(), actor.num_params());
        let cache = actor.cache(1);
        Self {
            actor,
            params,
            deterministic,
            eps: Vec::new(),
            caches: vec![cache],
            pool: WorkerPool::new(1),
        }
    }

    /// The same policy acting on `threads` threads (at most [`MAX_POLICY_THREADS`]) for
    /// batches of more than one chunk; the actions do not change.
    pub fn with_threads(mut self, threads: usize) -> Self {
        let threads = threads.clamp(1, MAX_POLICY_THREADS);
        self.caches = vec![self.actor.cache(1); threads];
        self.pool = WorkerPool::new(threads);
        self
    }

    /// a ~ π(·|s) (or tanh μ) of `batch` rows of `obs` with the noise in `self.eps`, into
    /// `actions`: contiguous blocks of rows, one per thread, each in chunks.
    fn act_with_noise(&mut self, obs: &[f32], batch: usize, actions: &mut [f32]) {
        if batch == 0 {
            return;
        }
        let (o, a) = (self.actor.obs_dim(), self.actor.act_dim());
        let chunks = batch.div_ceil(POLICY_CHUNK);
        let threads = self.pool.threads().min(chunks);
        // Whole chunks per block, so every chunk but the batch's last is full.
        let rows_per_block = chunks.div_ceil(threads) * POLICY_CHUNK;
        let mut blocks: [Option<PolicyBlock>; MAX_POLICY_THREADS] = Default::default();
        let parts = self
            .caches
            .iter_mut()
            .zip(obs[..batch * o].chunks(rows_per_block * o))
            .zip(self.eps[..batch * a].chunks(rows_per_block * a))
            .zip(actions[..batch * a].chunks_mut(rows_per_block * a));
        for (slot, (((cache, obs), eps), actions)) in blocks.iter_mut().zip(parts) {
            *slot = Some(PolicyBlock {
                cache,
                obs,
                eps,
                actions,
            });
        }
        let (actor, params) = (&self.actor, &self.params[..]);
        let used = batch.div_ceil(rows_per_block);
        let act_block = |block: &mut Option<PolicyBlock>| {
            let Some(b) = block.take() else { return };
            let chunks = b
                .obs
                .chunks(POLICY_CHUNK * o)
                .zip(b.eps.chunks(POLICY_CHUNK * a))
                .zip(b.actions.chunks_mut(POLICY_CHUNK * a));
            for ((obs, eps), out) in chunks {
                let rows = obs.len() / o;
                actor.ensure(b.cache, rows);
                b.cache.eps[..rows * a].copy_from_slice(eps);
                actor.sample_with_noise(params, obs, rows, b.cache);
                out.copy_from_slice(&b.cache.action[..rows * a]);
            }
        };
        if used == 1 {
            act_block(&mut blocks[0]);
        } else {
            self.pool
                .for_each_mut(&mut blocks[..used], |_, block| act_block(block));
        }
    }
}

impl BatchPolicy for ActorPolicy {
    fn act_batch(&mut self, obs: &[f32], batch: usize, actions: &mut [f32], rng: &mut Rng) {
        // Flushed on every path, inline or on the pool (mbpo_nn::subnormal says why).
        let _flush = mbpo_nn::FlushSubnormals::new();
        let n = batch * self.actor.act_dim();
        self.eps.resize(n.max(self.eps.len()), 0.0);
        let eps = &mut self.eps[..n];
        // The draws of `TanhGaussianActor::sample`: the whole batch's ε in row order.
        if self.deterministic {
            eps.fill(0.0);
        } else {
            eps.iter_mut().for_each(|e| *e = normal_f32(rng));
        }
        self.act_with_noise(obs, batch, actions);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_core::stream;

    /// log π(a|s) by the change-of-variables formula in f64: log N(u; μ, σ) − log(1 − tanh² u).
    fn reference_log_prob(mu: &[f64], log_std: &[f64], u: &[f64]) -> f64 {
        let mut lp = 0.0;
        for j in 0..mu.len() {
            let std = log_std[j].exp();
            let z = (u[j] - mu[j]) / std;
            lp += -0.5 * z * z - log_std[j] - 0.5 * (2.0 * std::f64::consts::PI).ln();
            lp -= (1.0 - u[j].tanh().powi(2)).ln();
        }
        lp
    }

    #[test]
    fn a_policy_acts_with_the_same_bits_in_chunks_and_on_threads() {
        // Hopper's sizes: 256-wide layers take faer's blocked kernels. 1000 rows are three
        // full chunks and a partial one; the reference is one pass over the whole batch.
        let actor = TanhGaussianActor::new(11, 3, &[256, 256], -20.0, 2.0);
        let mut params = vec![0.0; actor.num_params()];
        actor.init(&mut params, &mut stream(3, "a", 0));
        let rows = 1000;
        let mut g = stream(4, "obs", 0);
        let obs: Vec<f32> = (0..rows * 11).map(|_| 2.0 * normal_f32(&mut g)).collect();
        // 257 rows end in a chunk of one row: any thread count gives the same bits (that row
        // takes faer's matrix-vector kernel, so one pass over all rows may differ there).
        let act = |threads: usize, rows: usize| {
            let mut policy =
                ActorPolicy::new(actor.clone(), params.clone(), false).with_threads(threads);
            let mut actions = vec![f32::NAN; rows * 3];
            policy.act_batch(&obs, rows, &mut actions, &mut stream(5, "eps", 0));
            actions.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        };
        assert!([2, 3].iter().all(|&t| act(t, 257) == act(1, 257)));
        for deterministic in [false, true] {
            let mut whole = actor.cache(rows);
            let rng = (!deterministic).then(|| stream(5, "eps", 0));
            actor.sample(&params, &obs, rows, &mut whole, rng.clone().as_mut());
            let want: Vec<u32> = whole.action[..rows * 3]
                .iter()
                .map(|v| v.to_bits())
                .collect();
            for threads in [1, 2, 3] {
                let mut policy = ActorPolicy::new(actor.clone(), params.clone(), deterministic)
                    .with_threads(threads);
                let mut actions = vec![f32::NAN; rows * 3];
                let mut rng = stream(5, "eps", 0);
                policy.act_batch(&obs, rows, &mut actions, &mut rng);
                let got: Vec<u32> = actions.iter().map(|v| v.to_bits()).collect();
                assert!(
                    got == want,
                    "{threads} threads, deterministic {deterministic}"
                );
                // A small batch after a large one still acts right.
                policy.act_batch(&obs[..11], 1, &mut actions[..3], &mut stream(5, "eps", 0));
                assert_eq!(
                    actions[..3].iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
                    {
                        let mut one = actor.cache(1);
                        let rng = (!deterministic).then(|| stream(5, "eps", 0));
                        actor.sample(&params, &obs[..11], 1, &mut one, rng.clone().as_mut());
                        one.action[..3]
                            .iter()
                            .map(|v| v.to_bits())
                            .collect::<Vec<_>>()
                    }
                );
            }
        }
    }

    #[test]
    fn log_prob_matches_the_change_of_variables_formula() {
        let actor = TanhGaussianActor::new(3, 2, &[16], -20.0, 2.0);
        let mut params = vec![0.0; actor.num_params()];
        actor.init(&mut params, &mut stream(1, "a", 0));
        let obs: Vec<f32> = (0..3 * 50)
            .map(|i| ((i * 7 % 11) as f32 - 5.0) * 0.3)
            .collect();
        let mut cache = actor.cache(50);
        actor.sample(&params, &obs, 50, &mut cache, Some(&mut stream(1, "e", 0)));
        let mut mlp_cache = MlpCache::new(actor.mlp(), 50);
        let out = actor
            .mlp()
            .forward(&params, &obs, 50, &mut mlp_cache)
            .to_vec();
        for r in 0..50 {
            let mu: Vec<f64> = out[r * 4..r * 4 + 2].iter().map(|&v| v as f64).collect();
            let ls: Vec<f64> = out[r * 4 + 2..r * 4 + 4]
                .iter()
                .map(|&v| v as f64)
                .collect();
            let u: Vec<f64> = (0..2)
                .map(|j| mu[j] + ls[j].exp() * cache.eps[r * 2 + j] as f64)
                .collect();
            let want = reference_log_prob(&mu, &ls, &u);
            let got = cache.log_prob[r] as f64;
            assert!(
                (got - want).abs() < 1e-4 * (1.0 + want.abs()),
                "row {r}: {got} vs {want}"
            );
            for j in 0..2 {
                assert!((cache.action[r * 2 + j] as f64 - u[j].tanh()).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn squashed_density_integrates_to_one() {
        // ∫ π(a) da over (−1, 1) for a 1-D tanh-Gaussian, via the stable formula in f32.
        let (mu, log_std) = (0.7f32, -0.3f32);
        let n = 200_000;
        let mut total = 0.0f64;
        for i in 0..n {
            let a = -1.0 + (i as f64 + 0.5) * 2.0 / n as f64;
            let u = a.atanh() as f32;
            let eps = (u - mu) / log_std.exp();
            let lp =
                -0.5 * eps * eps - log_std - HALF_LOG_2PI - 2.0 * (LN_2 - u - softplus(-2.0 * u));
            total += (lp as f64).exp() * 2.0 / n as f64;
        }
        assert!((total - 1.0).abs() < 1e-3, "integral {total}");
    }

    #[test]
    fn deterministic_action_is_tanh_mu_and_clamp_blocks_gradient() {
        let actor = TanhGaussianActor::new(2, 1, &[4], -1.0, 0.5);
        let mut params = vec![0.0; actor.num_params()];
        // Output bias: μ = 0.3, log σ_raw = 5 (above the clamp).
        let b = actor.mlp().bias_range(1);
        params[b.start] = 0.3;
        params[b.start + 1] = 5.0;
        let mut cache = actor.cache(1);
        actor.sample(&params, &[0.0, 0.0], 1, &mut cache, None);
        assert!((cache.action[0] - 0.3f32.tanh()).abs() < 1e-7);
        actor.sample(
            &params,
            &[0.0, 0.0],
            1,
            &mut cache,
            Some(&mut stream(0, "c", 0)),
        );
        assert!(
            (cache.std[0] - 0.5f32.exp()).abs() < 1e-6,
            "log σ is clamped to 0.5"
        );
        let mut grads = vec![0.0; actor.num_params()];
        actor.backward(&params, &[0.0, 0.0], &mut cache, &[1.0], &[1.0], &mut grads);
        assert_eq!(grads[b.start + 1], 0.0, "no gradient into a clamped log σ");
        assert_ne!(grads[b.start], 0.0);
    }
}
