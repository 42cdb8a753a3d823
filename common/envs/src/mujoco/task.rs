//! What differs between the six Gymnasium v5 MuJoCo tasks: model file, frame skip, reset noise,
//! observation, reward terms and health rule, each transcribed from Gymnasium 1.4's
//! `gymnasium/envs/mujoco/<task>_v5.py` with its default constructor arguments but MBPO's
//! truncated observations (Ant with `include_cfrc_ext_in_observation=False`; Humanoid with
//! `include_cinert_in_observation`, `include_cvel_in_observation`,
//! `include_qfrc_actuator_in_observation` and `include_cfrc_ext_in_observation` all False: the
//! paper's HumanoidTruncatedObs, positions without the root's x and y, then velocities).
//!
//! Arithmetic follows NumPy's types so rewards round as Gymnasium's do: the control cost
//! `w * np.sum(np.square(action))` is float32 (the action is a float32 array and a Python float
//! weight stays float32 under NumPy 2's promotion rules) and joins the float64 reward at the last
//! subtraction; everything read from MuJoCo is float64.

use crate::numpy_sum::{pairwise_sum, sum_of_squares_f32};

/// The MuJoCo tasks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Task {
    /// Cart-pole balancing: reward 1 per step while |pole angle| ≤ 0.2.
    InvertedPendulum,
    /// Planar cheetah running forward; never terminates.
    HalfCheetah,
    /// Planar one-legged hopper; terminates when it falls or its state leaves (−100, 100).
    Hopper,
    /// Planar biped; terminates when its torso leaves 0.8 < z < 2 or |angle| ≥ 1.
    Walker2d,
    /// Quadruped; terminates when the torso leaves 0.2 ≤ z ≤ 1 or the state is not finite.
    Ant,
    /// 3D biped; terminates when the torso leaves 1 < z < 2.
    Humanoid,
}

/// How Gymnasium perturbs the initial velocities at reset (positions always get uniform noise).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum VelocityNoise {
    /// `init_qvel + U(-scale, scale)`.
    Uniform,
    /// `init_qvel + scale * N(0, 1)`.
    Normal,
}

/// Episode length of every task (Gymnasium's registered `max_episode_steps`).
pub const MAX_EPISODE_STEPS: usize = 1000;

impl Task {
    /// Every task, in the order `make` lists them.
    pub const ALL: [Task; 6] = [
        Task::InvertedPendulum,
        Task::HalfCheetah,
        Task::Hopper,
        Task::Walker2d,
        Task::Ant,
        Task::Humanoid,
    ];

    /// The task of a Gymnasium id.
    pub fn from_id(id: &str) -> Option<Task> {
        Task::ALL.into_iter().find(|t| t.id() == id)
    }

    /// Gymnasium id.
    pub fn id(self) -> &'static str {
        match self {
            Task::InvertedPendulum => "InvertedPendulum-v5",
            Task::HalfCheetah => "HalfCheetah-v5",
            Task::Hopper => "Hopper-v5",
            Task::Walker2d => "Walker2d-v5",
            Task::Ant => "Ant-v5",
            Task::Humanoid => "Humanoid-v5",
        }
    }

    /// MJCF file in Gymnasium's `envs/mujoco/assets` (v5 Walker2d has its own file).
    pub fn xml_file(self) -> &'static str {
        match self {
            Task::InvertedPendulum => "inverted_pendulum.xml",
            Task::HalfCheetah => "half_cheetah.xml",
            Task::Hopper => "hopper.xml",
            Task::Walker2d => "walker2d_v5.xml",
            Task::Ant => "ant.xml",
            Task::Humanoid => "humanoid.xml",
        }
    }

    /// MuJoCo steps per environment step.
    pub fn frame_skip(self) -> usize {
        match self {
            Task::InvertedPendulum => 2,
            Task::HalfCheetah | Task::Ant | Task::Humanoid => 5,
            Task::Hopper | Task::Walker2d => 4,
        }
    }

    /// Reset noise scale and the kind of velocity noise.
    pub fn reset_noise(self) -> (f64, VelocityNoise) {
        match self {
            Task::InvertedPendulum => (0.01, VelocityNoise::Uniform),
            Task::HalfCheetah | Task::Ant => (0.1, VelocityNoise::Normal),
            Task::Hopper | Task::Walker2d => (0.005, VelocityNoise::Uniform),
            Task::Humanoid => (0.01, VelocityNoise::Uniform),
        }
    }

    /// Leading qpos values left out of the observation (`exclude_current_positions_from_observation`).
    pub fn skipped_qpos(self) -> usize {
        match self {
            Task::InvertedPendulum => 0,
            Task::HalfCheetah | Task::Hopper | Task::Walker2d => 1,
            Task::Ant | Task::Humanoid => 2,
        }
    }

    /// Hopper and Walker2d clip the velocities in the observation to [−10, 10].
    pub fn clips_velocity_in_observation(self) -> bool {
        matches!(self, Task::Hopper | Task::Walker2d)
    }

    /// Names of the state values `reset_to` takes: qpos then qvel.
    pub fn state_layout(self) -> &'static str {
        match self {
            Task::InvertedPendulum => "qpos[2] (slider, hinge), qvel[2]",
            Task::HalfCheetah => "qpos[9] (rootx, rootz, rooty, 6 joints), qvel[9]",
            Task::Hopper => "qpos[6] (rootx, rootz, rooty, 3 joints), qvel[6]",
            Task::Walker2d => "qpos[9] (rootx, rootz, rooty, 6 joints), qvel[9]",
            Task::Ant => "qpos[15] (x, y, z, quaternion w x y z, 8 joints), qvel[14]",
            Task::Humanoid => "qpos[24] (x, y, z, quaternion w x y z, 17 joints), qvel[23]",
        }
    }

    /// `_get_obs`: qpos without the skipped values, then qvel (clipped for Hopper/Walker2d).
    pub fn write_observation(self, qpos: &[f64], qvel: &[f64], obs: &mut [f64]) {
        let pos = &qpos[self.skipped_qpos()..];
        let (obs_pos, obs_vel) = obs.split_at_mut(pos.len());
        obs_pos.copy_from_slice(pos);
        if self.clips_velocity_in_observation() {
            for (o, &v) in obs_vel.iter_mut().zip(qvel) {
                // np.clip; NaN passes through (as f64::clamp does).
                *o = v.clamp(-10.0, 10.0);
            }
        } else {
            obs_vel.copy_from_slice(qvel);
        }
    }

    /// Reward and `terminated` of one step, from the state after it.
    pub fn reward(self, s: &mut StepState<'_>) -> (f64, bool) {
        match self {
            Task::InvertedPendulum => inverted_pendulum(s),
            Task::HalfCheetah => half_cheetah(s),
            Task::Hopper => healthy_forward_reward(s, 0.001, hopper_is_healthy(s.qpos, s.qvel)),
            Task::Walker2d => healthy_forward_reward(s, 0.001, walker2d_is_healthy(s.qpos)),
            Task::Ant => ant(s),
            Task::Humanoid => humanoid(s),
        }
    }
}

/// What the reward functions read after a step.
pub struct StepState<'a> {
    /// Generalised positions after the step.
    pub qpos: &'a [f64],
    /// Generalised velocities after the step.
    pub qvel: &'a [f64],
    /// The observation after the step (float64).
    pub obs: &'a [f64],
    /// `(x_after - x_before) / dt` of the task's forward coordinate.
    pub x_velocity: f64,
    /// The action as given (MuJoCo clamps the control; the cost uses the unclamped action).
    pub action: &'a [f32],
    /// `data.cfrc_ext` flattened (nbody × 6; Ant and Humanoid, empty otherwise).
    pub cfrc_ext: &'a [f64],
    /// Scratch space of `cfrc_ext.len()` values for the contact cost.
    pub scratch: &'a mut [f64],
}

/// `ctrl_cost_weight * np.sum(np.square(action))` in float32.
fn control_cost(weight: f32, action: &[f32]) -> f32 {
    weight * sum_of_squares_f32(action)
}

/// InvertedPendulum-v5: terminated when the observation is not finite or |angle| > 0.2;
/// reward `int(not terminated)`.
fn inverted_pendulum(s: &StepState<'_>) -> (f64, bool) {
    let terminated = !s.obs.iter().all(|v| v.is_finite()) || s.obs[1].abs() > 0.2;
    (if terminated { 0.0 } else { 1.0 }, terminated)
}

/// HalfCheetah-v5: `1.0 * x_velocity - 0.1 * sum(action²)`; never terminates.
fn half_cheetah(s: &StepState<'_>) -> (f64, bool) {
    let forward = 1.0 * s.x_velocity;
    (forward - control_cost(0.1, s.action) as f64, false)
}

/// Hopper-v5 and Walker2d-v5: `(1.0 * x_velocity + healthy) - w * sum(action²)`, where the
/// healthy reward is 1 only while healthy (so 0 on the terminating step); terminated = unhealthy.
fn healthy_forward_reward(s: &StepState<'_>, ctrl_weight: f32, healthy: bool) -> (f64, bool) {
    let rewards = 1.0 * s.x_velocity + if healthy { 1.0 } else { 0.0 };
    (
        rewards - control_cost(ctrl_weight, s.action) as f64,
        !healthy,
    )
}

/// Hopper-v5 `is_healthy`: qpos[2:] and the unclipped qvel all in (−100, 100), z = qpos[1] > 0.7,
/// −0.2 < angle = qpos[2] < 0.2. NaN fails every comparison, so it is unhealthy.
pub fn hopper_is_healthy(qpos: &[f64], qvel: &[f64]) -> bool {
    let state_ok = qpos[2..]
        .iter()
        .chain(qvel)
        .all(|&v| -100.0 < v && v < 100.0);
    let (z, angle) = (qpos[1], qpos[2]);
    state_ok && 0.7 < z && z < f64::INFINITY && -0.2 < angle && angle < 0.2
}

/// Walker2d-v5 `is_healthy`: 0.8 < z = qpos[1] < 2 and −1 < angle = qpos[2] < 1.
pub fn walker2d_is_healthy(qpos: &[f64]) -> bool {
    let (z, angle) = (qpos[1], qpos[2]);
    0.8 < z && z < 2.0 && -1.0 < angle && angle < 1.0
}

/// Ant-v5 `is_healthy`: qpos and qvel finite and 0.2 ≤ z = qpos[2] ≤ 1.
pub fn ant_is_healthy(qpos: &[f64], qvel: &[f64]) -> bool {
    let finite = qpos.iter().chain(qvel).all(|v| v.is_finite());
    finite && 0.2 <= qpos[2] && qpos[2] <= 1.0
}

/// Ant-v5: `(x_velocity * 1 + healthy) - (0.5 * sum(action²) + 5e-4 * sum(clip(cfrc_ext, −1, 1)²))`.
/// The contact cost is float64 and summed over the whole nbody × 6 array (world body included),
/// even though the truncated observation leaves the contact forces out.
fn ant(s: &mut StepState<'_>) -> (f64, bool) {
    let healthy = ant_is_healthy(s.qpos, s.qvel);
    let rewards = s.x_velocity * 1.0 + if healthy { 1.0 } else { 0.0 };
    for (d, &f) in s.scratch.iter_mut().zip(s.cfrc_ext) {
        let c = f.clamp(-1.0, 1.0);
        *d = c * c;
    }
    let contact_cost = 5e-4 * pairwise_sum(&s.scratch[..s.cfrc_ext.len()]);
    let costs = control_cost(0.5, s.action) as f64 + contact_cost;
    (rewards - costs, !healthy)
}

/// Humanoid-v5 `is_healthy`: 1 < z = qpos[2] < 2 (NaN fails both comparisons).
pub fn humanoid_is_healthy(qpos: &[f64]) -> bool {
    1.0 < qpos[2] && qpos[2] < 2.0
}

/// Humanoid-v5: `(1.25 * x_velocity + 5 * healthy) - (0.1 * sum(ctrl²) + clip(5e-7 *
/// sum(cfrc_ext²), −inf, 10))`, all float64: the control cost reads `data.ctrl` (the action as
/// float64), the contact cost the whole nbody × 6 `cfrc_ext`; x_velocity is that of the centre of
/// mass ([`mass_center_x`]).
fn humanoid(s: &mut StepState<'_>) -> (f64, bool) {
    let healthy = humanoid_is_healthy(s.qpos);
    let rewards = 1.25 * s.x_velocity + if healthy { 5.0 } else { 0.0 };
    let n = s.action.len();
    for (d, &a) in s.scratch.iter_mut().zip(s.action) {
        let c = a as f64;
        *d = c * c;
    }
    let ctrl_cost = 0.1 * pairwise_sum(&s.scratch[..n]);
    for (d, &f) in s.scratch.iter_mut().zip(s.cfrc_ext) {
        *d = f * f;
    }
    // np.clip(cost, -inf, 10): NaN stays NaN.
    let contact_cost = match 5e-7 * pairwise_sum(&s.scratch[..s.cfrc_ext.len()]) {
        c if c > 10.0 => 10.0,
        c => c,
    };
    (rewards - (ctrl_cost + contact_cost), !healthy)
}

/// The x of the centre of mass, as Gymnasium's `mass_center`: `np.einsum("b,bj->j", body_mass,
/// xipos)` adds `mass · x` body by body in order (checked against NumPy 2.4 bit for bit), over
/// `body_mass.sum()`, a pairwise sum.
pub fn mass_center_x(body_mass: &[f64], xipos: &[[f64; 3]]) -> f64 {
    let num = body_mass
        .iter()
        .zip(xipos)
        .fold(0.0, |acc, (&m, p)| acc + m * p[0]);
    num / pairwise_sum(body_mass)
}
