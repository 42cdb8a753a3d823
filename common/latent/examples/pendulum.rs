//! Does the latent world model learn to control a task? TD-MPC2's loop in one process on
//! Pendulum-v1, with smaller networks than the 1M preset so it runs in minutes on a CPU:
//! random actions for the seed steps, a burst of updates, then one MPPI plan and one update per
//! env step; deterministic evaluations (MPPI without exploration noise) every 1000 steps.
//!
//!     cargo run --release -p mbpo-latent --example pendulum -- [STEPS] [SEED]
//!
//! Prints one JSON line per evaluation. (Not yet an algorithm of `mbpo train`: see issue 61.)

use std::time::Instant;

use mbpo_core::rng::{stream, uniform_range_f32};
use mbpo_latent::mppi::{LatentMppi, MppiConfig};
use mbpo_latent::update::{Learner, UpdateConfig};
use mbpo_latent::{EpisodeBuffer, NormedCache, Sequences, TwoHot, WorldModel, WorldModelConfig};

const SEED_STEPS: usize = 1000;
const EVAL_EVERY: usize = 1000;
const EVAL_EPISODES: usize = 2;
const BATCH: usize = 256;

struct Agent {
    learner: Learner,
    mppi: LatentMppi,
    encoder: NormedCache,
}

impl Agent {
    fn act(&mut self, obs: &[f32], explore: bool, rng: &mut mbpo_core::Rng, action: &mut [f32]) {
        let m = &self.learner.model;
        let p = &self.learner.params[m.encoder_range()];
        let z = m.encoder.forward(p, obs, 1, &mut self.encoder);
        self.mppi
            .plan(m, &self.learner.params, z, explore, rng, action);
    }
}

fn evaluate(agent: &mut Agent, seed: u64) -> f64 {
    let mut env = mbpo_envs::make("Pendulum-v1").unwrap();
    let mut rng = stream(seed, "example.eval", 0);
    let (mut obs, mut action) = (vec![0.0; 3], [0.0f32]);
    let mut total = 0.0;
    for _ in 0..EVAL_EPISODES {
        env.reset(&mut rng, &mut obs).unwrap();
        agent.mppi.reset();
        loop {
            agent.act(&obs, false, &mut rng, &mut action);
            let step = env.step(&[2.0 * action[0]], &mut obs).unwrap();
            total += step.reward;
            if step.terminated || step.truncated {
                break;
            }
        }
    }
    total / EVAL_EPISODES as f64
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let steps: usize = args.get(1).map_or(6000, |s| s.parse().expect("STEPS"));
    let seed: u64 = args.get(2).map_or(0, |s| s.parse().expect("SEED"));
    let cfg = WorldModelConfig {
        latent: 64,
        encoder_hidden: 128,
        hidden: 128,
        // TD-MPC2's heuristic for 200-step episodes: (200/5 - 1) / (200/5).
        discount: 0.975,
        two_hot: TwoHot::default(),
        ..Default::default()
    };
    let model = WorldModel::new(3, 1, cfg);
    let mut params = vec![0.0; model.num_params()];
    model.init(&mut params, &mut stream(seed, "example.init", 0));
    let h = model.cfg.horizon;
    let mppi = LatentMppi::new(
        &model,
        MppiConfig {
            samples: 256,
            policy_samples: 16,
            elites: 32,
            ..Default::default()
        },
    );
    let encoder = NormedCache::new(&model.encoder, 1);
    let learner = Learner::new(model, params, UpdateConfig::default(), BATCH);
    let mut agent = Agent {
        learner,
        mppi,
        encoder,
    };
    let mut buf = EpisodeBuffer::new(3, 1, steps);
    let mut seq = Sequences::zeros(BATCH, h, 3, 1);
    let (mut env, mut rng) = (
        mbpo_envs::make("Pendulum-v1").unwrap(),
        stream(seed, "example.act", 0),
    );
    let mut update_rng = stream(seed, "example.update", 0);
    let (mut obs, mut next, mut action) = (vec![0.0; 3], vec![0.0; 3], [0.0f32]);
    env.reset(&mut rng, &mut obs).unwrap();
    let started = Instant::now();
    let mut last = Default::default();
    for t in 1..=steps {
        match t <= SEED_STEPS {
            true => action[0] = uniform_range_f32(&mut rng, -1.0, 1.0),
            false => agent.act(&obs, true, &mut rng, &mut action),
        }
        let step = env.step(&[2.0 * action[0]], &mut next).unwrap();
        let ended = step.terminated || step.truncated;
        buf.push(&obs, &action, step.reward as f32, &next, ended);
        obs.copy_from_slice(&next);
        if ended {
            env.reset(&mut rng, &mut obs).unwrap();
            agent.mppi.reset();
        }
        // The seed steps' burst, then one update per step.
        let updates = match t {
            t if t == SEED_STEPS => SEED_STEPS,
            t if t > SEED_STEPS => 1,
            _ => 0,
        };
        for _ in 0..updates {
            assert!(buf.sample(h, &mut update_rng, &mut seq));
            last = agent.learner.update(&seq, &mut update_rng);
        }
        if t % EVAL_EVERY == 0 {
            let ret = evaluate(&mut agent, seed + 1000);
            println!(
                "{}",
                serde_json::json!({"env_steps": t, "eval_return": ret, "wall_seconds": started.elapsed().as_secs_f64(),
                    "consistency": last.model.consistency, "reward_loss": last.model.reward, "value_loss": last.model.value,
                    "policy_loss": last.policy, "q_scale": last.q_scale})
            );
        }
    }
}
