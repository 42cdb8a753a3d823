//! What one TD-MPC2 env step costs: a latent MPPI plan from an observation and one update on a
//! batch of subsequences, timed apart on random parameters and random episodes (the cost does
//! not depend on what was learned). `mbpo bench tdmpc-step` prints it; the official
//! implementation is timed the same way for the comparison in results/.

use std::time::Instant;

use mbpo_core::rng::{normal_f32, stream, uniform_range_f32};
use serde::Serialize;

use crate::mppi::{LatentMppi, MppiConfig};
use crate::update::{Learner, UpdateConfig};
use crate::{EpisodeBuffer, NormedCache, Sequences, WorldModel, WorldModelConfig};

/// Episodes of random transitions the updates draw from.
const EPISODES: usize = 10;

/// Milliseconds of a plan and of an update (medians over the timed calls).
#[derive(Debug, Clone, Serialize)]
pub struct StepCost {
    /// Observation width.
    pub obs: usize,
    /// Action width.
    pub act: usize,
    /// Parameters of the world model (encoder, dynamics, reward, Q heads, policy).
    pub params: usize,
    /// Calls timed of each.
    pub calls: usize,
    /// Median milliseconds of one plan (encode the observation, MPPI).
    pub plan_ms_median: f64,
    /// Median milliseconds of one update (draw the batch, losses, Adam steps, Polyak).
    pub update_ms_median: f64,
    /// Their sum: one env step of TD-MPC2 at one update per step.
    pub per_env_step_ms: f64,
    /// Whether the plans' products ran in bf16 on AMX.
    pub plan_bf16: bool,
}

/// Time `calls` plans and `calls` updates (after two of each untimed) of a world model of
/// `cfg` for a task of `obs` and `act` values with episodes of `episode_length` steps.
pub fn step_cost(
    (obs, act): (usize, usize),
    cfg: WorldModelConfig,
    planner: MppiConfig,
    batch: usize,
    episode_length: usize,
    calls: usize,
) -> StepCost {
    let model = WorldModel::new(obs, act, cfg);
    let mut params = vec![0.0; model.num_params()];
    model.init(&mut params, &mut stream(0, "bench.tdmpc.init", 0));
    let buffer = random_episodes(obs, act, episode_length);
    let mut seq = Sequences::zeros(batch, model.cfg.horizon, obs, act);
    let mut mppi = LatentMppi::new(&model, planner);
    let plan_bf16 = mppi.multiplies_in_bf16();
    let mut encoder = NormedCache::new(&model.encoder, 1);
    let mut rng = stream(0, "bench.tdmpc.draws", 0);
    let (mut ob, mut action) = (vec![0.0f32; obs], vec![0.0f32; act]);
    let mut plan_ms = Vec::with_capacity(calls);
    for i in 0..calls + 2 {
        ob.iter_mut().for_each(|x| *x = normal_f32(&mut rng));
        let started = Instant::now();
        let z = model
            .encoder
            .forward(&params[model.encoder_range()], &ob, 1, &mut encoder);
        mppi.plan(&model, &params, z, true, &mut rng, &mut action);
        if i >= 2 {
            plan_ms.push(started.elapsed().as_secs_f64() * 1e3);
        }
    }
    let horizon = model.cfg.horizon;
    let mut learner = Learner::new(model, params, UpdateConfig::default(), batch);
    let mut update_ms = Vec::with_capacity(calls);
    for i in 0..calls + 2 {
        let started = Instant::now();
        assert!(
            buffer.sample(horizon, &mut rng, &mut seq),
            "episodes longer than H"
        );
        learner.update(&seq, &mut rng);
        if i >= 2 {
            update_ms.push(started.elapsed().as_secs_f64() * 1e3);
        }
    }
    let plan = mbpo_core::stats::median(&mut plan_ms).unwrap_or(f64::NAN);
    let update = mbpo_core::stats::median(&mut update_ms).unwrap_or(f64::NAN);
    StepCost {
        obs,
        act,
        params: learner.model.num_params(),
        calls,
        plan_ms_median: plan,
        update_ms_median: update,
        per_env_step_ms: plan + update,
        plan_bf16,
    }
}

/// [`EPISODES`] episodes of `len` random transitions.
fn random_episodes(obs: usize, act: usize, len: usize) -> EpisodeBuffer {
    let mut buf = EpisodeBuffer::new(obs, act, EPISODES * len);
    let mut rng = stream(0, "bench.tdmpc.episodes", 0);
    let (mut o, mut next, mut a) = (vec![0.0f32; obs], vec![0.0f32; obs], vec![0.0f32; act]);
    for _ in 0..EPISODES {
        o.iter_mut().for_each(|x| *x = normal_f32(&mut rng));
        for step in 0..len {
            next.iter_mut().for_each(|x| *x = normal_f32(&mut rng));
            a.iter_mut()
                .for_each(|x| *x = uniform_range_f32(&mut rng, -1.0, 1.0));
            let reward = uniform_range_f32(&mut rng, 0.0, 1.0);
            buf.push(&o, &a, reward, &next, step + 1 == len);
            std::mem::swap(&mut o, &mut next);
        }
    }
    buf
}
