//! After warm-up, a latent MPPI plan allocates nothing, with f32 products and with bf16 ones on
//! AMX (where the CPU has it): an actor on a clock plans with it every step. A counting global
//! allocator wraps the system one; this file holds one test so no other test allocates
//! concurrently.

use mbpo_core::alloc_count::{allocations, ignore_libtest_main_thread, CountingAllocator};
use mbpo_core::rng::stream;
use mbpo_latent::mppi::{LatentMppi, MppiConfig};
use mbpo_latent::{WorldModel, WorldModelConfig};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

#[test]
fn latent_plans_do_not_allocate_after_warm_up() {
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
}
