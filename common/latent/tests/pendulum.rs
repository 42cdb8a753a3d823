//! The world model on a real task: from Pendulum-v1's random-action transitions, a few hundred
//! updates teach it the reward (in the latent, through the encoder and the dynamics) well
//! enough to tell good states from bad ones.

use mbpo_core::rng::{stream, uniform_range_f32};
use mbpo_latent::update::{Learner, UpdateConfig};
use mbpo_latent::{EpisodeBuffer, Sequences, TwoHot, WorldModel, WorldModelConfig};

fn random_pendulum(steps: usize) -> EpisodeBuffer {
    let mut env = mbpo_envs::make("Pendulum-v1").unwrap();
    let (o, a) = (env.obs_dim(), env.act_dim());
    let mut rng = stream(0, "test.pendulum", 0);
    let mut buf = EpisodeBuffer::new(o, a, steps);
    let (mut obs, mut next) = (vec![0.0; o], vec![0.0; o]);
    env.reset(&mut rng, &mut obs).unwrap();
    for _ in 0..steps {
        let act = [uniform_range_f32(&mut rng, -1.0, 1.0)];
        // Pendulum's torque is 2 x the action in [-1, 1].
        let step = env.step(&[2.0 * act[0]], &mut next).unwrap();
        let ended = step.terminated || step.truncated;
        buf.push(&obs, &act, step.reward as f32, &next, ended);
        if ended {
            env.reset(&mut rng, &mut obs).unwrap();
        } else {
            obs.copy_from_slice(&next);
        }
    }
    buf
}

#[test]
fn the_world_model_learns_pendulums_reward_from_random_actions() {
    let buf = random_pendulum(2000);
    let cfg = WorldModelConfig {
        latent: 32,
        encoder_hidden: 64,
        hidden: 64,
        two_hot: TwoHot::default(),
        ..Default::default()
    };
    let (batch, h) = (64, cfg.horizon);
    let model = WorldModel::new(3, 1, cfg);
    let mut params = vec![0.0; model.num_params()];
    model.init(&mut params, &mut stream(0, "test.pendulum.init", 0));
    let config = UpdateConfig {
        lr: 1e-3,
        ..Default::default()
    };
    let mut learner = Learner::new(model, params, config, batch);
    let mut seq = Sequences::zeros(batch, h, 3, 1);
    let mut rng = stream(0, "test.pendulum.updates", 0);
    assert!(buf.sample(h, &mut rng, &mut seq));
    let first = learner.update(&seq, &mut rng);
    let mut recent = Vec::new();
    for i in 0..600 {
        assert!(buf.sample(h, &mut rng, &mut seq));
        let s = learner.update(&seq, &mut rng);
        assert!(s.model.total.is_finite(), "update {i}: {s:?}");
        if i >= 550 {
            recent.push(s.model.reward);
        }
    }
    let late = recent.iter().sum::<f32>() / recent.len() as f32;
    // Pendulum's rewards lie in [-16.3, 0]: a two-hot head starting at 0 has a cross-entropy of
    // ln(101) = 4.6 per step; learned, a small fraction of that.
    assert!(
        late < 0.4 * first.model.reward,
        "reward loss {} -> {late}",
        first.model.reward
    );
}
