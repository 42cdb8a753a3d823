//! A SAC update allocates nothing once its buffers exist, on one thread or several.
//!
//! A counting global allocator wraps the system one; this file holds one test so no other test
//! allocates concurrently. It counts every thread's allocations, the pool's workers included,
//! except those of libtest's main thread when the test runs on a thread of its own: that thread
//! only waits for the test and does its own bookkeeping (seen: 4 allocations in 1 of 10 runs
//! under load, none of them on the test's thread).

use mbpo_core::rng::{normal_f32, stream};
use mbpo_core::Batch;
use mbpo_sac::{Sac, SacConfig};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicI64, AtomicUsize, Ordering};

struct Counting;
static ALLOCS: AtomicUsize = AtomicUsize::new(0);
/// Thread id whose allocations are not counted (libtest's main thread), or -1.
static IGNORED_TID: AtomicI64 = AtomicI64::new(-1);

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: gettid has no preconditions and does not allocate.
        if unsafe { libc::gettid() } as i64 != IGNORED_TID.load(Ordering::Relaxed) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        System.alloc(layout)
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

#[test]
fn updates_do_not_allocate_in_steady_state() {
    // SAFETY: getpid/gettid have no preconditions. The main thread's tid is the pid.
    let (pid, me) = unsafe { (libc::getpid(), libc::gettid()) };
    if me != pid {
        IGNORED_TID.store(pid as i64, Ordering::Relaxed);
    }
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
    for threads in [1, 2] {
        let config = SacConfig {
            batch_size: batch,
            hidden: vec![32, 32],
            threads,
            ..SacConfig::default()
        };
        let mut sac = Sac::new(obs, act, config, &mut stream(0, "alloc.init", 0));
        let mut rng = stream(0, "alloc.update", 0);
        // Warm-up: faer sizes its thread-local packing buffers on each thread's first use.
        for _ in 0..3 {
            sac.update(&data, &mut rng);
        }
        let before = ALLOCS.load(Ordering::Relaxed);
        for _ in 0..20 {
            sac.update(&data, &mut rng);
        }
        let allocs = ALLOCS.load(Ordering::Relaxed) - before;
        assert_eq!(
            allocs, 0,
            "{allocs} allocations in 20 updates on {threads} threads"
        );
    }
}
