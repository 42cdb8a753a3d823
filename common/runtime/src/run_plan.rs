//! A run resolved once. The launcher (`mbpo run`'s supervisor, the in-process pipeline)
//! validates the config, makes the environment and the model once to learn the sizes of
//! everything that crosses shared memory, and writes them with the run's shape into
//! `<run>/run-plan.json`; the head's gateway hands the same file to every worker. Every process
//! of the run reads it and trusts it: none validates the config again, nor builds an
//! environment or an ensemble to learn sizes.

use std::path::Path;

use mbpo_core::rng::stream;
use mbpo_model::ProbabilisticEnsemble;
use mbpo_sac::TanhGaussianActor;
use mbpo_train::ExperimentConfig;
use mbpo_wire::{ModelWireLayout, RowLayout, WeightsKind};
use serde::{Deserialize, Serialize};

use mbpo_train::algorithm::{self, AlgorithmSpec};

use crate::error::ensure_protocol;
use crate::pipeline::{PipelineRoles, PipelineSpec, RoleKind};
use crate::{Mode, Result, RuntimeError, Slack};
pub use mbpo_core::roles::Slot;

/// The file in a run directory.
pub const RUN_PLAN_FILE: &str = "run-plan.json";

/// This build's format of [`RUN_PLAN_FILE`].
pub const RUN_PLAN_FORMAT: u32 = 1;

/// Widths above this are refused: every network and wire layout is sized from them, and the
/// file may come from another host.
const MAX_WIDTH: usize = 1 << 16;

/// Sizes and layout hashes of everything that crosses shared memory in a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Dims {
    /// Observation width.
    pub obs: usize,
    /// Action width.
    pub act: usize,
    /// `ParamLayout::hash` of the SAC actor.
    pub policy_hash: u64,
    /// Floats in a policy snapshot.
    pub policy_len: usize,
    /// How model snapshots are laid out.
    pub model: ModelWireLayout,
    /// The latent world model's parameters (`algo = "tdmpc"`; every run has the figures).
    #[serde(default)]
    pub world_model: WeightsLayout,
    /// The task's time limit in env steps (TD-MPC2's discount follows from it).
    #[serde(default)]
    pub episode_length: usize,
}

/// The layout hash and length of one flat weight vector.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct WeightsLayout {
    /// What both ends must agree on.
    pub hash: u64,
    /// Floats.
    pub len: usize,
}

impl Dims {
    /// The dimensions of the run configured by `cfg` (makes its environment once).
    pub fn of(cfg: &ExperimentConfig) -> Result<Self> {
        let env = cfg.make_env()?;
        let widths = (env.obs_dim(), env.act_dim());
        Self::with_env_dims(cfg, widths, env.max_episode_steps())
    }

    /// [`Dims::of`] for the launcher of the run in `run_dir`: a Python env's widths come from
    /// the `env.json` written when the env was started once to describe it, so it is not
    /// started again here (a user's env may be costly to make, or drive a robot).
    pub fn of_run(cfg: &ExperimentConfig, run_dir: &Path) -> Result<Self> {
        let path = run_dir.join(mbpo_train::run_dir::ENV_FILE);
        let text = match cfg.is_gym_env() {
            true => std::fs::read_to_string(&path).ok(),
            false => None,
        };
        let Some(text) = text else {
            return Self::of(cfg);
        };
        let json: serde_json::Value = serde_json::from_str(&text).map_err(|e| {
            RuntimeError::protocol(format!("{}: not an env description: {e}", path.display()))
        })?;
        // Every network and wire layout is sized from these: 0 would panic building them, a
        // huge value would allocate its size (the file may come from another host).
        let width = |key: &str| {
            json[key]
                .as_u64()
                .filter(|&v| (1..=MAX_WIDTH as u64).contains(&v))
                .map(|v| v as usize)
                .ok_or_else(|| {
                    RuntimeError::protocol(format!(
                        "{}: no `{key}` in 1..={MAX_WIDTH}",
                        path.display()
                    ))
                })
        };
        let widths = (width("obs_dim")?, width("act_dim")?);
        let episode_length = json["max_episode_steps"].as_u64().unwrap_or(0) as usize;
        Self::with_env_dims(cfg, widths, episode_length)
    }

    fn with_env_dims(
        cfg: &ExperimentConfig,
        (obs, act): (usize, usize),
        episode_length: usize,
    ) -> Result<Self> {
        let net = actor_net(cfg, obs, act);
        // Architecture only; the stream is never used for anything else.
        let model = ProbabilisticEnsemble::new(
            obs,
            act,
            cfg.model_config(),
            &mut stream(cfg.seed, "wire.model-shape", 0),
        )
        .map_err(|e| RuntimeError::Model(e.to_string()))?;
        Ok(Self {
            obs,
            act,
            policy_hash: net.layout().hash(),
            policy_len: net.num_params(),
            model: ModelWireLayout::of_model(&model, cfg.model.elites),
            world_model: {
                let (hash, len) = mbpo_train::tdmpc::roles::world_model_layout(cfg, obs, act);
                WeightsLayout { hash, len }
            },
            episode_length,
        })
    }
    /// The layout hash and length of the weights of `kind` in this run.
    pub fn weights_layout(&self, kind: WeightsKind) -> (u64, usize) {
        match kind {
            WeightsKind::Policy => (self.policy_hash, self.policy_len),
            WeightsKind::Model => (self.model.layout_hash, self.model.len()),
            WeightsKind::WorldModel => (self.world_model.hash, self.world_model.len),
        }
    }
    /// The transition row layout.
    pub fn rows(&self) -> RowLayout {
        RowLayout::new(self.obs, self.act)
    }
}

pub(crate) fn actor_net(cfg: &ExperimentConfig, obs: usize, act: usize) -> TanhGaussianActor {
    let s = &cfg.sac;
    TanhGaussianActor::new(obs, act, &s.hidden, s.log_std_min, s.log_std_max)
}

/// What every process of a run is told, once.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ResolvedRun {
    /// [`RUN_PLAN_FORMAT`] of the build that wrote it.
    pub format: u32,
    /// Sizes and layout hashes of what crosses shared memory.
    pub dims: Dims,
    /// Hand-off mode.
    pub mode: Mode,
    /// Training actors, local and remote.
    pub actors: u16,
    /// Actors on the head (slots `0..local_actors`); the rest run on workers.
    pub local_actors: u16,
    /// Slack of pipelined mode (as given; zero is used in lockstep).
    pub slack: Slack,
    /// Roles besides the actors that run on workers (`mbpo run --remote-roles`), whose ports
    /// the head's gateway stands in for (absent in plans of builds before them: none).
    #[serde(default)]
    pub remote_services: Vec<RoleKind>,
    /// The run's algorithm and its roles (absent in plans of builds before it: the config's
    /// `algo` is then a built-in one).
    #[serde(default)]
    pub algorithm: Option<AlgorithmRow>,
}

/// The run's algorithm as the pipeline runs it: its name and its roles, the algorithm table's
/// row. A program that registered an algorithm (`mbpo_train::algorithm::register`) launches
/// it with role binaries that never heard of it: each process of the run learns it here
/// ([`AlgorithmRow::make_known`]) before it reads the config that names it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct AlgorithmRow {
    /// The config's `algo`.
    pub name: String,
    /// Its roles besides the training actors, in start order.
    pub services: Vec<RoleKind>,
    /// What its training actors are.
    pub actor: RoleKind,
}

impl AlgorithmRow {
    /// The row of `pipeline`.
    pub fn of(pipeline: &PipelineSpec) -> Self {
        Self {
            name: pipeline.algo.into(),
            services: pipeline.services.to_vec(),
            actor: pipeline.actor,
        }
    }

    /// Make the algorithm known in this process: one this process knows (built in, or
    /// registered by its program) must have these roles; another is registered for its roles
    /// alone (its single-process run refuses: only its launcher's program has it).
    pub fn make_known(&self) -> Result<()> {
        for _ in 0..2 {
            if let Some(known) = algorithm::lookup(&self.name) {
                let roles = known.pipeline.map(|p| (p.services.to_vec(), p.actor));
                ensure_protocol!(
                    roles == Some((self.services.clone(), self.actor)),
                    "the run plan's algorithm '{}' has roles {:?} and actors {:?}, this build's {:?}: run every process of a run with one build",
                    self.name,
                    self.services,
                    self.actor,
                    roles
                );
                return Ok(());
            }
            let spec = AlgorithmSpec {
                name: Box::leak(self.name.clone().into_boxed_str()),
                train: runs_only_as_roles,
                pipeline: Some(PipelineRoles {
                    services: Box::leak(self.services.clone().into_boxed_slice()),
                    actor: self.actor,
                }),
            };
            // Another thread of this process may have made it known meanwhile: look again.
            if algorithm::register(spec).is_ok() {
                return Ok(());
            }
        }
        Err(RuntimeError::protocol(format!(
            "the run plan's algorithm '{}' could not be registered",
            self.name
        )))
    }

    /// What is wrong with it, if anything (the plan may come from another host).
    fn check(&self) -> std::result::Result<(), String> {
        let name_ok = !self.name.is_empty()
            && self.name.len() <= 64
            && self.name.bytes().all(|b| b.is_ascii_graphic());
        if !name_ok {
            return Err(format!(
                "algorithm name {:?} is not a config key",
                self.name
            ));
        }
        if !self.actor.is_actor() || self.services.iter().any(|k| k.is_actor()) {
            return Err(format!(
                "algorithm '{}': actors {:?} and services {:?} (actors must be an actor kind, services none)",
                self.name, self.actor, self.services
            ));
        }
        Ok(())
    }
}

/// The single-process run of an algorithm learned from a run plan: its code is in the program
/// that launched the run, not here.
fn runs_only_as_roles(
    cfg: &ExperimentConfig,
    _: &Path,
    _: mbpo_train::RunOptions,
) -> std::result::Result<mbpo_train::Summary, mbpo_train::TrainError> {
    Err(mbpo_train::TrainError::Config(format!(
        "algorithm '{}' is known here from a run plan, for its roles: train it with the program that registered it",
        cfg.algo.name()
    )))
}

impl ResolvedRun {
    /// The plan of a run of `pipeline` and `dims` with `actors` actors, `local_actors` of them
    /// on this host.
    pub fn new(
        pipeline: &PipelineSpec,
        dims: Dims,
        mode: Mode,
        actors: u16,
        local_actors: u16,
        slack: Slack,
    ) -> Self {
        Self {
            format: RUN_PLAN_FORMAT,
            dims,
            mode,
            actors,
            local_actors,
            slack,
            remote_services: Vec::new(),
            algorithm: Some(AlgorithmRow::of(pipeline)),
        }
    }

    /// The same plan with `services` run on workers.
    pub fn with_remote_services(mut self, services: Vec<RoleKind>) -> Self {
        self.remote_services = services;
        self
    }

    /// The role processes workers run for this plan: actors `local_actors..actors` (of
    /// `actor`), then the remote services.
    pub fn remote_slots(&self, actor: RoleKind) -> Vec<Slot> {
        let actors = (self.local_actors..self.actors).map(|i| Slot::new(actor, i));
        let services = self.remote_services.iter().map(|&k| Slot::new(k, 0));
        actors.chain(services).collect()
    }

    /// Write `<run_dir>/run-plan.json`.
    pub fn write(&self, run_dir: &Path) -> Result<()> {
        let path = run_dir.join(RUN_PLAN_FILE);
        let text = serde_json::to_string_pretty(self).expect("a plan always serializes");
        std::fs::write(&path, text + "\n").map_err(|source| RuntimeError::Io { path, source })
    }

    /// Read `<run_dir>/run-plan.json`; an error names the file and what is wrong with it.
    pub fn read(run_dir: &Path) -> Result<Self> {
        let path = run_dir.join(RUN_PLAN_FILE);
        let text = std::fs::read_to_string(&path).map_err(|source| RuntimeError::Io {
            path: path.clone(),
            source,
        })?;
        Self::parse(&text).map_err(|why| {
            RuntimeError::protocol(format!(
                "{}: {why} (the launcher of the run writes it: start the run with `mbpo run`)",
                path.display()
            ))
        })
    }

    /// The plan in `text`, checked.
    pub fn parse(text: &str) -> std::result::Result<Self, String> {
        let plan: Self = serde_json::from_str(text).map_err(|e| format!("not a run plan: {e}"))?;
        if plan.format != RUN_PLAN_FORMAT {
            return Err(format!(
                "format {}, this build reads format {RUN_PLAN_FORMAT}: run every host with one build",
                plan.format
            ));
        }
        let d = plan.dims;
        let widths = [d.obs, d.act, d.policy_len, d.model.in_dim];
        if widths.contains(&0) || d.obs > MAX_WIDTH || d.act > MAX_WIDTH {
            return Err(format!(
                "sizes out of range: obs {}, act {} (1..={MAX_WIDTH}), policy {}, model inputs {}",
                d.obs, d.act, d.policy_len, d.model.in_dim
            ));
        }
        if let Some(k) = plan.remote_services.iter().find(|k| k.is_actor()) {
            return Err(format!(
                "{k:?} among the remote services: actors are remote by slot (local_actors)"
            ));
        }
        if let Some(row) = &plan.algorithm {
            row.check()?;
        }
        if plan.local_actors > plan.actors {
            return Err(format!(
                "{} local actors of {}",
                plan.local_actors, plan.actors
            ));
        }
        Ok(plan)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mbpo_wire::ModelWireLayout;

    fn plan() -> ResolvedRun {
        let model = ModelWireLayout {
            layout_hash: 7,
            n_params: 100,
            in_dim: 4,
            elites: 3,
            termination: 0,
        };
        let dims = Dims {
            obs: 3,
            act: 1,
            policy_hash: 9,
            policy_len: 50,
            model,
            world_model: WeightsLayout { hash: 11, len: 80 },
            episode_length: 200,
        };
        let mbpo = crate::pipeline::spec(mbpo_train::Algo::MBPO).unwrap();
        ResolvedRun::new(mbpo, dims, Mode::Pipelined, 3, 1, Slack::ZERO)
    }

    #[test]
    fn a_plan_reads_back_as_written() {
        let dir = std::env::temp_dir().join(format!("run-plan-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        plan().write(&dir).unwrap();
        assert_eq!(ResolvedRun::read(&dir).unwrap(), plan());
        std::fs::remove_dir_all(&dir).unwrap();
        let err = ResolvedRun::read(&dir).unwrap_err().to_string();
        assert!(err.contains("run-plan.json"), "{err}");
    }

    #[test]
    fn the_remote_slots_are_the_actors_past_the_local_ones_then_the_remote_services() {
        let p = plan().with_remote_services(vec![RoleKind::Evaluator]);
        let names: Vec<String> = p
            .remote_slots(RoleKind::Actor)
            .iter()
            .map(|s| s.name())
            .collect();
        assert_eq!(names, ["actor-1", "actor-2", "evaluator"]);
        let text = serde_json::to_string(&p).unwrap();
        assert!(
            text.contains(r#""remote_services":["evaluator"]"#),
            "{text}"
        );
        assert_eq!(ResolvedRun::parse(&text).unwrap(), p);
        // A plan of a build before remote services reads as none.
        let old = text.replace(r#","remote_services":["evaluator"]"#, "");
        assert_eq!(ResolvedRun::parse(&old).unwrap(), plan());
        let actor = text.replace(r#"["evaluator"]"#, r#"["actor"]"#);
        assert!(ResolvedRun::parse(&actor)
            .unwrap_err()
            .contains("remote by slot"));
    }

    #[test]
    fn a_plans_algorithm_is_made_known_and_another_of_a_known_name_is_refused() {
        let mpc_roles = vec![RoleKind::ModelTrainer, RoleKind::PlanningEvaluator];
        let row = AlgorithmRow {
            name: "plan-only-mpc".into(),
            services: mpc_roles.clone(),
            actor: RoleKind::PlanningActor,
        };
        assert!(algorithm::lookup(&row.name).is_none());
        row.make_known().unwrap();
        let known = algorithm::lookup(&row.name).unwrap().pipeline.unwrap();
        assert_eq!((known.services, known.actor), (&mpc_roles[..], row.actor));
        row.make_known().unwrap(); // known now, with the same roles
        let p = crate::pipeline::spec(mbpo_train::Algo::parse(&row.name).unwrap()).unwrap();
        assert_eq!(AlgorithmRow::of(p), row);
        // MBPO under MPC's roles: another build's table.
        let renamed = AlgorithmRow {
            name: "mbpo".into(),
            ..row.clone()
        };
        let err = renamed.make_known().unwrap_err().to_string();
        assert!(
            err.contains("run every process of a run with one build"),
            "{err}"
        );
        for (name, actor) in [("two words", row.actor), ("ok", RoleKind::Learner)] {
            let bad = AlgorithmRow {
                name: name.into(),
                actor,
                ..row.clone()
            };
            let mut p = plan();
            p.algorithm = Some(bad);
            let text = serde_json::to_string(&p).unwrap();
            let err = ResolvedRun::parse(&text).unwrap_err();
            assert!(err.contains(name), "{err}");
        }
    }

    #[test]
    fn a_damaged_or_foreign_plan_is_refused_with_the_reason() {
        let text = |p: &ResolvedRun| serde_json::to_string(p).unwrap();
        let mut p = plan();
        p.format = 99;
        assert!(ResolvedRun::parse(&text(&p))
            .unwrap_err()
            .contains("format 99"));
        let mut p = plan();
        p.dims.obs = 0;
        assert!(ResolvedRun::parse(&text(&p)).unwrap_err().contains("obs 0"));
        let mut p = plan();
        p.local_actors = 4;
        assert!(ResolvedRun::parse(&text(&p))
            .unwrap_err()
            .contains("4 local actors of 3"));
        assert!(ResolvedRun::parse("{}")
            .unwrap_err()
            .contains("not a run plan"));
    }
}
