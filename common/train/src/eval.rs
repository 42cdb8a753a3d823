//! Deterministic evaluation episodes.

use mbpo_core::Rng;
use mbpo_envs::Env;
use mbpo_sac::{ActionScale, Sac};

/// Mean undiscounted return of `episodes` episodes with the deterministic policy tanh μ(s);
/// start states come from `rng` (the evaluation stream, separate from training's).
pub fn evaluate(sac: &mut Sac, env: &mut dyn Env, episodes: usize, rng: &mut Rng) -> f64 {
    let scale = ActionScale::new(&env.action_space().low, &env.action_space().high);
    let mut obs = vec![0.0f32; env.obs_dim()];
    let mut action = vec![0.0f32; env.act_dim()];
    let mut env_action = vec![0.0f32; env.act_dim()];
    let mut total = 0.0;
    for _ in 0..episodes {
        env.reset(rng, &mut obs);
        loop {
            sac.act(&obs, true, rng, &mut action);
            scale.to_env(&action, &mut env_action);
            let step = env.step(&env_action, &mut obs);
            total += step.reward;
            if step.terminated || step.truncated {
                break;
            }
        }
    }
    total / episodes as f64
}
