//! Evaluation episodes: one loop for every evaluator (SAC's policy, MPC's and TD-MPC2's
//! planners), with one rule for a Python env whose process exits mid-episode.

use mbpo_core::Rng;
use mbpo_envs::{Env, EnvError};
use mbpo_sac::ActionScale;

/// How an episode ended early: its env failed, or the agent did.
enum Failure<E> {
    Env(EnvError),
    Agent(E),
}

/// The buffers of one evaluation (made once, reused by every episode).
struct Scratch {
    scale: ActionScale,
    obs: Vec<f32>,
    action: Vec<f32>,
    env_action: Vec<f32>,
}

/// Mean undiscounted return of `episodes` episodes of `agent`: each starts from a reset drawn
/// from `env_rng` and `begin(agent)` (a planner forgets its warm start); every step asks
/// `abandon()` first (`Ok(None)`: abandoned, the streams moved on), then `act` writes the action
/// in [−1, 1] for the observation (it may draw from `env_rng`: SAC's evaluation does), rescaled
/// to the env's box.
///
/// An episode whose Python env process exited ([`EnvError::PythonExited`]) is played once more
/// in the new process the env starts at its next reset (its partial return is dropped, the
/// streams have moved on), as the actors do; a second exit, or any other error, ends the
/// evaluation with it.
pub fn evaluation_episodes<P: ?Sized, E: From<EnvError>>(
    env: &mut dyn Env,
    episodes: usize,
    env_rng: &mut Rng,
    agent: &mut P,
    mut begin: impl FnMut(&mut P),
    mut act: impl FnMut(&mut P, &mut Rng, &[f32], &mut [f32]) -> Result<(), E>,
    mut abandon: impl FnMut() -> bool,
) -> Result<Option<f64>, E> {
    let (o, a) = (env.obs_dim(), env.act_dim());
    let mut s = Scratch {
        scale: ActionScale::new(&env.action_space().low, &env.action_space().high),
        obs: vec![0.0f32; o],
        action: vec![0.0f32; a],
        env_action: vec![0.0f32; a],
    };
    let mut total = 0.0;
    for _ in 0..episodes {
        let mut play =
            |s: &mut Scratch| episode(env, env_rng, agent, s, &mut begin, &mut act, &mut abandon);
        let ret = match play(&mut s) {
            Err(Failure::Env(e @ EnvError::PythonExited { .. })) => {
                tracing::warn!("{e}; evaluating the episode again in a new process");
                play(&mut s)
            }
            other => other,
        };
        match ret {
            Ok(Some(ret)) => total += ret,
            Ok(None) => return Ok(None),
            Err(Failure::Env(e)) => return Err(e.into()),
            Err(Failure::Agent(e)) => return Err(e),
        }
    }
    Ok(Some(total / episodes.max(1) as f64))
}

/// Why an evaluation nobody abandons has a return.
pub(crate) const NEVER_ABANDONED: &str = "an evaluation nobody abandons completes";

/// [`evaluation_episodes`] played to the end: their mean undiscounted return.
pub fn mean_return<P: ?Sized, E: From<EnvError>>(
    env: &mut dyn Env,
    episodes: usize,
    env_rng: &mut Rng,
    agent: &mut P,
    begin: impl FnMut(&mut P),
    act: impl FnMut(&mut P, &mut Rng, &[f32], &mut [f32]) -> Result<(), E>,
) -> Result<f64, E> {
    let ret = evaluation_episodes(env, episodes, env_rng, agent, begin, act, || false)?;
    Ok(ret.expect(NEVER_ABANDONED))
}

/// One episode of [`evaluation_episodes`]: its return, or `None` once abandoned.
fn episode<P: ?Sized, E>(
    env: &mut dyn Env,
    env_rng: &mut Rng,
    agent: &mut P,
    s: &mut Scratch,
    begin: &mut impl FnMut(&mut P),
    act: &mut impl FnMut(&mut P, &mut Rng, &[f32], &mut [f32]) -> Result<(), E>,
    abandon: &mut impl FnMut() -> bool,
) -> Result<Option<f64>, Failure<E>> {
    env.reset(env_rng, &mut s.obs).map_err(Failure::Env)?;
    begin(agent);
    let mut ret = 0.0;
    loop {
        if abandon() {
            return Ok(None);
        }
        act(agent, env_rng, &s.obs, &mut s.action).map_err(Failure::Agent)?;
        s.scale.to_env(&s.action, &mut s.env_action);
        let step = env.step(&s.env_action, &mut s.obs).map_err(Failure::Env)?;
        ret += step.reward;
        if step.terminated || step.truncated {
            return Ok(Some(ret));
        }
    }
}
