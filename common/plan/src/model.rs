//! What a planner needs from a model: [`PlanningModel`], and its implementation for the learned
//! ensemble, [`EnsembleModel`].
//!
//! Planners work in the agent's normalised action box [−1, 1]^A (the model's input space, the
//! same as everywhere else in the workspace); a model that needs environment-scale actions (a
//! known task reward) maps them itself.

use crate::error::PlanError;
use mbpo_core::Rng;
use mbpo_envs::RewardFn;
use mbpo_model::{MeanTape, ProbabilisticEnsemble, RolloutRule};

/// A one-step model of the environment, queried in batches of rows.
///
/// A model has [`PlanningModel::members`] members (an ensemble's elites; 1 for a deterministic
/// model). Trajectory sampling binds each particle to one member for the whole horizon (PETS'
/// TS∞), so every call says which member propagates each row.
pub trait PlanningModel {
    /// Observation width.
    fn obs_dim(&self) -> usize;
    /// Action width.
    fn act_dim(&self) -> usize;
    /// Members a particle can be bound to (≥ 1).
    fn members(&self) -> usize;

    /// Sampled one-step predictions of `members.len()` rows: row i of `obs` (`n x obs_dim`) and
    /// `act` (`n x act_dim`, in [−1, 1]) propagated by member `members[i]`; writes `reward` (`n`)
    /// and `next_obs` (`n x obs_dim`), drawing any noise from `rng`.
    fn step(
        &mut self,
        obs: &[f32],
        act: &[f32],
        members: &[usize],
        rng: &mut Rng,
        reward: &mut [f32],
        next_obs: &mut [f32],
    ) -> Result<(), PlanError>;

    /// Whether each of `n` transitions (row-major `obs`, `act`, `next_obs`) ends the episode,
    /// into `out`: rewards after it do not count. Default: never.
    fn terminated(
        &mut self,
        _obs: &[f32],
        _act: &[f32],
        _next_obs: &[f32],
        n: usize,
        out: &mut [bool],
    ) -> Result<(), PlanError> {
        out[..n].fill(false);
        Ok(())
    }

    /// Mean (noise-free) one-step predictions like [`PlanningModel::step`], recorded in slot `t`
    /// for [`PlanningModel::mean_step_backward`]. Only models the gradient planner can use
    /// implement it.
    #[allow(clippy::too_many_arguments)]
    fn mean_step_recorded(
        &mut self,
        _t: usize,
        _obs: &[f32],
        _act: &[f32],
        _members: &[usize],
        _reward: &mut [f32],
        _next_obs: &mut [f32],
    ) -> Result<(), PlanError> {
        Err(PlanError::NotDifferentiable)
    }

    /// Backward pass of slot `t`: from `∂L/∂reward` and `∂L/∂next_obs` of its rows, overwrite
    /// `d_obs` and `d_act` with `∂L/∂obs` and `∂L/∂act`.
    fn mean_step_backward(
        &mut self,
        _t: usize,
        _d_reward: &[f32],
        _d_next_obs: &[f32],
        _d_obs: &mut [f32],
        _d_act: &mut [f32],
    ) -> Result<(), PlanError> {
        Err(PlanError::NotDifferentiable)
    }
}

/// Where the planner's rewards come from.
#[derive(Debug, Clone, Copy)]
pub enum RewardSource {
    /// The ensemble's reward head (the first predicted component).
    Model,
    /// The task's known reward `r(obs, a_env, next_obs)` (`mbpo_envs::reward_fn`), evaluated on
    /// the predicted observations with the action mapped to the environment's box.
    Known(RewardFn),
}

/// The learned [`ProbabilisticEnsemble`] as a [`PlanningModel`]: member slot s is elite s, sampled
/// steps draw `μ + σ·ε` of that member, and rewards come from the [`RewardSource`].
///
/// Owns the ensemble (load new weights through [`EnsembleModel::ensemble_mut`]) and every scratch
/// buffer, so planning with it allocates nothing once the buffers have grown.
pub struct EnsembleModel {
    ensemble: ProbabilisticEnsemble,
    reward: RewardSource,
    termination: Option<RolloutRule>,
    /// Environment action box (for the known reward).
    low: Vec<f32>,
    high: Vec<f32>,
    /// Member index per row (slots mapped to elites).
    members: Vec<usize>,
    /// One row's environment-scale action and the reward's gradient w.r.t. it.
    env_act: Vec<f32>,
    d_env_act: Vec<f32>,
    tape: MeanTape,
    /// Per recorded slot: obs, act, next_obs (`Known` reward gradient needs them).
    recorded: Vec<[Vec<f32>; 3]>,
    /// ∂L/∂next_obs plus the known reward's own contribution.
    d_next: Vec<f32>,
    /// The known reward's ∂/∂obs and ∂/∂a of every row.
    r_obs: Vec<f32>,
    r_act: Vec<f32>,
    /// ∂L/∂(model reward head) = 0 when the reward is known.
    zeros: Vec<f32>,
}

impl EnsembleModel {
    /// Plan with `ensemble`; `low`/`high` is the environment's action box, `termination` the
    /// task's rule, the ensemble's learned one or a Python one (None: never terminates).
    pub fn new(
        ensemble: ProbabilisticEnsemble,
        reward: RewardSource,
        termination: Option<RolloutRule>,
        low: &[f32],
        high: &[f32],
    ) -> Result<Self, PlanError> {
        if low.len() != ensemble.act_dim() || high.len() != ensemble.act_dim() {
            return Err(PlanError::Dims(format!(
                "action box has {} / {} bounds for a model with {} action dimensions",
                low.len(),
                high.len(),
                ensemble.act_dim()
            )));
        }
        Ok(Self {
            env_act: vec![0.0; ensemble.act_dim()],
            d_env_act: vec![0.0; ensemble.act_dim()],
            ensemble,
            reward,
            termination,
            low: low.to_vec(),
            high: high.to_vec(),
            members: Vec::new(),
            tape: MeanTape::new(),
            recorded: Vec::new(),
            d_next: Vec::new(),
            r_obs: Vec::new(),
            r_act: Vec::new(),
            zeros: Vec::new(),
        })
    }

    /// The ensemble (parameters, elites).
    pub fn ensemble(&self) -> &ProbabilisticEnsemble {
        &self.ensemble
    }

    /// The ensemble, to load newer weights.
    pub fn ensemble_mut(&mut self) -> &mut ProbabilisticEnsemble {
        &mut self.ensemble
    }

    /// Map member slots to the ensemble's elites.
    fn map_members(&mut self, slots: &[usize]) -> Result<(), PlanError> {
        let elites = self.ensemble.elites();
        self.members.clear();
        for &s in slots {
            let &m = elites.get(s).ok_or(PlanError::Member {
                member: s,
                members: elites.len(),
            })?;
            self.members.push(m);
        }
        Ok(())
    }

    /// `a_env = low + (a + 1)/2·(high − low)` for one row (as `mbpo_sac::ActionScale`).
    fn to_env(env_act: &mut [f32], low: &[f32], high: &[f32], a: &[f32]) {
        for (((e, &a), &l), &h) in env_act.iter_mut().zip(a).zip(low).zip(high) {
            *e = l + (a + 1.0) * 0.5 * (h - l);
        }
    }

    /// Overwrite `reward` with the known reward of every row.
    fn known_rewards(
        &mut self,
        f: &RewardFn,
        obs: &[f32],
        act: &[f32],
        next_obs: &[f32],
        reward: &mut [f32],
    ) {
        let (o, a) = (self.ensemble.obs_dim(), self.ensemble.act_dim());
        for (i, r) in reward.iter_mut().enumerate() {
            Self::to_env(
                &mut self.env_act,
                &self.low,
                &self.high,
                &act[i * a..(i + 1) * a],
            );
            *r = (f.value)(
                &obs[i * o..(i + 1) * o],
                &self.env_act,
                &next_obs[i * o..(i + 1) * o],
            );
        }
    }
}

impl PlanningModel for EnsembleModel {
    fn obs_dim(&self) -> usize {
        self.ensemble.obs_dim()
    }
    fn act_dim(&self) -> usize {
        self.ensemble.act_dim()
    }
    fn members(&self) -> usize {
        self.ensemble.elites().len()
    }

    fn step(
        &mut self,
        obs: &[f32],
        act: &[f32],
        members: &[usize],
        rng: &mut Rng,
        reward: &mut [f32],
        next_obs: &mut [f32],
    ) -> Result<(), PlanError> {
        self.map_members(members)?;
        let n = members.len();
        self.ensemble
            .predict_sample(obs, act, n, &self.members, rng, reward, next_obs)?;
        if let RewardSource::Known(f) = self.reward {
            self.known_rewards(&f, obs, act, next_obs, reward);
        }
        Ok(())
    }

    fn terminated(
        &mut self,
        obs: &[f32],
        act: &[f32],
        next_obs: &[f32],
        n: usize,
        out: &mut [bool],
    ) -> Result<(), PlanError> {
        match &mut self.termination {
            Some(rule) => Ok(rule.done_batch(&mut self.ensemble, obs, act, next_obs, n, out)?),
            None => {
                out[..n].fill(false);
                Ok(())
            }
        }
    }

    fn mean_step_recorded(
        &mut self,
        t: usize,
        obs: &[f32],
        act: &[f32],
        members: &[usize],
        reward: &mut [f32],
        next_obs: &mut [f32],
    ) -> Result<(), PlanError> {
        self.map_members(members)?;
        let n = members.len();
        self.ensemble.mean_step_recorded(
            &mut self.tape,
            t,
            obs,
            act,
            n,
            &self.members,
            reward,
            next_obs,
        )?;
        if let RewardSource::Known(f) = self.reward {
            self.known_rewards(&f, obs, act, next_obs, reward);
            if self.recorded.len() <= t {
                self.recorded.resize_with(t + 1, Default::default);
            }
            let [o, a, s] = &mut self.recorded[t];
            for (dst, src) in [(o, obs), (a, act), (s, &*next_obs)] {
                dst.clear();
                dst.extend_from_slice(src);
            }
        }
        Ok(())
    }

    fn mean_step_backward(
        &mut self,
        t: usize,
        d_reward: &[f32],
        d_next_obs: &[f32],
        d_obs: &mut [f32],
        d_act: &mut [f32],
    ) -> Result<(), PlanError> {
        let RewardSource::Known(f) = self.reward else {
            // The reward is the model's own output: one backward pass covers both.
            self.ensemble.mean_step_backward(
                &mut self.tape,
                t,
                d_reward,
                d_next_obs,
                d_obs,
                d_act,
            )?;
            return Ok(());
        };
        // Known reward r(obs, a_env(a), next_obs): its gradient joins ∂L/∂next_obs before the
        // model's backward pass, and ∂L/∂obs, ∂L/∂a after it.
        known_reward_grads(self, f, t, d_reward, d_next_obs)?;
        let Self {
            ensemble,
            tape,
            r_obs,
            r_act,
            d_next,
            zeros,
            ..
        } = self;
        ensemble.mean_step_backward(tape, t, zeros, d_next, d_obs, d_act)?;
        d_obs
            .iter_mut()
            .zip(r_obs.iter())
            .for_each(|(g, &r)| *g += r);
        d_act
            .iter_mut()
            .zip(r_act.iter())
            .for_each(|(g, &r)| *g += r);
        Ok(())
    }
}

/// The known reward's part of a backward pass of slot `t` with `∂L/∂reward` = `d_reward`:
/// `model.d_next` = `d_next_obs` + ∂L/∂next_obs through r, `model.r_obs` and `model.r_act` its
/// ∂L/∂obs and ∂L/∂a (∂a_env/∂a = (high − low)/2), `model.zeros` the model reward head's
/// gradient (none: r is not the model's).
fn known_reward_grads(
    model: &mut EnsembleModel,
    f: RewardFn,
    t: usize,
    d_reward: &[f32],
    d_next_obs: &[f32],
) -> Result<(), PlanError> {
    let (o, a) = (model.ensemble.obs_dim(), model.ensemble.act_dim());
    let n = d_reward.len();
    let EnsembleModel {
        recorded,
        low,
        high,
        env_act,
        d_env_act,
        r_obs,
        r_act,
        d_next,
        zeros,
        ..
    } = model;
    let [obs, act, next] = recorded.get(t).ok_or_else(|| {
        PlanError::Dims(format!(
            "backward of planning step {t}, which was not recorded"
        ))
    })?;
    d_next.clear();
    d_next.extend_from_slice(d_next_obs);
    zeros.clear();
    zeros.resize(n, 0.0);
    r_obs.clear();
    r_obs.resize(n * o, 0.0);
    r_act.clear();
    r_act.resize(n * a, 0.0);
    for i in 0..n {
        EnsembleModel::to_env(env_act, low, high, &act[i * a..(i + 1) * a]);
        d_env_act.fill(0.0);
        (f.grad)(
            &obs[i * o..(i + 1) * o],
            env_act,
            &next[i * o..(i + 1) * o],
            d_reward[i],
            &mut r_obs[i * o..(i + 1) * o],
            d_env_act,
            &mut d_next[i * o..(i + 1) * o],
        );
        for (j, (g, &de)) in r_act[i * a..(i + 1) * a]
            .iter_mut()
            .zip(d_env_act.iter())
            .enumerate()
        {
            *g = de * 0.5 * (high[j] - low[j]);
        }
    }
    Ok(())
}
