//! Environments with Gymnasium's exact semantics.
//!
//! Every environment implements [`Env`]. Observations are `f32` (Gymnasium returns float32
//! arrays), rewards are `f64` (Gymnasium returns Python floats), actions are `f32` (what a policy
//! network emits). Time limits are part of the environment and are reported as `truncated`, never
//! as `terminated`: MBPO bootstraps through truncation and stops only at termination.
//!
//! ```
//! use mbpo_envs::{make, Env};
//! let mut env = make("Pendulum-v1").unwrap();
//! let mut obs = vec![0.0f32; env.obs_dim()];
//! let restorable = env.restorable_mut().expect("Pendulum can start from a given state");
//! restorable.reset_to(&[0.5, 0.0], &mut obs).unwrap();
//! let step = env.step(&[1.0], &mut obs).unwrap();
//! assert!(!step.terminated && !step.truncated);
//! ```
//!
//! With the cargo feature `mujoco`, [`make`] also builds the Gymnasium v5 MuJoCo tasks
//! ([`MUJOCO_ENV_IDS`]; module [`mujoco`]). Every task and what depends on it (termination
//! rule, known reward, target return) is one row of the [`registry`]. Without it those ids give
//! [`EnvError::MujocoNotBuilt`], so the default build needs no MuJoCo library.
#![warn(missing_docs)]

mod mountain_car;
#[cfg(feature = "mujoco")]
pub mod mujoco;
pub mod numpy_sum;
mod pendulum;
pub mod python;
pub mod registry;
pub mod reward;
mod slow;
mod space;
pub mod termination;

pub use mountain_car::MountainCarContinuous;
pub use pendulum::Pendulum;
pub use python::{GymSpec, PythonEnv, PythonTermination, GYM_PREFIX};
pub use registry::{
    make, register, reward_fn, target_return, task, tasks, termination_fn, TaskSpec, ENV_IDS,
    MUJOCO_ENV_IDS, REWARD_ENV_IDS, TERMINATION_ENV_IDS,
};
pub use reward::{RewardFn, RewardGradFn, RewardValueFn};
pub use slow::SlowEnv;
pub use space::{BoxSpace, ObsPart};
pub use termination::TerminationFn;

use mbpo_core::Rng;

/// The result of one environment step (the observation is written into the caller's buffer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Step {
    /// Reward of the transition, as Gymnasium computes it (f64).
    pub reward: f64,
    /// The task reached a terminal state: no bootstrapping past it.
    pub terminated: bool,
    /// The time limit was reached: bootstrapping continues through it.
    pub truncated: bool,
}

/// Errors of [`RestorableEnv::reset_to`] and [`make`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum EnvError {
    /// The state vector has the wrong length.
    #[error("{env}: state has {found} values, expected {expected} ({layout})")]
    StateDim {
        /// Environment id.
        env: &'static str,
        /// Expected number of state values.
        expected: usize,
        /// Number given.
        found: usize,
        /// What the values mean, e.g. `theta,thetadot`.
        layout: &'static str,
    },
    /// The environment id is not known.
    #[error("unknown environment '{0}'; known: {known}", known = registry::known_ids())]
    UnknownEnv(String),
    /// A task registered with an id that is already taken.
    #[error("a task with id '{0}' is already registered: give yours another id")]
    DuplicateTask(String),
    /// A MuJoCo task in a build without the `mujoco` feature.
    #[error(
        "{0} is a MuJoCo task and this build has no MuJoCo: run `bash deploy/setup_mujoco.sh`, \
         then build with `--features mujoco`"
    )]
    MujocoNotBuilt(String),
    /// A checkpoint holds an episode in progress for an environment that cannot restore one.
    #[error(
        "{0} cannot restore an episode from a checkpoint (it has no saved-state capability), \
         but this checkpoint holds one: resume with the build and environment that wrote it"
    )]
    NotRestorable(&'static str),
    /// MuJoCo refused a checkpoint's resume state (one written for another model).
    #[error("{env}: cannot restore the checkpoint's MuJoCo state: {message}")]
    ResumeState {
        /// Environment id.
        env: &'static str,
        /// What MuJoCo reported.
        message: String,
    },
    /// A Python Gymnasium environment could not be started; the message says why and the fix.
    #[error("{env}: {message}")]
    PythonStart {
        /// Environment id (`gym:...`).
        env: String,
        /// What went wrong and how to fix it.
        message: String,
    },
    /// A Python environment raised an exception in `reset` or `step`.
    #[error("{env} raised an exception in {call}:\n{traceback}")]
    PythonException {
        /// Environment id (`gym:...`).
        env: String,
        /// `reset` or `step`.
        call: &'static str,
        /// Python's traceback.
        traceback: String,
    },
    /// The Python process hosting an environment exited; the next reset starts a new one.
    #[error("{env}: the Python process hosting the environment exited during {call} ({status})")]
    PythonExited {
        /// Environment id (`gym:...`).
        env: String,
        /// `reset` or `step`.
        call: &'static str,
        /// How it ended (exit status or signal).
        status: String,
    },
    /// A MuJoCo model could not be loaded.
    #[error("{env}: cannot load the MuJoCo model: {message}")]
    Model {
        /// Environment id.
        env: &'static str,
        /// What went wrong, with the file.
        message: String,
    },
}

/// A single-agent environment with continuous actions.
///
/// Saving and restoring the episode in progress is an optional capability,
/// [`RestorableEnv`], reached through [`Env::restorable`]: an environment in another process (a
/// Python Gymnasium env) or a real robot cannot offer it. Checkpoints keep the episode of an
/// environment that can; an actor whose environment cannot starts a new episode when it resumes.
pub trait Env: Send {
    /// Gymnasium id, e.g. `Pendulum-v1`.
    fn id(&self) -> &'static str;
    /// Observation space (bounds as Gymnasium declares them).
    fn observation_space(&self) -> &BoxSpace;
    /// Action space; actions outside it are clipped by the environment exactly as Gymnasium does.
    fn action_space(&self) -> &BoxSpace;
    /// Episode length after which `truncated` is reported.
    fn max_episode_steps(&self) -> usize;
    /// Draw a start state from Gymnasium's start distribution and write the observation.
    /// Built-in environments never fail; a Python one can ([`EnvError::PythonException`],
    /// [`EnvError::PythonExited`]).
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) -> Result<(), EnvError>;
    /// Steps taken in the current episode (what the time limit counts).
    fn elapsed_steps(&self) -> usize;
    /// Advance one step with `action` (length `act_dim`) and write the next observation.
    /// Fails like [`Env::reset`].
    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<Step, EnvError>;

    /// Observation dimension.
    fn obs_dim(&self) -> usize {
        self.observation_space().dim()
    }
    /// Action dimension.
    fn act_dim(&self) -> usize {
        self.action_space().dim()
    }
    /// The last observation in f64, for environments that compute it in f64 (Gymnasium's MuJoCo
    /// tasks return float64 observations, which [`Env::step`] rounds to f32); `None` otherwise.
    fn observation_f64(&self) -> Option<&[f64]> {
        None
    }
    /// The parts of a Dict observation in the order the flat observation holds them (a Python
    /// env's); empty for a Box observation, the default.
    fn observation_parts(&self) -> &[ObsPart] {
        &[]
    }
    /// Saving and restoring its state, where the environment can (`None`, the default: it
    /// cannot, e.g. a Python process or a robot).
    fn restorable(&self) -> Option<&dyn RestorableEnv> {
        None
    }
    /// [`Env::restorable`], mutably.
    fn restorable_mut(&mut self) -> Option<&mut dyn RestorableEnv> {
        None
    }
}

/// The optional capability of an [`Env`] to report its physical state and start from one:
/// checkpoints resume an episode in progress with it, replays against Gymnasium set start
/// states with it. Implement it and return `Some(self)` from [`Env::restorable`] and
/// [`Env::restorable_mut`].
pub trait RestorableEnv: Env {
    /// Number of values of the physical state accepted by [`RestorableEnv::reset_to`].
    fn state_dim(&self) -> usize;
    /// Names of the state values, comma-separated (e.g. `theta,thetadot`).
    fn state_layout(&self) -> &'static str;
    /// Start an episode from the given physical state and write the observation.
    fn reset_to(&mut self, state: &[f64], obs: &mut [f32]) -> Result<(), EnvError>;
    /// The current physical state (length [`RestorableEnv::state_dim`]).
    fn state(&self) -> Vec<f64>;
    /// Set the episode's step count (checkpoint restore, after [`RestorableEnv::reset_to`]).
    fn set_elapsed_steps(&mut self, steps: usize);
    /// What the next steps depend on beyond [`RestorableEnv::state`], so a checkpoint taken
    /// mid-episode resumes it bit for bit; empty (the default) where `state` is all of it.
    fn resume_state(&self) -> Vec<f64> {
        Vec::new()
    }
    /// Restore [`RestorableEnv::resume_state`] (checkpoint restore, after
    /// [`RestorableEnv::reset_to`] with the checkpoint's `state`).
    fn set_resume_state(&mut self, extra: &[f64]) -> Result<(), EnvError> {
        if extra.is_empty() {
            return Ok(());
        }
        Err(EnvError::StateDim {
            env: self.id(),
            expected: 0,
            found: extra.len(),
            layout: "no resume state (this environment's state is all of it)",
        })
    }
}
