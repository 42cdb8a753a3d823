//! A training call on several threads ([`crate::ModelConfig::threads`]): members in blocks,
//! one block per thread.
//!
//! The members of the ensemble are independent networks except in two places: the
//! log-variance bounds, shared by all members, whose gradient is a sum over members; and Adam,
//! which is element-wise over θ. So one gradient step runs as
//!
//! 1. every thread computes the loss gradient of its block of members (a contiguous range of
//!    θ, which is member-major), each member's bound gradient into that member's own slot
//!    ([`members_loss_and_grads`]);
//! 2. the caller adds the slots in member order ([`sum_bound_slots`]);
//! 3. Adam, cut into one equal range of θ per thread ([`adam_step`]).
//!
//! The holdout MSE of an epoch is per member as well ([`holdout_mse`]). Every floating-point
//! sum has the same operands in the same order whatever the number of threads, so a training
//! call gives bit-identical weights for any `threads` (`tests/training.rs` checks it); with 1
//! thread everything runs inline on the caller.
//!
//! Load balance is by members: 7 members on 2 threads are blocks of 4 and 3, so the second
//! thread idles for one member's work per step (about 1.75x on two cores: the gradient work
//! splits 4 : 3, Adam and the holdout pass split evenly).

use crate::config::MAX_THREADS;
use crate::network::{member_loss_and_grad, member_mse, InferBuffers, Net, TrainBuffers};
use mbpo_nn::adam::AdamPart;
use mbpo_nn::{Adam, WorkerPool};
use std::ops::Range;

/// One thread's scratch memory: a training minibatch and its activations, and the buffers of
/// a holdout forward pass.
#[derive(Debug, Clone, Default)]
struct MemberWorker {
    train: TrainBuffers,
    infer: InferBuffers,
    /// Standardised inputs of one member's minibatch (`batch x in`).
    x_chunk: Vec<f32>,
    /// Its targets (`batch x d`).
    t_chunk: Vec<f32>,
}

/// The threads of training calls and their scratch memory, created on first use.
///
/// A clone starts without a pool (a `WorkerPool` owns OS threads); it makes its own when it
/// trains.
#[derive(Default)]
pub(crate) struct MemberThreads {
    pool: Option<WorkerPool>,
    workers: Vec<MemberWorker>,
    /// Each member's `[∂/∂max_logvar | ∂/∂min_logvar]` of the current step (`members x 2d`).
    bound_slots: Vec<f32>,
}

impl Clone for MemberThreads {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl std::fmt::Debug for MemberThreads {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MemberThreads")
            .field("threads", &self.workers.len())
            .finish_non_exhaustive()
    }
}

impl MemberThreads {
    /// Make sure there are `min(threads, members)` threads with buffers for `batch` rows.
    pub(crate) fn ensure(&mut self, threads: usize, net: &Net, batch: usize) {
        let threads = threads.clamp(1, MAX_THREADS).min(net.members());
        if self.pool.as_ref().is_none_or(|p| p.threads() != threads) {
            self.pool = Some(WorkerPool::new(threads));
        }
        self.workers.resize_with(threads, MemberWorker::default);
        for w in &mut self.workers {
            w.train.ensure(net, batch);
            w.infer.ensure(net);
            w.x_chunk.resize(batch * net.in_dim(), 0.0);
            w.t_chunk.resize(batch * net.d(), 0.0);
        }
        self.bound_slots.resize(net.members() * 2 * net.d(), 0.0);
    }

    fn threads(&self) -> usize {
        self.workers.len()
    }

    /// Members per thread: thread i takes `i·block .. min((i + 1)·block, members)`.
    fn block(&self, members: usize) -> usize {
        members.div_ceil(self.threads().max(1))
    }

    /// The pool, the threads' scratch memory and the bound slots, borrowed together.
    fn parts(&mut self) -> (&mut WorkerPool, &mut [MemberWorker], &mut [f32]) {
        let pool = self
            .pool
            .as_mut()
            .expect("MemberThreads::ensure runs before any training step");
        (pool, &mut self.workers, &mut self.bound_slots)
    }
}

/// One thread's share of step 1: its members, their gradient range of θ, their bound slots and
/// losses.
struct MemberBlock<'a> {
    worker: &'a mut MemberWorker,
    members: Range<usize>,
    grads: &'a mut [f32],
    bound_slots: &'a mut [f32],
    losses: &'a mut [f64],
}

/// Steps 1 and 2: every member's loss gradient on its minibatch (row indices `rows_of(e)` of
/// the standardised training split `x_all`/`t_all`) into `grads` (θ-shaped; the MLP part
/// overwritten, the bound part set to the sum over members), and `loss·rows` added to
/// `losses[e]`.
#[allow(clippy::too_many_arguments)]
pub(crate) fn members_loss_and_grads<'r>(
    threads: &mut MemberThreads,
    net: &Net,
    theta: &[f32],
    x_all: &[f32],
    t_all: &[f32],
    rows_of: impl Fn(usize) -> &'r [u32] + Sync,
    grads: &mut [f32],
    losses: &mut [f64],
) {
    let (members, in_dim, d) = (net.members(), net.in_dim(), net.d());
    let block = threads.block(members);
    let per_member = net.ensemble().mlp().num_params();
    let (g_net, g_bounds) = grads.split_at_mut(net.num_net_params());
    let (pool, workers, bound_slots) = threads.parts();
    let mut items: [Option<MemberBlock>; MAX_THREADS] = std::array::from_fn(|_| None);
    let blocks = workers
        .iter_mut()
        .zip(g_net.chunks_mut(block * per_member))
        .zip(bound_slots.chunks_mut(block * 2 * d))
        .zip(losses.chunks_mut(block))
        .enumerate();
    let mut used = 0;
    for (slot, (i, (((worker, grads), bound_slots), losses))) in items.iter_mut().zip(blocks) {
        let start = i * block;
        *slot = Some(MemberBlock {
            worker,
            members: start..start + losses.len(),
            grads,
            bound_slots,
            losses,
        });
        used += 1;
    }
    pool.for_each_mut(&mut items[..used], |_, item| {
        let Some(b) = item.take() else { return };
        let w = b.worker;
        let grads = b.grads.chunks_mut(per_member);
        let slots = b.bound_slots.chunks_mut(2 * d);
        for (((e, g), slot), loss) in b.members.zip(grads).zip(slots).zip(b.losses.iter_mut()) {
            let idx = rows_of(e);
            let rows = idx.len();
            for (r, &i) in idx.iter().enumerate() {
                let i = i as usize;
                w.x_chunk[r * in_dim..(r + 1) * in_dim]
                    .copy_from_slice(&x_all[i * in_dim..(i + 1) * in_dim]);
                w.t_chunk[r * d..(r + 1) * d].copy_from_slice(&t_all[i * d..(i + 1) * d]);
            }
            slot.fill(0.0);
            let member_loss = member_loss_and_grad(
                net,
                theta,
                e,
                &w.x_chunk,
                &w.t_chunk,
                rows,
                &mut w.train,
                g,
                slot,
            );
            *loss += member_loss * rows as f64;
        }
    });
    sum_bound_slots(bound_slots, g_bounds);
}

/// Step 2: `g_bounds` = the members' bound gradients added in member order.
pub(crate) fn sum_bound_slots(slots: &[f32], g_bounds: &mut [f32]) {
    g_bounds.fill(0.0);
    for slot in slots.chunks_exact(g_bounds.len()) {
        g_bounds.iter_mut().zip(slot).for_each(|(g, &s)| *g += s);
    }
}

/// Step 3: one Adam step on θ, one equal range per thread (Adam's result does not depend on
/// the cut).
pub(crate) fn adam_step(
    threads: &mut MemberThreads,
    adam: &mut Adam,
    theta: &mut [f32],
    grads: &[f32],
) {
    let parts = threads.threads();
    let mut items: [Option<AdamPart>; MAX_THREADS] = std::array::from_fn(|_| None);
    for (slot, part) in items.iter_mut().zip(adam.step_parts(theta, parts)) {
        *slot = Some(part);
    }
    threads
        .parts()
        .0
        .for_each_mut(&mut items[..parts], |_, item| {
            if let Some(part) = item.take() {
                let range = part.range();
                part.apply(&grads[range]);
            }
        });
}

/// Every member's holdout MSE ([`member_mse`]) on `n` standardised rows, a block of members
/// per thread.
pub(crate) fn holdout_mse(
    threads: &mut MemberThreads,
    net: &Net,
    theta: &[f32],
    x: &[f32],
    targets: &[f32],
    n: usize,
    mse: &mut [f32],
) {
    let block = threads.block(net.members());
    let (pool, workers, _) = threads.parts();
    let mut items: [Option<(usize, &mut MemberWorker, &mut [f32])>; MAX_THREADS] =
        std::array::from_fn(|_| None);
    let mut used = 0;
    for (slot, (i, (worker, out))) in items
        .iter_mut()
        .zip(workers.iter_mut().zip(mse.chunks_mut(block)).enumerate())
    {
        *slot = Some((i * block, worker, out));
        used += 1;
    }
    pool.for_each_mut(&mut items[..used], |_, item| {
        let Some((first, worker, out)) = item.take() else {
            return;
        };
        for (k, m) in out.iter_mut().enumerate() {
            *m = member_mse(net, theta, first + k, x, targets, n, &mut worker.infer);
        }
    });
}
