//! After warm-up, a latent MPPI plan allocates nothing, with f32 products and with bf16 ones on
//! AMX (where the CPU has it): an actor on a clock plans with it every step; nor does drawing a
//! batch of subsequences and updating the world model on it, the learner's step. A counting global
//! allocator wraps the system one; this file holds one test so no other test allocates
//! concurrently.

use mbpo_core::alloc_count::{allocations, ignore_libtest_main_thread, CountingAllocator};
use mbpo_core::rng::stream;
use mbpo_core::rng::{normal_f32, Rng};
use mbpo_latent::mppi::{LatentMppi, MppiConfig};
use mbpo_latent::update::{Learner, UpdateConfig};
use mbpo_latent::{EpisodeBuffer, Sequences, WorldModel, WorldModelConfig};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

#[test]
fn latent_plans_and_updates_do_not_allocate_after_warm_up() {
    if !mbpo_nn::gemm::allocation_free() {
        eprintln!("SKIPPED: this CPU's GEMMs allocate (mbpo_nn::gemm::allocation_free says why)");
        return;
    }
    ignore_libtest_main_thread();
    let cfg = WorldModelConfig {
        latent: 32,
        encoder_hidden: 48,
        hidden: 64,
        ..WorldModelConfig::default()
    };
    let model = WorldModel::new(5, 2, cfg);
    let mut params = vec![0.0; model.num_params()];
    model.init(&mut params, &mut stream(0, "test.latent.no_alloc", 0));
    let z0 = vec![1.0 / 8.0; 32];
    for bf16 in [false, true] {
        let planner = MppiConfig {
            samples: 100,
            policy_samples: 6,
            elites: 10,
            iterations: 3,
            bf16,
            ..MppiConfig::default()
        };
        let mut mppi = LatentMppi::new(&model, planner);
        let (mut rng, mut action) = (stream(1, "test.latent.no_alloc.plan", 0), [0.0f32; 2]);
        for _ in 0..2 {
            mppi.plan(&model, &params, &z0, true, &mut rng, &mut action);
        }
        let before = allocations();
        for _ in 0..5 {
            mppi.plan(&model, &params, &z0, true, &mut rng, &mut action);
        }
        let n = allocations() - before;
        let products = if mppi.multiplies_in_bf16() {
            "bf16"
        } else {
            "f32"
        };
        assert_eq!(n, 0, "{products} products: {n} allocations in 5 plans");
    }
    let mut rng = stream(2, "test.latent.no_alloc.update", 0);
    let buffer = episodes(5, 2, &mut rng);
    let horizon = model.cfg.horizon;
    let mut seq = Sequences::zeros(16, horizon, 5, 2);
    let mut learner = Learner::new(model, params, UpdateConfig::default(), 16);
    let mut step = |rng: &mut Rng| {
        assert!(
            buffer.sample(horizon, rng, &mut seq),
            "episodes longer than H"
        );
        learner.update(&seq, rng);
    };
    for _ in 0..2 {
        step(&mut rng);
    }
    let before = allocations();
    for _ in 0..3 {
        step(&mut rng);
    }
    let n = allocations() - before;
    assert_eq!(n, 0, "{n} allocations in 3 draws and updates");
}

/// Three episodes of 40 random transitions.
fn episodes(obs: usize, act: usize, rng: &mut Rng) -> EpisodeBuffer {
    let mut buffer = EpisodeBuffer::new(obs, act, 120);
    let mut o: Vec<f32> = (0..obs).map(|_| normal_f32(rng)).collect();
    for t in 0..120 {
        let next: Vec<f32> = (0..obs).map(|_| normal_f32(rng)).collect();
        let a: Vec<f32> = (0..act).map(|_| normal_f32(rng).tanh()).collect();
        buffer.push(&o, &a, normal_f32(rng), &next, t % 40 == 39);
        o = next;
    }
    buffer
}
