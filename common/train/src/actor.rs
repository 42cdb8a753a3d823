//! Acting in the real environment: the part of every trainer (and later of the actor
//! process) that turns a policy into stored transitions.

use crate::error::TrainError;
use mbpo_core::rng::{stream, uniform_range_f32};
use mbpo_core::{BatchPolicy, Rng, TransitionSink};
use mbpo_envs::{Env, EnvError};
use mbpo_sac::ActionScale;
use serde::{Deserialize, Serialize};

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
    /// Episodes cut short by resumes (see [`EnvActorState::episodes_cut`]).
    pub episodes_cut: u64,
    /// Episodes lost to an environment process that exited (see [`EnvActorState::episodes_lost`]).
    pub episodes_lost: u64,
    /// Env steps since the environment's process last started (a process that exits before
    /// its first step is not restarted again: the run fails instead of looping).
    steps_since_env_start: u64,
}

/// What a checkpoint keeps of an [`EnvActor`]: the episode in progress (where the environment
/// can save it), the random streams and the counters.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EnvActorState {
    /// The episode in progress; `None` when the environment cannot save its state
    /// ([`mbpo_envs::Env::restorable`]): the resumed actor then starts a new episode.
    pub episode: Option<EpisodeState>,
    /// The `actor.env` stream (start states).
    pub env_rng: Rng,
    /// The `actor.policy` stream (action noise).
    pub policy_rng: Rng,
    /// Env steps taken.
    pub steps: u64,
    /// Episodes finished.
    pub episodes: u64,
    /// Return of the last finished episode.
    pub last_return: Option<f64>,
    /// Episodes cut short by a resume: the environment could not save the episode in progress,
    /// so the resumed actor started a new one (never counted in `episodes`).
    pub episodes_cut: u64,
    /// Episodes lost because the process hosting the environment (a Python env) exited
    /// mid-episode: the actor started a new process and a new episode, and stored nothing of
    /// the step that failed (never counted in `episodes`).
    pub episodes_lost: u64,
}

/// The episode in progress of an environment that can save its state.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeState {
    /// `RestorableEnv::state()`.
    pub env_state: Vec<f64>,
    /// Steps taken in the episode (the time limit's count).
    pub elapsed_steps: usize,
    /// `RestorableEnv::resume_state()`: what the episode's next steps depend on beyond
    /// `env_state` (MuJoCo's solver warm start, ...), so the resumed episode is the same bit
    /// for bit.
    pub env_resume_state: Vec<f64>,
    /// The observation the policy sees next.
    pub obs: Vec<f32>,
    /// Return of the episode so far.
    pub episode_return: f64,
}

impl EnvActor {
    /// The actor's state (for checkpoints).
    pub fn checkpoint(&self) -> EnvActorState {
        let episode = self.env.restorable().map(|env| EpisodeState {
            env_state: env.state(),
            elapsed_steps: env.elapsed_steps(),
            env_resume_state: env.resume_state(),
            obs: self.obs.clone(),
            episode_return: self.episode_return,
        });
        EnvActorState {
            episode,
            env_rng: self.env_rng.clone(),
            policy_rng: self.policy_rng.clone(),
            steps: self.steps,
            episodes: self.episodes,
            last_return: self.last_return,
            episodes_cut: self.episodes_cut
                + u64::from(self.env.restorable().is_none() && self.env.elapsed_steps() > 0),
            episodes_lost: self.episodes_lost,
        }
    }

    /// Continue from [`EnvActor::checkpoint`]: the same streams and counters, and the same
    /// episode where the checkpoint holds it; otherwise a new episode from the checkpoint's
    /// `actor.env` stream (the checkpoint already counted the cut one).
    pub fn restore(&mut self, s: EnvActorState) -> Result<(), EnvError> {
        self.env_rng = s.env_rng;
        self.policy_rng = s.policy_rng;
        self.steps = s.steps;
        self.episodes = s.episodes;
        self.last_return = s.last_return;
        self.episodes_cut = s.episodes_cut;
        self.episodes_lost = s.episodes_lost;
        let Some(episode) = s.episode else {
            tracing::info!(
                "{}: the environment cannot restore an episode; the resumed actor starts a new one",
                self.env.id()
            );
            self.episode_return = 0.0;
            return self.env.reset(&mut self.env_rng, &mut self.obs);
        };
        if episode.obs.len() != self.obs.len() {
            return Err(EnvError::StateDim {
                env: self.env.id(),
                expected: self.obs.len(),
                found: episode.obs.len(),
                layout: "the observation of a checkpointed actor",
            });
        }
        let id = self.env.id();
        let env = self
            .env
            .restorable_mut()
            .ok_or(EnvError::NotRestorable(id))?;
        let mut scratch = vec![0.0; self.obs.len()];
        env.reset_to(&episode.env_state, &mut scratch)?;
        env.set_elapsed_steps(episode.elapsed_steps);
        env.set_resume_state(&episode.env_resume_state)?;
        self.obs = episode.obs;
        self.episode_return = episode.episode_return;
        Ok(())
    }

    /// Actor `index` of run `seed` on `env` (see [`crate::ExperimentConfig::make_env`]),
    /// reset to its first start state.
    pub fn new(mut env: Box<dyn Env>, seed: u64, index: u64) -> Result<Self, EnvError> {
        let scale = ActionScale::new(&env.action_space().low, &env.action_space().high);
        let mut env_rng = stream(seed, "actor.env", index);
        let mut obs = vec![0.0; env.obs_dim()];
        env.reset(&mut env_rng, &mut obs)?;
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
            episodes_cut: 0,
            episodes_lost: 0,
            steps_since_env_start: 0,
        })
    }

    /// Observation width.
    pub fn obs_dim(&self) -> usize {
        self.env.obs_dim()
    }
    /// Whether an episode is under way (its first step taken): a paced actor waits for
    /// weights only between episodes.
    pub fn mid_episode(&self) -> bool {
        self.env.elapsed_steps() > 0
    }
    /// Action width.
    pub fn act_dim(&self) -> usize {
        self.env.act_dim()
    }

    /// One env step: choose the action (uniformly, or from `policy` on this one observation),
    /// step, store (s, a, r, s', terminated) with the normalised action, reset at episode end.
    /// A NaN or infinite observation, reward or action stops here, before it is stored.
    ///
    /// When the environment's process exits mid-step (a Python env), the episode is lost
    /// (counted in `episodes_lost`), a new process starts a new episode and the step is taken
    /// there: every call stores exactly one transition. A process that exits again before its
    /// first step fails the run.
    pub fn step(
        &mut self,
        behaviour: Behaviour,
        policy: &mut dyn BatchPolicy,
        replay: &mut dyn TransitionSink,
    ) -> Result<(), TrainError> {
        let step = loop {
            self.choose_action(behaviour, policy);
            match self.env.step(&self.env_action, &mut self.next_obs) {
                Ok(step) => break step,
                Err(e @ EnvError::PythonExited { .. }) if self.steps_since_env_start > 0 => {
                    tracing::warn!("{e}; the episode is lost, starting a new process");
                    self.episodes_lost += 1;
                    self.episode_return = 0.0;
                    self.steps_since_env_start = 0;
                    self.env.reset(&mut self.env_rng, &mut self.obs)?;
                    self.check_finite_reset()?;
                }
                Err(e) => return Err(e.into()),
            }
        };
        self.steps_since_env_start += 1;
        self.check_finite(step.reward)?;
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
            self.env.reset(&mut self.env_rng, &mut self.obs)?;
            self.check_finite_reset()?;
        } else {
            std::mem::swap(&mut self.obs, &mut self.next_obs);
        }
        Ok(())
    }

    /// The next action: uniform in [-1, 1] or from the policy, then rescaled to the env's box.
    fn choose_action(&mut self, behaviour: Behaviour, policy: &mut dyn BatchPolicy) {
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
    }

    /// A reset's observation is all finite numbers.
    fn check_finite_reset(&self) -> Result<(), TrainError> {
        match self.obs.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            Some((i, &v)) => Err(TrainError::NonFinite {
                role: "actor",
                quantity: format!("observation[{i}] of a reset"),
                value: v as f64,
                at: format!("env step {} of {}", self.steps, self.env.id()),
            }),
            None => Ok(()),
        }
    }

    /// The step just taken (action, reward, next observation) is all finite numbers.
    fn check_finite(&self, reward: f64) -> Result<(), TrainError> {
        let at = || format!("env step {} of {}", self.steps + 1, self.env.id());
        let bad = |quantity: String, value: f64| TrainError::NonFinite {
            role: "actor",
            quantity,
            value,
            at: at(),
        };
        if let Some((i, &v)) = self.action.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(bad(format!("action[{i}] of the policy"), v as f64));
        }
        if let Some((i, &v)) = self
            .next_obs
            .iter()
            .enumerate()
            .find(|(_, v)| !v.is_finite())
        {
            return Err(bad(format!("observation[{i}]"), v as f64));
        }
        if !reward.is_finite() {
            return Err(bad("the reward".into(), reward));
        }
        Ok(())
    }
}
