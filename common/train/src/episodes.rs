//! Evaluation episodes of a planner (MPC's and TD-MPC2's evaluators share this loop).

use mbpo_core::Rng;
use mbpo_envs::Env;
use mbpo_sac::ActionScale;

use crate::error::TrainError;

/// Mean undiscounted return of `episodes` episodes of `planner` (MPC's, TD-MPC2's): each
/// starts from a reset drawn from `env_rng` and `begin(planner)` (it forgets its warm start);
/// every step asks `abandon()` first (`Ok(None)`: abandoned, the streams moved on), then `act`
/// writes the action in [−1, 1] for the observation, rescaled to the env's box.
pub fn planning_episodes<P>(
    env: &mut dyn Env,
    episodes: usize,
    env_rng: &mut Rng,
    planner: &mut P,
    mut begin: impl FnMut(&mut P),
    mut act: impl FnMut(&mut P, &[f32], &mut [f32]) -> Result<(), TrainError>,
    mut abandon: impl FnMut() -> bool,
) -> Result<Option<f64>, TrainError> {
    let scale = ActionScale::new(&env.action_space().low, &env.action_space().high);
    let (o, a) = (env.obs_dim(), env.act_dim());
    let (mut obs, mut action, mut env_action) = (vec![0.0f32; o], vec![0.0f32; a], vec![0.0f32; a]);
    let mut total = 0.0;
    for _ in 0..episodes {
        env.reset(env_rng, &mut obs)?;
        begin(planner);
        loop {
            if abandon() {
                return Ok(None);
            }
            act(planner, &obs, &mut action)?;
            scale.to_env(&action, &mut env_action);
            let step = env.step(&env_action, &mut obs)?;
            total += step.reward;
            if step.terminated || step.truncated {
                break;
            }
        }
    }
    Ok(Some(total / episodes.max(1) as f64))
}
