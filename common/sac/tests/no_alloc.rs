//! A SAC update allocates nothing once its buffers exist, on one thread or several.
//!
//! The counting allocator of `mbpo_core::alloc_count` counts every thread's allocations, the
//! pool's workers included (not libtest's main thread); this file holds one test so no other
//! test allocates concurrently.

use mbpo_core::alloc_count::{allocations, ignore_libtest_main_thread, CountingAllocator};
use mbpo_core::rng::{normal_f32, stream};
use mbpo_core::Batch;
use mbpo_sac::{Sac, SacConfig};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

#[test]
fn updates_do_not_allocate_in_steady_state() {
    if !mbpo_nn::gemm::allocation_free() {
        eprintln!("SKIPPED: this CPU's GEMMs allocate (mbpo_nn::gemm::allocation_free says why)");
        return;
    }
    ignore_libtest_main_thread();
    let (obs, act, batch) = (5, 2, 64);
    let mut g = stream(0, "alloc.data", 0);
    let mut data = Batch::new(obs, act, batch);
    for v in data
        .obs
        .iter_mut()
        .chain(&mut data.next_obs)
        .chain(&mut data.reward)
    {
        *v = normal_f32(&mut g);
    }
    data.act
        .iter_mut()
        .for_each(|v| *v = normal_f32(&mut g).tanh());
    for (threads, critic_layer_norm) in [(1, false), (2, false), (1, true), (2, true)] {
        let config = SacConfig {
            batch_size: batch,
            hidden: vec![32, 32],
            threads,
            critic_layer_norm,
            ..SacConfig::default()
        };
        let mut sac = Sac::new(obs, act, config, &mut stream(0, "alloc.init", 0));
        let mut rng = stream(0, "alloc.update", 0);
        // Warm-up: faer sizes its thread-local packing buffers on each thread's first use.
        for _ in 0..3 {
            sac.update(&data, &mut rng);
        }
        let before = allocations();
        for _ in 0..20 {
            sac.update(&data, &mut rng);
        }
        let allocs = allocations() - before;
        assert_eq!(
            allocs, 0,
            "{allocs} allocations in 20 updates on {threads} threads (critic LayerNorm: {critic_layer_norm})"
        );
    }
}
