//! The hot loops allocate nothing: a training call's allocations do not grow with its number of
//! gradient steps, and predictions and rollouts of a size seen before allocate (almost) nothing.
//!
//! A counting global allocator wraps the system one; this file holds one test so no other test
//! allocates concurrently.

mod common;

use common::{pendulum_data, small_config};
use mbpo_core::alloc_count::{allocations, ignore_libtest_main_thread, CountingAllocator};
use mbpo_core::{stream, ReplayBuffer, UniformPolicy};
use mbpo_model::{ModelConfig, ProbabilisticEnsemble, RolloutFilter, RolloutTermination};

#[global_allocator]
static GLOBAL: CountingAllocator = CountingAllocator;

fn count(f: impl FnOnce()) -> usize {
    let before = allocations();
    f();
    allocations() - before
}

#[test]
fn training_steps_predictions_and_rollouts_do_not_allocate() {
    if !mbpo_nn::gemm::allocation_free() {
        eprintln!("SKIPPED: this CPU's GEMMs allocate (mbpo_nn::gemm::allocation_free says why)");
        return;
    }
    ignore_libtest_main_thread();
    let data = pendulum_data(3000, 1); // 2400 training rows: 10 steps per epoch
    let mut rng = stream(0, "alloc", 0);
    // One thread runs inline; two run members in blocks on a pool (spawned in the warm-up).
    for threads in [1, 2] {
        let train_for = |epochs: usize| ModelConfig {
            max_epochs: Some(epochs),
            max_epochs_since_update: 100,
            threads,
            ..small_config(3, 2, &[32, 32])
        };
        let mut model = ProbabilisticEnsemble::new(3, 1, train_for(1), &mut rng).unwrap();
        model.train(&data, &mut rng).unwrap(); // warm-up: buffers and faer's packing memory
        let one = count(|| {
            model.train(&data, &mut rng).unwrap();
        });
        let mut longer = ProbabilisticEnsemble::new(3, 1, train_for(6), &mut rng).unwrap();
        longer.train(&data, &mut rng).unwrap();
        let six = count(|| {
            longer.train(&data, &mut rng).unwrap();
        });
        // 50 more gradient steps; only the per-epoch report rows (and their Vec's growth) may add.
        assert!(
            six - one <= 5 * 3,
            "{threads} thread(s): 1 epoch: {one} allocations, 6 epochs: {six}"
        );
    }
    let mut model = ProbabilisticEnsemble::new(
        3,
        1,
        ModelConfig {
            max_epochs: Some(1),
            ..small_config(3, 2, &[32, 32])
        },
        &mut rng,
    )
    .unwrap();
    model.train(&data, &mut rng).unwrap();

    let n = 1500;
    let obs = vec![0.1f32; n * 3];
    let act = vec![0.2f32; n];
    let members: Vec<usize> = (0..n).map(|i| i % 3).collect();
    let (mut reward, mut next) = (vec![0.0; n], vec![0.0; n * 3]);
    let (mut mean, mut lv) = (vec![0.0; n * 4], vec![0.0; n * 4]);
    let mut predict = |model: &mut ProbabilisticEnsemble| {
        model
            .predict_sample(&obs, &act, n, &members, &mut rng, &mut reward, &mut next)
            .unwrap();
        model
            .predict_gaussian(&obs, &act, n, &members, &mut mean, &mut lv)
            .unwrap();
    };
    predict(&mut model);
    assert_eq!(count(|| predict(&mut model)), 0);

    let mut policy = UniformPolicy {
        low: vec![-2.0],
        high: vec![2.0],
    };
    let mut pool = ReplayBuffer::new(3, 1, 10 * n);
    let never = |_: &[f32], _: &[f32], _: &[f32]| false;
    let mut rrng = stream(0, "alloc", 1);
    let mut rollout = |model: &mut ProbabilisticEnsemble, k: usize, keep_fraction: f64| {
        let filter = RolloutFilter {
            keep_fraction,
            ..RolloutFilter::PAPER
        };
        model
            .rollout(
                &obs,
                n,
                &mut policy,
                k,
                RolloutTermination::Rule(&never),
                filter,
                &mut rrng,
                &mut pool,
            )
            .unwrap();
    };
    rollout(&mut model, 5, 1.0);
    // One allocation: the returned statistics' per-step vector.
    assert_eq!(count(|| rollout(&mut model, 5, 1.0)), 1);
    // Masked: the elites' scores and the ranking reuse their buffers too.
    rollout(&mut model, 5, 0.5);
    assert_eq!(count(|| rollout(&mut model, 5, 0.5)), 1);
}
