//! Known task rewards `r(obs, act, next_obs)` for planning with a learned model.
//!
//! A planner can score imagined transitions with the model's reward head or, when the task's
//! reward is a known function of the observation (PETS does this for all its tasks), with the
//! function itself: one source of model error fewer. Each function here is written on the
//! *observation* vector (what a model predicts), with the **environment-scale** action (the
//! caller maps the agent's [−1, 1] action to the box first), and comes with its gradient so the
//! gradient-based planner can backpropagate through it.
//!
//! | env | r(obs, a, next_obs) |
//! |---|---|
//! | Pendulum-v1 | −(θ² + 0.1·θ̇² + 0.001·u²), θ = atan2(obs[1], obs[0]), θ̇ = obs[2], u = clip(a, −2, 2) |
//! | MountainCarContinuous-v0 | 100·[next_obs is the goal] − 0.1·a² (a unclipped) |
//!
//! Pitfall: Pendulum's cost is computed from the state **before** the step (Gymnasium's
//! `step` evaluates the cost, then integrates), so it reads `obs`, never `next_obs`; and θ is
//! recovered with `atan2`, which lands in (−π, π] like Gymnasium's `angle_normalize` up to the
//! single point θ = π (where both squares are π²). The observation is f32, so the value matches
//! the environment's f64 reward to about 1e-6 relative, not bit for bit.

use crate::termination::mountain_car as mountain_car_goal;

/// `r(obs, act, next_obs)` for one transition (environment-scale action).
pub type RewardValueFn = fn(obs: &[f32], act: &[f32], next_obs: &[f32]) -> f32;

/// Accumulate `∂r/∂obs`, `∂r/∂act`, `∂r/∂next_obs` times `scale` into the three slices (`+=`).
pub type RewardGradFn = fn(
    obs: &[f32],
    act: &[f32],
    next_obs: &[f32],
    scale: f32,
    d_obs: &mut [f32],
    d_act: &mut [f32],
    d_next_obs: &mut [f32],
);

/// A task's known reward and its gradient.
#[derive(Debug, Clone, Copy)]
pub struct RewardFn {
    /// The reward value.
    pub value: RewardValueFn,
    /// Its gradient (zero where the reward is piecewise constant, e.g. a goal bonus or a clip).
    pub grad: RewardGradFn,
}

/// Pendulum-v1: `−(θ² + 0.1·θ̇² + 0.001·u²)` on the pre-step observation `[cos θ, sin θ, θ̇]`.
pub fn pendulum(obs: &[f32], act: &[f32], _next_obs: &[f32]) -> f32 {
    let theta = obs[1].atan2(obs[0]);
    let u = act[0].clamp(-2.0, 2.0);
    -(theta * theta + 0.1 * obs[2] * obs[2] + 0.001 * u * u)
}

/// Gradient of [`pendulum`]: `∂θ/∂cos = −sin/(cos² + sin²)`, `∂θ/∂sin = cos/(cos² + sin²)`
/// (exact for a model's off-circle predictions too); `∂/∂u` is 0 where the action is clipped.
pub fn pendulum_grad(
    obs: &[f32],
    act: &[f32],
    _next_obs: &[f32],
    scale: f32,
    d_obs: &mut [f32],
    d_act: &mut [f32],
    _d_next_obs: &mut [f32],
) {
    let (c, s) = (obs[0], obs[1]);
    let theta = s.atan2(c);
    let r2 = (c * c + s * s).max(f32::MIN_POSITIVE);
    // r = −θ² − …  ⇒  ∂r/∂θ = −2θ.
    let dr_dtheta = -2.0 * theta * scale;
    d_obs[0] += dr_dtheta * (-s / r2);
    d_obs[1] += dr_dtheta * (c / r2);
    d_obs[2] += -0.2 * obs[2] * scale;
    let a = act[0];
    if (-2.0..=2.0).contains(&a) {
        d_act[0] += -0.002 * a * scale;
    }
}

/// MountainCarContinuous-v0: `100·[goal reached by next_obs] − 0.1·a²` with the **unclipped**
/// action (Gymnasium's `reward -= math.pow(action[0], 2) * 0.1` reads the raw action).
pub fn mountain_car(obs: &[f32], act: &[f32], next_obs: &[f32]) -> f32 {
    let bonus = if mountain_car_goal(obs, act, next_obs) {
        100.0
    } else {
        0.0
    };
    bonus - 0.1 * act[0] * act[0]
}

/// Gradient of [`mountain_car`]: the goal bonus is a step (gradient 0), the penalty `−0.2·a`.
pub fn mountain_car_grad(
    _obs: &[f32],
    act: &[f32],
    _next_obs: &[f32],
    scale: f32,
    _d_obs: &mut [f32],
    d_act: &mut [f32],
    _d_next_obs: &mut [f32],
) {
    d_act[0] += -0.2 * act[0] * scale;
}

#[cfg(test)]
mod tests {
    use crate::{make, reward_fn};
    use mbpo_core::rng::{stream, uniform_range_f32};

    /// Every step of random-action episodes: the known reward from (obs, a, next_obs) equals
    /// the environment's own reward (f64, from its f64 state) to f32 precision.
    fn agrees_with_env(id: &str, episodes: usize) {
        let mut env = make(id).unwrap();
        let r = reward_fn(id).unwrap();
        let mut rng = stream(3, "reward.test", 0);
        let (mut obs, mut next) = (vec![0.0f32; env.obs_dim()], vec![0.0f32; env.obs_dim()]);
        let (low, high) = (env.action_space().low[0], env.action_space().high[0]);
        let mut steps = 0;
        for _ in 0..episodes {
            env.reset(&mut rng, &mut obs).unwrap();
            loop {
                // Some actions outside the box: the clip (Pendulum) and the raw-action penalty
                // (MountainCar) must both be reproduced.
                let a = [uniform_range_f32(&mut rng, 1.25 * low, 1.25 * high)];
                let step = env.step(&a, &mut next).unwrap();
                let got = (r.value)(&obs, &a, &next) as f64;
                let tol = 2e-5 * step.reward.abs().max(1.0);
                assert!(
                    (got - step.reward).abs() <= tol,
                    "{id} step {steps}: obs {obs:?} a {a:?} -> known {got} vs env {}",
                    step.reward
                );
                steps += 1;
                obs.copy_from_slice(&next);
                if step.terminated || step.truncated {
                    break;
                }
            }
        }
        assert!(steps >= episodes, "{id}: {steps} steps");
    }

    #[test]
    fn pendulum_reward_matches_the_environment_including_the_pre_step_state() {
        agrees_with_env("Pendulum-v1", 10);
        // The cost reads the state before the step: from θ = 0 at rest with u = 2 the reward
        // is −0.004 (the control cost only), although the pendulum has moved by then.
        let f = reward_fn("Pendulum-v1").unwrap();
        let moved = [0.999f32, 0.04, 0.5];
        let r = (f.value)(&[1.0, 0.0, 0.0], &[2.0], &moved);
        assert!((r + 0.004).abs() < 1e-7, "{r}");
        // Upside down (θ = π): the largest angle cost, π².
        let r = (f.value)(&[-1.0, 0.0, 0.0], &[0.0], &moved);
        let pi2 = std::f32::consts::PI * std::f32::consts::PI;
        assert!((r + pi2).abs() < 1e-5, "{r}");
    }

    #[test]
    fn mountain_car_reward_matches_the_environment() {
        agrees_with_env("MountainCarContinuous-v0", 3);
        let f = reward_fn("MountainCarContinuous-v0").unwrap();
        // Unclipped action penalty and the goal bonus on next_obs.
        assert!(((f.value)(&[0.0, 0.0], &[1.5], &[0.0, 0.0]) + 0.225).abs() < 1e-7);
        assert!(((f.value)(&[0.4, 0.01], &[0.0], &[0.46, 0.01]) - 100.0).abs() < 1e-5);
    }

    /// Central differences in f64 of the f32 function at points away from kinks.
    fn fd_check(id: &str, obs: &[f32], act: &[f32], next: &[f32]) {
        let f = reward_fn(id).unwrap();
        let (mut d_obs, mut d_act, mut d_next) = (
            vec![0.0f32; obs.len()],
            vec![0.0f32; act.len()],
            vec![0.0f32; next.len()],
        );
        (f.grad)(obs, act, next, 1.0, &mut d_obs, &mut d_act, &mut d_next);
        let h = 1e-3f32;
        let check = |which: usize, i: usize, analytic: f32| {
            let eval = |delta: f32| {
                let (mut o, mut a, mut n) = (obs.to_vec(), act.to_vec(), next.to_vec());
                [&mut o, &mut a, &mut n][which][i] += delta;
                (f.value)(&o, &a, &n) as f64
            };
            let fd = (eval(h) - eval(-h)) / (2.0 * h as f64);
            assert!(
                (fd - analytic as f64).abs() <= 2e-3 * fd.abs().max(1.0),
                "{id} input {which}[{i}]: analytic {analytic} vs finite difference {fd}"
            );
        };
        for (i, &g) in d_obs.iter().enumerate() {
            check(0, i, g);
        }
        for (i, &g) in d_act.iter().enumerate() {
            check(1, i, g);
        }
        for (i, &g) in d_next.iter().enumerate() {
            check(2, i, g);
        }
    }

    #[test]
    fn gradients_match_finite_differences() {
        // Off the unit circle (a model's prediction), both signs of θ, inside the action box.
        fd_check("Pendulum-v1", &[0.6, 0.9, -1.5], &[1.2], &[0.0; 3]);
        fd_check("Pendulum-v1", &[-0.8, -0.5, 3.0], &[-0.7], &[0.0; 3]);
        fd_check("Pendulum-v1", &[0.95, 0.3, 0.1], &[2.6], &[0.0; 3]); // clipped: ∂/∂u = 0
        fd_check(
            "MountainCarContinuous-v0",
            &[-0.5, 0.01],
            &[0.8],
            &[-0.49, 0.01],
        );
    }
}
