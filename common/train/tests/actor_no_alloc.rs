//! A pipeline actor's env step allocates nothing: the policy forward pass, the env step, the
//! episode reset and the transition it hands on (a one-row batch it reuses) all run in buffers
//! that exist from the start. (One test in this file: the counting allocator sees every thread.)

use mbpo_core::alloc_count::{allocations, ignore_libtest_main_thread, CountingAllocator};
use mbpo_train::actor::Behaviour;
use mbpo_train::roles::{ActorRole, PolicySnapshot};
use mbpo_train::ExperimentConfig;

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

#[test]
fn an_actor_step_allocates_nothing() {
    ignore_libtest_main_thread();
    let mut cfg = ExperimentConfig::default();
    cfg.sac.hidden = vec![32, 32];
    let mut role = ActorRole::new(&cfg, 0).unwrap();
    let n = role.checkpoint().policy.len();
    let snapshot = PolicySnapshot {
        version: 1,
        params: (0..n).map(|i| ((i % 13) as f32 - 6.0) * 0.01).collect(),
    };
    role.set_policy(&snapshot);
    // Warm-up: faer sizes its thread-local packing buffers on first use.
    for _ in 0..3 {
        role.act(Behaviour::Policy).unwrap();
    }
    let before = allocations();
    // Pendulum episodes are 200 steps: 450 steps cross two resets.
    let mut reward = 0.0;
    for t in 0..450 {
        let behaviour = match t % 3 {
            0 => Behaviour::Uniform,
            _ => Behaviour::Policy,
        };
        reward += role.act(behaviour).unwrap().reward[0];
    }
    let allocs = allocations() - before;
    assert_eq!(allocs, 0, "{allocs} allocations in 450 actor steps");
    assert!(
        role.env_actor().episodes >= 2,
        "the steps crossed episode ends"
    );
    assert!(reward < 0.0, "Pendulum rewards are negative: the steps ran");
}
