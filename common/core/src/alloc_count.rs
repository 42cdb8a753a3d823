//! A counting global allocator for the workspace's no-allocation tests (`tests/no_alloc.rs` of
//! nn, model, sac, plan, wire): install it with
//! `#[global_allocator] static A: CountingAllocator = CountingAllocator;` and compare
//! [`allocations`] before and after the code under test.
//!
//! It counts `alloc` and `realloc` on every thread (worker pools included) except libtest's
//! main thread once [`ignore_libtest_main_thread`] was called: when a test runs on a thread of
//! its own, that thread only waits for it and keeps its own books, and under load it allocated
//! a few times in some runs (4 in 1 of 10 SAC runs, 2 in a wire run), never on the test's
//! thread. Each such test file holds one test, so no other test allocates concurrently.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicI64, AtomicUsize, Ordering};

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);
/// Thread id whose allocations are not counted, or -1.
static IGNORED_TID: AtomicI64 = AtomicI64::new(-1);

/// The system allocator, counting allocations.
pub struct CountingAllocator;

fn count() {
    // SAFETY: gettid has no preconditions and does not allocate.
    if unsafe { libc::gettid() } as i64 != IGNORED_TID.load(Ordering::Relaxed) {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
    }
}

// SAFETY: every call is forwarded to `System` unchanged; counting has no effect on memory.
unsafe impl GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        count();
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        count();
        // SAFETY: the caller's contract, forwarded.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

/// Allocations counted so far (`alloc` + `realloc`).
pub fn allocations() -> usize {
    ALLOCATIONS.load(Ordering::Relaxed)
}

/// Stop counting libtest's main thread if the calling test runs on another thread (call it
/// first in the test).
pub fn ignore_libtest_main_thread() {
    // SAFETY: getpid/gettid have no preconditions. The main thread's tid is the pid.
    let (pid, me) = unsafe { (libc::getpid(), libc::gettid()) };
    if me != pid {
        IGNORED_TID.store(pid as i64, Ordering::Relaxed);
    }
}
