//! The Python Gymnasium bridge (`gym:` envs): the same transitions as the built-in env, the
//! spaces and time limit the env declares, seeding, and every failure named.
//!
//! Needs the project venv (`deploy/setup_python.sh`, run by `deploy/test.sh`).

use std::path::PathBuf;

use mbpo_core::rng::{stream, uniform_range_f32};
use mbpo_envs::{Env, EnvError, GymSpec, Pendulum, PythonEnv, PythonTermination, RestorableEnv};

/// The test suite's Python envs (tests/python/mbpo_test_envs.py).
fn test_envs_dir() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../../tests/python"))
}

fn spec(target: &str, kwargs: serde_json::Value) -> GymSpec {
    GymSpec {
        target: target.into(),
        kwargs: kwargs.as_object().cloned().unwrap_or_default(),
        path: vec![test_envs_dir()],
        ..GymSpec::default()
    }
}

fn start_error(spec: GymSpec) -> String {
    match PythonEnv::start(spec) {
        Ok(_) => panic!("the env started"),
        Err(e) => {
            assert!(matches!(e, EnvError::PythonStart { .. }), "{e:?}");
            e.to_string()
        }
    }
}

#[test]
fn gym_pendulum_through_the_bridge_equals_the_builtin_pendulum_bit_for_bit() {
    let (theta, thetadot) = (2.5f64, -0.75f64);
    let kwargs = serde_json::json!({ "theta": theta, "thetadot": thetadot });
    let mut python = PythonEnv::start(spec("mbpo_test_envs:PendulumAt", kwargs)).unwrap();
    let mut builtin = Pendulum::new();
    let (mut obs_py, mut obs_rs) = ([0f32; 3], [0f32; 3]);
    python
        .reset(&mut stream(0, "test", 0), &mut obs_py)
        .unwrap();
    builtin.reset_to(&[theta, thetadot], &mut obs_rs).unwrap();
    assert_eq!(obs_py.map(f32::to_bits), obs_rs.map(f32::to_bits));
    // Actions beyond the bounds too (both clip them), over a whole episode to its time limit.
    let mut rng = stream(0, "test.actions", 0);
    for t in 1..=200 {
        let action = [uniform_range_f32(&mut rng, -3.0, 3.0)];
        let a = python.step(&action, &mut obs_py).unwrap();
        let b = builtin.step(&action, &mut obs_rs).unwrap();
        assert_eq!(
            obs_py.map(f32::to_bits),
            obs_rs.map(f32::to_bits),
            "step {t}"
        );
        assert_eq!(a.reward.to_bits(), b.reward.to_bits(), "step {t}: reward");
        assert_eq!(
            (a.terminated, a.truncated),
            (b.terminated, b.truncated),
            "step {t}"
        );
        assert_eq!(python.elapsed_steps(), t);
    }
    assert!(
        python.restorable().is_none(),
        "a Python env cannot restore a state"
    );
}

#[test]
fn a_registered_id_reports_its_spaces_and_time_limit_and_the_same_seed_gives_the_same_episode() {
    let run = |seed: u64| {
        let mut env = PythonEnv::start(GymSpec::from_id("gym:Pendulum-v1").unwrap()).unwrap();
        assert_eq!(env.id(), "gym:Pendulum-v1");
        assert_eq!(env.action_space().low, [-2.0]);
        assert_eq!(env.action_space().high, [2.0]);
        assert_eq!(env.observation_space().high, [1.0, 1.0, 8.0]);
        assert_eq!(env.max_episode_steps(), 200);
        let mut rng = stream(seed, "actor.env", 0);
        let mut obs = [0f32; 3];
        let mut seen = Vec::new();
        for _ in 0..2 {
            env.reset(&mut rng, &mut obs).unwrap();
            seen.extend(obs);
            for _ in 0..5 {
                env.step(&[0.5], &mut obs).unwrap();
                seen.extend(obs);
            }
        }
        seen
    };
    let a = run(1);
    assert_eq!(a, run(1), "same stream, same episodes");
    assert_ne!(a, run(2), "another stream, other start states");
    assert_ne!(
        a[..3],
        a[18..21],
        "each reset draws a new seed from the stream"
    );
}

#[test]
fn a_dict_observation_is_flattened_in_key_order_and_its_layout_reported() {
    let mut env = PythonEnv::start(GymSpec {
        max_episode_steps: Some(7),
        ..spec("mbpo_test_envs:DictObs", serde_json::json!({}))
    })
    .unwrap();
    let keys: Vec<_> = env
        .observation_parts()
        .iter()
        .map(|p| (p.key.as_str(), p.shape.clone()))
        .collect();
    assert_eq!(keys, [("a", vec![1]), ("b", vec![2])]);
    let mut obs = [0f32; 3];
    env.reset(&mut stream(0, "t", 0), &mut obs).unwrap();
    assert_eq!(obs, [0.5, 0.25, -0.25]);
    let step = env.step(&[-0.5], &mut obs).unwrap();
    assert_eq!(obs, [-0.5, 1.0, -1.0]);
    assert!(!step.truncated);
    for _ in 1..7 {
        let step = env.step(&[0.0], &mut obs).unwrap();
        assert_eq!(
            step.truncated,
            env.elapsed_steps() == 7,
            "the configured time limit"
        );
    }
}

#[test]
fn spaces_the_model_cannot_use_are_refused_naming_the_env_the_space_and_why() {
    let cases = [
        ("DiscreteActions", "Discrete(3)", "not a Box"),
        ("UnboundedActions", "inf", "unbounded"),
        ("ImageObs", "uint8", "float type"),
    ];
    for (class, space, why) in cases {
        let target = format!("mbpo_test_envs:{class}");
        let e = start_error(GymSpec {
            max_episode_steps: Some(10),
            ..spec(&target, serde_json::json!({}))
        });
        assert!(
            e.contains(&target) && e.contains(space) && e.contains(why),
            "{class}: {e}"
        );
    }
}

#[test]
fn what_cannot_start_is_an_error_that_names_the_fix() {
    let e = start_error(spec("no_such_module:Env", serde_json::json!({})));
    assert!(
        e.contains("No module named 'no_such_module'") && e.contains("pip install"),
        "{e}"
    );
    let e = start_error(spec("NoSuchEnv-v9", serde_json::json!({})));
    assert!(
        e.contains("gym:NoSuchEnv-v9") && e.contains("NoSuchEnv"),
        "{e}"
    );
    let e = start_error(spec("mbpo_test_envs:Drift", serde_json::json!({})));
    assert!(
        e.contains("no time limit") && e.contains("max_episode_steps"),
        "{e}"
    );
    let e = start_error(spec(
        "mbpo_test_envs:Drift",
        serde_json::json!({ "speed": 2 }),
    ));
    assert!(e.contains("unexpected keyword argument 'speed'"), "{e}");
    let e = start_error(GymSpec {
        python: Some("/nonexistent/python3".into()),
        ..spec("Pendulum-v1", serde_json::json!({}))
    });
    assert!(
        e.contains("/nonexistent/python3") && e.contains("[gym]"),
        "{e}"
    );
}

#[test]
fn an_exception_in_step_carries_the_python_traceback() {
    let mut env = PythonEnv::start(GymSpec {
        max_episode_steps: Some(100),
        ..spec("mbpo_test_envs:Drift", serde_json::json!({ "raise_at": 5 }))
    })
    .unwrap();
    let mut obs = [0f32; 2];
    env.reset(&mut stream(0, "t", 0), &mut obs).unwrap();
    for _ in 1..5 {
        env.step(&[1.0], &mut obs).unwrap();
    }
    let e = env.step(&[1.0], &mut obs).unwrap_err();
    let EnvError::PythonException {
        call, traceback, ..
    } = &e
    else {
        panic!("{e:?}")
    };
    assert_eq!(*call, "step");
    assert!(
        traceback.contains("RuntimeError: Drift: failing on purpose at step 5")
            && traceback.contains("mbpo_test_envs.py"),
        "{traceback}"
    );
}

#[test]
fn a_process_that_exits_is_reported_and_the_next_reset_starts_a_new_one() {
    let marker = std::env::temp_dir().join(format!("mbpo-exit-marker-{}", std::process::id()));
    let _ = std::fs::remove_file(&marker);
    let kwargs = serde_json::json!({ "exit_at": 3, "exit_marker": marker });
    let mut env = PythonEnv::start(GymSpec {
        max_episode_steps: Some(100),
        ..spec("mbpo_test_envs:Drift", kwargs)
    })
    .unwrap();
    let mut obs = [0f32; 2];
    let mut rng = stream(0, "t", 0);
    env.reset(&mut rng, &mut obs).unwrap();
    env.step(&[1.0], &mut obs).unwrap();
    env.step(&[1.0], &mut obs).unwrap();
    let e = env.step(&[1.0], &mut obs).unwrap_err();
    assert!(
        matches!(&e, EnvError::PythonExited { status, .. } if status.contains('3')),
        "{e:?}"
    );
    assert_eq!(env.restarts(), 0);
    env.reset(&mut rng, &mut obs).unwrap();
    assert_eq!(env.restarts(), 1);
    for _ in 0..10 {
        env.step(&[1.0], &mut obs).unwrap();
    }
    let _ = std::fs::remove_file(&marker);
}

#[test]
fn a_python_termination_rule_judges_a_batch_and_reports_its_errors() {
    let spec = spec("", serde_json::json!({}));
    let mut rule = PythonTermination::start("mbpo_test_envs:beyond_1_2", &spec, 2, 1).unwrap();
    let obs = [0.0f32; 6];
    let act = [0.0f32; 3];
    let next = [1.0f32, 0.0, -1.5, 0.0, 1.25, 9.0];
    let mut done = [false; 3];
    rule.done_batch(&obs, &act, &next, 3, &mut done).unwrap();
    assert_eq!(done, [false, true, true]);
    rule.done_batch(&obs, &act, &next, 1, &mut done[..1])
        .unwrap();
    assert!(!done[0]);

    let mut broken = PythonTermination::start("mbpo_test_envs:broken_rule", &spec, 2, 1).unwrap();
    let e = broken
        .done_batch(&obs, &act, &next, 3, &mut done)
        .unwrap_err();
    assert!(
        e.to_string().contains("ValueError: rule broken on purpose"),
        "{e}"
    );
    let mut short = PythonTermination::start("mbpo_test_envs:wrong_length", &spec, 2, 1).unwrap();
    let e = short
        .done_batch(&obs, &act, &next, 3, &mut done)
        .unwrap_err();
    assert!(
        e.to_string().contains("returned 1 flags for 3 transitions"),
        "{e}"
    );
    let e = PythonTermination::start("mbpo_test_envs:no_such_rule", &spec, 2, 1)
        .err()
        .unwrap();
    assert!(
        e.to_string().contains("has no function no_such_rule"),
        "{e}"
    );
}

/// Seeding through the bridge on a MuJoCo v5 env: the same stream gives the same episodes bit
/// for bit, another stream other ones (Gymnasium's Hopper-v5, MuJoCo from the project venv).
#[cfg(feature = "mujoco")]
#[test]
fn gym_hopper_is_deterministic_per_seed_through_the_bridge() {
    let run = |seed: u64| {
        let mut env = PythonEnv::start(GymSpec::from_id("gym:Hopper-v5").unwrap()).unwrap();
        assert_eq!(
            (env.obs_dim(), env.act_dim(), env.max_episode_steps()),
            (11, 3, 1000)
        );
        let mut rng = stream(seed, "actor.env", 0);
        let mut actions = stream(0, "test.actions", 0);
        let mut obs = [0f32; 11];
        let mut seen: Vec<u64> = Vec::new();
        env.reset(&mut rng, &mut obs).unwrap();
        for _ in 0..300 {
            let a: Vec<f32> = (0..3)
                .map(|_| uniform_range_f32(&mut actions, -1.0, 1.0))
                .collect();
            let step = env.step(&a, &mut obs).unwrap();
            seen.extend(env.observation_f64().unwrap().iter().map(|v| v.to_bits()));
            seen.push(step.reward.to_bits());
            if step.terminated || step.truncated {
                env.reset(&mut rng, &mut obs).unwrap();
            }
        }
        seen
    };
    let a = run(3);
    assert_eq!(a, run(3), "same stream, same episodes");
    assert_ne!(a, run(4), "another stream, other start states");
}
