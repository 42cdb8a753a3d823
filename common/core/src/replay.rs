//! Fixed-capacity FIFO transition storage with uniform sampling.
//!
//! Used for the real data D_env and for MBPO's model buffer D_model. Storage is column-wise
//! (`obs` rows contiguous, `act` rows contiguous, ...), so a sampled batch lands directly in the
//! row-major matrices the networks consume. When full, the oldest transition is overwritten.
//! Sampling is uniform with replacement and allocates nothing: it writes into a caller-owned
//! [`Batch`].

use crate::rng::{index, Rng};
use serde::{Deserialize, Serialize};

/// A batch of transitions, row-major per field (`obs` is `len x obs_dim`, ...).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Batch {
    /// Observation width.
    pub obs_dim: usize,
    /// Action width.
    pub act_dim: usize,
    /// Number of rows.
    pub len: usize,
    /// Observations s.
    pub obs: Vec<f32>,
    /// Actions a.
    pub act: Vec<f32>,
    /// Rewards r.
    pub reward: Vec<f32>,
    /// Next observations s'.
    pub next_obs: Vec<f32>,
    /// 1.0 where s' is terminal (never for time-limit truncation), else 0.0.
    pub terminated: Vec<f32>,
}

impl Batch {
    /// A zeroed batch of `len` rows.
    pub fn new(obs_dim: usize, act_dim: usize, len: usize) -> Self {
        Self {
            obs_dim,
            act_dim,
            len,
            obs: vec![0.0; len * obs_dim],
            act: vec![0.0; len * act_dim],
            reward: vec![0.0; len],
            next_obs: vec![0.0; len * obs_dim],
            terminated: vec![0.0; len],
        }
    }

    /// A 64-bit digest of every value's bits, in row order: whether two batches hold the
    /// same bits (a checkpoint's D_model computed again, `mbpo_train::d_model_branches`).
    /// Not cryptographic.
    pub fn digest(&self) -> u64 {
        const K: u64 = 0x9e37_79b9_7f4a_7c15;
        let fields = [
            &self.obs[..],
            &self.act,
            &self.reward,
            &self.next_obs,
            &self.terminated,
        ];
        let mut h = (self.len as u64).wrapping_mul(K);
        for field in fields {
            for &v in field {
                h = (h.rotate_left(23) ^ v.to_bits() as u64).wrapping_mul(K);
            }
        }
        h
    }

    /// Copy row `src` of `from` into row `dst` of `self`.
    #[inline]
    fn copy_row(&mut self, dst: usize, from: &ReplayBuffer, src: usize) {
        let (o, a) = (self.obs_dim, self.act_dim);
        self.obs[dst * o..(dst + 1) * o].copy_from_slice(&from.obs[src * o..(src + 1) * o]);
        self.act[dst * a..(dst + 1) * a].copy_from_slice(&from.act[src * a..(src + 1) * a]);
        self.reward[dst] = from.reward[src];
        self.next_obs[dst * o..(dst + 1) * o]
            .copy_from_slice(&from.next_obs[src * o..(src + 1) * o]);
        self.terminated[dst] = from.terminated[src];
    }
}

/// Where an env step's transition goes: appended to a replay buffer, or held as the last
/// transition of an actor that sends it on ([`LastTransition`]).
pub trait TransitionSink {
    /// Take one transition `(s, a, r, s', terminated)`.
    fn push(&mut self, obs: &[f32], act: &[f32], reward: f32, next_obs: &[f32], terminated: bool);
}

impl TransitionSink for ReplayBuffer {
    fn push(&mut self, obs: &[f32], act: &[f32], reward: f32, next_obs: &[f32], terminated: bool) {
        ReplayBuffer::push(self, obs, act, reward, next_obs, terminated)
    }
}

/// The transition of an actor's last env step as a one-row [`Batch`], overwritten by each
/// step: what a pipeline actor publishes, without a ring buffer or an allocation per step.
#[derive(Debug, Clone, PartialEq)]
pub struct LastTransition {
    row: Batch,
}

impl LastTransition {
    /// Room for one transition of these widths.
    pub fn new(obs_dim: usize, act_dim: usize) -> Self {
        Self {
            row: Batch::new(obs_dim, act_dim, 1),
        }
    }
    /// The last transition (one row; zeros before the first step).
    pub fn batch(&self) -> &Batch {
        &self.row
    }
}

impl TransitionSink for LastTransition {
    fn push(&mut self, obs: &[f32], act: &[f32], reward: f32, next_obs: &[f32], terminated: bool) {
        let b = &mut self.row;
        let (o, a) = (b.obs_dim, b.act_dim);
        b.obs.copy_from_slice(&obs[..o]);
        b.act.copy_from_slice(&act[..a]);
        b.reward[0] = reward;
        b.next_obs.copy_from_slice(&next_obs[..o]);
        b.terminated[0] = if terminated { 1.0 } else { 0.0 };
    }
}

/// A ring buffer of transitions.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayBuffer {
    obs_dim: usize,
    act_dim: usize,
    capacity: usize,
    len: usize,
    /// Slot the next push writes.
    head: usize,
    /// Transitions ever pushed.
    pushed: u64,
    obs: Vec<f32>,
    act: Vec<f32>,
    reward: Vec<f32>,
    next_obs: Vec<f32>,
    terminated: Vec<f32>,
}

impl ReplayBuffer {
    /// An empty buffer holding at most `capacity` transitions (memory is reserved up front).
    pub fn new(obs_dim: usize, act_dim: usize, capacity: usize) -> Self {
        assert!(capacity > 0, "replay capacity must be positive");
        Self {
            obs_dim,
            act_dim,
            capacity,
            len: 0,
            head: 0,
            pushed: 0,
            obs: vec![0.0; capacity * obs_dim],
            act: vec![0.0; capacity * act_dim],
            reward: vec![0.0; capacity],
            next_obs: vec![0.0; capacity * obs_dim],
            terminated: vec![0.0; capacity],
        }
    }

    /// Observation width.
    pub fn obs_dim(&self) -> usize {
        self.obs_dim
    }
    /// Action width.
    pub fn act_dim(&self) -> usize {
        self.act_dim
    }
    /// Transitions currently held.
    pub fn len(&self) -> usize {
        self.len
    }
    /// True when nothing is held.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }
    /// Maximum transitions held.
    pub fn capacity(&self) -> usize {
        self.capacity
    }
    /// Transitions ever pushed (including overwritten ones).
    pub fn pushed(&self) -> u64 {
        self.pushed
    }

    /// Append one transition, overwriting the oldest when full.
    pub fn push(
        &mut self,
        obs: &[f32],
        act: &[f32],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
    ) {
        let (o, a, i) = (self.obs_dim, self.act_dim, self.head);
        self.obs[i * o..(i + 1) * o].copy_from_slice(&obs[..o]);
        self.act[i * a..(i + 1) * a].copy_from_slice(&act[..a]);
        self.reward[i] = reward;
        self.next_obs[i * o..(i + 1) * o].copy_from_slice(&next_obs[..o]);
        self.terminated[i] = if terminated { 1.0 } else { 0.0 };
        self.head = (self.head + 1) % self.capacity;
        self.len = (self.len + 1).min(self.capacity);
        self.pushed += 1;
    }

    /// Append the first `batch.len` rows of `batch`, in order.
    pub fn push_batch(&mut self, batch: &Batch) {
        let (o, a) = (self.obs_dim, self.act_dim);
        for r in 0..batch.len {
            self.push(
                &batch.obs[r * o..(r + 1) * o],
                &batch.act[r * a..(r + 1) * a],
                batch.reward[r],
                &batch.next_obs[r * o..(r + 1) * o],
                batch.terminated[r] != 0.0,
            );
        }
    }

    /// Slot of the `i`-th oldest transition held.
    #[inline]
    fn slot(&self, i: usize) -> usize {
        (self.head + self.capacity - self.len + i) % self.capacity
    }

    /// Fill `out` with `out.len` transitions drawn uniformly with replacement.
    pub fn sample_into(&self, rng: &mut Rng, out: &mut Batch) {
        self.sample_rows(rng, out, 0, out.len);
    }

    /// Fill rows `start..start + n` of `out` with uniform draws.
    pub fn sample_rows(&self, rng: &mut Rng, out: &mut Batch, start: usize, n: usize) {
        assert!(
            !self.is_empty(),
            "cannot sample from an empty replay buffer"
        );
        assert_eq!((out.obs_dim, out.act_dim), (self.obs_dim, self.act_dim));
        for r in start..start + n {
            // Slots 0..len are exactly the held transitions whether or not the ring wrapped.
            let src = index(rng, self.len);
            out.copy_row(r, self, src);
        }
    }

    /// Every state and then every next state held, one slice each, in slot order (not age
    /// order: for [`crate::StateBox`], which only needs each of them once).
    pub fn held_states(&self) -> impl Iterator<Item = &[f32]> {
        let held = self.len * self.obs_dim;
        // Slots 0..len are exactly the held transitions whether or not the ring wrapped.
        self.obs[..held]
            .chunks_exact(self.obs_dim)
            .chain(self.next_obs[..held].chunks_exact(self.obs_dim))
    }

    /// All held transitions, oldest first, as one batch (allocates; for model training).
    pub fn to_batch(&self) -> Batch {
        let mut b = Batch::new(self.obs_dim, self.act_dim, self.len);
        for i in 0..self.len {
            b.copy_row(i, self, self.slot(i));
        }
        b
    }

    /// Change the capacity, keeping the newest `min(len, capacity)` transitions in order
    /// (MBPO reallocates its model buffer when the rollout length changes).
    pub fn set_capacity(&mut self, capacity: usize) {
        if capacity == self.capacity {
            return;
        }
        let kept = self.len.min(capacity);
        let old = self.to_batch();
        let pushed = self.pushed;
        *self = Self::new(self.obs_dim, self.act_dim, capacity);
        let (o, a) = (self.obs_dim, self.act_dim);
        for r in old.len - kept..old.len {
            self.push(
                &old.obs[r * o..(r + 1) * o],
                &old.act[r * a..(r + 1) * a],
                old.reward[r],
                &old.next_obs[r * o..(r + 1) * o],
                old.terminated[r] != 0.0,
            );
        }
        self.pushed = pushed;
    }
}

impl ReplayBuffer {
    /// The buffer as it was after its first `n` pushes, when none of them has been overwritten
    /// since (it never wrapped): the same capacity, the same slots, so it samples what it
    /// sampled then. D_env only grows in MBPO's runs (1M rows of capacity), so a rollout branch
    /// done at any earlier step can be done again from it.
    pub fn prefix(&self, n: u64) -> Result<Self, SnapshotMismatch> {
        if self.pushed > self.capacity as u64 || n > self.pushed {
            return Err(SnapshotMismatch(format!(
                "no prefix of {n} rows in a buffer that holds {} of {} pushed (capacity {})",
                self.len, self.pushed, self.capacity
            )));
        }
        let n = n as usize;
        let mut buf = Self::new(self.obs_dim, self.act_dim, self.capacity);
        let (o, a) = (self.obs_dim, self.act_dim);
        buf.obs[..n * o].copy_from_slice(&self.obs[..n * o]);
        buf.act[..n * a].copy_from_slice(&self.act[..n * a]);
        buf.reward[..n].copy_from_slice(&self.reward[..n]);
        buf.next_obs[..n * o].copy_from_slice(&self.next_obs[..n * o]);
        buf.terminated[..n].copy_from_slice(&self.terminated[..n]);
        buf.len = n;
        buf.head = n % self.capacity;
        buf.pushed = n as u64;
        Ok(buf)
    }

    /// The buffer whose positions are `layout`'s (capacity, head, pushed; its slots are not
    /// read) holding `rows`, oldest first: the inverse of [`ReplayBuffer::to_batch`] for a
    /// buffer whose rows a checkpoint did not store.
    pub fn from_age_order(layout: &ReplaySnapshot, rows: &Batch) -> Result<Self, SnapshotMismatch> {
        let mut fill = Self::fill_from_newest(layout, rows.obs_dim, rows.act_dim, rows.len)?;
        fill.prepend(rows);
        fill.finish()
    }

    /// A buffer with `layout`'s positions that will hold `len` rows, to be filled newest
    /// first ([`FillFromNewest::prepend`]): rows that come in pieces (D_model's branches) go
    /// straight to their slots, and pieces older than the `len` newest rows are never needed.
    pub fn fill_from_newest(
        layout: &ReplaySnapshot,
        obs_dim: usize,
        act_dim: usize,
        len: usize,
    ) -> Result<FillFromNewest, SnapshotMismatch> {
        let (capacity, head) = (layout.capacity, layout.head);
        let dims = (layout.slots.obs_dim, layout.slots.act_dim);
        if (obs_dim, act_dim) != dims {
            return Err(SnapshotMismatch(format!(
                "rows have obs/act dims {obs_dim}/{act_dim}, the buffer {}/{}",
                dims.0, dims.1
            )));
        }
        if !layout_is_consistent(capacity, head, len, layout.pushed) {
            return Err(inconsistent(len, capacity, head, layout.pushed));
        }
        let mut buf = Self::new(obs_dim, act_dim, capacity);
        buf.len = len;
        buf.head = head;
        buf.pushed = layout.pushed;
        Ok(FillFromNewest { buf, missing: len })
    }

    /// Write row `src` of `from` into slot `dst`.
    fn set_row(&mut self, dst: usize, from: &Batch, src: usize) {
        let (o, a) = (self.obs_dim, self.act_dim);
        self.obs[dst * o..(dst + 1) * o].copy_from_slice(&from.obs[src * o..(src + 1) * o]);
        self.act[dst * a..(dst + 1) * a].copy_from_slice(&from.act[src * a..(src + 1) * a]);
        self.reward[dst] = from.reward[src];
        self.next_obs[dst * o..(dst + 1) * o]
            .copy_from_slice(&from.next_obs[src * o..(src + 1) * o]);
        self.terminated[dst] = from.terminated[src];
    }
}

/// A [`ReplayBuffer`] being filled from its newest row back ([`ReplayBuffer::fill_from_newest`]).
pub struct FillFromNewest {
    buf: ReplayBuffer,
    /// Rows not yet filled: ages `0..missing`.
    missing: usize,
}

impl FillFromNewest {
    /// Put the rows of `rows` in, older than every row put in so far: its last row goes to the
    /// newest free age. Rows beyond what the buffer holds are left out. Returns the rows still
    /// missing.
    pub fn prepend(&mut self, rows: &Batch) -> usize {
        let n = rows.len.min(self.missing);
        for j in 0..n {
            let slot = self.buf.slot(self.missing - 1 - j);
            self.buf.set_row(slot, rows, rows.len - 1 - j);
        }
        self.missing -= n;
        self.missing
    }

    /// The buffer, once every row is in.
    pub fn finish(self) -> Result<ReplayBuffer, SnapshotMismatch> {
        match self.missing {
            0 => Ok(self.buf),
            missing => Err(SnapshotMismatch(format!(
                "{missing} of the buffer's {} rows are missing",
                self.buf.len
            ))),
        }
    }
}

/// Whether a ring of `capacity` slots can hold `len` rows with its next write at `head` after
/// `pushed` pushes: rows fill slots from 0 until the ring is full.
fn layout_is_consistent(capacity: usize, head: usize, len: usize, pushed: u64) -> bool {
    capacity > 0
        && len <= capacity
        && head < capacity
        && (len == capacity || head == len)
        && pushed >= len as u64
}

fn inconsistent(len: usize, capacity: usize, head: usize, pushed: u64) -> SnapshotMismatch {
    SnapshotMismatch(format!(
        "replay snapshot is inconsistent: {len} rows, capacity {capacity}, head {head}, pushed {pushed}"
    ))
}

/// A [`ReplayBuffer`] as a checkpoint stores it: the held slots in slot order (not age order)
/// and the write position, because sampling draws slot indices -- a buffer rebuilt from this
/// samples exactly the rows the original would have.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplaySnapshot {
    /// Maximum transitions held.
    pub capacity: usize,
    /// Slot the next push writes.
    pub head: usize,
    /// Transitions ever pushed.
    pub pushed: u64,
    /// Slots `0..len`, in slot order.
    pub slots: Batch,
}

/// Why a [`ReplaySnapshot`] cannot be restored.
#[derive(Debug, Clone, PartialEq)]
pub struct SnapshotMismatch(pub String);

impl std::fmt::Display for SnapshotMismatch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for SnapshotMismatch {}

impl ReplayBuffer {
    /// The buffer's contents and positions (allocates; for checkpoints).
    pub fn snapshot(&self) -> ReplaySnapshot {
        let mut slots = Batch::new(self.obs_dim, self.act_dim, self.len);
        for i in 0..self.len {
            slots.copy_row(i, self, i);
        }
        ReplaySnapshot {
            capacity: self.capacity,
            head: self.head,
            pushed: self.pushed,
            slots,
        }
    }

    /// [`ReplayBuffer::snapshot`] without the rows: the capacity, write position and push
    /// count, for a checkpoint that stores the rows in another form
    /// ([`ReplayBuffer::from_age_order`] puts them back).
    pub fn positions(&self) -> ReplaySnapshot {
        ReplaySnapshot {
            capacity: self.capacity,
            head: self.head,
            pushed: self.pushed,
            slots: Batch::new(self.obs_dim, self.act_dim, 0),
        }
    }

    /// Rebuild a buffer from [`ReplayBuffer::snapshot`]; `obs_dim`/`act_dim` are what the
    /// caller expects (a mismatch or an inconsistent snapshot is an error, not a panic).
    pub fn from_snapshot(
        s: &ReplaySnapshot,
        obs_dim: usize,
        act_dim: usize,
    ) -> Result<Self, SnapshotMismatch> {
        let b = &s.slots;
        let consistent = layout_is_consistent(s.capacity, s.head, b.len, s.pushed)
            && b.obs.len() == b.len * b.obs_dim
            && b.next_obs.len() == b.len * b.obs_dim
            && b.act.len() == b.len * b.act_dim
            && b.reward.len() == b.len
            && b.terminated.len() == b.len;
        if (b.obs_dim, b.act_dim) != (obs_dim, act_dim) {
            return Err(SnapshotMismatch(format!(
                "replay snapshot has obs/act dims {}/{}, expected {obs_dim}/{act_dim}",
                b.obs_dim, b.act_dim
            )));
        }
        if !consistent {
            return Err(inconsistent(b.len, s.capacity, s.head, s.pushed));
        }
        let mut buf = Self::new(obs_dim, act_dim, s.capacity);
        let (o, a) = (obs_dim, act_dim);
        buf.obs[..b.len * o].copy_from_slice(&b.obs);
        buf.act[..b.len * a].copy_from_slice(&b.act);
        buf.reward[..b.len].copy_from_slice(&b.reward);
        buf.next_obs[..b.len * o].copy_from_slice(&b.next_obs);
        buf.terminated[..b.len].copy_from_slice(&b.terminated);
        buf.len = b.len;
        buf.head = s.head;
        buf.pushed = s.pushed;
        Ok(buf)
    }
}

/// Fill `out` with `n_real = floor(out.len · real_ratio)` rows from `real` followed by the rest
/// from `model` (MBPO's `_training_batch`: 12 real + 244 model rows at 256 x 0.05). Falls back to
/// all-real while the model buffer is empty.
pub fn sample_mixed(
    real: &ReplayBuffer,
    model: &ReplayBuffer,
    real_ratio: f64,
    rng: &mut Rng,
    out: &mut Batch,
) {
    let n = out.len;
    let n_real = if model.is_empty() {
        n
    } else {
        ((n as f64) * real_ratio) as usize
    };
    if n_real > 0 {
        real.sample_rows(rng, out, 0, n_real);
    }
    if n_real < n {
        model.sample_rows(rng, out, n_real, n - n_real);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stream;

    fn push_n(buf: &mut ReplayBuffer, from: usize, n: usize) {
        for i in from..from + n {
            let v = i as f32;
            buf.push(&[v, -v], &[v * 0.5], v, &[v + 1.0, 0.0], i % 2 == 0);
        }
    }

    #[test]
    fn snapshot_restores_slots_so_sampling_continues_identically() {
        for pushes in [3, 4, 11] {
            let mut original = ReplayBuffer::new(2, 1, 4);
            push_n(&mut original, 0, pushes);
            let mut restored = ReplayBuffer::from_snapshot(&original.snapshot(), 2, 1).unwrap();
            assert_eq!(restored, original);
            push_n(&mut original, 100, 2);
            push_n(&mut restored, 100, 2);
            let (mut a, mut b) = (Batch::new(2, 1, 16), Batch::new(2, 1, 16));
            original.sample_into(&mut stream(3, "t", 0), &mut a);
            restored.sample_into(&mut stream(3, "t", 0), &mut b);
            assert_eq!(a, b);
        }
    }

    #[test]
    fn age_order_and_positions_rebuild_the_buffer() {
        // Not full, full with the oldest at slot 0, and wrapped (the oldest mid-ring).
        for pushes in [3, 4, 11] {
            let mut original = ReplayBuffer::new(2, 1, 4);
            push_n(&mut original, 0, pushes);
            let rebuilt =
                ReplayBuffer::from_age_order(&original.positions(), &original.to_batch()).unwrap();
            assert_eq!(rebuilt, original, "{pushes} pushes");
        }
        let mut buf = ReplayBuffer::new(2, 1, 4);
        push_n(&mut buf, 0, 3);
        let mut layout = buf.positions();
        layout.head = 1;
        let err = ReplayBuffer::from_age_order(&layout, &buf.to_batch()).unwrap_err();
        assert!(err.0.contains("inconsistent"), "{err}");
    }

    #[test]
    fn filled_from_newest_in_pieces_is_the_buffer() {
        let mut original = ReplayBuffer::new(2, 1, 4);
        push_n(&mut original, 0, 3);
        let mut older = ReplayBuffer::new(2, 1, 8);
        push_n(&mut older, 0, 3); // rows 0-2: only row 2 is still held
        push_n(&mut original, 3, 3);
        let mut newer = ReplayBuffer::new(2, 1, 8);
        push_n(&mut newer, 3, 3);
        let layout = original.positions();
        let mut fill = ReplayBuffer::fill_from_newest(&layout, 2, 1, 4).unwrap();
        assert_eq!(fill.prepend(&newer.to_batch()), 1);
        let mut short = ReplayBuffer::fill_from_newest(&layout, 2, 1, 4).unwrap();
        short.prepend(&newer.to_batch());
        assert!(short
            .finish()
            .unwrap_err()
            .0
            .contains("1 of the buffer's 4 rows are missing"));
        assert_eq!(fill.prepend(&older.to_batch()), 0);
        assert_eq!(fill.finish().unwrap(), original);
    }

    #[test]
    fn a_prefix_is_the_buffer_as_it_was_until_it_wraps() {
        let mut then = ReplayBuffer::new(2, 1, 8);
        push_n(&mut then, 0, 5);
        let mut now = then.clone();
        push_n(&mut now, 5, 3);
        assert_eq!(now.prefix(5).unwrap(), then);
        assert_eq!(now.prefix(8).unwrap(), now);
        assert!(now.prefix(9).is_err());
        push_n(&mut now, 8, 1); // the first row is overwritten: no prefix is what it was
        let err = now.prefix(5).unwrap_err();
        assert!(err.0.contains("no prefix"), "{err}");
    }

    #[test]
    fn the_digest_sees_every_value() {
        let mut buf = ReplayBuffer::new(2, 1, 8);
        push_n(&mut buf, 0, 5);
        let b = buf.to_batch();
        let changed = |f: &dyn Fn(&mut Batch)| {
            let mut c = b.clone();
            f(&mut c);
            c.digest()
        };
        assert_eq!(b.clone().digest(), b.digest());
        for (name, d) in [
            (
                "obs",
                changed(&|c| c.obs[3] = f32::from_bits(c.obs[3].to_bits() ^ 1)),
            ),
            ("act", changed(&|c| c.act[0] += 1.0)),
            ("reward", changed(&|c| c.reward[4] = -0.0)),
            ("next_obs", changed(&|c| c.next_obs[9] += 1.0)),
            (
                "terminated",
                changed(&|c| c.terminated[1] = 1.0 - c.terminated[1]),
            ),
        ] {
            assert_ne!(d, b.digest(), "{name}");
        }
    }

    #[test]
    fn bad_snapshots_are_errors() {
        let mut buf = ReplayBuffer::new(2, 1, 4);
        push_n(&mut buf, 0, 3);
        let snap = buf.snapshot();
        let err = ReplayBuffer::from_snapshot(&snap, 3, 1).unwrap_err();
        assert!(err.0.contains("expected 3/1"), "{err}");
        let mut bad = snap.clone();
        bad.head = 1;
        assert!(ReplayBuffer::from_snapshot(&bad, 2, 1).is_err());
        let mut bad = snap;
        bad.slots.reward.pop();
        assert!(ReplayBuffer::from_snapshot(&bad, 2, 1).is_err());
    }

    #[test]
    fn ring_overwrites_oldest_and_keeps_order() {
        let mut b = ReplayBuffer::new(2, 1, 4);
        push_n(&mut b, 0, 6);
        assert_eq!((b.len(), b.pushed()), (4, 6));
        let all = b.to_batch();
        assert_eq!(all.reward, vec![2.0, 3.0, 4.0, 5.0]);
        assert_eq!(all.obs, vec![2.0, -2.0, 3.0, -3.0, 4.0, -4.0, 5.0, -5.0]);
        assert_eq!(all.terminated, vec![1.0, 0.0, 1.0, 0.0]);
    }

    #[test]
    fn samples_are_rows_that_exist_and_cover_the_buffer() {
        let mut b = ReplayBuffer::new(2, 1, 8);
        push_n(&mut b, 0, 11);
        let mut out = Batch::new(2, 1, 400);
        b.sample_into(&mut stream(1, "t", 0), &mut out);
        let mut seen = [false; 11];
        for r in 0..out.len {
            let v = out.reward[r];
            assert!((3.0..=10.0).contains(&v), "sampled an overwritten row {v}");
            // Fields of one row stay together.
            assert_eq!(out.obs[2 * r], v);
            assert_eq!(out.act[r], v * 0.5);
            assert_eq!(out.next_obs[2 * r], v + 1.0);
            seen[v as usize] = true;
        }
        assert!(seen[3..].iter().all(|&s| s));
    }

    #[test]
    fn shrinking_capacity_keeps_the_newest() {
        let mut b = ReplayBuffer::new(2, 1, 8);
        push_n(&mut b, 0, 10);
        b.set_capacity(3);
        assert_eq!(b.to_batch().reward, vec![7.0, 8.0, 9.0]);
        b.set_capacity(5);
        push_n(&mut b, 10, 1);
        assert_eq!(b.to_batch().reward, vec![7.0, 8.0, 9.0, 10.0]);
        assert_eq!(b.pushed(), 11);
    }

    #[test]
    fn mixed_sampling_takes_the_ratio_from_real_data() {
        let mut real = ReplayBuffer::new(2, 1, 10);
        let mut model = ReplayBuffer::new(2, 1, 10);
        let mut out = Batch::new(2, 1, 256);
        let mut rng = stream(2, "t", 0);
        push_n(&mut real, 0, 5); // rewards 0..5
        sample_mixed(&real, &model, 0.05, &mut rng, &mut out);
        assert!(
            out.reward.iter().all(|&r| r < 5.0),
            "empty model buffer: all real"
        );
        push_n(&mut model, 100, 5); // rewards 100..105
        sample_mixed(&real, &model, 0.05, &mut rng, &mut out);
        let n_real = out.reward.iter().filter(|&&r| r < 5.0).count();
        assert_eq!(n_real, 12);
        assert!(out.reward[..12].iter().all(|&r| r < 5.0));
    }
}
