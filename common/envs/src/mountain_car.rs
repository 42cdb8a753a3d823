//! MountainCarContinuous-v0 (Gymnasium `classic_control/continuous_mountain_car.py`), bit for bit.
//!
//! State `(p, v)`, observation `[p, v]` in f32. One step with `f = clip(a, −1, 1)`:
//!
//! ```text
//! v' = clip(v + f·0.0015 − 0.0025·cos(3p), −0.07, 0.07)
//! p' = clip(p + v', −1.2, 0.6);  if p' = −1.2 and v' < 0 then v' = 0
//! terminated = p' ≥ 0.45 ∧ v' ≥ 0;  reward = 100·terminated − 0.1·a²   (a unclipped)
//! ```
//!
//! truncated after 999 steps.
//!
//! # Precision
//!
//! Gymnasium stores the state as a float32 array after every step, but its `reset` stores a
//! float64 array, and the step is plain Python arithmetic on NumPy scalars, whose type follows
//! NumPy 2's promotion rules (NEP 50: a Python float next to a float32 scalar is cast to float32
//! and the operation is float32). Hence:
//!
//! * the first step after a reset runs in f64 ([`Precision::F64`]), every later one in f32;
//! * `force * power − 0.0025·cos(3p)` is f32 when the action is inside the bounds (it stays a
//!   float32 scalar), but f64 when it was clipped (Python's `min`/`max` return the Python-float
//!   bound), and is then cast to the velocity's precision;
//! * `cos` itself is always `math.cos` in f64, of `3p` computed in the state's precision;
//! * comparisons with Python floats (`v > 0.07`, `p < −1.2`, `p ≥ 0.45`) are done in the state's
//!   precision too, i.e. against the f32-rounded constants in f32 steps.

use mbpo_core::rng::uniform_range_f64;
use mbpo_core::Rng;

use crate::{BoxSpace, Env, EnvError, RestorableEnv, Step};

const ID: &str = "MountainCarContinuous-v0";
const LAYOUT: &str = "position,velocity";
const MIN_ACTION: f32 = -1.0;
const MAX_ACTION: f32 = 1.0;
const MIN_POSITION: f64 = -1.2;
const MAX_POSITION: f64 = 0.6;
const MAX_SPEED: f64 = 0.07;
const GOAL_POSITION: f64 = 0.45;
const GOAL_VELOCITY: f64 = 0.0;
const POWER: f64 = 0.0015;
const MAX_EPISODE_STEPS: usize = 999;

/// The floating-point type Gymnasium's state array has (and so the next step's arithmetic).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Precision {
    /// Right after `reset`: `np.array([uniform(...), 0])` is float64.
    F64,
    /// After any step: `np.array([position, velocity], dtype=np.float32)`.
    F32,
}

/// MountainCarContinuous-v0 with Gymnasium 1.4's exact arithmetic (see the module docs).
#[derive(Debug, Clone)]
pub struct MountainCarContinuous {
    /// Position; an exact f32 value when `precision` is [`Precision::F32`].
    position: f64,
    /// Velocity; an exact f32 value when `precision` is [`Precision::F32`].
    velocity: f64,
    precision: Precision,
    steps: usize,
    observation_space: BoxSpace,
    action_space: BoxSpace,
}

impl MountainCarContinuous {
    /// A car at rest at the valley's usual start (call [`Env::reset`] or [`RestorableEnv::reset_to`] first).
    pub fn new() -> Self {
        Self {
            position: -0.5,
            velocity: 0.0,
            precision: Precision::F64,
            steps: 0,
            observation_space: BoxSpace::new(
                vec![MIN_POSITION as f32, -MAX_SPEED as f32],
                vec![MAX_POSITION as f32, MAX_SPEED as f32],
            ),
            action_space: BoxSpace::new(vec![MIN_ACTION], vec![MAX_ACTION]),
        }
    }

    fn write_obs(&self, obs: &mut [f32]) {
        obs[0] = self.position as f32;
        obs[1] = self.velocity as f32;
    }

    /// The step in f64: the first step after a reset.
    ///
    /// `accel` is the velocity increment, already in the precision Gymnasium computes it in.
    fn physics_f64(p: f64, v: f64, accel: f64) -> (f64, f64) {
        let v = (v + accel).clamp(-MAX_SPEED, MAX_SPEED);
        let p = (p + v).clamp(MIN_POSITION, MAX_POSITION);
        let v = if p == MIN_POSITION && v < 0.0 { 0.0 } else { v };
        (p, v)
    }

    /// The step in f32: every step but the first. Python-float constants are rounded to f32
    /// (NEP 50), including the clip bounds that replace the value.
    fn physics_f32(p: f32, v: f32, accel: f32) -> (f32, f32) {
        let max_speed = MAX_SPEED as f32;
        let v = (v + accel).clamp(-max_speed, max_speed);
        let p = (p + v).clamp(MIN_POSITION as f32, MAX_POSITION as f32);
        let v = if p == MIN_POSITION as f32 && v < 0.0 {
            0.0
        } else {
            v
        };
        (p, v)
    }
}

impl Default for MountainCarContinuous {
    fn default() -> Self {
        Self::new()
    }
}

impl Env for MountainCarContinuous {
    fn id(&self) -> &'static str {
        ID
    }

    fn observation_space(&self) -> &BoxSpace {
        &self.observation_space
    }

    fn action_space(&self) -> &BoxSpace {
        &self.action_space
    }

    fn elapsed_steps(&self) -> usize {
        self.steps
    }

    fn max_episode_steps(&self) -> usize {
        MAX_EPISODE_STEPS
    }

    /// p ~ U(−0.6, −0.4), v = 0, kept in f64 as Gymnasium's reset does.
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) -> Result<(), EnvError> {
        self.position = uniform_range_f64(rng, -0.6, -0.4);
        self.velocity = 0.0;
        self.precision = Precision::F64;
        self.steps = 0;
        self.write_obs(obs);
        Ok(())
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<Step, EnvError> {
        debug_assert_eq!(action.len(), 1, "{ID}: action has 1 value");
        let a = action[0];
        // `min(max(a, -1.0), 1.0)` with Python's builtins: an in-bounds action stays a float32
        // scalar, a clipped one becomes the Python float bound. NaN passes through (kept f32).
        let clipped = if a < MIN_ACTION {
            Some(MIN_ACTION as f64)
        } else if a > MAX_ACTION {
            Some(MAX_ACTION as f64)
        } else {
            None
        };
        let (p, v) = match self.precision {
            Precision::F64 => {
                let slope = 0.0025 * (3.0 * self.position).cos();
                let accel = match clipped {
                    Some(force) => force * POWER - slope,
                    None => (a * POWER as f32 - slope as f32) as f64,
                };
                Self::physics_f64(self.position, self.velocity, accel)
            }
            Precision::F32 => {
                let (p, v) = (self.position as f32, self.velocity as f32);
                // `3 * position` is a float32 product; `math.cos` takes it as a double.
                let slope = 0.0025 * ((3.0 * p) as f64).cos();
                let accel = match clipped {
                    // Python-float arithmetic, cast to f32 when added to the float32 velocity.
                    Some(force) => (force * POWER - slope) as f32,
                    None => a * POWER as f32 - slope as f32,
                };
                let (p, v) = Self::physics_f32(p, v, accel);
                (p as f64, v as f64)
            }
        };
        // Terminated is decided before the state is rounded to f32, in the step's precision.
        let terminated = match self.precision {
            Precision::F64 => p >= GOAL_POSITION && v >= GOAL_VELOCITY,
            Precision::F32 => p as f32 >= GOAL_POSITION as f32 && v >= GOAL_VELOCITY,
        };
        self.position = p as f32 as f64;
        self.velocity = v as f32 as f64;
        self.precision = Precision::F32;
        self.steps += 1;
        self.write_obs(obs);
        // `math.pow(a, 2) * 0.1` on the unclipped action, in f64. An f32 value squared is exact
        // in f64 (48 significant bits), so libm `pow` and `a * a` agree here.
        let a = a as f64;
        let goal_bonus = if terminated { 100.0 } else { 0.0 };
        let reward = goal_bonus - a * a * 0.1;
        Ok(Step {
            reward,
            terminated,
            truncated: self.steps >= MAX_EPISODE_STEPS,
        })
    }

    fn restorable(&self) -> Option<&dyn RestorableEnv> {
        Some(self)
    }

    fn restorable_mut(&mut self) -> Option<&mut dyn RestorableEnv> {
        Some(self)
    }
}

impl RestorableEnv for MountainCarContinuous {
    fn set_elapsed_steps(&mut self, steps: usize) {
        self.steps = steps;
    }

    fn state_dim(&self) -> usize {
        2
    }

    fn state_layout(&self) -> &'static str {
        LAYOUT
    }

    /// Sets the state as Gymnasium's reset leaves it: a float64 array, so the next step runs in
    /// f64 and the observation is the state rounded to f32.
    fn reset_to(&mut self, state: &[f64], obs: &mut [f32]) -> Result<(), EnvError> {
        let &[position, velocity] = state else {
            return Err(EnvError::StateDim {
                env: ID,
                expected: 2,
                found: state.len(),
                layout: LAYOUT,
            });
        };
        self.position = position;
        self.velocity = velocity;
        self.precision = Precision::F64;
        self.steps = 0;
        self.write_obs(obs);
        Ok(())
    }

    fn state(&self) -> Vec<f64> {
        vec![self.position, self.velocity]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reward_penalises_the_unclipped_action() {
        let mut env = MountainCarContinuous::new();
        let mut obs = [0.0f32; 2];
        env.reset_to(&[-0.5, 0.0], &mut obs).unwrap();
        let step = env.step(&[1.5], &mut obs).unwrap();
        assert_eq!(step.reward, -(1.5f64 * 1.5) * 0.1);
        assert!(!step.terminated && !step.truncated);
    }

    #[test]
    fn left_wall_stops_the_car() {
        let mut env = MountainCarContinuous::new();
        let mut obs = [0.0f32; 2];
        env.reset_to(&[-1.19, -0.05], &mut obs).unwrap();
        env.step(&[-1.0], &mut obs).unwrap();
        assert_eq!(obs, [-1.2f32, 0.0]);
        // At the wall the slope pushes back harder than full reverse power.
        env.step(&[-1.0], &mut obs).unwrap();
        assert!(obs[0] > -1.2f32 && obs[1] > 0.0);
    }

    #[test]
    fn state_is_f32_after_a_step() {
        let mut env = MountainCarContinuous::new();
        let mut obs = [0.0f32; 2];
        env.reset_to(&[-0.5123456789, 0.0], &mut obs).unwrap();
        assert_eq!(env.state(), vec![-0.5123456789, 0.0]);
        env.step(&[0.3], &mut obs).unwrap();
        let s = env.state();
        assert_eq!(s, vec![obs[0] as f64, obs[1] as f64]);
    }
}
