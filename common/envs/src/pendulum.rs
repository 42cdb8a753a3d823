//! Pendulum-v1 (Gymnasium `classic_control/pendulum.py`), bit for bit.
//!
//! State `(θ, θ̇)` in f64, observation `[cos θ, sin θ, θ̇]` in f32. One step with `u = clip(a, −2, 2)`:
//!
//! ```text
//! cost = norm(θ)² + 0.1·θ̇² + 0.001·u²        (state before the update; norm(x) = ((x+π) mod 2π) − π)
//! θ̇'  = clip(θ̇ + (3g/(2l)·sin θ + 3/(ml²)·u)·dt, −8, 8)
//! θ'   = θ + θ̇'·dt                            (θ is not wrapped)
//! ```
//!
//! with g = 10, m = l = 1, dt = 0.05; reward = −cost; never terminated, truncated after 200 steps.
//!
//! Gymnasium's action is a float32 NumPy scalar, so every term that involves `u` alone is float32
//! arithmetic (NumPy 2 keeps `float32 op python-float` in float32), and the squares are NumPy
//! scalar powers, which call libm `pow`/`powf` rather than multiplying. Both are copied here; see
//! [`libm_square`] and [`libm_square_f32`].

use mbpo_core::rng::uniform_range_f64;
use mbpo_core::Rng;

use crate::{BoxSpace, Env, EnvError, RestorableEnv, Step};

const ID: &str = "Pendulum-v1";
const LAYOUT: &str = "theta,thetadot";
const MAX_SPEED: f64 = 8.0;
const MAX_TORQUE: f32 = 2.0;
const DT: f64 = 0.05;
const G: f64 = 10.0;
const M: f64 = 1.0;
const L: f64 = 1.0;
const MAX_EPISODE_STEPS: usize = 200;

/// Pendulum-v1 with Gymnasium 1.4's exact arithmetic (see the module docs).
#[derive(Debug, Clone)]
pub struct Pendulum {
    theta: f64,
    thetadot: f64,
    steps: usize,
    observation_space: BoxSpace,
    action_space: BoxSpace,
}

impl Pendulum {
    /// A pendulum hanging still at θ = 0 (call [`Env::reset`] or [`RestorableEnv::reset_to`] before use).
    pub fn new() -> Self {
        let high = [1.0, 1.0, MAX_SPEED as f32];
        Self {
            theta: 0.0,
            thetadot: 0.0,
            steps: 0,
            observation_space: BoxSpace::new(high.iter().map(|h| -h).collect(), high.to_vec()),
            action_space: BoxSpace::new(vec![-MAX_TORQUE], vec![MAX_TORQUE]),
        }
    }

    /// `_get_obs`: cos and sin in f64, then the whole vector cast to f32.
    fn write_obs(&self, obs: &mut [f32]) {
        obs[0] = self.theta.cos() as f32;
        obs[1] = self.theta.sin() as f32;
        obs[2] = self.thetadot as f32;
    }
}

impl Default for Pendulum {
    fn default() -> Self {
        Self::new()
    }
}

/// `x ** 2` on a NumPy float64 scalar: NumPy calls libm `pow(x, 2.0)`, which (in glibc) is not
/// always the correctly rounded `x * x` (about 1 in 1000 random inputs differ by one ulp).
/// The exponent goes through [`std::hint::black_box`] so LLVM cannot fold `pow(x, 2)` into `x * x`.
#[inline]
fn libm_square(x: f64) -> f64 {
    x.powf(std::hint::black_box(2.0))
}

/// `u ** 2` on a NumPy float32 scalar: libm `powf(u, 2.0f)`, which (in glibc) is not always the
/// correctly rounded `u * u` either. Same folding guard as [`libm_square`].
#[inline]
fn libm_square_f32(u: f32) -> f32 {
    u.powf(std::hint::black_box(2.0))
}

/// Gymnasium's `angle_normalize`: `((x + π) % 2π) − π`, with NumPy's float remainder (the `fmod`
/// result moved into `[0, 2π)` by adding the divisor when it is negative).
#[inline]
fn angle_normalize(x: f64) -> f64 {
    let two_pi = 2.0 * std::f64::consts::PI;
    let mut m = (x + std::f64::consts::PI) % two_pi;
    if m < 0.0 {
        m += two_pi;
    }
    m - std::f64::consts::PI
}

impl Env for Pendulum {
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

    /// θ ~ U(−π, π), then θ̇ ~ U(−1, 1), as Gymnasium's `np_random.uniform(low, high)` draws them.
    fn reset(&mut self, rng: &mut Rng, obs: &mut [f32]) -> Result<(), EnvError> {
        use std::f64::consts::PI;
        self.theta = uniform_range_f64(rng, -PI, PI);
        self.thetadot = uniform_range_f64(rng, -1.0, 1.0);
        self.steps = 0;
        self.write_obs(obs);
        Ok(())
    }

    fn step(&mut self, action: &[f32], obs: &mut [f32]) -> Result<Step, EnvError> {
        debug_assert_eq!(action.len(), 1, "{ID}: action has 1 value");
        let (th, thdot) = (self.theta, self.thetadot);
        // np.clip on the float32 action array: stays float32 (NaN passes through, as in NumPy).
        let u = action[0].clamp(-MAX_TORQUE, MAX_TORQUE);
        // `0.001 * (u**2)` is float32 (0.001 rounded to f32, powf, f32 product); it joins the
        // float64 sum only at the last addition.
        let control_cost = 0.001f32 * libm_square_f32(u);
        let cost =
            libm_square(angle_normalize(th)) + 0.1 * libm_square(thdot) + control_cost as f64;
        // `3.0 / (m * l**2) * u` is float32 too (`3.0 * u`, rounded to f32); `3g/(2l)·sin θ` is f64.
        let torque_term = (3.0 / (M * L * L)) as f32 * u;
        let newthdot = thdot + (3.0 * G / (2.0 * L) * th.sin() + torque_term as f64) * DT;
        let newthdot = newthdot.clamp(-MAX_SPEED, MAX_SPEED);
        self.theta = th + newthdot * DT;
        self.thetadot = newthdot;
        self.steps += 1;
        self.write_obs(obs);
        Ok(Step {
            reward: -cost,
            terminated: false,
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

impl RestorableEnv for Pendulum {
    fn set_elapsed_steps(&mut self, steps: usize) {
        self.steps = steps;
    }

    fn state_dim(&self) -> usize {
        2
    }

    fn state_layout(&self) -> &'static str {
        LAYOUT
    }

    fn reset_to(&mut self, state: &[f64], obs: &mut [f32]) -> Result<(), EnvError> {
        let &[theta, thetadot] = state else {
            return Err(EnvError::StateDim {
                env: ID,
                expected: 2,
                found: state.len(),
                layout: LAYOUT,
            });
        };
        self.theta = theta;
        self.thetadot = thetadot;
        self.steps = 0;
        self.write_obs(obs);
        Ok(())
    }

    fn state(&self) -> Vec<f64> {
        vec![self.theta, self.thetadot]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_normalize_matches_python_floor_remainder() {
        use std::f64::consts::PI;
        assert_eq!(angle_normalize(0.0), 0.0);
        assert_eq!(angle_normalize(PI), -PI);
        assert!((angle_normalize(3.0 * PI / 2.0) + PI / 2.0).abs() < 1e-12);
        assert!((angle_normalize(-7.0) - (-7.0 + 2.0 * PI)).abs() < 1e-12);
        assert!((angle_normalize(100.0) - (100.0 - 16.0 * 2.0 * PI)).abs() < 1e-9);
    }
}
