//! A MuJoCo episode restored from a checkpoint mid-episode continues bit for bit (cargo feature
//! `mujoco`): `reset_to(state)` alone starts a fresh `mjData`, so the solver's warm start (and
//! for Ant the x position the forward velocity is measured from) must come from
//! `Env::resume_state`.

#![cfg(feature = "mujoco")]

use mbpo_core::rng::{stream, uniform_range_f64};
use mbpo_envs::{make, Env, MUJOCO_ENV_IDS};

/// Observation bits, reward bits and flags of each step of `actions`, up to the episode's end.
fn rollout(env: &mut dyn Env, actions: &[Vec<f32>]) -> Vec<(Vec<u64>, u64, bool, bool)> {
    let mut obs = vec![0.0f32; env.obs_dim()];
    let mut out = Vec::new();
    for a in actions {
        let s = env.step(a, &mut obs).unwrap();
        let bits = env
            .observation_f64()
            .unwrap()
            .iter()
            .map(|v| v.to_bits())
            .collect();
        out.push((bits, s.reward.to_bits(), s.terminated, s.truncated));
        if s.terminated || s.truncated {
            break;
        }
    }
    out
}

/// Random actions in `scale` times the control range.
fn actions(env: &dyn Env, n: usize, seed: u64, scale: f32) -> Vec<Vec<f32>> {
    let mut rng = stream(seed, "test.actions", 0);
    let high: Vec<f32> = env.action_space().high.iter().map(|h| h * scale).collect();
    (0..n)
        .map(|_| {
            high.iter()
                .map(|&h| uniform_range_f64(&mut rng, -(h as f64), h as f64) as f32)
                .collect()
        })
        .collect()
}

/// Play `before` steps, take what a checkpoint keeps, and return it with the env.
fn played(id: &str, before: &[Vec<f32>]) -> (Box<dyn Env>, Vec<f64>, usize, Vec<f64>) {
    let mut env = make(id).unwrap();
    let mut obs = vec![0.0f32; env.obs_dim()];
    env.reset(&mut stream(1, "test.reset", 0), &mut obs)
        .unwrap();
    for a in before {
        let s = env.step(a, &mut obs).unwrap();
        assert!(
            !s.terminated && !s.truncated,
            "{id}: episode ended before the cut"
        );
    }
    let saved = env.restorable().expect("MuJoCo tasks save their state");
    let (state, steps, extra) = (saved.state(), env.elapsed_steps(), saved.resume_state());
    (env, state, steps, extra)
}

#[test]
fn a_mujoco_episode_resumed_mid_way_continues_bit_for_bit() {
    let mut differs_without = Vec::new();
    for id in MUJOCO_ENV_IDS {
        let probe = make(id).unwrap();
        // A short prefix keeps Hopper/Walker/Ant healthy under random actions; the pendulum
        // stays up a while only under small pushes.
        let scale = if *id == "InvertedPendulum-v5" {
            0.02
        } else {
            1.0
        };
        let before = actions(probe.as_ref(), 5, 7, scale);
        let after = actions(probe.as_ref(), 60, 8, scale);

        let (mut original, state, steps, extra) = played(id, &before);
        let want = rollout(original.as_mut(), &after);
        assert!(
            want.len() >= 5,
            "{id}: only {} steps after the cut",
            want.len()
        );

        let mut obs = vec![0.0f32; probe.obs_dim()];
        let mut resumed = make(id).unwrap();
        let restore = resumed.restorable_mut().unwrap();
        restore.reset_to(&state, &mut obs).unwrap();
        restore.set_elapsed_steps(steps);
        restore.set_resume_state(&extra).unwrap();
        // A checkpoint of the restored env before it steps (a resumed run stopped again at
        // once) carries the same state on.
        let (state2, extra2) = (restore.state(), restore.resume_state());
        assert_eq!((&state2, &extra2), (&state, &extra), "{id}");
        assert_eq!(rollout(resumed.as_mut(), &after), want, "{id}");

        // Without the resume state the continuation drifts (what checkpoints did before).
        let mut plain = make(id).unwrap();
        let restore = plain.restorable_mut().unwrap();
        restore.reset_to(&state, &mut obs).unwrap();
        restore.set_elapsed_steps(steps);
        if rollout(plain.as_mut(), &after) != want {
            differs_without.push(*id);
        }

        // A resume state of the wrong length names the task and what it holds.
        let err = resumed
            .restorable_mut()
            .unwrap()
            .set_resume_state(&extra[1..])
            .unwrap_err()
            .to_string();
        assert!(
            err.contains(id) && err.contains("mjSTATE_INTEGRATION"),
            "{err}"
        );
    }
    // The test has teeth: the contact-rich tasks need the warm start.
    assert!(
        differs_without.contains(&"HalfCheetah-v5") && differs_without.contains(&"Ant-v5"),
        "without the resume state only {differs_without:?} drift"
    );
}
