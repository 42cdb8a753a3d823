//! [`ProbabilisticEnsemble`]: construction, parameters, the training objective and predictions.

use crate::config::{ModelConfig, ModelConfigError, MAX_THREADS};
use crate::error::{ParamsError, PredictError};
use crate::grouped::{
    forward_grouped, sample_block, ChunkBlock, GroupedInputs, Grouping, InputChunk,
};
use crate::network::{members_mse, InferBuffers, Net};
use crate::normalizer::InputNormalizer;
use crate::parallel::{for_each_with_inference, members_loss_and_grads, MemberThreads};
use crate::simd::fill_standard_normal;
use crate::termination::{TerminationClassifier, TerminationWeights};
use mbpo_core::rng::index;
use mbpo_core::{Batch, Rng};
use mbpo_nn::{Adam, AdamConfig, AdamState, Init, ParamLayout, WeightDecay};
use serde::{Deserialize, Serialize};

/// MBPO's dynamics model: an ensemble of Gaussian MLPs predicting `[reward, Δobs]` from
/// `[obs, act]` (Chua et al. 2018, "PE"; Janner et al. 2019, §4).
///
/// Member b outputs a mean μ_b and a log-variance, softly bounded by learned `max_logvar` /
/// `min_logvar` shared by all members. Training ([`ProbabilisticEnsemble::train`]) fits the
/// members on bootstrap resamples with holdout early stopping and picks the elites; predictions
/// use one member per sample, chosen by the caller ([`ProbabilisticEnsemble::predict_gaussian`],
/// [`ProbabilisticEnsemble::predict_sample`]) or uniformly among the elites
/// ([`ProbabilisticEnsemble::rollout`]).
///
/// All scratch memory is owned by the model and sized on first use, so repeated calls of the
/// same size allocate nothing.
#[derive(Debug, Clone)]
pub struct ProbabilisticEnsemble {
    pub(crate) config: ModelConfig,
    pub(crate) obs_dim: usize,
    pub(crate) act_dim: usize,
    pub(crate) net: Net,
    /// θ = `[MLP weights and biases, member-major | max_logvar | min_logvar]`.
    pub(crate) theta: Vec<f32>,
    pub(crate) adam: Adam,
    pub(crate) normalizer: InputNormalizer,
    pub(crate) elites: Vec<usize>,
    /// The learned termination rule (`config.learn_termination`), trained with the ensemble.
    pub(crate) termination: Option<TerminationClassifier>,
    pub(crate) ws: Workspace,
}

/// Everything a rollout worker needs to reproduce the model's predictions: parameters,
/// input normaliser and elites (what a weight broadcast or checkpoint carries).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelWeights {
    /// [`ParamLayout::hash`] of the writer's [`ProbabilisticEnsemble::layout`].
    pub layout_hash: u64,
    /// θ in the layout's order.
    pub params: Vec<f32>,
    /// The input standardisation fitted by the last training call.
    pub normalizer: InputNormalizer,
    /// Elite member indices, best first.
    pub elites: Vec<usize>,
    /// The learned termination rule, when the model has one.
    pub termination: Option<TerminationWeights>,
}

/// What a checkpoint stores of a model being trained: its [`ModelWeights`] and the Adam
/// moments, so training resumes exactly where it stopped.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelState {
    /// Parameters, normaliser, elites.
    pub weights: ModelWeights,
    /// Adam's moments and step count over θ.
    pub adam: AdamState,
    /// The learned termination rule's Adam moments, when the model has one.
    pub termination_adam: Option<AdamState>,
}

/// Scratch memory (not model state: cloning or loading weights never depends on it).
#[derive(Debug, Clone, Default)]
pub(crate) struct Workspace {
    pub(crate) infer: InferBuffers,
    /// Standardised inputs of one inference chunk.
    pub(crate) input: InputChunk,
    /// The threads of training calls, with their own minibatch and activation buffers.
    pub(crate) threads: MemberThreads,
    /// Row indices of [`ProbabilisticEnsemble::loss_and_gradient`]'s minibatches.
    pub(crate) rows: Vec<u32>,
    pub(crate) grads: Vec<f32>,
    /// Standardised inputs and targets of a whole data set (training call, evaluation).
    pub(crate) x_all: Vec<f32>,
    pub(crate) t_all: Vec<f32>,
    pub(crate) group: Grouping,
    /// Standard-normal draws of a sampled prediction, in member-grouped order (`n x d`).
    pub(crate) eps: Vec<f32>,
    /// The sampled `[reward, Δobs]` rows of a prediction, in member-grouped order (`n x d`).
    pub(crate) sampled: Vec<f32>,
    /// Member per sample.
    pub(crate) members: Vec<usize>,
    pub(crate) rollout: RolloutBuffers,
    /// The buffers of a masked rollout's scores (`rollout_mask.rs`).
    pub(crate) mask: MaskBuffers,
}

/// The buffers of a masked rollout (`rollout_mask.rs`), kept in the workspace: sized once,
/// then reused.
#[derive(Debug, Clone, Default)]
pub(crate) struct MaskBuffers {
    pub(crate) members: Vec<usize>,
    pub(crate) mean: Vec<f32>,
    pub(crate) logvar: Vec<f32>,
    pub(crate) sum: Vec<f64>,
    pub(crate) sum_sq: Vec<f64>,
    pub(crate) disagreement: Vec<f32>,
    pub(crate) order: Vec<u32>,
    /// Whether each live transition of the last mask is kept.
    pub(crate) keep: Vec<bool>,
}

/// The buffers of [`ProbabilisticEnsemble::rollout`] (`rollout.rs`), taken out of the model's
/// workspace for the duration of a call.
#[derive(Debug, Clone, Default)]
pub(crate) struct RolloutBuffers {
    pub(crate) obs: Vec<f32>,
    pub(crate) act: Vec<f32>,
    pub(crate) next_obs: Vec<f32>,
    pub(crate) reward: Vec<f32>,
    pub(crate) done: Vec<bool>,
}

impl ProbabilisticEnsemble {
    /// A freshly initialised model for observations of width `obs_dim` and actions of width
    /// `act_dim`: truncated-normal weights (σ = 1/(2√fan_in)), zero biases, bounds at their
    /// configured initial values, identity input normaliser, elites `0..config.elites`.
    pub fn new(
        obs_dim: usize,
        act_dim: usize,
        config: ModelConfig,
        rng: &mut Rng,
    ) -> Result<Self, ModelConfigError> {
        config.validate(obs_dim, act_dim)?;
        let d = 1 + obs_dim;
        let net = Net::new(config.members, obs_dim + act_dim, &config.hidden, d);
        let mut theta = vec![0.0; net.num_params()];
        net.ensemble().init(
            &mut theta[..net.num_net_params()],
            Init::TruncatedNormal,
            rng,
        );
        theta[net.max_logvar_range()].fill(config.init_max_logvar);
        theta[net.min_logvar_range()].fill(config.init_min_logvar);
        let mut adam = Adam::new(theta.len(), AdamConfig::with_lr(config.lr));
        // Weight decay wd_l·½‖W_l‖² on every member's weights (not biases, not the bounds).
        for e in 0..config.members {
            let offset = net.ensemble().member_range(e).start;
            for (l, &wd) in config.weight_decay.iter().enumerate() {
                let r = net.mlp().weight_range(l);
                if wd > 0.0 {
                    adam.set_decay(offset + r.start..offset + r.end, WeightDecay::L2(wd));
                }
            }
        }
        // After the ensemble's draws, so a model without it initialises exactly as before.
        let termination = config
            .learn_termination
            .then(|| TerminationClassifier::new(obs_dim, act_dim, rng));
        Ok(Self {
            termination,
            elites: (0..config.elites).collect(),
            normalizer: InputNormalizer::identity(obs_dim + act_dim),
            config,
            obs_dim,
            act_dim,
            net,
            theta,
            adam,
            ws: Workspace::default(),
        })
    }

    /// The configuration the model was built with.
    pub fn config(&self) -> &ModelConfig {
        &self.config
    }
    /// Observation width.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }
    /// Action width.
    pub fn act_dim(&self) -> usize {
        self.act_dim
    }
    /// Width of a prediction target `[reward, Δobs]`: 1 + obs_dim.
    pub fn target_dim(&self) -> usize {
        self.net.d()
    }
    /// Ensemble size.
    pub fn members(&self) -> usize {
        self.config.members
    }
    /// Elite member indices, best holdout MSE first.
    pub fn elites(&self) -> &[usize] {
        &self.elites
    }
    /// The input standardisation in use.
    pub fn normalizer(&self) -> &InputNormalizer {
        &self.normalizer
    }
    /// Names and shapes of θ: `ensemble.m{e}.l{l}.{w,b}`, `max_logvar`, `min_logvar`.
    pub fn layout(&self) -> &ParamLayout {
        self.net.layout()
    }
    /// All parameters θ (see [`ProbabilisticEnsemble::layout`]).
    pub fn params(&self) -> &[f32] {
        &self.theta
    }
    /// Current upper log-variance bounds (one per target dimension).
    pub fn max_logvar(&self) -> &[f32] {
        &self.theta[self.net.max_logvar_range()]
    }
    /// Current lower log-variance bounds (one per target dimension).
    pub fn min_logvar(&self) -> &[f32] {
        &self.theta[self.net.min_logvar_range()]
    }

    /// Replace θ (Adam's moments are kept).
    pub fn set_params(&mut self, params: &[f32]) -> Result<(), ParamsError> {
        if params.len() != self.theta.len() {
            return Err(ParamsError::Length {
                expected: self.theta.len(),
                found: params.len(),
            });
        }
        self.theta.copy_from_slice(params);
        Ok(())
    }

    /// Parameters, normaliser and elites, for a weight broadcast or a checkpoint.
    pub fn weights(&self) -> ModelWeights {
        ModelWeights {
            layout_hash: self.layout().hash(),
            params: self.theta.clone(),
            normalizer: self.normalizer.clone(),
            elites: self.elites.clone(),
            termination: self.termination.as_ref().map(|c| c.weights()),
        }
    }

    /// `done` of `n` transitions (row-major `obs`, `act`, `next_obs`) by the learned rule,
    /// into `out`; an error when the model learns none.
    pub fn predict_terminated(
        &mut self,
        obs: &[f32],
        act: &[f32],
        next_obs: &[f32],
        n: usize,
        out: &mut [bool],
    ) -> Result<(), crate::RolloutError> {
        let c = self
            .termination
            .as_mut()
            .ok_or(crate::RolloutError::NoTerminationRule)?;
        c.predict(obs, act, next_obs, n, out);
        Ok(())
    }

    /// The learned termination rule (`None` unless `config.learn_termination`).
    pub fn termination(&self) -> Option<&TerminationClassifier> {
        self.termination.as_ref()
    }

    /// Load the learned termination rule's parts (params, input mean, input std) out of a
    /// snapshot; an error when the model has none or the shapes differ.
    pub fn load_termination_parts(
        &mut self,
        params: &[f32],
        mean: &[f32],
        std: &[f32],
    ) -> Result<(), ParamsError> {
        let c = self.termination.as_mut().ok_or_else(|| {
            ParamsError::Inconsistent("weights with a termination rule for a model without".into())
        })?;
        c.load_parts(params, mean, std)
            .map_err(ParamsError::Inconsistent)
    }

    /// Load [`ModelWeights`] from a model of the same architecture.
    pub fn load_weights(&mut self, w: &ModelWeights) -> Result<(), ParamsError> {
        let elites = w.elites.iter().copied();
        let normalizer = &w.normalizer;
        self.load_parts(
            w.layout_hash,
            &w.params,
            &normalizer.mean,
            &normalizer.std,
            elites,
        )?;
        match (&w.termination, self.termination.is_some()) {
            (Some(t), true) => self.load_termination_parts(&t.params, &t.mean, &t.std),
            (None, false) => Ok(()),
            (found, _) => Err(ParamsError::Inconsistent(format!(
                "weights {} a learned termination rule, the model {}",
                if found.is_some() { "with" } else { "without" },
                if found.is_some() {
                    "has none"
                } else {
                    "learns one"
                }
            ))),
        }
    }

    /// Load weights given as their parts -- θ, the normaliser's mean and std, the elites --
    /// from a model of the same architecture: a receiver loads a snapshot straight out of
    /// shared memory with one copy and, once sized, no allocation.
    pub fn load_parts(
        &mut self,
        layout_hash: u64,
        params: &[f32],
        mean: &[f32],
        std: &[f32],
        elites: impl Iterator<Item = usize> + Clone,
    ) -> Result<(), ParamsError> {
        if layout_hash != self.layout().hash() {
            return Err(ParamsError::Layout {
                expected: self.layout().hash(),
                found: layout_hash,
                layout: self.layout().describe(),
            });
        }
        let dim = self.obs_dim + self.act_dim;
        if mean.len() != dim || std.len() != dim {
            return Err(ParamsError::Inconsistent(format!(
                "normaliser has {} means / {} stds for {dim} inputs",
                mean.len(),
                std.len()
            )));
        }
        let members = self.members();
        if elites.clone().next().is_none() || elites.clone().any(|e| e >= members) {
            return Err(ParamsError::Inconsistent(format!(
                "elites {:?} for {members} members",
                elites.collect::<Vec<_>>()
            )));
        }
        self.set_params(params)?;
        self.normalizer.mean.clear();
        self.normalizer.mean.extend_from_slice(mean);
        self.normalizer.std.clear();
        self.normalizer.std.extend_from_slice(std);
        self.elites.clear();
        self.elites.extend(elites);
        Ok(())
    }

    /// Weights and optimiser state (allocates; for checkpoints).
    pub fn checkpoint(&self) -> ModelState {
        ModelState {
            weights: self.weights(),
            adam: self.adam.state().clone(),
            termination_adam: self.termination.as_ref().map(|c| c.adam_state().clone()),
        }
    }

    /// Continue training from a [`ProbabilisticEnsemble::checkpoint`] of the same architecture.
    pub fn restore(&mut self, state: &ModelState) -> Result<(), ParamsError> {
        let n = self.theta.len();
        if state.adam.m.len() != n || state.adam.v.len() != n {
            return Err(ParamsError::Inconsistent(format!(
                "optimiser state has {}/{} moments for {n} parameters",
                state.adam.m.len(),
                state.adam.v.len()
            )));
        }
        self.load_weights(&state.weights)?;
        self.adam.set_state(state.adam.clone());
        match (&mut self.termination, &state.termination_adam) {
            (Some(c), Some(adam)) => c
                .set_adam_state(adam.clone())
                .map_err(ParamsError::Inconsistent),
            (None, None) => Ok(()),
            _ => Err(ParamsError::Inconsistent(
                "a checkpoint of a model with another termination rule".into(),
            )),
        }
    }

    /// The training objective and its gradient on one minibatch per member, *without* weight
    /// decay (Adam adds `wd·W` to the gradient, the derivative of `wd·½‖W‖²`):
    ///
    /// ```text
    /// L = Σ_b [ mean((μ_b − y)²·e^(−lv_b)) + mean(lv_b) ] + c·(Σ max_logvar − Σ min_logvar)
    /// ```
    ///
    /// `inputs` are standardised `[obs, act]` rows stacked per member (`[E, batch, in]`),
    /// `targets` the `[reward, Δobs]` rows (`[E, batch, d]`); `grads` (θ-shaped) is overwritten.
    /// The bound gradients are zero when `learn_logvar_bounds` is off. Exposed for gradient checks
    /// and custom training loops; [`ProbabilisticEnsemble::train`] runs the same code.
    pub fn loss_and_gradient(
        &mut self,
        inputs: &[f32],
        targets: &[f32],
        batch: usize,
        grads: &mut [f32],
    ) -> Result<f64, PredictError> {
        let (e_n, in_dim, d) = (self.members(), self.net.in_dim(), self.net.d());
        check_len("inputs", e_n * batch * in_dim, inputs.len())?;
        check_len("targets", e_n * batch * d, targets.len())?;
        check_len("grads", self.theta.len(), grads.len())?;
        // The training step's own code (`parallel.rs`), on rows e·batch .. (e + 1)·batch.
        let ws = &mut self.ws;
        ws.threads.ensure(self.config.threads, &self.net, batch);
        ws.rows.clear();
        ws.rows.extend(0..(e_n * batch) as u32);
        let mut losses = vec![0.0; e_n];
        let rows = &ws.rows;
        members_loss_and_grads(
            &mut ws.threads,
            &self.net,
            &self.theta,
            inputs,
            targets,
            |e| &rows[e * batch..(e + 1) * batch],
            grads,
            &mut losses,
        );
        let loss: f64 = losses.iter().map(|l| l / batch as f64).sum();
        Ok(loss + self.finish_bound_grads(grads))
    }

    /// Add the bound regulariser's gradient (or zero the bound gradients when the bounds are
    /// frozen); returns the regulariser's value.
    pub(crate) fn finish_bound_grads(&self, grads: &mut [f32]) -> f64 {
        let c = self.config.logvar_bound_penalty;
        let (max_r, min_r) = (self.net.max_logvar_range(), self.net.min_logvar_range());
        if !self.config.learn_logvar_bounds {
            grads[max_r.start..min_r.end].fill(0.0);
            return 0.0;
        }
        grads[max_r.clone()].iter_mut().for_each(|g| *g += c);
        grads[min_r.clone()].iter_mut().for_each(|g| *g -= c);
        let sum = |r: std::ops::Range<usize>| self.theta[r].iter().map(|&v| v as f64).sum::<f64>();
        c as f64 * (sum(max_r) - sum(min_r))
    }

    /// Draw one member per sample uniformly among the elites (MBPO's `random_inds`).
    pub fn sample_elite_members(&self, rng: &mut Rng, members: &mut [usize]) {
        for m in members.iter_mut() {
            *m = self.elites[index(rng, self.elites.len())];
        }
    }

    /// Gaussian one-step predictions of `n` samples, sample i by member `members[i]`.
    ///
    /// Writes the means of `[reward, next_obs]` (next_obs = obs + Δobs) into `mean` and the
    /// log-variances of `[reward, Δobs]` (equally of next_obs given obs) into `logvar`, both
    /// `n x (1 + obs_dim)`. Planners (PETS' TS∞) fix a member per particle through `members`.
    pub fn predict_gaussian(
        &mut self,
        obs: &[f32],
        act: &[f32],
        n: usize,
        members: &[usize],
        mean: &mut [f32],
        logvar: &mut [f32],
    ) -> Result<(), PredictError> {
        let _flush = mbpo_nn::FlushSubnormals::new();
        let (o, d) = (self.obs_dim, self.net.d());
        self.check_predict(obs, act, n, members)?;
        check_len("mean", n * d, mean.len())?;
        check_len("logvar", n * d, logvar.len())?;
        let Workspace {
            infer,
            group,
            input,
            ..
        } = &mut self.ws;
        group.build(&members[..n], self.config.members);
        let inputs = GroupedInputs {
            net: &self.net,
            theta: &self.theta,
            group,
            obs,
            act,
        };
        forward_grouped(&inputs, &self.normalizer, input, infer, |_, idx, y| {
            for (row, &i) in y.chunks_exact(2 * d).zip(idx) {
                let i = i as usize;
                let (m, lv) = row.split_at(d);
                let out = &mut mean[i * d..(i + 1) * d];
                out[0] = m[0];
                for ((v, &dm), &s) in out[1..]
                    .iter_mut()
                    .zip(&m[1..])
                    .zip(&obs[i * o..(i + 1) * o])
                {
                    *v = s + dm;
                }
                logvar[i * d..(i + 1) * d].copy_from_slice(lv);
            }
        });
        Ok(())
    }

    /// Sampled one-step predictions of `n` samples, sample i by member `members[i]`:
    /// `[reward, Δobs] = μ + σ·ε` with σ = e^(logvar/2) and ε ~ N(0, I) drawn from `rng`
    /// (Box-Muller, member 0's samples first); `reward` gets the first component
    /// (`n`), `next_obs` = obs + Δobs (`n x obs_dim`).
    #[allow(clippy::too_many_arguments)]
    pub fn predict_sample(
        &mut self,
        obs: &[f32],
        act: &[f32],
        n: usize,
        members: &[usize],
        rng: &mut Rng,
        reward: &mut [f32],
        next_obs: &mut [f32],
    ) -> Result<(), PredictError> {
        self.check_predict(obs, act, n, members)?;
        check_len("reward", n, reward.len())?;
        check_len("next_obs", n * self.obs_dim, next_obs.len())?;
        self.ws.group.build(&members[..n], self.config.members);
        self.sample_grouped(obs, act, n, rng, reward, next_obs);
        Ok(())
    }

    /// The body of [`ProbabilisticEnsemble::predict_sample`] once `ws.group` is built.
    ///
    /// The grouped chunks are cut into one contiguous run per thread of the training calls
    /// (`model.threads`); each thread samples its chunks into its range of the grouped-order
    /// buffer `ws.sampled`, and the caller scatters them to the samples. ε is drawn first, in
    /// grouped order, so the result is the same bits for any thread count.
    pub(crate) fn sample_grouped(
        &mut self,
        obs: &[f32],
        act: &[f32],
        n: usize,
        rng: &mut Rng,
        reward: &mut [f32],
        next_obs: &mut [f32],
    ) {
        // Flushed on every thread count (the pool's jobs are; mbpo_nn::subnormal says why).
        let _flush = mbpo_nn::FlushSubnormals::new();
        let (o, d) = (self.obs_dim, self.net.d());
        let Workspace {
            group,
            eps,
            sampled,
            threads,
            ..
        } = &mut self.ws;
        // ε in member-grouped order (the order of the chunks), so each chunk's draws are
        // contiguous; the grouping is a fixed function of the members drawn, so a seed still
        // fixes every sample's noise.
        eps.resize(n * d, 0.0);
        fill_standard_normal(rng, eps);
        sampled.resize(n * d, 0.0);
        let workers = threads.ensure_inference(self.config.threads, &self.net, &self.normalizer);
        let chunks = group.chunk_count();
        let used = workers.min(chunks);
        let mut blocks: [Option<ChunkBlock>; MAX_THREADS] = std::array::from_fn(|_| None);
        let mut rest = &mut sampled[..];
        for (t, slot) in blocks.iter_mut().enumerate().take(used) {
            let run = t * chunks / used..(t + 1) * chunks / used;
            let (first, end) = (
                group.chunk_position(run.start),
                group.chunk_position(run.end),
            );
            let (out, tail) = std::mem::take(&mut rest).split_at_mut((end - first) * d);
            rest = tail;
            *slot = Some(ChunkBlock {
                chunks: run,
                first,
                out,
            });
        }
        let inputs = GroupedInputs {
            net: &self.net,
            theta: &self.theta,
            group,
            obs,
            act,
        };
        let eps = &eps[..];
        for_each_with_inference(threads, &mut blocks[..used], |block, infer, input| {
            if let Some(block) = block.take() {
                sample_block(&inputs, eps, block, input, infer);
            }
        });
        for (&i, row) in group.order.iter().zip(sampled.chunks_exact(d)) {
            let i = i as usize;
            reward[i] = row[0];
            let next = &mut next_obs[i * o..(i + 1) * o];
            for ((v, &dm), &s) in next.iter_mut().zip(&row[1..]).zip(&obs[i * o..(i + 1) * o]) {
                *v = s + dm;
            }
        }
    }

    /// Mean-squared error of each member's mean prediction of `[reward, Δobs]` on `data`
    /// (mean over rows and dimensions; the holdout criterion of training).
    pub fn evaluate_mse(&mut self, data: &Batch) -> Result<Vec<f32>, PredictError> {
        if (data.obs_dim, data.act_dim) != (self.obs_dim, self.act_dim) {
            return Err(PredictError::Dims {
                obs_dim: self.obs_dim,
                act_dim: self.act_dim,
                found_obs: data.obs_dim,
                found_act: data.act_dim,
            });
        }
        let n = data.len;
        check_len("obs", n * self.obs_dim, data.obs.len())?;
        check_len("next_obs", n * self.obs_dim, data.next_obs.len())?;
        check_len("act", n * self.act_dim, data.act.len())?;
        check_len("reward", n, data.reward.len())?;
        let rows = (0..n as u32).collect::<Vec<_>>();
        let Workspace {
            infer,
            x_all,
            t_all,
            ..
        } = &mut self.ws;
        standardize(&self.normalizer, data, &rows, x_all, t_all);
        let mut mse = vec![0.0; self.config.members];
        members_mse(&self.net, &self.theta, x_all, t_all, n, infer, &mut mse);
        Ok(mse)
    }

    fn check_predict(
        &mut self,
        obs: &[f32],
        act: &[f32],
        n: usize,
        members: &[usize],
    ) -> Result<(), PredictError> {
        check_len("obs", n * self.obs_dim, obs.len())?;
        check_len("act", n * self.act_dim, act.len())?;
        check_len("members", n, members.len())?;
        if let Some(&member) = members.iter().find(|&&m| m >= self.members()) {
            return Err(PredictError::Member {
                member,
                members: self.members(),
            });
        }
        Ok(())
    }
}

pub(crate) fn check_len(
    what: &'static str,
    expected: usize,
    found: usize,
) -> Result<(), PredictError> {
    if expected == found {
        Ok(())
    } else {
        Err(PredictError::Length {
            what,
            expected,
            found,
        })
    }
}

/// Standardised inputs (`rows x in`) and targets `[reward, Δobs]` (`rows x d`) of the given
/// rows of `data`, written into `x` and `t` (resized; reuses their capacity).
pub(crate) fn standardize(
    normalizer: &InputNormalizer,
    data: &Batch,
    rows: &[u32],
    x: &mut Vec<f32>,
    t: &mut Vec<f32>,
) {
    let (o, a) = (data.obs_dim, data.act_dim);
    let (in_dim, d) = (o + a, o + 1);
    x.resize(rows.len() * in_dim, 0.0);
    t.resize(rows.len() * d, 0.0);
    for ((&r, xr), tr) in rows
        .iter()
        .zip(x.chunks_exact_mut(in_dim))
        .zip(t.chunks_exact_mut(d))
    {
        let r = r as usize;
        let obs = &data.obs[r * o..(r + 1) * o];
        normalizer.transform_into(obs, &data.act[r * a..(r + 1) * a], xr);
        tr[0] = data.reward[r];
        for ((v, &s), &s2) in tr[1..]
            .iter_mut()
            .zip(obs)
            .zip(&data.next_obs[r * o..(r + 1) * o])
        {
            *v = s2 - s;
        }
    }
}
