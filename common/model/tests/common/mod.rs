//! Shared helpers of the model's integration tests.
#![allow(dead_code)]

use mbpo_core::{stream, Batch, BatchPolicy, UniformPolicy};
use mbpo_envs::make;
use mbpo_model::ModelConfig;

/// `n` Pendulum-v1 transitions under a uniform random policy, in 200-step episodes
/// (time-limit resets, never terminal), from the stream `(seed, "test.pendulum", 0)`.
pub fn pendulum_data(n: usize, seed: u64) -> Batch {
    let mut env = make("Pendulum-v1").unwrap();
    let mut rng = stream(seed, "test.pendulum", 0);
    let mut policy = UniformPolicy {
        low: vec![-2.0],
        high: vec![2.0],
    };
    let mut b = Batch::new(3, 1, n);
    let mut obs = [0.0f32; 3];
    env.reset(&mut rng, &mut obs).unwrap();
    for r in 0..n {
        let mut a = [0.0f32];
        policy.act_batch(&obs, 1, &mut a, &mut rng);
        let mut next = [0.0f32; 3];
        let step = env.step(&a, &mut next).unwrap();
        b.obs[3 * r..3 * r + 3].copy_from_slice(&obs);
        b.act[r] = a[0];
        b.reward[r] = step.reward as f32;
        b.next_obs[3 * r..3 * r + 3].copy_from_slice(&next);
        b.terminated[r] = step.terminated as u8 as f32;
        obs = next;
        if step.terminated || step.truncated {
            env.reset(&mut rng, &mut obs).unwrap();
        }
    }
    b
}

/// A small ensemble for fast tests: the real code path with narrower layers.
pub fn small_config(members: usize, elites: usize, hidden: &[usize]) -> ModelConfig {
    ModelConfig {
        members,
        elites,
        hidden: hidden.to_vec(),
        weight_decay: ModelConfig::default().weight_decay[..hidden.len() + 1].to_vec(),
        ..ModelConfig::default()
    }
}
