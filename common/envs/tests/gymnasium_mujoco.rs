//! The MuJoCo tasks against Gymnasium v5 itself (cargo feature `mujoco`).
//!
//! The fixtures `tests/fixtures/<EnvId>.json` for the MuJoCo ids are Gymnasium 1.4.0 / MuJoCo
//! 3.17.0 trajectories written by `tools/gym_mujoco_reference.py`; regenerate them with
//! `bash deploy/setup_mujoco.sh && .venv/bin/python tools/gym_mujoco_reference.py`.
//! Every episode is replayed with `reset_to(qpos ++ qvel)` + `step` and compared step by step:
//! float64 observations and rewards within 1e-9, `terminated`/`truncated` exactly, the f32
//! observation equal to the float64 one rounded. With the same MuJoCo library and glibc the
//! replay is also bit-exact, which the test asserts there (see [`BIT_EXACT_PLATFORM`]).
#![cfg(feature = "mujoco")]

use fixture::Episode;
use mbpo_core::rng::stream;
use mbpo_envs::mujoco::{MujocoEnv, Task, MAX_EPISODE_STEPS};
use mbpo_envs::{make, termination_fn, Env, EnvError, MUJOCO_ENV_IDS};
use serde::Deserialize;

mod fixture;

const TOL: f64 = 1e-9;

/// Same libm and MuJoCo build as the fixtures: any inexact value is a regression.
const BIT_EXACT_PLATFORM: bool = cfg!(all(target_os = "linux", target_env = "gnu"));

#[derive(Deserialize)]
struct Fixture {
    env_id: String,
    gymnasium_version: String,
    mujoco_version: String,
    episodes: Vec<Episode>,
}

fn load(env_id: &str) -> Fixture {
    let fixture: Fixture = fixture::load(
        env_id,
        "bash deploy/setup_mujoco.sh && .venv/bin/python tools/gym_mujoco_reference.py",
    );
    assert_eq!(fixture.env_id, env_id);
    fixture
}

#[derive(Debug, Default)]
struct Deviation {
    steps: usize,
    obs_abs: f64,
    reward_abs: f64,
    inexact: usize,
}

fn check_obs(dev: &mut Deviation, ctx: &str, env: &dyn Env, obs32: &[f32], want: &[f64]) {
    let got = env
        .observation_f64()
        .expect("MuJoCo tasks keep the f64 observation");
    assert_eq!(got.len(), want.len(), "{ctx}: observation length");
    for (i, ((&g, &g32), &w)) in got.iter().zip(obs32).zip(want).enumerate() {
        let d = (g - w).abs();
        assert!(
            d <= TOL,
            "{ctx}: obs[{i}] = {g:e}, gymnasium {w:e} (|Δ| = {d:e})"
        );
        assert_eq!(
            g32, g as f32,
            "{ctx}: f32 obs[{i}] is not the f64 value rounded"
        );
        dev.obs_abs = dev.obs_abs.max(d);
        dev.inexact += (g != w) as usize;
    }
}

fn replay(env_id: &str) -> Deviation {
    let fixture = load(env_id);
    let mut env = make(env_id).unwrap();
    let mut obs = vec![0.0f32; env.obs_dim()];
    let mut dev = Deviation::default();
    assert!(!fixture.episodes.is_empty());
    for ep in &fixture.episodes {
        let n = ep.actions.len();
        assert!(
            n > 0 && ep.obs.len() == n + 1 && ep.rewards.len() == n,
            "{}",
            ep.name
        );
        assert!(
            ep.terminated.len() == n && ep.truncated.len() == n,
            "{}",
            ep.name
        );
        env.restorable_mut()
            .unwrap()
            .reset_to(&ep.state, &mut obs)
            .unwrap();
        assert_eq!(
            env.restorable().unwrap().state(),
            ep.state,
            "{env_id} {}: state after reset_to",
            ep.name
        );
        check_obs(
            &mut dev,
            &format!("{env_id} {} reset", ep.name),
            &*env,
            &obs,
            &ep.obs[0],
        );
        for t in 0..n {
            let ctx = format!("{env_id} {} step {}", ep.name, t + 1);
            let action: Vec<f32> = ep.actions[t].iter().map(|&a| a as f32).collect();
            for (&a, &a64) in action.iter().zip(&ep.actions[t]) {
                assert_eq!(a as f64, a64, "{ctx}: action is not an f32 value");
            }
            let step = env.step(&action, &mut obs).unwrap();
            check_obs(&mut dev, &ctx, &*env, &obs, &ep.obs[t + 1]);
            let want = ep.rewards[t];
            let d = (step.reward - want).abs();
            assert!(
                d <= TOL,
                "{ctx}: reward {} vs gymnasium {want} (|Δ| = {d:e})",
                step.reward
            );
            dev.reward_abs = dev.reward_abs.max(d);
            dev.inexact += (step.reward != want) as usize;
            assert_eq!(step.terminated, ep.terminated[t], "{ctx}: terminated");
            assert_eq!(step.truncated, ep.truncated[t], "{ctx}: truncated");
            dev.steps += 1;
        }
    }
    println!(
        "{env_id} vs gymnasium {} / mujoco {}: {} episodes, {} steps, max |Δobs| = {:e}, \
         max |Δreward| = {:e}, non-bit-exact values: {}",
        fixture.gymnasium_version,
        fixture.mujoco_version,
        fixture.episodes.len(),
        dev.steps,
        dev.obs_abs,
        dev.reward_abs,
        dev.inexact,
    );
    if BIT_EXACT_PLATFORM {
        assert_eq!(dev.inexact, 0, "{env_id}: within 1e-9 but not bit-exact");
    }
    dev
}

#[test]
fn inverted_pendulum_matches_gymnasium() {
    assert!(replay("InvertedPendulum-v5").steps >= 1000);
}

#[test]
fn half_cheetah_matches_gymnasium() {
    assert!(replay("HalfCheetah-v5").steps >= 1000);
}

#[test]
fn hopper_matches_gymnasium() {
    assert!(replay("Hopper-v5").steps >= 100);
}

#[test]
fn walker2d_matches_gymnasium() {
    assert!(replay("Walker2d-v5").steps >= 100);
}

#[test]
fn ant_matches_gymnasium() {
    assert!(replay("Ant-v5").steps >= 100);
}

#[test]
fn humanoid_matches_gymnasium() {
    assert!(replay("Humanoid-v5").steps >= 100);
}

#[test]
fn fixtures_exercise_termination_truncation_and_clamped_actions() {
    for id in MUJOCO_ENV_IDS {
        let f = load(id);
        let ends = |pick: fn(&Episode) -> bool| f.episodes.iter().filter(|e| pick(e)).count();
        let terminated = ends(|e| *e.terminated.last().unwrap());
        let truncated = ends(|e| *e.truncated.last().unwrap());
        match *id {
            "HalfCheetah-v5" => assert!(terminated == 0 && truncated >= 1, "{id}"),
            "InvertedPendulum-v5" => assert!(terminated >= 1 && truncated >= 1, "{id}"),
            _ => assert!(terminated >= 2, "{id}: too few terminal episodes"),
        }
        let high = make(id).unwrap().action_space().high.clone();
        let clamped = f
            .episodes
            .iter()
            .flat_map(|e| &e.actions)
            .any(|a| a.iter().zip(&high).any(|(&x, &h)| x.abs() > h as f64));
        assert!(clamped, "{id}: no action outside the control range");
    }
}

/// The termination functions used in model rollouts see only the f32 observation; on real
/// trajectories they must agree with the environment's own rule. The one known gap: Hopper's
/// rule checks |qvel| < 100 on the *unclipped* velocity, which the observation (clipped to ±10)
/// cannot show, so an episode started with a velocity of 150 is excluded for Hopper.
#[test]
fn termination_functions_agree_with_the_environments() {
    for id in MUJOCO_ENV_IDS {
        let f = load(id);
        let done = termination_fn(id).unwrap();
        let mut checked = 0;
        for ep in &f.episodes {
            if *id == "Hopper-v5" && ep.state.iter().any(|v| v.abs() >= 100.0) {
                continue;
            }
            for t in 0..ep.actions.len() {
                let to32 = |v: &[f64]| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
                let (obs, act, next) =
                    (to32(&ep.obs[t]), to32(&ep.actions[t]), to32(&ep.obs[t + 1]));
                assert_eq!(
                    done(&obs, &act, &next),
                    ep.terminated[t],
                    "{id} {} step {}",
                    ep.name,
                    t + 1
                );
                checked += ep.terminated[t] as usize;
            }
        }
        if *id != "HalfCheetah-v5" {
            assert!(
                checked >= 2,
                "{id}: rule checked on {checked} terminal steps"
            );
        }
    }
}

#[test]
fn spaces_dims_and_state_layout() {
    // (id, obs dim, act dim, nq + nv, action high)
    let want = [
        ("InvertedPendulum-v5", 4, 1, 4, 3.0),
        ("HalfCheetah-v5", 17, 6, 18, 1.0),
        ("Hopper-v5", 11, 3, 12, 1.0),
        ("Walker2d-v5", 17, 6, 18, 1.0),
        ("Ant-v5", 27, 8, 29, 1.0),
        ("Humanoid-v5", 45, 17, 47, 0.4),
    ];
    for (id, obs, act, state, high) in want {
        let env = make(id).unwrap();
        assert_eq!(
            (
                env.obs_dim(),
                env.act_dim(),
                env.restorable().unwrap().state_dim()
            ),
            (obs, act, state),
            "{id}"
        );
        assert!(env.action_space().high.iter().all(|&h| h == high), "{id}");
        assert!(env.action_space().low.iter().all(|&l| l == -high), "{id}");
        assert_eq!(env.max_episode_steps(), 1000);
        assert!(env.observation_space().high.iter().all(|h| h.is_infinite()));
    }
}

#[test]
fn reset_to_rejects_a_wrong_state_length_and_state_round_trips() {
    let mut env = make("Hopper-v5").unwrap();
    let mut obs = vec![0.0f32; env.obs_dim()];
    let err = env
        .restorable_mut()
        .unwrap()
        .reset_to(&[0.0; 11], &mut obs)
        .unwrap_err();
    assert_eq!(
        err.to_string(),
        "Hopper-v5: state has 11 values, expected 12 (qpos[6] (rootx, rootz, rooty, 3 joints), qvel[6])"
    );
    let state: Vec<f64> = (0..12)
        .map(|i| 0.01 * i as f64 + if i == 1 { 1.25 } else { 0.0 })
        .collect();
    env.restorable_mut()
        .unwrap()
        .reset_to(&state, &mut obs)
        .unwrap();
    assert_eq!(env.restorable().unwrap().state(), state);
    // Observation: qpos[1..] then qvel (clipped to ±10: none is that large here).
    let want: Vec<f32> = state[1..].iter().map(|&x| x as f32).collect();
    assert_eq!(obs, want);
}

#[test]
fn time_limit_truncates_at_1000_steps_and_reset_restarts_the_count() {
    let mut env = make("HalfCheetah-v5").unwrap();
    let mut rng = stream(0, "test.mujoco", 0);
    let mut obs = vec![0.0f32; env.obs_dim()];
    let action = vec![0.0f32; env.act_dim()];
    for _ in 0..2 {
        env.reset(&mut rng, &mut obs).unwrap();
        let truncated_at: Vec<usize> = (1..=MAX_EPISODE_STEPS)
            .filter(|_| {
                let s = env.step(&action, &mut obs).unwrap();
                assert!(!s.terminated);
                s.truncated
            })
            .collect();
        assert_eq!(truncated_at, vec![1000]);
    }
}

/// Mean and standard deviation.
fn moments(xs: &[f64]) -> (f64, f64) {
    let mean = xs.iter().sum::<f64>() / xs.len() as f64;
    let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
    (mean, var.sqrt())
}

/// `reset` draws qpos = init + U(−s, s) and qvel = init + U(−s, s) or s·N(0, 1) per task.
#[test]
fn reset_draws_from_gymnasiums_start_distribution() {
    let n = 4000;
    let mut rng = stream(1, "test.mujoco.reset", 0);
    for task in Task::ALL {
        let mut env = MujocoEnv::new(task).unwrap();
        let mut obs = vec![0.0f32; env.obs_dim()];
        let init = env.restorable().unwrap().state(); // a fresh env sits at qpos0, zero velocity
        let (scale, _) = task.reset_noise();
        let mut draws: Vec<Vec<f64>> = vec![Vec::with_capacity(n); init.len()];
        for _ in 0..n {
            env.reset(&mut rng, &mut obs).unwrap();
            for (d, (s, i)) in draws
                .iter_mut()
                .zip(env.restorable().unwrap().state().iter().zip(&init))
            {
                d.push(s - i);
            }
        }
        let qpos_len = match task {
            Task::InvertedPendulum => 2,
            Task::HalfCheetah | Task::Walker2d => 9,
            Task::Hopper => 6,
            Task::Ant => 15,
            Task::Humanoid => 24,
        };
        let normal_velocity = matches!(task, Task::HalfCheetah | Task::Ant);
        for (k, d) in draws.iter().enumerate() {
            let (mean, sd) = moments(d);
            let (lo, hi) = d
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), &x| (a.min(x), b.max(x)));
            if k >= qpos_len && normal_velocity {
                // s·N(0, 1): sd s, and values beyond 3s occur.
                assert!(
                    (sd / scale - 1.0).abs() < 0.05,
                    "{task:?} qvel[{}] sd {sd}",
                    k - qpos_len
                );
                assert!(lo < -3.0 * scale && hi > 3.0 * scale, "{task:?} tails");
            } else {
                // U(−s, s): inside the interval, sd s/√3.
                assert!(
                    lo >= -scale && hi <= scale,
                    "{task:?} state[{k}] in [{lo}, {hi}]"
                );
                assert!(
                    lo < -0.98 * scale && hi > 0.98 * scale,
                    "{task:?} state[{k}] covers"
                );
                assert!(
                    (sd / (scale / 3f64.sqrt()) - 1.0).abs() < 0.05,
                    "{task:?} state[{k}] sd {sd}"
                );
            }
            assert!(mean.abs() < 0.1 * scale, "{task:?} state[{k}] mean {mean}");
        }
    }
}

#[test]
fn missing_model_files_name_the_path_and_the_setup_script() {
    let dir = std::env::temp_dir().join("mbpo-no-such-mujoco-assets");
    let err = MujocoEnv::with_assets(Task::Hopper, &dir).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(
        err,
        EnvError::Model {
            env: "Hopper-v5",
            ..
        }
    ));
    assert!(
        msg.contains("hopper.xml")
            && msg.contains("deploy/setup_mujoco.sh")
            && msg.contains("MBPO_MUJOCO_ASSETS"),
        "{msg}"
    );
}
