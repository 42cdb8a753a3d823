//! Acting in the real environment: the part of every trainer (and later of the actor
//! process) that turns a policy into stored transitions.

use mbpo_core::rng::{stream, uniform_range_f32};
use mbpo_core::{BatchPolicy, ReplayBuffer, Rng};
use mbpo_envs::{make, Env, EnvError};
use mbpo_sac::ActionScale;

/// How the next real action is chosen.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Behaviour {
    /// Uniform over the action box (warm-up).
    Uniform,
    /// a ~ π(·|s), the current stochastic policy.
    Policy,
}

/// One environment with its episode bookkeeping and its random streams
/// (`actor.env` for resets, `actor.policy` for action noise, index = actor id).
pub struct EnvActor {
    env: Box<dyn Env>,
    scale: ActionScale,
    env_rng: Rng,
    policy_rng: Rng,
    obs: Vec<f32>,
    next_obs: Vec<f32>,
    action: Vec<f32>,
    env_action: Vec<f32>,
    episode_return: f64,
    /// Env steps taken.
    pub steps: u64,
    /// Episodes finished.
    pub episodes: u64,
    /// Return of the last finished episode.
    pub last_return: Option<f64>,
}

impl EnvActor {
    /// Actor `index` of run `seed` on environment `env_id`, reset to its first start state.
    pub fn new(env_id: &str, seed: u64, index: u64) -> Result<Self, EnvError> {
        let mut env = make(env_id)?;
        let scale = ActionScale::new(&env.action_space().low, &env.action_space().high);
        let mut env_rng = stream(seed, "actor.env", index);
        let mut obs = vec![0.0; env.obs_dim()];
        env.reset(&mut env_rng, &mut obs);
        let (o, a) = (env.obs_dim(), env.act_dim());
        Ok(Self {
            env,
            scale,
            env_rng,
            policy_rng: stream(seed, "actor.policy", index),
            obs,
            next_obs: vec![0.0; o],
            action: vec![0.0; a],
            env_action: vec![0.0; a],
            episode_return: 0.0,
            steps: 0,
            episodes: 0,
            last_return: None,
        })
    }

    /// Observation width.
    pub fn obs_dim(&self) -> usize {
        self.env.obs_dim()
    }
    /// Action width.
    pub fn act_dim(&self) -> usize {
        self.env.act_dim()
    }

    /// One env step: choose the action (uniformly, or from `policy` on this one observation),
    /// step, store (s, a, r, s', terminated) with the normalised action, reset at episode end.
    pub fn step(
        &mut self,
        behaviour: Behaviour,
        policy: &mut dyn BatchPolicy,
        replay: &mut ReplayBuffer,
    ) {
        match behaviour {
            Behaviour::Uniform => self
                .action
                .iter_mut()
                .for_each(|a| *a = uniform_range_f32(&mut self.policy_rng, -1.0, 1.0)),
            Behaviour::Policy => {
                policy.act_batch(&self.obs, 1, &mut self.action, &mut self.policy_rng)
            }
        }
        self.scale.to_env(&self.action, &mut self.env_action);
        let step = self.env.step(&self.env_action, &mut self.next_obs);
        replay.push(
            &self.obs,
            &self.action,
            step.reward as f32,
            &self.next_obs,
            step.terminated,
        );
        self.steps += 1;
        self.episode_return += step.reward;
        if step.terminated || step.truncated {
            self.episodes += 1;
            self.last_return = Some(self.episode_return);
            self.episode_return = 0.0;
            self.env.reset(&mut self.env_rng, &mut self.obs);
        } else {
            std::mem::swap(&mut self.obs, &mut self.next_obs);
        }
    }
}
