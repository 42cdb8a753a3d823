//! A small persistent thread pool for data-parallel phases of a computation.
//!
//! SAC's update on two cores runs each phase (the actor's samples, the critics' steps, the
//! actor's gradient) on both at once, a few times per update, thousands of times per second.
//! Spawning threads per phase would cost tens of microseconds and lose faer's thread-local
//! packing buffers each time, so the workers live as long as the pool and sleep on a condvar
//! between phases. A thread that waits (a worker for the next phase, the caller for the
//! workers) first polls for [`SPIN`], a little longer than the gap between two updates, and then
//! sleeps: no busy polling beyond that.
//!
//! Work is assigned statically: item i always runs on thread i (item 0 on the caller), so what
//! a shard computes never depends on scheduling, and results are deterministic for a given
//! thread count.

use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// How long a waiting thread polls an atomic before sleeping on its condvar: longer than the
/// gap between two SAC updates (drawing the next minibatch), so a worker is awake when the
/// next update starts. 100 µs instead of 30 made Hopper's SAC updates on two threads 2.64 ->
/// 2.50 ms (`mbpo bench breakdown`; results/measurements.md, "Where an MBPO run's time goes",
/// 2026-11-26, commit cab65f9).
pub const SPIN: Duration = Duration::from_micros(100);

/// A job with its lifetime erased; [`WorkerPool::run`] does not return before every worker has
/// finished with it, which is what makes the erasure sound.
#[derive(Clone, Copy)]
struct JobPtr(*const (dyn Fn(usize) + Sync));
// SAFETY: the pointee is `Sync`, and it outlives every use (see `WorkerPool::run`).
unsafe impl Send for JobPtr {}

struct State {
    generation: u64,
    job: Option<JobPtr>,
    shutdown: bool,
}

struct Shared {
    state: Mutex<State>,
    wake: Condvar,
    /// `state.generation`, readable without the lock (for polling).
    generation: AtomicU64,
    /// Workers still inside the current job.
    pending: AtomicUsize,
    done_lock: Mutex<()>,
    done: Condvar,
    panicked: AtomicBool,
}

fn lock<T>(m: &Mutex<T>) -> MutexGuard<'_, T> {
    // No code panics while holding these locks; a poisoned lock still holds consistent data.
    m.lock().unwrap_or_else(|e| e.into_inner())
}

/// `threads − 1` parked worker threads plus the caller.
pub struct WorkerPool {
    shared: Arc<Shared>,
    workers: Vec<JoinHandle<()>>,
}

impl WorkerPool {
    /// A pool running jobs on `threads` threads (the caller and `threads − 1` workers);
    /// `threads` = 1 spawns nothing and runs every job inline.
    pub fn new(threads: usize) -> Self {
        assert!(threads >= 1, "a pool needs at least one thread");
        let shared = Arc::new(Shared {
            state: Mutex::new(State {
                generation: 0,
                job: None,
                shutdown: false,
            }),
            wake: Condvar::new(),
            generation: AtomicU64::new(0),
            pending: AtomicUsize::new(0),
            done_lock: Mutex::new(()),
            done: Condvar::new(),
            panicked: AtomicBool::new(false),
        });
        let workers = (1..threads)
            .map(|index| {
                let shared = Arc::clone(&shared);
                std::thread::Builder::new()
                    .name(format!("mbpo-worker-{index}"))
                    .spawn(move || {
                        crate::FlushSubnormals::for_this_thread();
                        worker_loop(&shared, index)
                    })
                    .expect("cannot spawn a worker thread")
            })
            .collect();
        Self { shared, workers }
    }

    /// Threads that run a job (including the caller).
    pub fn threads(&self) -> usize {
        self.workers.len() + 1
    }

    /// Run `job(i)` for every thread index i in `0..threads()` at once (i = 0 on the caller)
    /// and return when all have finished. A panic in any of them is re-raised here.
    pub fn run(&mut self, job: &(dyn Fn(usize) + Sync)) {
        let _flush = crate::FlushSubnormals::new();
        if self.workers.is_empty() {
            job(0);
            return;
        }
        let shared = &*self.shared;
        shared.pending.store(self.workers.len(), Ordering::Release);
        {
            let mut st = lock(&shared.state);
            // SAFETY: only the lifetime changes; this function waits below until no worker
            // uses the pointer any more, before `job`'s borrow ends.
            let ptr: *const (dyn Fn(usize) + Sync + 'static) =
                unsafe { std::mem::transmute(job as *const (dyn Fn(usize) + Sync + '_)) };
            st.job = Some(JobPtr(ptr));
            st.generation += 1;
            shared.generation.store(st.generation, Ordering::Release);
        }
        shared.wake.notify_all();
        let mine = catch_unwind(AssertUnwindSafe(|| job(0)));
        // Wait for the workers even if our share panicked: they still borrow `job`.
        let start = Instant::now();
        while shared.pending.load(Ordering::Acquire) != 0 && start.elapsed() < SPIN {
            std::hint::spin_loop();
        }
        if shared.pending.load(Ordering::Acquire) != 0 {
            let mut guard = lock(&shared.done_lock);
            while shared.pending.load(Ordering::Acquire) != 0 {
                guard = shared.done.wait(guard).unwrap_or_else(|e| e.into_inner());
            }
        }
        lock(&shared.state).job = None;
        if let Err(payload) = mine {
            resume_unwind(payload);
        }
        if shared.panicked.swap(false, Ordering::AcqRel) {
            panic!("a worker thread panicked (its message is above)");
        }
    }

    /// `f(i, &mut items[i])` for every item at once, item i on thread i; `items` may be
    /// shorter than [`WorkerPool::threads`] (the extra threads idle).
    pub fn for_each_mut<T: Send>(&mut self, items: &mut [T], f: impl Fn(usize, &mut T) + Sync) {
        assert!(
            items.len() <= self.threads(),
            "more items than threads: {} > {}",
            items.len(),
            self.threads()
        );
        let len = items.len();
        let base = SyncPtr(items.as_mut_ptr());
        let base = &base;
        self.run(&move |i| {
            if i < len {
                // SAFETY: index i is handed to exactly one thread, so the `&mut` are disjoint,
                // and `items` stays borrowed until `run` returns.
                let item = unsafe { &mut *base.0.add(i) };
                f(i, item);
            }
        });
    }
}

/// A pointer to the items of [`WorkerPool::for_each_mut`], shared across the job's threads.
struct SyncPtr<T>(*mut T);
// SAFETY: each thread dereferences a distinct element, and T: Send lets it move to that thread.
unsafe impl<T: Send> Sync for SyncPtr<T> {}

fn worker_loop(shared: &Shared, index: usize) {
    let mut seen = 0u64;
    loop {
        let start = Instant::now();
        while shared.generation.load(Ordering::Acquire) == seen && start.elapsed() < SPIN {
            std::hint::spin_loop();
        }
        let job = {
            let mut st = lock(&shared.state);
            while st.generation == seen && !st.shutdown {
                st = shared.wake.wait(st).unwrap_or_else(|e| e.into_inner());
            }
            if st.shutdown {
                return;
            }
            seen = st.generation;
            st.job.expect("a new generation always carries a job")
        };
        // SAFETY: `run` keeps the job alive until `pending` reaches zero, after this call.
        let result = catch_unwind(AssertUnwindSafe(|| unsafe { (*job.0)(index) }));
        if result.is_err() {
            shared.panicked.store(true, Ordering::Release);
        }
        if shared.pending.fetch_sub(1, Ordering::AcqRel) == 1 {
            let _guard = lock(&shared.done_lock);
            shared.done.notify_one();
        }
    }
}

impl Drop for WorkerPool {
    fn drop(&mut self) {
        lock(&self.shared.state).shutdown = true;
        self.shared.wake.notify_all();
        for w in self.workers.drain(..) {
            let _ = w.join();
        }
    }
}

impl Clone for WorkerPool {
    /// A new pool with as many threads (threads are not shared).
    fn clone(&self) -> Self {
        Self::new(self.threads())
    }
}

impl std::fmt::Debug for WorkerPool {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WorkerPool")
            .field("threads", &self.threads())
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_item_runs_once_on_its_own_thread_for_many_rounds() {
        let mut pool = WorkerPool::new(3);
        let mut items = vec![(0u64, None::<std::thread::ThreadId>); 3];
        for round in 0..2000u64 {
            pool.for_each_mut(&mut items, |i, item| {
                item.0 += round * (i as u64 + 1);
                let id = std::thread::current().id();
                assert!(item.1.is_none_or(|t| t == id), "item {i} changed thread");
                item.1 = Some(id);
            });
        }
        let total: u64 = (0..2000).sum();
        assert_eq!(
            items.iter().map(|x| x.0).collect::<Vec<_>>(),
            [total, 2 * total, 3 * total]
        );
        assert_eq!(items[0].1, Some(std::thread::current().id()));
        assert_ne!(items[1].1, items[2].1);
    }

    #[test]
    fn fewer_items_than_threads_and_a_single_thread_pool_work() {
        let mut pool = WorkerPool::new(2);
        let mut one = [0];
        pool.for_each_mut(&mut one, |_, v| *v += 1);
        assert_eq!(one, [1]);
        let mut inline = WorkerPool::new(1);
        let mut two = [0];
        inline.for_each_mut(&mut two, |i, v| *v = i + 7);
        assert_eq!(two, [7]);
    }

    #[test]
    fn a_worker_panic_reaches_the_caller_and_the_pool_survives() {
        let mut pool = WorkerPool::new(2);
        let mut items = [0, 0];
        let caught = catch_unwind(AssertUnwindSafe(|| {
            pool.for_each_mut(&mut items, |i, _| assert!(i == 0, "boom in worker"))
        }));
        assert!(caught.is_err());
        pool.for_each_mut(&mut items, |i, v| *v = i + 1);
        assert_eq!(items, [1, 2]);
    }
}
