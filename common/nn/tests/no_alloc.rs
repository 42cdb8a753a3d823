//! Forward and backward passes allocate nothing once their caches are sized.
//!
//! A counting global allocator wraps the system one; this file holds one test so no other test
//! allocates concurrently.

use mbpo_core::alloc_count::{allocations, ignore_libtest_main_thread, CountingAllocator};
use mbpo_core::stream;
use mbpo_nn::{Activation, Adam, AdamConfig, EnsembleCache, EnsembleMlp, Init, Mlp, MlpCache};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

#[test]
fn forward_backward_and_adam_do_not_allocate_in_steady_state() {
    if !mbpo_nn::gemm::allocation_free() {
        eprintln!("SKIPPED: this CPU's GEMMs allocate (mbpo_nn::gemm::allocation_free says why)");
        return;
    }
    ignore_libtest_main_thread();
    let net = Mlp::new(&[23, 256, 256, 1], Activation::Relu, Activation::Identity);
    let ens = EnsembleMlp::new(
        7,
        Mlp::new(
            &[23, 200, 200, 200, 200, 36],
            Activation::Silu,
            Activation::Identity,
        ),
    );
    let batch = 256;
    let mut rng = stream(0, "alloc", 0);
    let mut p = vec![0.0; net.num_params()];
    net.init(&mut p, Init::TorchDefault, &mut rng);
    let mut pe = vec![0.0; ens.num_params()];
    ens.init(&mut pe, Init::TruncatedNormal, &mut rng);
    let x = vec![0.1f32; batch * 23];
    let xe = vec![0.1f32; 7 * batch * 23];
    let dy = vec![1.0f32; batch];
    let dye = vec![1.0f32; 7 * batch * 36];
    let mut g = vec![0.0; p.len()];
    let mut ge = vec![0.0; pe.len()];
    let mut dx = vec![0.0; x.len()];
    let mut cache = MlpCache::new(&net, batch);
    let mut ecache = EnsembleCache::new(&ens, batch);
    let mut adam = Adam::new(p.len(), AdamConfig::default());
    let mut run = |p: &mut Vec<f32>| {
        net.forward(p, &x, batch, &mut cache);
        net.backward(p, &x, &mut cache, &dy, Some(&mut g), Some(&mut dx));
        adam.step(p, &g);
        ens.forward(&pe, &xe, batch, &mut ecache);
        ens.backward(&pe, &xe, &mut ecache, &dye, Some(&mut ge), None);
        // A smaller batch reuses the buffers.
        net.forward(p, &x, batch / 2, &mut cache);
    };
    run(&mut p); // warm-up: faer sizes its thread-local packing buffers on first use
    let before = allocations();
    for _ in 0..3 {
        run(&mut p);
    }
    let allocs = allocations() - before;
    assert_eq!(
        allocs, 0,
        "{allocs} allocations in 3 steady-state iterations"
    );
}
