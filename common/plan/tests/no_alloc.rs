//! After warm-up, a planning step (one MPC action) allocates nothing, for every planner, with the
//! learned ensemble and the known reward. A counting global allocator wraps the system one; this
//! file holds one test so no other test allocates concurrently.

use mbpo_core::alloc_count::{allocations, ignore_libtest_main_thread, CountingAllocator};
use mbpo_core::stream;
use mbpo_model::{ModelConfig, ProbabilisticEnsemble};
use mbpo_plan::{build, EnsembleModel, Mpc, PlannerConfig, PlannerKind, RewardSource};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

#[test]
fn planning_steps_do_not_allocate_after_warm_up() {
    if !mbpo_nn::gemm::allocation_free() {
        eprintln!("SKIPPED: this CPU's GEMMs allocate (mbpo_nn::gemm::allocation_free says why)");
        return;
    }
    ignore_libtest_main_thread();
    let cfg = ModelConfig {
        members: 3,
        elites: 3,
        hidden: vec![32, 32],
        weight_decay: vec![0.0; 3],
        ..ModelConfig::default()
    };
    let ensemble = ProbabilisticEnsemble::new(3, 1, cfg, &mut stream(0, "na", 0)).unwrap();
    let reward = mbpo_envs::reward_fn("Pendulum-v1").unwrap();
    for (kind, source) in [
        (PlannerKind::Random, RewardSource::Known(reward)),
        (PlannerKind::Cem, RewardSource::Known(reward)),
        (PlannerKind::Cem, RewardSource::Model),
        (PlannerKind::Mppi, RewardSource::Known(reward)),
        (PlannerKind::Grad, RewardSource::Known(reward)),
        (PlannerKind::Grad, RewardSource::Model),
    ] {
        let mut pc = PlannerConfig {
            kind,
            horizon: 8,
            particles: 6,
            ..PlannerConfig::default()
        };
        pc.random.candidates = 300; // more than one inference chunk of rows
        pc.cem.candidates = 100;
        pc.cem.elites = 10;
        pc.mppi.candidates = 100;
        pc.grad.sequences = 4;
        pc.grad.iterations = 3;
        let mut model =
            EnsembleModel::new(ensemble.clone(), source, None, &[-2.0], &[2.0]).unwrap();
        let mut mpc = Mpc::new(build(&pc, 1).unwrap(), false);
        let mut rng = stream(1, "na.plan", 0);
        let mut obs = [1.0f32, 0.0, 0.0];
        let mut action = [0.0f32];
        for _ in 0..3 {
            mpc.act(&mut model, &obs, &mut rng, &mut action).unwrap();
        }
        let before = allocations();
        for i in 0..5 {
            obs[2] = i as f32 * 0.3;
            mpc.act(&mut model, &obs, &mut rng, &mut action).unwrap();
        }
        let n = allocations() - before;
        assert_eq!(
            n, 0,
            "{kind:?} ({source:?}): {n} allocations in 5 planning steps"
        );
    }
}
