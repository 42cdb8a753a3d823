//! A training call on several threads ([`crate::ModelConfig::threads`]): members, or halves
//! of their minibatches, in blocks, one block per thread.
//!
//! The members of the ensemble are independent networks except in two places: the
//! log-variance bounds, shared by all members, whose gradient is a sum over members; and Adam,
//! which is element-wise over θ. So one gradient step runs as
//!
//! 1. every thread computes the loss gradient of its block of units ([`members_loss_and_grads`]).
//!    A unit is a whole member when the threads divide the members; otherwise every member's
//!    minibatch is cut into two halves of rows ([`parts_per_member`], [`part_rows`]) and the
//!    halves are dealt out in equal blocks, so that 7 members on 2 threads are 3½ : 3½
//!    instead of 4 : 3. A member whose two halves fall in one block still runs whole, in one
//!    pass; only a member that a block boundary cuts (member 3 on 2 threads) runs as two
//!    halves on two threads. A first half (or a whole member) writes the member's range of the
//!    gradient, a second half the member's range of a second buffer; each unit's bound
//!    gradient goes into its own slot (a whole member's second slot holds zeros);
//! 2. the second half of a member cut between two blocks is added to its first once both
//!    threads are done; the caller adds the bound slots in member and part order
//!    ([`sum_bound_slots`]);
//! 3. Adam, cut into one equal range of θ per thread ([`adam_step`]).
//!
//! The holdout MSE of an epoch is per member ([`holdout_mse`]). Every floating-point sum has
//! the same operands in the same order for any number of threads that cuts the same members,
//! so a training call gives bit-identical weights for them (`tests/training.rs` checks it):
//! one thread, any thread count that divides the members, and any whose blocks hold whole
//! members (4 or 8 threads for 7 members) cut none. With 1 thread everything runs inline on
//! the caller.

use crate::config::MAX_THREADS;
use crate::grouped::InputChunk;
use crate::network::{member_loss_and_grad, member_mse, InferBuffers, Net, TrainBuffers};
use crate::normalizer::InputNormalizer;
use mbpo_nn::adam::AdamPart;
use mbpo_nn::{Adam, WorkerPool};
use std::ops::Range;

/// One thread's scratch memory: a training minibatch and its activations, and the buffers of
/// a holdout forward pass.
#[derive(Debug, Clone, Default)]
struct MemberWorker {
    train: TrainBuffers,
    infer: InferBuffers,
    /// Standardised inputs of one inference chunk (a sampled prediction's share).
    input: InputChunk,
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
    /// Parts per member's minibatch: 1 (whole members) or 2 (halves).
    parts: usize,
    /// Each part's `[∂/∂max_logvar | ∂/∂min_logvar]` of the current step (`parts·members x 2d`).
    bound_slots: Vec<f32>,
    /// The MLP gradients of the members' second halves (θ-shaped like the MLP part of θ).
    second_halves: Vec<f32>,
    /// Each part's share of its member's mean loss (`parts·members`).
    half_losses: Vec<f64>,
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
    /// Make sure there are `min(threads, parts·members)` threads with buffers for `batch` rows,
    /// where `parts` ([`parts_per_member`]) is how many parts each member's minibatch is cut into.
    pub(crate) fn ensure(&mut self, threads: usize, net: &Net, batch: usize) {
        let threads = threads.clamp(1, MAX_THREADS);
        self.parts = parts_per_member(net.members(), threads);
        let threads = threads.min(self.parts * net.members());
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
        self.bound_slots
            .resize(self.parts * net.members() * 2 * net.d(), 0.0);
        let second_halves = if self.parts == 2 {
            net.num_net_params()
        } else {
            0
        };
        self.second_halves.resize(second_halves, 0.0);
        self.half_losses.resize(self.parts * net.members(), 0.0);
    }

    /// Make sure there are the threads a training call on `threads` threads would use, each
    /// with inference buffers and an input chunk prepared for `normalizer`; returns how many.
    /// (The same count as [`MemberThreads::ensure`], so inference never rebuilds the pool.)
    pub(crate) fn ensure_inference(
        &mut self,
        threads: usize,
        net: &Net,
        normalizer: &InputNormalizer,
    ) -> usize {
        let threads = threads.clamp(1, MAX_THREADS);
        let threads = threads.min(parts_per_member(net.members(), threads) * net.members());
        if self.pool.as_ref().is_none_or(|p| p.threads() != threads) {
            self.pool = Some(WorkerPool::new(threads));
        }
        self.workers.resize_with(threads, MemberWorker::default);
        for w in &mut self.workers {
            w.infer.ensure(net);
            w.input.prepare(normalizer);
        }
        threads
    }

    fn threads(&self) -> usize {
        self.workers.len()
    }

    /// Members per thread (the holdout pass): thread i takes `i·block .. min((i + 1)·block,
    /// members)`.
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

/// How many parts each member's minibatch is cut into on `threads` threads: whole members
/// (1) when the threads divide the members, as one thread always does; halves (2) otherwise,
/// so that no thread idles for a member's work (7 members on 2 threads: 14 halves, 7 each,
/// instead of members 4 : 3). A member whose halves land on one thread runs whole all the
/// same: a 128-row GEMM runs about 3 % below a 256-row one and the halves' sum is one more
/// pass (one thread is about 6 % slower on halves, `mbpo bench model-train`;
/// results/measurements.md, "Halves of minibatches on two threads", 2026-11-26, commit 9101bce).
fn parts_per_member(members: usize, threads: usize) -> usize {
    if members.is_multiple_of(threads) {
        1
    } else {
        2
    }
}

/// Rows of part `h` of a minibatch of `rows` cut into `parts`: the first part takes the odd
/// row.
pub(crate) fn part_rows(rows: usize, h: usize, parts: usize) -> Range<usize> {
    let cut = |h: usize| (h * rows).div_ceil(parts);
    cut(h)..cut(h + 1)
}

/// The members whose part `h` is among `units` (unit u is member u / parts, part u % parts).
fn members_with_part(units: &Range<usize>, h: usize, parts: usize) -> Range<usize> {
    if h >= parts {
        return 0..0;
    }
    let first = |u: usize| (u + parts - 1 - h) / parts;
    first(units.start)..first(units.end)
}

/// One thread's share of step 1: its units, the gradient buffers they write, their bound
/// slots and losses.
struct UnitBlock<'a> {
    worker: &'a mut MemberWorker,
    units: Range<usize>,
    /// MLP gradients of the members in `members_with_part(units, 0, parts)`.
    first_halves: &'a mut [f32],
    /// Second-half gradients of the members in `members_with_part(units, 1, parts)`.
    second_halves: &'a mut [f32],
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
    let (members, d) = (net.members(), net.d());
    let parts = threads.parts;
    let units = parts * members;
    let block = units.div_ceil(threads.threads().max(1));
    let per_member = net.ensemble().mlp().num_params();
    let (g_net, g_bounds) = grads.split_at_mut(net.num_net_params());
    let MemberThreads {
        pool,
        workers,
        parts: _,
        bound_slots,
        second_halves,
        half_losses,
    } = threads;
    let pool = pool
        .as_mut()
        .expect("MemberThreads::ensure runs before any training step");
    let mut items: [Option<UnitBlock>; MAX_THREADS] = std::array::from_fn(|_| None);
    let (mut firsts, mut seconds) = (&mut g_net[..], &mut second_halves[..]);
    let mut slots = bound_slots.chunks_mut(block * 2 * d);
    let mut unit_losses = half_losses.chunks_mut(block);
    let mut used = 0;
    for (i, (slot, worker)) in items.iter_mut().zip(workers.iter_mut()).enumerate() {
        let units = i * block..((i + 1) * block).min(units);
        if units.is_empty() {
            break;
        }
        let first_len = members_with_part(&units, 0, parts).len() * per_member;
        let second_len = members_with_part(&units, 1, parts).len() * per_member;
        let (first_halves, rest) = std::mem::take(&mut firsts).split_at_mut(first_len);
        firsts = rest;
        let (second, rest) = std::mem::take(&mut seconds).split_at_mut(second_len);
        seconds = rest;
        *slot = Some(UnitBlock {
            worker,
            units,
            first_halves,
            second_halves: second,
            bound_slots: slots.next().expect("a slot block per thread"),
            losses: unit_losses.next().expect("a loss block per thread"),
        });
        used += 1;
    }
    let data = StepData::new(net, theta, (x_all, t_all), &rows_of, parts);
    pool.for_each_mut(&mut items[..used], |_, item| {
        if let Some(b) = item.take() {
            data.run_units(b);
        }
    });
    sum_bound_slots(bound_slots, g_bounds);
    // The members cut between two blocks (a block boundary at an odd unit).
    for t in 1..used {
        let boundary = t * block;
        if boundary % parts == 1 {
            let member = (boundary / parts) * per_member..(boundary / parts + 1) * per_member;
            add_second_halves(pool, &mut g_net[member.clone()], &second_halves[member]);
        }
    }
    for (e, loss) in losses.iter_mut().enumerate() {
        *loss +=
            half_losses[parts * e..parts * (e + 1)].iter().sum::<f64>() * rows_of(e).len() as f64;
    }
}

/// What every thread of step 1 reads.
struct StepData<'a, 'r> {
    net: &'a Net,
    theta: &'a [f32],
    /// The standardised training split.
    x_all: &'a [f32],
    t_all: &'a [f32],
    /// Member e's minibatch: row indices into the split.
    rows_of: &'a (dyn Fn(usize) -> &'r [u32] + Sync),
    parts: usize,
    per_member: usize,
}

impl<'a, 'r> StepData<'a, 'r> {
    fn new(
        net: &'a Net,
        theta: &'a [f32],
        (x_all, t_all): (&'a [f32], &'a [f32]),
        rows_of: &'a (dyn Fn(usize) -> &'r [u32] + Sync),
        parts: usize,
    ) -> Self {
        let per_member = net.ensemble().mlp().num_params();
        Self {
            net,
            theta,
            x_all,
            t_all,
            rows_of,
            parts,
            per_member,
        }
    }

    /// One thread's units: each (member, half) gathers its rows and runs its loss and gradient.
    fn run_units(&self, b: UnitBlock<'_>) {
        let (parts, per_member) = (self.parts, self.per_member);
        let (in_dim, d) = (self.net.in_dim(), self.net.d());
        let w = b.worker;
        let first_members = members_with_part(&b.units, 0, parts);
        let second_members = members_with_part(&b.units, 1, parts);
        let slots = b.bound_slots.chunks_mut(2 * d);
        let units = b.units.clone();
        for ((u, slot), loss) in b.units.zip(slots).zip(b.losses.iter_mut()) {
            let (e, h) = (u / parts, u % parts);
            // Both halves of member e in this block: the first unit runs the whole member in
            // one pass (wider products, no sum), the second contributes zeros.
            let whole =
                parts == 2 && units.contains(&(e * parts)) && units.contains(&(e * parts + 1));
            if whole && h == 1 {
                slot.fill(0.0);
                *loss = 0.0;
                continue;
            }
            let g = if h == 0 {
                let k = e - first_members.start;
                &mut b.first_halves[k * per_member..(k + 1) * per_member]
            } else {
                let k = e - second_members.start;
                &mut b.second_halves[k * per_member..(k + 1) * per_member]
            };
            let member_rows = (self.rows_of)(e);
            let idx = if whole {
                member_rows
            } else {
                &member_rows[part_rows(member_rows.len(), h, parts)]
            };
            for (r, &i) in idx.iter().enumerate() {
                let i = i as usize;
                w.x_chunk[r * in_dim..(r + 1) * in_dim]
                    .copy_from_slice(&self.x_all[i * in_dim..(i + 1) * in_dim]);
                w.t_chunk[r * d..(r + 1) * d].copy_from_slice(&self.t_all[i * d..(i + 1) * d]);
            }
            *loss = half_loss_and_grad(
                self.net,
                self.theta,
                e,
                (&w.x_chunk, &w.t_chunk, idx.len()),
                member_rows.len(),
                &mut w.train,
                g,
                slot,
            );
        }
    }
}

/// One half of member e's minibatch (`x`, `targets` with `rows` rows) whose loss is a mean over
/// `mean_over` rows: its MLP gradient into `g` (overwritten), its bound gradient into `slot`
/// (overwritten); returns its share of the member's loss. An empty half (a minibatch of one
/// row) contributes zeros.
#[allow(clippy::too_many_arguments)]
fn half_loss_and_grad(
    net: &Net,
    theta: &[f32],
    e: usize,
    (x, targets, rows): (&[f32], &[f32], usize),
    mean_over: usize,
    buf: &mut TrainBuffers,
    g: &mut [f32],
    slot: &mut [f32],
) -> f64 {
    slot.fill(0.0);
    if rows == 0 {
        g.fill(0.0);
        return 0.0;
    }
    member_loss_and_grad(net, theta, e, x, targets, rows, mean_over, buf, g, slot)
}

/// `first += second` element-wise: a member's second-half gradient added to its first half's.
/// The one rule for the sum, wherever it runs (the f32 adds are the same on any thread).
fn add_into(first: &mut [f32], second: &[f32]) {
    first.iter_mut().zip(second).for_each(|(f, &s)| *f += s);
}

/// Step 2b for a member whose halves ran on two threads: [`add_into`], one equal range per
/// thread.
fn add_second_halves(pool: &mut WorkerPool, first: &mut [f32], second: &[f32]) {
    let parts = pool.threads();
    let len = first.len().div_ceil(parts);
    let mut items: [Option<(&mut [f32], &[f32])>; MAX_THREADS] = std::array::from_fn(|_| None);
    let mut used = 0;
    for (slot, pair) in items
        .iter_mut()
        .zip(first.chunks_mut(len).zip(second.chunks(len)))
    {
        *slot = Some(pair);
        used += 1;
    }
    pool.for_each_mut(&mut items[..used], |_, item| {
        if let Some((f, s)) = item.take() {
            add_into(f, s);
        }
    });
}

/// Step 2: `g_bounds` = the halves' bound gradients added in member and half order.
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

/// `f(item, infer, input)` for each of `items` at once, item i on thread i with that thread's
/// inference buffers and input chunk (after [`MemberThreads::ensure_inference`]; at most that
/// many items).
pub(crate) fn for_each_with_inference<T: Send>(
    threads: &mut MemberThreads,
    items: &mut [T],
    f: impl Fn(&mut T, &mut InferBuffers, &mut InputChunk) + Sync,
) {
    let (pool, workers, _) = threads.parts();
    let used = items.len();
    assert!(used <= workers.len(), "more items than threads");
    let mut pairs: [Option<(&mut T, &mut MemberWorker)>; MAX_THREADS] =
        std::array::from_fn(|_| None);
    for (slot, pair) in pairs
        .iter_mut()
        .zip(items.iter_mut().zip(workers.iter_mut()))
    {
        *slot = Some(pair);
    }
    pool.for_each_mut(&mut pairs[..used], |_, pair| {
        if let Some((item, worker)) = pair.take() {
            f(item, &mut worker.infer, &mut worker.input);
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parts_cover_every_row_once_and_the_first_takes_the_odd_row() {
        assert_eq!(
            (part_rows(256, 0, 2), part_rows(256, 1, 2)),
            (0..128, 128..256)
        );
        assert_eq!((part_rows(7, 0, 2), part_rows(7, 1, 2)), (0..4, 4..7));
        assert_eq!((part_rows(1, 0, 2), part_rows(1, 1, 2)), (0..1, 1..1));
        assert_eq!((part_rows(0, 0, 2), part_rows(0, 1, 2)), (0..0, 0..0));
        assert_eq!(part_rows(7, 0, 1), 0..7);
        assert_eq!(
            members_with_part(&(0..7), 1, 1),
            0..0,
            "whole members have no second half"
        );
    }

    #[test]
    fn members_are_halved_only_when_the_threads_do_not_divide_them() {
        assert_eq!(parts_per_member(7, 1), 1);
        assert_eq!(parts_per_member(7, 7), 1);
        assert_eq!(parts_per_member(8, 4), 1);
        assert_eq!(parts_per_member(7, 2), 2);
        assert_eq!(parts_per_member(7, 4), 2);
        assert_eq!(parts_per_member(7, 8), 2);
    }

    /// The blocks of `members_loss_and_grads` hand every member's every part to exactly one
    /// thread, in member order, for any member and thread count.
    #[test]
    fn blocks_give_each_part_of_each_member_to_one_thread() {
        for members in 1..=9 {
            for threads in 1..=16 {
                let parts = parts_per_member(members, threads);
                let units = parts * members;
                let threads = threads.min(units);
                let block = units.div_ceil(threads);
                for h in 0..parts {
                    let mut next = 0;
                    for t in 0..threads {
                        let mine = t * block..((t + 1) * block).min(units);
                        if mine.is_empty() {
                            break;
                        }
                        let owned = members_with_part(&mine, h, parts);
                        assert_eq!(owned.start, next, "{members} members, {threads} threads");
                        for e in owned.clone() {
                            assert!(mine.contains(&(parts * e + h)));
                        }
                        next = owned.end.max(next);
                    }
                    assert_eq!(
                        next, members,
                        "{members} members, {threads} threads, part {h}"
                    );
                }
            }
        }
    }
}
