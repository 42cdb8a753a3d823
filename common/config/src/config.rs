//! The experiment file: one TOML document holding every hyper-parameter of a run.
//!
//! Unknown keys, wrong types and out-of-range values are rejected before anything runs, with
//! the file, the key, what was expected and what was found.

use mbpo_sac::SacConfig;
use schemars::JsonSchema;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::RwLock;

/// Which training algorithm a config runs: a name of the algorithm registry
/// (`mbpo_train::algorithm`: `sac`, `mbpo` and `mpc` built in, more with
/// `mbpo_train::algorithm::register`). In a config file it is the name, e.g. `algo = "mbpo"`.
///
/// The names are kept here, the runs they name in the registry: a config is checked against
/// the names without knowing how any algorithm runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Algo(&'static str);

/// Names of the algorithms added at run time, in order ([`Algo::register`]).
static REGISTERED_NAMES: RwLock<Vec<&'static str>> = RwLock::new(Vec::new());

impl Algo {
    /// Model-free SAC on real data only.
    pub const SAC: Algo = Algo("sac");
    /// Model-based policy optimization.
    pub const MBPO: Algo = Algo("mbpo");
    /// Model predictive control with a planner on the learned model (no policy network).
    pub const MPC: Algo = Algo("mpc");
    /// TD-MPC2: planning in a learned latent space with a value at the horizon.
    pub const TDMPC: Algo = Algo("tdmpc");
    /// The algorithms every build has.
    pub const BUILT_IN: [Algo; 4] = [Algo::SAC, Algo::MBPO, Algo::MPC, Algo::TDMPC];

    /// Lower-case name (as in config files and run directory names).
    pub const fn name(self) -> &'static str {
        self.0
    }

    /// The names of every algorithm, built-in first.
    pub fn names() -> Vec<&'static str> {
        let registered = REGISTERED_NAMES.read().unwrap_or_else(|e| e.into_inner());
        Self::BUILT_IN
            .iter()
            .map(|a| a.0)
            .chain(registered.iter().copied())
            .collect()
    }

    /// The algorithm called `name`, or an error that lists the known ones.
    pub fn parse(name: &str) -> Result<Algo, String> {
        let names = Self::names();
        match names.iter().find(|&&n| n == name) {
            Some(&n) => Ok(Algo(n)),
            None => Err(format!(
                "unknown algorithm '{name}'; known: {}",
                names.join(", ")
            )),
        }
    }

    /// Add `name` to the names (the registry's half of `mbpo_train::algorithm::register`, which is how a program adds one); a
    /// name already taken is refused.
    #[doc(hidden)]
    pub fn register(name: &'static str) -> Result<Algo, String> {
        let mut registered = REGISTERED_NAMES.write().unwrap_or_else(|e| e.into_inner());
        if Self::BUILT_IN
            .iter()
            .map(|a| a.0)
            .chain(registered.iter().copied())
            .any(|n| n == name)
        {
            return Err(format!(
                "an algorithm named '{name}' is already registered: give yours another name"
            ));
        }
        registered.push(name);
        Ok(Algo(name))
    }
}

impl JsonSchema for Algo {
    fn schema_name() -> std::borrow::Cow<'static, str> {
        "Algo".into()
    }

    /// A string: the built-in names (a program's registered ones are added at run time).
    fn json_schema(_: &mut schemars::SchemaGenerator) -> schemars::Schema {
        let names: Vec<&str> = Algo::BUILT_IN.iter().map(|a| a.name()).collect();
        schemars::json_schema!({ "type": "string", "enum": names })
    }
}

impl Serialize for Algo {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(self.0)
    }
}

impl<'de> Deserialize<'de> for Algo {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let name = String::deserialize(d)?;
        Algo::parse(&name).map_err(serde::de::Error::custom)
    }
}

/// The `[gym]` table: how to start a Python Gymnasium environment (`env = "gym:..."`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct GymConfig {
    /// The Python interpreter (default: `$MBPO_PYTHON`, else the project venv made by
    /// `deploy/setup_python.sh`, else `python3`); add packages with its pip.
    pub python: Option<String>,
    /// A time limit for an env that has none (an entry point), or to override the registered one.
    pub max_episode_steps: Option<usize>,
    /// Folders where the env's Python module is, put before `PYTHONPATH`; relative ones are
    /// relative to the config file's folder (the run directory's copy holds them absolute).
    pub path: Vec<PathBuf>,
    /// Keyword arguments of `gymnasium.make` or of the entry point.
    #[schemars(with = "std::collections::BTreeMap<String, serde_json::Value>")]
    pub kwargs: toml::Table,
    /// The env's name in file and folder names (`runs/<algo>-<name>-s0`, `learning-<name>.json`)
    /// instead of its id with `:` and `/` as `-`: for an entry point that makes several tasks
    /// from its kwargs (e.g. `dmc-walker-walk` for `gym:dmc_env:make` with `task =
    /// "walker-walk"`), so their runs and results files do not share a name. Letters, digits,
    /// `.`, `_` and `-`. It changes no bit of a run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
}

/// Evaluation schedule.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct EvalConfig {
    /// Evaluate every this many real env steps.
    pub every: u64,
    /// Deterministic episodes per evaluation.
    pub episodes: usize,
    /// The eval return that counts as solving the task, for "env steps to reach the target"
    /// in summaries and learning benchmarks. Unset: the task's own ([`mbpo_envs::target_return`]:
    /// Gymnasium's `reward_threshold`, −200 for Pendulum). It changes no bit of training.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub target_return: Option<f64>,
    /// End the run once this many evaluations in a row reach `target_return`: it stops with a
    /// checkpoint and the status `solved` (0: run every step). Counted from the
    /// start of a run; extending a solved run (`--resume RUN --steps N`) runs every step.
    /// `mbpo run` stops at its next checkpoint cut after the evaluation that solved it.
    pub stop_when_solved: u32,
}

impl Default for EvalConfig {
    fn default() -> Self {
        Self {
            every: 1000,
            episodes: 1,
            target_return: None,
            stop_when_solved: 0,
        }
    }
}

/// Settings of the model-free SAC loop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SacLoopConfig {
    /// Uniform-random env steps before the policy acts and updates start.
    pub random_steps: u64,
    /// SAC updates per env step.
    pub updates_per_step: usize,
    /// Replay capacity (transitions).
    pub replay_capacity: usize,
}

impl Default for SacLoopConfig {
    fn default() -> Self {
        Self {
            random_steps: 5000,
            updates_per_step: 1,
            replay_capacity: 1_000_000,
        }
    }
}

/// How the run's environments act in time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ActorConfig {
    /// Wall milliseconds every env step takes at least (0: as fast as it computes). A stand-in
    /// for a robot or a simulator that runs in real time, applied to every environment the run
    /// makes (actors and evaluator, `mbpo train` and `mbpo run`); results are unchanged, only
    /// the timing is.
    pub env_step_ms: f64,
    /// Steps a second each actor of `mbpo run --mode pipelined` takes, on absolute deadlines of
    /// the monotonic clock (0: as fast as it can, waiting for the weights it needs). A paced
    /// actor never waits for the learner or the model trainer inside an episode: it acts with
    /// the newest weights it holds, and waits for the ones its next step needs only between
    /// episodes, where a robot rests. Missed deadlines are counted (`mbpo run` logs them).
    pub control_hz: f64,
    /// Real-time priority of a paced actor (`control_hz` above 0) and of its environment's
    /// process: SCHED_FIFO at this priority (1 to 99), pinned to one core (actor i to the i-th
    /// core from the last), above the learning roles and everything else on the default
    /// scheduler; 0 leaves it on the default scheduler. Where the system refuses it (not root and no
    /// CAP_SYS_NICE, or RLIMIT_RTPRIO below it) the actor says so in its log, with the fix, and
    /// runs on the default scheduler. Unpaced runs ignore it.
    pub realtime_priority: u32,
    /// When a paced actor may wait for the weights its next step needs under `--policy-lag`:
    /// `between_episodes` keeps MBPO's G updates per env step on average by resting there,
    /// where a robot rests; `never` lets it act with whatever it holds, so the realised
    /// updates per env step float (the summary's `ratios.updates_per_env_step_while_acting`
    /// and `actor_policy_lag` say how far). Either waits once for its first weights after the
    /// warm-up. Unpaced runs ignore it.
    pub catch_up: CatchUp,
}

/// When a paced actor catches up with the learner (`actor.catch_up`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum CatchUp {
    /// Wait between episodes, if it must, for the weights the next step needs.
    #[default]
    BetweenEpisodes,
    /// Never wait after the first weights: act with the newest held.
    Never,
}

impl Default for ActorConfig {
    fn default() -> Self {
        Self {
            env_step_ms: 0.0,
            control_hz: 0.0,
            realtime_priority: 10,
            catch_up: CatchUp::BetweenEpisodes,
        }
    }
}

/// When runs write checkpoints (`<run>/checkpoints/`, see `mbpo_train::checkpoint`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct CheckpointConfig {
    /// Checkpoint every this many real env steps (0: only at the end and on a clean stop).
    pub every: u64,
    /// Complete checkpoints kept; older ones are deleted.
    pub keep: usize,
    /// Also keep every checkpoint taken at a multiple of this many env steps (0: none), e.g.
    /// to measure a long run's costs later at several sizes of D_env (`mbpo bench breakdown`).
    pub keep_every: u64,
}

impl Default for CheckpointConfig {
    fn default() -> Self {
        Self {
            every: 1000,
            keep: 2,
            keep_every: 0,
        }
    }
}

/// MBPO's loop settings (Janner et al. 2019, Alg. 2; names as in the paper and the MBPO code).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct MbpoConfig {
    /// Uniform-random real env steps before the model-based loop starts ("n_initial_exploration_steps").
    pub init_random_steps: u64,
    /// Env steps per epoch; the rollout length k follows the epoch ("epoch_length").
    pub epoch_length: u64,
    /// Train the model and branch new rollouts every this many env steps ("model_train_freq").
    pub model_train_freq: u64,
    /// M: model rollouts per env step; each model training branches M · model_train_freq
    /// rollouts ("rollout_batch_size" = M · model_train_freq).
    pub rollouts_per_step: usize,
    /// [e_min, e_max, k_min, k_max]: k grows linearly from k_min at epoch e_min to k_max at e_max.
    pub rollout_schedule: [usize; 4],
    /// Epochs of rollouts the model buffer keeps ("model_retain_epochs"): D_model holds
    /// `rollouts_per_step · epoch_length · k · retain_epochs` imagined transitions (k the
    /// rollout length in force), the newest replacing the oldest.
    pub retain_epochs: usize,
    /// Fraction of each SAC batch drawn from real data.
    pub real_ratio: f64,
    /// G: SAC updates per env step ("n_train_repeat").
    pub updates_per_step: usize,
    /// Capacity of the real-data buffer D_env.
    pub replay_capacity: usize,
    /// Clamp imagined next states into the box of the real states seen (not in the paper; off
    /// by default).
    pub clip_imagined_states: ImaginedStateClip,
    /// Fraction of each rollout step's live transitions kept: those the elites disagree on
    /// least (the variance of their mean predictions, summed over reward and next state); the
    /// rest are not stored and their rollouts end. M2AC's masking (Pan et al. 2020) without
    /// its reward penalty; not in the paper: 1 keeps every transition (the default). D_model's
    /// capacity stays the paper's, so it holds more branches, as when rollouts terminate.
    pub rollout_keep_fraction: f64,
}

/// What happens to an imagined next state outside every range the real states were seen in
/// (`mbpo.clip_imagined_states`). The paper's code keeps it; on Walker2d-v5, 45-55 % of one-step
/// imagined states leave the real box, mostly in joint velocities the environment clips to
/// [−10, 10] in its observation (`mbpo bench diagnose`, results/diagnose-mbpo-Walker2d-v5-s2.json).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum ImaginedStateClip {
    /// Keep the model's prediction (the paper).
    #[default]
    Off,
    /// Clamp each dimension into [min, max] of the real states and next states in D_env when
    /// the rollouts are branched (`mbpo_core::StateBox`).
    RealBox,
}

impl Default for MbpoConfig {
    fn default() -> Self {
        Self {
            init_random_steps: 5000,
            epoch_length: 1000,
            model_train_freq: 250,
            rollouts_per_step: 400,
            rollout_schedule: [20, 150, 1, 1],
            retain_epochs: 1,
            real_ratio: 0.05,
            updates_per_step: 20,
            replay_capacity: 1_000_000,
            clip_imagined_states: ImaginedStateClip::Off,
            rollout_keep_fraction: 1.0,
        }
    }
}

/// Where the planner's rewards come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum PlanReward {
    /// The task's known reward function (`mbpo_envs::reward_fn`), as PETS does.
    Known,
    /// The model's reward head.
    Model,
}

/// Settings of model predictive control (algo = "mpc"): random warm-up, then every env step a
/// plan on the newest model; the model is retrained on all real data every `model_train_freq`
/// steps (data aggregation: the planner's own transitions teach the model where it goes).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct MpcConfig {
    /// Uniform-random env steps before the first model is trained.
    pub init_random_steps: u64,
    /// Retrain the model every this many env steps after the warm-up (the first training is
    /// at step init_random_steps + 1).
    pub model_train_freq: u64,
    /// Reward source of the planner.
    pub reward: PlanReward,
    /// Execute each plan open loop (all H actions, then plan anew) instead of replanning every
    /// step; for comparison.
    pub open_loop: bool,
    /// The planner.
    pub planner: mbpo_plan::PlannerConfig,
}

impl Default for MpcConfig {
    fn default() -> Self {
        Self {
            init_random_steps: 200,
            model_train_freq: 200,
            reward: PlanReward::Known,
            open_loop: false,
            planner: mbpo_plan::PlannerConfig::default(),
        }
    }
}

/// One experiment.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ExperimentConfig {
    /// Training algorithm.
    pub algo: Algo,
    /// Environment id: a built-in task (see `mbpo env list`) or a Python Gymnasium env,
    /// `gym:<registered id>` or `gym:<module>:<class or function>` (settings in `[gym]`).
    pub env: String,
    /// How model rollouts decide that a predicted state ends its episode (see
    /// [`crate::env_config`]). Unset: the task's own rule, and `"learned"` for a `gym:` env.
    /// `"never"`; `"learned"` (a classifier trained with the model on the real transitions'
    /// flags); a built-in task's id (its rule); or `"python:<module>:<function>"` (a function
    /// of `obs, act, next_obs`, NumPy arrays of n rows, returning n booleans).
    pub termination: Option<String>,
    /// Python Gymnasium environment settings (`env = "gym:..."`).
    pub gym: GymConfig,
    /// Run seed: every random stream derives from it.
    pub seed: u64,
    /// Total real environment steps.
    pub steps: u64,
    /// Evaluation schedule.
    pub eval: EvalConfig,
    /// SAC hyper-parameters.
    pub sac: SacConfig,
    /// Model-free SAC loop settings (algo = "sac").
    pub sac_loop: SacLoopConfig,
    /// MBPO loop settings (algo = "mbpo").
    pub mbpo: MbpoConfig,
    /// Dynamics-model settings (algo = "mbpo" and "mpc").
    pub model: mbpo_model::ModelConfig,
    /// Checkpoint schedule.
    pub checkpoint: CheckpointConfig,
    /// Model predictive control settings (algo = "mpc").
    pub mpc: MpcConfig,
    /// How the environments act in time.
    pub actor: ActorConfig,
    /// TD-MPC2 on a latent world model (algo = "tdmpc").
    pub tdmpc: crate::tdmpc::TdmpcConfig,
}

impl Default for ExperimentConfig {
    fn default() -> Self {
        Self {
            algo: Algo::SAC,
            env: "Pendulum-v1".into(),
            termination: None,
            gym: Default::default(),
            seed: 0,
            steps: 20_000,
            eval: EvalConfig::default(),
            sac: SacConfig::default(),
            sac_loop: SacLoopConfig::default(),
            mbpo: MbpoConfig::default(),
            model: mbpo_model::ModelConfig::default(),
            checkpoint: CheckpointConfig::default(),
            mpc: MpcConfig::default(),
            actor: ActorConfig::default(),
            tdmpc: Default::default(),
        }
    }
}

/// Why a config was rejected.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("cannot read config file {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Not valid TOML, an unknown key or a wrong type (the message shows the line and key).
    #[error("config file {path}: {message}")]
    Parse {
        /// The file.
        path: PathBuf,
        /// toml's message: line, column, key, expected and found.
        message: String,
    },
    /// A `--set key=value` override that is malformed, names an unknown key or has the wrong type.
    #[error("command line --set {spec}: {message}")]
    Override {
        /// The override as given.
        spec: String,
        /// What is wrong: unknown key (with the known ones), expected vs found type.
        message: String,
    },
    /// A value outside its allowed range.
    #[error("config {source_name}: key `{key}` must be {expected}, found {found}")]
    Invalid {
        /// File (or "defaults"/"command line") the value came from.
        source_name: String,
        /// Dotted key, e.g. `sac.gamma`.
        key: String,
        /// The allowed range, in words.
        expected: String,
        /// The value found.
        found: String,
    },
}

impl ExperimentConfig {
    /// Parse and validate a TOML config file.
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = read_config_text(path)?;
        let cfg: Self = toml::from_str(&text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        cfg.validate(&path.display().to_string())?;
        Ok(cfg)
    }

    /// The resolved config of a run its launcher wrote (`<run>/config.toml`), read by the run's
    /// own processes and gateways: parsed, not validated again. The launcher validated it
    /// (and validating a model's sizes makes the environment, which only the processes that
    /// step it should do).
    pub fn load_resolved(path: &Path) -> Result<Self, ConfigError> {
        let text = read_config_text(path)?;
        toml::from_str(&text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            message: e.to_string(),
        })
    }

    /// The config a run uses: the file (or the defaults), then each `--set key=value` in order,
    /// validated as a whole. Errors name the file or the override that caused them.
    ///
    /// A value is read as a TOML literal (`sac.gamma=0.98`, `sac.hidden=[64,64]`,
    /// `sac.autotune_alpha=false`); anything that is not one is taken as a string
    /// (`env=MountainCarContinuous-v0`).
    pub fn resolve(path: Option<&Path>, overrides: &[String]) -> Result<Self, ConfigError> {
        Self::resolve_with(path, overrides, |_| Ok(()))
    }

    /// [`ExperimentConfig::resolve`] with a command's own flags (`--seed`, `--steps`, `--algo`,
    /// `--env`) applied by `flags` after the overrides, before the one validation.
    pub fn resolve_with(
        path: Option<&Path>,
        overrides: &[String],
        flags: impl FnOnce(&mut Self) -> Result<(), ConfigError>,
    ) -> Result<Self, ConfigError> {
        let mut cfg = Self::layered(path, overrides)?;
        let source = match (path, overrides.is_empty()) {
            (Some(p), true) => p.display().to_string(),
            (None, true) => "defaults".to_string(),
            (p, false) => format!(
                "{} with --set {}",
                p.map_or("defaults".into(), |p| p.display().to_string()),
                overrides.join(" --set ")
            ),
        };
        // gym.path entries are relative to the config file (or to the working directory).
        let base = match path.and_then(Path::parent) {
            Some(dir) if !dir.as_os_str().is_empty() => dir.to_path_buf(),
            _ => std::env::current_dir().unwrap_or_default(),
        };
        for p in &mut cfg.gym.path {
            if p.is_relative() {
                *p = base.join(&*p);
            }
        }
        let before = cfg.clone();
        flags(&mut cfg)?;
        let source = match cfg == before {
            true => source,
            false => format!("{source} and the command line's flags"),
        };
        cfg.validate(&source)?;
        Ok(cfg)
    }

    /// The file (or the defaults) with the overrides applied in order. The file is
    /// deserialised on its own (its errors point at its line and column, also where an
    /// override would replace the bad value), then once more with all the overrides; a
    /// failure there is blamed on the first override that breaks it.
    fn layered(path: Option<&Path>, overrides: &[String]) -> Result<Self, ConfigError> {
        let text = path.map(read_config_text).transpose()?;
        let in_file = |e: toml::de::Error| ConfigError::Parse {
            path: path.map_or("defaults".into(), Path::to_path_buf),
            message: e.to_string(),
        };
        let text = text.as_deref().unwrap_or("");
        let file: Self = toml::from_str(text).map_err(in_file)?;
        if overrides.is_empty() {
            return Ok(file);
        }
        let mut table: toml::Table = toml::from_str(text).map_err(in_file)?;
        for spec in overrides {
            apply_override(&mut table, spec)?;
        }
        toml::Value::Table(table)
            .try_into()
            .map_err(|e| blame_override(text, overrides, e))
    }

    /// The eval return the run's "env steps to target" refers to: `eval.target_return`, else the
    /// task's own (`None` when the task has none and the config sets none).
    pub fn target_return(&self) -> Option<f64> {
        // `gym:Hopper-v5` is Gymnasium's own Hopper-v5: the built-in task's target applies.
        let task = self
            .env
            .strip_prefix(mbpo_envs::GYM_PREFIX)
            .unwrap_or(&self.env);
        self.eval
            .target_return
            .or_else(|| mbpo_envs::target_return(task))
    }

    /// The config as TOML (the run directory keeps this resolved copy).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("a config always serializes")
    }

    /// Check every value's range; `source_name` names where the config came from.
    pub fn validate(&self, source_name: &str) -> Result<(), ConfigError> {
        let bad = |key: &str, expected: &str, found: String| ConfigError::Invalid {
            source_name: source_name.to_string(),
            key: key.to_string(),
            expected: expected.to_string(),
            found,
        };
        self.validate_env(&bad)?;
        self.validate_task(&bad)?;
        self.validate_positive(&bad)?;
        self.validate_mbpo(&bad)?;
        if self.algo == Algo::MPC {
            self.validate_mpc(&bad)?;
        }
        if self.algo == Algo::TDMPC {
            self.tdmpc
                .check()
                .map_err(|(key, expected, found)| bad(&format!("tdmpc.{key}"), &expected, found))?;
        }
        if matches!(self.algo, Algo::MBPO | Algo::MPC) {
            self.validate_model(&bad)?;
        }
        self.validate_sac(&bad)
    }

    /// `env` names a task of this build (or a Python env).
    fn validate_task(
        &self,
        bad: &dyn Fn(&str, &str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        match mbpo_envs::task(&self.env) {
            _ if self.is_gym_env() => Ok(()),
            Ok(task) if !task.builds() => Err(bad(
                "env",
                "an environment of this build (MuJoCo tasks need `bash deploy/setup_mujoco.sh` \
                 and a build with `--features mujoco`)",
                format!("{:?}", self.env),
            )),
            Ok(_) => Ok(()),
            Err(_) => Err(bad(
                "env",
                &format!("one of {}", mbpo_envs::registry::known_ids()),
                format!("{:?}", self.env),
            )),
        }
    }

    /// Counts, rates and sizes that must be positive (and finite).
    fn validate_positive(
        &self,
        bad: &dyn Fn(&str, &str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        let (m, c) = (&self.mbpo, &self.checkpoint);
        let positive = [
            ("steps", self.steps as f64),
            ("eval.every", self.eval.every as f64),
            ("sac.batch_size", self.sac.batch_size as f64),
            ("sac.actor_lr", self.sac.actor_lr as f64),
            ("sac.critic_lr", self.sac.critic_lr as f64),
            ("sac.alpha_lr", self.sac.alpha_lr as f64),
            ("sac.init_alpha", self.sac.init_alpha as f64),
            ("sac.threads", self.sac.threads as f64),
            (
                "sac_loop.replay_capacity",
                self.sac_loop.replay_capacity as f64,
            ),
            ("mbpo.epoch_length", m.epoch_length as f64),
            ("mbpo.model_train_freq", m.model_train_freq as f64),
            ("mbpo.rollouts_per_step", m.rollouts_per_step as f64),
            ("mbpo.retain_epochs", m.retain_epochs as f64),
            ("mbpo.updates_per_step", m.updates_per_step as f64),
            ("mbpo.replay_capacity", m.replay_capacity as f64),
            ("checkpoint.keep", c.keep as f64),
        ];
        for (key, v) in positive {
            if !(v > 0.0 && v.is_finite()) {
                return Err(bad(key, "a positive number", v.to_string()));
            }
        }
        if let Some(t) = self.eval.target_return.filter(|t| !t.is_finite()) {
            return Err(bad("eval.target_return", "a finite number", t.to_string()));
        }
        if self.eval.stop_when_solved > 0 && self.target_return().is_none() {
            return Err(bad(
                "eval.stop_when_solved",
                &format!(
                    "0 while the task has no target return (or set eval.target_return for {})",
                    self.env
                ),
                self.eval.stop_when_solved.to_string(),
            ));
        }
        if c.keep_every > 0 && (c.every == 0 || !c.keep_every.is_multiple_of(c.every)) {
            return Err(bad(
                "checkpoint.keep_every",
                &format!(
                    "0 or a multiple of checkpoint.every ({}), where checkpoints are taken",
                    c.every
                ),
                c.keep_every.to_string(),
            ));
        }
        Ok(())
    }

    /// MBPO's ratio and rollout schedule.
    fn validate_mbpo(
        &self,
        bad: &dyn Fn(&str, &str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        let m = &self.mbpo;
        if !(0.0..=1.0).contains(&m.real_ratio) {
            return Err(bad(
                "mbpo.real_ratio",
                "in [0, 1]",
                m.real_ratio.to_string(),
            ));
        }
        if !(m.rollout_keep_fraction > 0.0 && m.rollout_keep_fraction <= 1.0) {
            return Err(bad(
                "mbpo.rollout_keep_fraction",
                "in (0, 1] (1 keeps every imagined transition)",
                m.rollout_keep_fraction.to_string(),
            ));
        }
        let [e_min, e_max, k_min, k_max] = m.rollout_schedule;
        if e_max < e_min || k_min == 0 || k_max < k_min {
            return Err(bad(
                "mbpo.rollout_schedule",
                "[e_min, e_max, k_min, k_max] with e_min <= e_max and 1 <= k_min <= k_max",
                format!("{:?}", m.rollout_schedule),
            ));
        }
        Ok(())
    }

    /// The model's own ranges, and a warm-up long enough for its first training.
    fn validate_model(
        &self,
        bad: &dyn Fn(&str, &str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        // The model crate checks its own ranges (dims, elites <= members, decay lengths).
        // A Python env's dims are known only once its interpreter runs, and every process
        // validates its config: its model is checked with placeholder dims (the bridge
        // refuses an env with no observation or action values).
        let (obs_dim, act_dim) = match self.is_gym_env() {
            true => (1, 1),
            false => {
                let env = mbpo_envs::make(&self.env)
                    .map_err(|e| bad("env", "an environment that loads", e.to_string()))?;
                (env.obs_dim(), env.act_dim())
            }
        };
        self.model.validate(obs_dim, act_dim).map_err(|e| {
            let (field, expected, found) = e.parts();
            bad(&format!("model.{field}"), &expected, found)
        })?;
        // The first model trains on the warm-up's transitions alone.
        let (key, warm_up) = match self.algo {
            Algo::MPC => ("mpc.init_random_steps", self.mpc.init_random_steps),
            _ => ("mbpo.init_random_steps", self.mbpo.init_random_steps),
        };
        let need = self.model.min_training_transitions();
        if warm_up < need as u64 {
            return Err(bad(
                key,
                &format!(
                    "at least {need}: the first model trains on the warm-up's transitions \
                     alone, and model.holdout_ratio = {} needs {need} to hold some out",
                    self.model.holdout_ratio
                ),
                warm_up.to_string(),
            ));
        }
        Ok(())
    }

    /// SAC's discount, Polyak rate, widths and log-std range.
    fn validate_sac(
        &self,
        bad: &dyn Fn(&str, &str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        for (key, v) in [("sac.gamma", self.sac.gamma), ("sac.tau", self.sac.tau)] {
            if !(v > 0.0 && v <= 1.0) {
                return Err(bad(key, "in (0, 1]", v.to_string()));
            }
        }
        if self.sac.hidden.is_empty() || self.sac.hidden.contains(&0) {
            return Err(bad(
                "sac.hidden",
                "a non-empty list of positive widths",
                format!("{:?}", self.sac.hidden),
            ));
        }
        if self.sac.log_std_min >= self.sac.log_std_max {
            return Err(bad(
                "sac.log_std_min",
                &format!("below sac.log_std_max = {}", self.sac.log_std_max),
                self.sac.log_std_min.to_string(),
            ));
        }
        Ok(())
    }
}

/// The text of the config file `path`. An empty file is refused: it would run every default,
/// which is rarely what naming a file meant (no file at all runs the defaults on purpose).
/// The first of `overrides` (applied in order over the file's `text`) after which the config
/// no longer deserialises, as an error naming it; `error` is the whole stack's.
fn blame_override(text: &str, overrides: &[String], error: toml::de::Error) -> ConfigError {
    let mut table: toml::Table = toml::from_str(text).unwrap_or_default();
    for spec in overrides {
        if let Err(e) = apply_override(&mut table, spec) {
            return e;
        }
        let layer: Result<ExperimentConfig, _> = toml::Value::Table(table.clone()).try_into();
        if let Err(e) = layer {
            return ConfigError::Override {
                spec: spec.clone(),
                message: e.message().trim().to_string(),
            };
        }
    }
    ConfigError::Override {
        spec: overrides.join(" --set "),
        message: error.message().trim().to_string(),
    }
}

fn read_config_text(path: &Path) -> Result<String, ConfigError> {
    let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
        path: path.to_path_buf(),
        source,
    })?;
    if text.trim().is_empty() {
        return Err(ConfigError::Parse {
            path: path.to_path_buf(),
            message: "the file is empty; a config names at least `algo` and `env` (examples in \
                      deploy/configs/)"
                .into(),
        });
    }
    Ok(text)
}

/// Apply one `key=value` override to a parsed TOML table (dotted keys address sub-tables).
fn apply_override(table: &mut toml::Table, spec: &str) -> Result<(), ConfigError> {
    let fail = |message: &str| ConfigError::Override {
        spec: spec.to_string(),
        message: message.to_string(),
    };
    let (key, raw) = spec
        .split_once('=')
        .ok_or_else(|| fail("expected key=value, e.g. sac.gamma=0.98"))?;
    let path: Vec<&str> = key.trim().split('.').collect();
    if path.iter().any(|part| part.is_empty()) {
        return Err(fail(
            "the key is empty or has an empty part; e.g. sac.gamma",
        ));
    }
    let raw = raw.trim();
    let value = toml::from_str::<toml::Table>(&format!("v = {raw}"))
        .ok()
        .and_then(|mut t| t.remove("v"))
        .unwrap_or_else(|| toml::Value::String(raw.to_string()));
    let (last, parents) = path.split_last().expect("at least one part");
    let mut node = table;
    for (depth, part) in parents.iter().enumerate() {
        let entry = node
            .entry(part.to_string())
            .or_insert_with(|| toml::Value::Table(toml::Table::new()));
        node = entry.as_table_mut().ok_or_else(|| {
            fail(&format!(
                "`{}` is a value, not a section",
                path[..=depth].join(".")
            ))
        })?;
    }
    node.insert(last.to_string(), value);
    Ok(())
}

impl ExperimentConfig {
    /// `env`, `termination` and `[gym]`: a `gym:` id names something, a model-based run has a
    /// termination rule, keyword arguments are finite.
    fn validate_env(
        &self,
        bad: &dyn Fn(&str, &str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        if self.is_gym_env() && self.env[mbpo_envs::GYM_PREFIX.len()..].trim().is_empty() {
            return Err(bad(
                "env",
                "gym:<registered id> or gym:<module>:<class or function>",
                format!("{:?}", self.env),
            ));
        }
        if !self.is_gym_env() && self.gym != Default::default() {
            return Err(bad(
                "gym",
                "no [gym] table: it is for Python envs (env = \"gym:...\")",
                format!("a [gym] table with env = {:?}", self.env),
            ));
        }
        if matches!(self.algo, Algo::MBPO | Algo::MPC) || self.termination.is_some() {
            self.termination().map_err(|expected| {
                let found = self
                    .termination
                    .as_ref()
                    .map_or("nothing".into(), |t| format!("{t:?}"));
                bad("termination", &expected, found)
            })?;
        }
        for (key, v) in [
            ("actor.env_step_ms", self.actor.env_step_ms),
            ("actor.control_hz", self.actor.control_hz),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(bad(key, "0 or a positive number", v.to_string()));
            }
        }
        if self.actor.realtime_priority > 99 {
            return Err(bad(
                "actor.realtime_priority",
                "0 (off) or a SCHED_FIFO priority 1..=99",
                self.actor.realtime_priority.to_string(),
            ));
        }
        self.validate_gym_table(bad)
    }

    /// The `[gym]` table's own values: folders that exist, a name fit for files, a positive
    /// time limit, kwargs JSON can carry.
    fn validate_gym_table(
        &self,
        bad: &dyn Fn(&str, &str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        if let Some(p) = self.gym.path.iter().find(|p| !p.is_dir()) {
            return Err(bad(
                "gym.path",
                "folders that exist (relative ones are relative to the config file)",
                p.display().to_string(),
            ));
        }
        let file_safe = |c: char| c.is_ascii_alphanumeric() || "._-".contains(c);
        if let Some(name) = self
            .gym
            .name
            .as_ref()
            .filter(|n| n.is_empty() || !n.chars().all(file_safe))
        {
            return Err(bad(
                "gym.name",
                "a name for files: letters, digits, '.', '_' and '-'",
                format!("{name:?}"),
            ));
        }
        if self.gym.max_episode_steps == Some(0) {
            return Err(bad(
                "gym.max_episode_steps",
                "a positive number",
                "0".into(),
            ));
        }
        fn non_finite(v: &toml::Value) -> Option<f64> {
            match v {
                toml::Value::Float(f) if !f.is_finite() => Some(*f),
                toml::Value::Array(a) => a.iter().find_map(non_finite),
                toml::Value::Table(t) => t.values().find_map(non_finite),
                _ => None,
            }
        }
        for (key, v) in &self.gym.kwargs {
            if let Some(f) = non_finite(v) {
                return Err(bad(
                    &format!("gym.kwargs.{key}"),
                    "finite numbers (JSON has no NaN or infinity)",
                    f.to_string(),
                ));
            }
        }
        Ok(())
    }

    /// The `[mpc]` table: positive periods, a known reward that exists, a valid planner.
    fn validate_mpc(
        &self,
        bad: &dyn Fn(&str, &str, String) -> ConfigError,
    ) -> Result<(), ConfigError> {
        let m = &self.mpc;
        if m.model_train_freq == 0 {
            return Err(bad("mpc.model_train_freq", "a positive number", "0".into()));
        }
        if m.reward == PlanReward::Known && mbpo_envs::reward_fn(&self.env).is_none() {
            return Err(bad(
                "mpc.reward",
                &format!(
                    "\"model\" for {} (known rewards exist for {})",
                    self.env,
                    mbpo_envs::REWARD_ENV_IDS.join(", ")
                ),
                "\"known\"".into(),
            ));
        }
        m.planner.validate().map_err(|e| match e {
            mbpo_plan::PlanError::Config {
                key,
                expected,
                found,
            } => bad(&format!("mpc.planner.{key}"), &expected, found),
            other => bad("mpc.planner", "a valid planner", other.to_string()),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Load `text` as a config file from a scratch directory of its own (tests run in
    /// parallel), removed afterwards.
    fn parse(text: &str) -> Result<ExperimentConfig, ConfigError> {
        static CALLS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
        let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        let dir = std::env::temp_dir().join(format!("mbpo-cfg-{}-{call}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join(format!("{:x}.toml", mbpo_core::rng::fnv1a(text.as_bytes())));
        std::fs::write(&path, text).unwrap();
        let parsed = ExperimentConfig::load(&path);
        std::fs::remove_dir_all(&dir).unwrap();
        parsed
    }

    #[test]
    fn shipped_configs_parse_and_validate() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../deploy/configs");
        let mut n = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                match ExperimentConfig::load(&path) {
                    Ok(_) => {}
                    // Without the `mujoco` feature a MuJoCo config must fail, saying how to fix it.
                    Err(e) if !cfg!(feature = "mujoco") && is_mujoco_config(&path) => {
                        assert!(e.to_string().contains("--features mujoco"), "{e}");
                    }
                    Err(e) => panic!("{e}"),
                }
                n += 1;
            }
        }
        assert!(n > 0);
    }

    fn is_mujoco_config(path: &Path) -> bool {
        let text = std::fs::read_to_string(path).unwrap();
        let cfg: ExperimentConfig = toml::from_str(&text).unwrap();
        mbpo_envs::MUJOCO_ENV_IDS.contains(&cfg.env.as_str())
    }

    #[test]
    fn unknown_key_is_rejected_with_its_name() {
        let err = parse("[sac]\ngama = 0.9\n").unwrap_err().to_string();
        assert!(err.contains("gama") && err.contains(".toml"), "{err}");
    }

    #[test]
    fn wrong_type_names_expected_and_found() {
        let err = parse("[sac]\ngamma = \"high\"\n").unwrap_err().to_string();
        assert!(
            err.contains("gamma") && err.contains("string") && err.contains("f32"),
            "{err}"
        );
    }

    #[test]
    fn out_of_range_value_names_key_range_and_value() {
        let err = parse("[sac]\ngamma = 1.5\n").unwrap_err().to_string();
        assert!(
            err.contains("sac.gamma") && err.contains("(0, 1]") && err.contains("1.5"),
            "{err}"
        );
        let err = parse("env = \"CartPole-v1\"\n").unwrap_err().to_string();
        assert!(
            err.contains("Pendulum-v1") && err.contains("CartPole-v1"),
            "{err}"
        );
        // A table's settings are named by their full key, with what they accept.
        let cases = [
            (
                "[model]\nmembers = 3\nelites = 5\n",
                "`model.elites` must be between 1 and members (3), found 5",
            ),
            (
                "[model]\nhidden = [200, 0]\n",
                "`model.hidden` must be positive widths, found [200, 0]",
            ),
            (
                "[model]\nholdout_ratio = 1.5\n",
                "`model.holdout_ratio` must be in (0, 1), found 1.5",
            ),
            // The first model trains on the warm-up alone: 4 rows hold none out at ratio 0.2.
            (
                "[mbpo]\ninit_random_steps = 4\n",
                "`mbpo.init_random_steps` must be at least 5",
            ),
            (
                "[mbpo]\ninit_random_steps = 0\n",
                "the first model trains on the warm-up's transitions alone",
            ),
            (
                "[model]\nholdout_ratio = 0.05\n[mbpo]\ninit_random_steps = 19\n",
                "`mbpo.init_random_steps` must be at least 20",
            ),
            (
                "[actor]\nrealtime_priority = 100\n",
                "`actor.realtime_priority` must be 0 (off) or a SCHED_FIFO priority 1..=99, found 100",
            ),
        ];
        for (text, want) in cases {
            let err = parse(&format!("algo = \"mbpo\"\n{text}"))
                .unwrap_err()
                .to_string();
            assert!(err.contains(want), "{err}");
        }
    }

    fn overridden(overrides: &[&str]) -> Result<ExperimentConfig, ConfigError> {
        let overrides: Vec<String> = overrides.iter().map(|s| s.to_string()).collect();
        let file = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../deploy/configs/pendulum.toml");
        ExperimentConfig::resolve(Some(&file), &overrides)
    }

    #[test]
    fn overrides_apply_in_order_over_the_file() {
        let cfg = overridden(&[
            "sac.gamma=0.98",
            "sac.hidden=[64, 64]",
            "mbpo.updates_per_step=5",
            "sac.target_entropy=-0.5",
            "env=MountainCarContinuous-v0",
            "sac.gamma=0.97",
        ])
        .unwrap();
        assert_eq!(cfg.sac.gamma, 0.97);
        assert_eq!(cfg.sac.hidden, vec![64, 64]);
        assert_eq!(cfg.mbpo.updates_per_step, 5);
        assert_eq!(cfg.sac.target_entropy, Some(-0.5));
        assert_eq!(cfg.env, "MountainCarContinuous-v0");
        // Everything not overridden comes from the file.
        assert_eq!(cfg.mbpo.init_random_steps, 400);
        let no_file = ExperimentConfig::resolve(None, &["seed=7".into()]).unwrap();
        assert_eq!(no_file.seed, 7);
        assert_eq!(no_file.sac, ExperimentConfig::default().sac);
    }

    #[test]
    fn a_bad_file_is_refused_where_an_override_replaces_the_value_and_flags_are_named() {
        let dir = std::env::temp_dir().join(format!("mbpo-config-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let file = dir.join("bad.toml");
        std::fs::write(&file, "seed = 1\n[sac]\ngamma = \"x\"\n").unwrap();
        let err = ExperimentConfig::resolve(Some(&file), &["sac.gamma=0.9".into()])
            .unwrap_err()
            .to_string();
        assert!(err.contains("bad.toml") && err.contains("line 3"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
        let err = ExperimentConfig::resolve_with(None, &["seed=3".into()], |cfg| {
            cfg.steps = 0;
            Ok(())
        })
        .unwrap_err()
        .to_string();
        let want = "config defaults with --set seed=3 and the command line's flags: key `steps`";
        assert!(err.contains(want), "{err}");
    }

    #[test]
    fn bad_overrides_name_the_override_and_the_problem() {
        let err = overridden(&["sac.gama=0.9"]).unwrap_err().to_string();
        assert!(
            err.contains("--set sac.gama=0.9") && err.contains("gama"),
            "{err}"
        );
        let err = overridden(&["sac.gamma=high"]).unwrap_err().to_string();
        assert!(
            err.contains("--set sac.gamma=high") && err.contains("f32"),
            "{err}"
        );
        let err = overridden(&["sac.gamma"]).unwrap_err().to_string();
        assert!(err.contains("key=value"), "{err}");
        let err = overridden(&["seed.x=1"]).unwrap_err().to_string();
        assert!(err.contains("`seed` is a value"), "{err}");
        let err = overridden(&["sac.gamma=1.5"]).unwrap_err().to_string();
        assert!(
            err.contains("--set sac.gamma=1.5") && err.contains("(0, 1]"),
            "{err}"
        );
    }

    #[test]
    fn mpc_settings_are_checked_with_their_keys() {
        let err = parse("algo = \"mpc\"\n[mpc.planner.cem]\nelites = 900\n")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("mpc.planner.cem.elites") && err.contains("900"),
            "{err}"
        );
        let err = parse("algo = \"mpc\"\n[mpc.planner]\nkind = \"ilqr\"\n")
            .unwrap_err()
            .to_string();
        assert!(err.contains("ilqr") && err.contains("cem"), "{err}");
        let cfg =
            parse("algo = \"mpc\"\n[mpc]\nreward = \"model\"\n[mpc.planner]\nkind = \"grad\"\n")
                .unwrap();
        assert_eq!(cfg.mpc.planner.kind, mbpo_plan::PlannerKind::Grad);
        assert_eq!(cfg.mpc.reward, PlanReward::Model);
    }

    #[test]
    fn resolved_config_round_trips() {
        let cfg = ExperimentConfig::default();
        let back: ExperimentConfig = toml::from_str(&cfg.to_toml()).unwrap();
        assert_eq!(back, cfg);
    }

    #[test]
    fn the_target_return_is_the_tasks_unless_the_config_sets_one() {
        let cfg = parse("env = \"Pendulum-v1\"\n").unwrap();
        assert_eq!(cfg.target_return(), Some(-200.0));
        let cfg = parse("env = \"MountainCarContinuous-v0\"\n").unwrap();
        assert_eq!(cfg.target_return(), Some(90.0));
        let cfg = parse("[eval]\ntarget_return = -150\n").unwrap();
        assert_eq!(cfg.target_return(), Some(-150.0));
        // Unset, it stays out of the resolved TOML (run directories of older builds compare equal).
        assert!(!ExperimentConfig::default()
            .to_toml()
            .contains("target_return"));
        let err = parse("[eval]\ntarget_return = nan\n")
            .unwrap_err()
            .to_string();
        assert!(
            err.contains("eval.target_return") && err.contains("finite"),
            "{err}"
        );
    }
}
