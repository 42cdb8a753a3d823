//! The task registry: every environment the system knows, with everything that depends on the
//! task in one row -- constructor, MBPO's termination rule for model rollouts, the known reward
//! MPC can plan with, the target return of "env steps to target". A [`TaskSpec`] has no
//! defaults, so the compiler refuses a task that forgets one of them; [`make`],
//! [`termination_fn`], [`reward_fn`], [`target_return`] and the id lists all read this table.
//!
//! Built-in tasks are [`BUILTIN`]. A program can add its own at run time with [`register`]
//! (a toy task in a test, a user's environment); ids are unique. A registered task exists in
//! the registering process only: the in-process pipeline sees it, the service binaries that
//! `mbpo run` spawns do not.

use std::sync::RwLock;

use crate::reward::{self, RewardFn};
use crate::termination::{self, TerminationFn};
use crate::{Env, EnvError, GymSpec, MountainCarContinuous, Pendulum, PythonEnv};

/// Everything the system knows about one task.
#[derive(Debug, Clone, Copy)]
pub struct TaskSpec {
    /// Gymnasium id, e.g. `Pendulum-v1`.
    pub id: &'static str,
    /// A fresh environment (reset with [`Env::reset`] before use).
    pub make: fn() -> Result<Box<dyn Env>, EnvError>,
    /// `done(obs, act, next_obs)` on predicted states: MBPO does not learn termination.
    pub termination: TerminationFn,
    /// The task's reward with its gradient, where written by hand (MPC plans with it; without
    /// one it plans with the model's reward head).
    pub reward: Option<RewardFn>,
    /// The return the task counts as solved at: Gymnasium's `reward_threshold`; −200 for
    /// Pendulum-v1, which has none (this project's sample-efficiency line); `None` for tasks
    /// without either. A config's `eval.target_return` overrides it.
    pub target_return: Option<f64>,
    /// A MuJoCo task (built only with the cargo feature `mujoco`).
    pub mujoco: bool,
}

impl TaskSpec {
    /// True when this build can make the task (MuJoCo tasks need the `mujoco` feature).
    pub const fn builds(&self) -> bool {
        !self.mujoco || cfg!(feature = "mujoco")
    }
}

fn pendulum() -> Result<Box<dyn Env>, EnvError> {
    Ok(Box::new(Pendulum::new()))
}

fn mountain_car() -> Result<Box<dyn Env>, EnvError> {
    Ok(Box::new(MountainCarContinuous::new()))
}

/// A MuJoCo task's constructor: the environment with the feature, a clear error without it.
macro_rules! mujoco_task {
    ($id:literal, $termination:expr, $target:expr) => {{
        fn make() -> Result<Box<dyn Env>, EnvError> {
            #[cfg(feature = "mujoco")]
            {
                let task = crate::mujoco::Task::from_id($id).expect("every MuJoCo id has a task");
                Ok(Box::new(crate::mujoco::MujocoEnv::new(task)?))
            }
            #[cfg(not(feature = "mujoco"))]
            Err(EnvError::MujocoNotBuilt($id.to_string()))
        }
        TaskSpec {
            id: $id,
            make,
            termination: $termination,
            reward: None,
            target_return: $target,
            mujoco: true,
        }
    }};
}

/// The built-in tasks. (Ant-v5 and Humanoid-v5 have MBPO's truncated observations: 27 and 45
/// values, positions without the root's x and y, then velocities.)
pub const BUILTIN: &[TaskSpec] = &[
    TaskSpec {
        id: "Pendulum-v1",
        make: pendulum,
        termination: termination::never,
        reward: Some(RewardFn {
            value: reward::pendulum,
            grad: reward::pendulum_grad,
        }),
        target_return: Some(-200.0),
        mujoco: false,
    },
    TaskSpec {
        id: "MountainCarContinuous-v0",
        make: mountain_car,
        termination: termination::mountain_car,
        reward: Some(RewardFn {
            value: reward::mountain_car,
            grad: reward::mountain_car_grad,
        }),
        target_return: Some(90.0),
        mujoco: false,
    },
    mujoco_task!(
        "InvertedPendulum-v5",
        termination::inverted_pendulum,
        Some(950.0)
    ),
    mujoco_task!("HalfCheetah-v5", termination::never, Some(4800.0)),
    mujoco_task!("Hopper-v5", termination::hopper, Some(3800.0)),
    mujoco_task!("Walker2d-v5", termination::walker2d, None),
    mujoco_task!("Ant-v5", termination::ant, Some(6000.0)),
    mujoco_task!("Humanoid-v5", termination::humanoid, None),
];

/// Tasks added at run time with [`register`].
static REGISTERED: RwLock<Vec<TaskSpec>> = RwLock::new(Vec::new());

/// Add a task (its id must be new).
pub fn register(task: TaskSpec) -> Result<(), EnvError> {
    let mut registered = REGISTERED.write().unwrap_or_else(|e| e.into_inner());
    if BUILTIN
        .iter()
        .chain(registered.iter())
        .any(|t| t.id == task.id)
    {
        return Err(EnvError::DuplicateTask(task.id.to_string()));
    }
    registered.push(task);
    Ok(())
}

/// Every known task: the built-in ones, then those registered.
pub fn tasks() -> Vec<TaskSpec> {
    let registered = REGISTERED.read().unwrap_or_else(|e| e.into_inner());
    BUILTIN.iter().chain(registered.iter()).copied().collect()
}

/// The ids this build can make, built-in and registered, joined by ", " (for messages).
pub fn known_ids() -> String {
    let all = tasks();
    let ids = |builds: bool| -> Vec<&str> {
        let of_build = all.iter().filter(|t| t.builds() == builds);
        of_build.map(|t| t.id).collect()
    };
    let (built, not_built) = (ids(true), ids(false));
    match not_built.is_empty() {
        true => built.join(", "),
        false => format!(
            "{}; with `bash deploy/setup_mujoco.sh` and a build with `--features mujoco` also {}",
            built.join(", "),
            not_built.join(", ")
        ),
    }
}

/// The task `id`, or [`EnvError::UnknownEnv`].
pub fn task(id: &str) -> Result<TaskSpec, EnvError> {
    if let Some(t) = BUILTIN.iter().find(|t| t.id == id) {
        return Ok(*t);
    }
    let registered = REGISTERED.read().unwrap_or_else(|e| e.into_inner());
    registered
        .iter()
        .find(|t| t.id == id)
        .copied()
        .ok_or_else(|| EnvError::UnknownEnv(id.to_string()))
}

/// Build an environment by its id: a task of the table, or a Python Gymnasium env (`gym:...`,
/// default interpreter, no keyword arguments; [`crate::PythonEnv::start`] takes the rest).
pub fn make(id: &str) -> Result<Box<dyn Env>, EnvError> {
    match GymSpec::from_id(id) {
        Some(spec) => Ok(Box::new(PythonEnv::start(spec)?)),
        None => (task(id)?.make)(),
    }
}

/// The termination function of the task `id`, or `None` for an unknown id (callers should
/// fail rather than guess: a wrong rule silently ruins MBPO).
pub fn termination_fn(id: &str) -> Option<TerminationFn> {
    task(id).ok().map(|t| t.termination)
}

/// The known reward of the task `id`, or `None` when there is none (then plan with the
/// model's reward head).
pub fn reward_fn(id: &str) -> Option<RewardFn> {
    task(id).ok().and_then(|t| t.reward)
}

/// The return the task `id` counts as solved at (see [`TaskSpec::target_return`]).
pub fn target_return(id: &str) -> Option<f64> {
    task(id).ok().and_then(|t| t.target_return)
}

/// Ids of the built-in tasks [`make`] can build in this build, in table order.
pub const ENV_IDS: &[&str] = &ids::<{ count(Builds) }>(Builds);
/// Ids of the MuJoCo tasks (built only with the `mujoco` feature).
pub const MUJOCO_ENV_IDS: &[&str] = &ids::<{ count(MuJoCo) }>(MuJoCo);
/// Ids of the built-in tasks with a termination function (all of them).
pub const TERMINATION_ENV_IDS: &[&str] = &ids::<{ count(All) }>(All);
/// Ids of the built-in tasks with a known reward.
pub const REWARD_ENV_IDS: &[&str] = &ids::<{ count(WithReward) }>(WithReward);

/// Which built-in tasks an id list holds (const fns cannot take closures).
#[derive(Clone, Copy)]
enum Subset {
    All,
    Builds,
    MuJoCo,
    WithReward,
}
use Subset::*;

const fn holds(subset: Subset, t: &TaskSpec) -> bool {
    match subset {
        All => true,
        Builds => t.builds(),
        MuJoCo => t.mujoco,
        WithReward => t.reward.is_some(),
    }
}

const fn count(subset: Subset) -> usize {
    let (mut i, mut n) = (0, 0);
    while i < BUILTIN.len() {
        if holds(subset, &BUILTIN[i]) {
            n += 1;
        }
        i += 1;
    }
    n
}

const fn ids<const N: usize>(subset: Subset) -> [&'static str; N] {
    let mut out = [""; N];
    let (mut i, mut n) = (0, 0);
    while i < BUILTIN.len() {
        if holds(subset, &BUILTIN[i]) {
            out[n] = BUILTIN[i].id;
            n += 1;
        }
        i += 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_id_lists_follow_the_table() {
        assert_eq!(TERMINATION_ENV_IDS.len(), BUILTIN.len());
        assert_eq!(REWARD_ENV_IDS, ["Pendulum-v1", "MountainCarContinuous-v0"]);
        assert_eq!(
            MUJOCO_ENV_IDS,
            [
                "InvertedPendulum-v5",
                "HalfCheetah-v5",
                "Hopper-v5",
                "Walker2d-v5",
                "Ant-v5",
                "Humanoid-v5"
            ]
        );
        let built = if cfg!(feature = "mujoco") { 8 } else { 2 };
        assert_eq!(ENV_IDS.len(), built);
        for id in ENV_IDS {
            assert_eq!(make(id).unwrap().id(), *id);
        }
    }

    #[test]
    fn unknown_and_duplicate_ids_are_errors_that_name_them() {
        let e = make("CartPole-v1").err().unwrap().to_string();
        assert!(
            e.contains("CartPole-v1") && e.contains("Pendulum-v1"),
            "{e}"
        );
        // Every task is listed; those of another build say how to get them.
        assert!(e.contains("Hopper-v5"), "{e}");
        assert_eq!(
            e.contains("--features mujoco"),
            !cfg!(feature = "mujoco"),
            "{e}"
        );
        let e = register(BUILTIN[0]).unwrap_err();
        assert!(e.to_string().contains("Pendulum-v1"), "{e}");
        if !cfg!(feature = "mujoco") {
            let e = make("Hopper-v5").err().unwrap();
            assert!(matches!(e, EnvError::MujocoNotBuilt(_)), "{e}");
        }
    }
}
