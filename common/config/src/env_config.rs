//! Which environment a config runs and how model rollouts end: the one place that turns the
//! config's `env`, `[gym]` and `termination` into an environment and a termination rule.
//!
//! ```toml
//! env = "gym:my_pkg.envs:MyRobot"   # or a built-in id, or gym:<registered Gymnasium id>
//! termination = "learned"           # (the default for gym:) or "never", a built-in task's id,
//!                                   # or "python:my_pkg.term:done" (batched over NumPy arrays)
//! [gym]
//! python = "/path/to/venv/bin/python"   # default: $MBPO_PYTHON, else the project venv
//! max_episode_steps = 500               # for an env without a time limit
//! [gym.kwargs]
//! friction = 0.8
//! ```

use mbpo_envs::{termination, Env, EnvError, GymSpec, TerminationFn, GYM_PREFIX};
pub use mbpo_model::RolloutRule;
use std::path::PathBuf;

use crate::config::ExperimentConfig;

/// How model rollouts decide that a predicted state is terminal.
#[derive(Debug, Clone, PartialEq)]
pub enum Termination {
    /// The built-in rule of the task (the env's own, or another task's named in the config).
    Task(String),
    /// No predicted state is terminal (tasks without termination, e.g. Pendulum).
    Never,
    /// Learned with the model from the real transitions' flags
    /// ([`mbpo_model::TerminationClassifier`]); the default for a Python env.
    Learned,
    /// A Python function `module:function` of `obs, act, next_obs` (NumPy arrays, n rows)
    /// returning n booleans ([`mbpo_envs::PythonTermination`]).
    Python(String),
}

impl ExperimentConfig {
    /// True when `env` names a Python Gymnasium environment (`gym:...`).
    pub fn is_gym_env(&self) -> bool {
        self.env.starts_with(GYM_PREFIX)
    }

    /// The Python environment's spec (`None` for a built-in task).
    pub fn gym_spec(&self) -> Option<GymSpec> {
        let mut spec = GymSpec::from_id(&self.env)?;
        spec.python = self.gym.python.as_ref().map(PathBuf::from);
        spec.max_episode_steps = self.gym.max_episode_steps;
        spec.path = self.gym.path.clone();
        spec.kwargs = self
            .gym
            .kwargs
            .iter()
            .map(|(k, v)| (k.clone(), toml_to_json(v)))
            .collect();
        Some(spec)
    }

    /// The env as it appears in file and folder names (`runs/mbpo-<it>-s0`,
    /// `learning-<it>.json`): `gym.name` where set, else the id with `:` and `/` as `-`.
    pub fn env_file_name(&self) -> String {
        match &self.gym.name {
            Some(name) => name.clone(),
            None => self.env.replace([':', '/'], "-"),
        }
    }

    /// A fresh environment of this config (a Python one starts its process here), slowed to
    /// `actor.env_step_ms` per step when that is set.
    pub fn make_env(&self) -> Result<Box<dyn Env>, EnvError> {
        let env: Box<dyn Env> = match self.gym_spec() {
            Some(spec) => Box::new(mbpo_envs::PythonEnv::start(spec)?),
            None => mbpo_envs::make(&self.env)?,
        };
        Ok(match self.actor.env_step_ms {
            ms if ms > 0.0 => {
                let step_time = std::time::Duration::from_secs_f64(ms / 1e3);
                Box::new(mbpo_envs::SlowEnv::new(env, step_time))
            }
            _ => env,
        })
    }

    /// What the environment of this config is, in words (its spaces and episode length), from
    /// making it once: the check that `env` exists (a `gym:` id is only known to Python).
    pub fn describe_env(&self) -> Result<String, EnvError> {
        let env = self.make_env()?;
        let (act, obs) = (env.action_space(), env.observation_space());
        let range = |v: &[f32]| {
            let (lo, hi) = v
                .iter()
                .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &x| {
                    (lo.min(x), hi.max(x))
                });
            if lo == hi {
                format!("{lo}")
            } else {
                format!("{lo}..{hi}")
            }
        };
        Ok(format!(
            "observation {} wide, action {} wide (low {}, high {}), episodes of at most {} steps",
            obs.low.len(),
            act.low.len(),
            range(&act.low),
            range(&act.high),
            env.max_episode_steps()
        ))
    }

    /// The termination rule of model rollouts: `termination` if set, else the task's own, and
    /// learned for a Python env. An error says what is expected (the caller names what it
    /// found: validation reports both, once).
    pub fn termination(&self) -> Result<Termination, String> {
        match self.termination.as_deref() {
            Some("never") => Ok(Termination::Never),
            Some("learned") => Ok(Termination::Learned),
            Some(python) if python.starts_with("python:") => {
                let target = &python["python:".len()..];
                match target.split_once(':') {
                    Some((module, function)) if !module.is_empty() && !function.is_empty() => {
                        Ok(Termination::Python(target.to_string()))
                    }
                    _ => Err("\"python:<module>:<function>\" for a Python rule".into()),
                }
            }
            Some(id) if mbpo_envs::termination_fn(id).is_some() => {
                Ok(Termination::Task(id.to_string()))
            }
            Some(_) => Err(format!(
                "\"learned\", \"never\", \"python:<module>:<function>\" or the id of a built-in \
                 task whose rule applies ({})",
                mbpo_envs::TERMINATION_ENV_IDS.join(", ")
            )),
            None if self.is_gym_env() => Ok(Termination::Learned),
            None => Ok(Termination::Task(self.env.clone())),
        }
    }

    /// [`ExperimentConfig::termination`] as a Rust function; `None` for the learned rule (the
    /// model holds it) and a Python one (see [`ExperimentConfig::rollout_termination`]).
    pub fn termination_fn(&self) -> Result<Option<TerminationFn>, String> {
        Ok(match self.termination()? {
            Termination::Never => Some(termination::never),
            Termination::Task(id) => mbpo_envs::termination_fn(&id),
            Termination::Learned | Termination::Python(_) => None,
        })
    }

    /// The rule of this run's model rollouts, for a model of `obs_dim`/`act_dim` (a Python
    /// rule starts its process here, with the `[gym]` table's interpreter and path).
    pub fn rollout_termination(
        &self,
        obs_dim: usize,
        act_dim: usize,
    ) -> Result<RolloutRule, RolloutTerminationError> {
        let config = RolloutTerminationError::Config;
        Ok(match self.termination().map_err(config)? {
            Termination::Learned => RolloutRule::Learned,
            Termination::Python(target) => {
                let spec = GymSpec {
                    python: self.gym.python.as_ref().map(PathBuf::from),
                    path: self.gym.path.clone(),
                    ..GymSpec::default()
                };
                let rule = mbpo_envs::PythonTermination::start(&target, &spec, obs_dim, act_dim)?;
                RolloutRule::Python(rule)
            }
            _ => RolloutRule::Rule(self.termination_fn().map_err(config)?.expect("a Rust rule")),
        })
    }

    /// The dynamics model's config: `[model]`, plus a learned termination rule when
    /// `termination` is learned. Every model of a run is built from this.
    pub fn model_config(&self) -> mbpo_model::ModelConfig {
        mbpo_model::ModelConfig {
            learn_termination: self.termination() == Ok(Termination::Learned),
            ..self.model.clone()
        }
    }
}

fn toml_to_json(v: &toml::Value) -> serde_json::Value {
    use serde_json::Value as J;
    match v {
        toml::Value::String(s) => J::String(s.clone()),
        toml::Value::Integer(i) => J::from(*i),
        toml::Value::Float(f) => serde_json::Number::from_f64(*f).map_or(J::Null, J::Number),
        toml::Value::Boolean(b) => J::Bool(*b),
        toml::Value::Datetime(d) => J::String(d.to_string()),
        toml::Value::Array(a) => J::Array(a.iter().map(toml_to_json).collect()),
        toml::Value::Table(t) => J::Object(
            t.iter()
                .map(|(k, v)| (k.clone(), toml_to_json(v)))
                .collect(),
        ),
    }
}

/// Why a run's rollout termination rule could not be made.
#[derive(Debug, thiserror::Error)]
pub enum RolloutTerminationError {
    /// The config names no usable rule.
    #[error("{0}")]
    Config(String),
    /// A Python rule's process did not start.
    #[error(transparent)]
    Env(#[from] mbpo_envs::EnvError),
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn file_names_come_from_the_id_or_from_gym_name() {
        let mut cfg = ExperimentConfig {
            env: "gym:dmc_env:make".into(),
            ..Default::default()
        };
        assert_eq!(cfg.env_file_name(), "gym-dmc_env-make");
        cfg.gym.name = Some("dmc-walker-walk".into());
        assert_eq!(cfg.env_file_name(), "dmc-walker-walk");
        cfg.env = "Hopper-v5".into();
        cfg.gym.name = None;
        assert_eq!(cfg.env_file_name(), "Hopper-v5");
    }
}
