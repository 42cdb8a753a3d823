//! Hand-written termination functions `done(obs, act, next_obs)` for model rollouts (each
//! task's is named in its row of [`crate::registry`]).
//!
//! MBPO does not learn termination: a model transition is terminal when the task's own rule
//! says the predicted next observation is (`mbpo/static/*.py`; mbrl-lib `termination_fns.py`).
//! Each rule below is the negation of the environment's health condition, written on the
//! observation vector so it applies to predicted states:
//!
//! | env | done when |
//! |---|---|
//! | Pendulum-v1, HalfCheetah-v5 | never |
//! | MountainCarContinuous-v0 | position ≥ 0.45 ∧ velocity ≥ 0 |
//! | Hopper-v5 | ¬[all finite ∧ all \|obs[1:]\| < 100 ∧ obs[0] > 0.7 ∧ \|obs[1]\| < 0.2] |
//! | Walker2d-v5 | ¬[0.8 < obs[0] < 2 ∧ −1 < obs[1] < 1] |
//! | Ant-v5 (truncated obs) | ¬[all finite ∧ 0.2 ≤ obs[0] ≤ 1] |
//! | Humanoid-v5 (truncated obs) | ¬[1 < obs[0] < 2] |
//! | InvertedPendulum-v5 | ¬[all finite ∧ \|obs[1]\| ≤ 0.2] |
//!
//! The MuJoCo rules assume the v5 default `exclude_current_positions_from_observation=True`, so
//! obs[0] is the torso height z (and obs[1] its angle for Hopper/Walker). Ant and Humanoid are
//! the "truncated observation" variants MBPO uses (no contact forces etc.); the rule reads only
//! obs[0], so it holds for any of their observation sets.
//!
//! Comparisons are written as health conditions that NaN fails, so a model that predicts NaN
//! ends its rollout (except HalfCheetah and Pendulum, which never terminate).
//!
//! Pitfalls this module avoids: MBPO's Hopper rule `np.abs(next_obs[:,1:] < 100)` takes the
//! absolute value of a boolean, so large *negative* values never terminate (mbrl-lib #113); and
//! running Humanoid with Ant's rule (mbrl-lib #138) — each id maps to its own function.

/// `done(obs, act, next_obs)` for one transition.
pub type TerminationFn = fn(obs: &[f32], act: &[f32], next_obs: &[f32]) -> bool;

fn all_finite(x: &[f32]) -> bool {
    x.iter().all(|v| v.is_finite())
}

/// Tasks without terminal states (time limits are truncation, not termination).
pub fn never(_obs: &[f32], _act: &[f32], _next_obs: &[f32]) -> bool {
    false
}

/// MountainCarContinuous-v0: the goal `position ≥ 0.45 ∧ velocity ≥ 0`, on the f32 observation
/// (the environment compares the f32 state after every step but the first after a reset, which
/// it decides in f64 before rounding; a predicted state has only the f32 value anyway).
pub fn mountain_car(_obs: &[f32], _act: &[f32], next_obs: &[f32]) -> bool {
    next_obs[0] >= 0.45f32 && next_obs[1] >= 0.0
}

/// Hopper-v5: unhealthy unless every value is finite, |obs[1:]| < 100, height obs[0] > 0.7 and
/// |angle obs[1]| < 0.2 (Gymnasium's `healthy_state_range`, `healthy_z_range`,
/// `healthy_angle_range`). The absolute value is of the observation, not of the comparison.
pub fn hopper(_obs: &[f32], _act: &[f32], next_obs: &[f32]) -> bool {
    let (height, angle) = (next_obs[0], next_obs[1]);
    let healthy = all_finite(next_obs)
        && next_obs[1..].iter().all(|v| v.abs() < 100.0)
        && height > 0.7
        && angle.abs() < 0.2;
    !healthy
}

/// Walker2d-v5: unhealthy unless 0.8 < height < 2 and −1 < angle < 1.
pub fn walker2d(_obs: &[f32], _act: &[f32], next_obs: &[f32]) -> bool {
    let (height, angle) = (next_obs[0], next_obs[1]);
    let healthy = 0.8 < height && height < 2.0 && -1.0 < angle && angle < 1.0;
    !healthy
}

/// Ant-v5 (truncated observation): unhealthy unless finite and 0.2 ≤ height ≤ 1 (inclusive, as
/// Gymnasium's `min_z <= z <= max_z`).
pub fn ant(_obs: &[f32], _act: &[f32], next_obs: &[f32]) -> bool {
    let z = next_obs[0];
    let healthy = all_finite(next_obs) && (0.2..=1.0).contains(&z);
    !healthy
}

/// Humanoid-v5 (truncated observation): unhealthy unless 1 < height < 2 (Gymnasium's strict
/// `min_z < z < max_z`; MBPO's `z < 1 or z > 2` differs only at exactly 1 or 2, and for NaN).
pub fn humanoid(_obs: &[f32], _act: &[f32], next_obs: &[f32]) -> bool {
    let z = next_obs[0];
    let healthy = 1.0 < z && z < 2.0;
    !healthy
}

/// InvertedPendulum-v5: done unless finite and |pole angle obs[1]| ≤ 0.2.
pub fn inverted_pendulum(_obs: &[f32], _act: &[f32], next_obs: &[f32]) -> bool {
    let healthy = all_finite(next_obs) && next_obs[1].abs() <= 0.2;
    !healthy
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{make, termination_fn, TERMINATION_ENV_IDS};

    fn done(id: &str, next_obs: &[f32]) -> bool {
        termination_fn(id).unwrap()(&[], &[], next_obs)
    }

    /// MBPO's original Hopper rule, abs applied to the boolean (`mbpo/static/hopper.py`).
    fn hopper_mbpo_buggy(next_obs: &[f32]) -> bool {
        let (height, angle) = (next_obs[0], next_obs[1]);
        let not_done = all_finite(next_obs)
            && next_obs[1..].iter().all(|&v| v < 100.0) // np.abs(next_obs[:,1:] < 100)
            && height > 0.7
            && angle.abs() < 0.2;
        !not_done
    }

    #[test]
    fn hopper_terminates_on_large_negative_velocity_unlike_mbpo_bug() {
        // Healthy height and angle, but a joint velocity of −150: outside (−100, 100).
        let mut s = [1.25f32, 0.05, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        s[7] = -150.0;
        assert!(done("Hopper-v5", &s));
        assert!(!hopper_mbpo_buggy(&s), "the buggy rule misses it");
        s[7] = -99.0;
        assert!(!done("Hopper-v5", &s));
        s[7] = 150.0;
        assert!(done("Hopper-v5", &s) && hopper_mbpo_buggy(&s));
    }

    #[test]
    fn hopper_height_angle_and_nan() {
        let ok = [1.25f32, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert!(!done("Hopper-v5", &ok));
        assert!(
            done("Hopper-v5", &[0.7, 0.0, 0.0]),
            "height must exceed 0.7"
        );
        assert!(
            done("Hopper-v5", &[1.0, 0.2, 0.0]),
            "|angle| must be below 0.2"
        );
        assert!(done("Hopper-v5", &[1.0, -0.25, 0.0]));
        assert!(done("Hopper-v5", &[1.0, 0.0, f32::NAN]));
        assert!(done("Hopper-v5", &[1.0, 0.0, f32::INFINITY]));
    }

    #[test]
    fn walker_ant_humanoid_inverted_pendulum_ranges() {
        assert!(!done("Walker2d-v5", &[1.2, 0.5, 9.0]));
        assert!(done("Walker2d-v5", &[0.8, 0.0]) && done("Walker2d-v5", &[2.0, 0.0]));
        assert!(done("Walker2d-v5", &[1.2, -1.0]) && done("Walker2d-v5", &[1.2, 1.0]));
        assert!(done("Walker2d-v5", &[f32::NAN, 0.0]));

        assert!(!done("Ant-v5", &[0.2, 5.0]) && !done("Ant-v5", &[1.0, 5.0]));
        assert!(done("Ant-v5", &[0.19, 0.0]) && done("Ant-v5", &[1.01, 0.0]));
        assert!(done("Ant-v5", &[0.5, f32::INFINITY]));

        assert!(!done("Humanoid-v5", &[1.4, 0.0]));
        assert!(done("Humanoid-v5", &[0.9, 0.0]) && done("Humanoid-v5", &[2.1, 0.0]));
        assert!(done("Humanoid-v5", &[f32::NAN, 0.0]));
        // Humanoid's rule is not Ant's (mbrl-lib #138): z = 0.5 is a healthy ant, a fallen humanoid.
        assert!(!done("Ant-v5", &[0.5, 0.0]) && done("Humanoid-v5", &[0.5, 0.0]));

        assert!(!done("InvertedPendulum-v5", &[0.0, 0.2, 0.0, 0.0]));
        assert!(done("InvertedPendulum-v5", &[0.0, -0.21, 0.0, 0.0]));
        assert!(done("InvertedPendulum-v5", &[f32::NAN, 0.0, 0.0, 0.0]));
    }

    #[test]
    fn tasks_without_termination_never_end() {
        for id in ["Pendulum-v1", "HalfCheetah-v5"] {
            assert!(!done(id, &[f32::NAN; 17]));
            assert!(!done(id, &[1e9; 17]));
        }
        assert!(termination_fn("Hopper-v2").is_none());
        assert!(termination_fn("CartPole-v1").is_none());
        for id in TERMINATION_ENV_IDS {
            assert!(termination_fn(id).is_some(), "{id}");
        }
    }

    #[test]
    fn mountain_car_rule_agrees_with_the_environment() {
        // Full throttle in the direction of motion swings the car up the right hill; check the
        // rule against the env's own `terminated` on every step of several episodes.
        let mut env = make("MountainCarContinuous-v0").unwrap();
        let f = termination_fn("MountainCarContinuous-v0").unwrap();
        let (mut obs, mut next) = ([0.0f32; 2], [0.0f32; 2]);
        let mut goals = 0;
        for start in [-0.6, -0.5, -0.4, -0.55] {
            env.restorable_mut()
                .unwrap()
                .reset_to(&[start, 0.0], &mut obs)
                .unwrap();
            for _ in 0..999 {
                let a = [if obs[1] >= 0.0 { 1.0f32 } else { -1.0 }];
                let step = env.step(&a, &mut next).unwrap();
                assert_eq!(f(&obs, &a, &next), step.terminated, "{obs:?} -> {next:?}");
                obs = next;
                if step.terminated {
                    goals += 1;
                    break;
                }
            }
        }
        assert_eq!(goals, 4, "every episode should reach the goal");
        // Boundary cases: exactly 0.45 with zero velocity is the goal; moving left is not.
        assert!(f(&[0.0; 2], &[0.0], &[0.45, 0.0]));
        assert!(!f(&[0.0; 2], &[0.0], &[0.45, -1e-6]));
        let below = f32::from_bits(0.45f32.to_bits() - 1);
        assert!(!f(&[0.0; 2], &[0.0], &[below, 0.01]));
    }
}
