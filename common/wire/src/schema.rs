//! The bytes in shared memory: `#[repr(C)]` headers and payloads, and the transition row layout.
//!
//! Every type here derives `ZeroCopySend` with an explicit `#[type_name("mbpo::...")]`, so a
//! process built from another crate path (or a Python `ctypes.Structure` with the same fields
//! and `type_name()`) still matches. Fields are ordered 8-byte first and padded explicitly, so
//! the layout has no hidden holes. Changing any of them means bumping [`SCHEMA_VERSION`].
//!
//! A transition batch is `n_rows` rows of `RowLayout::width()` floats each (array of structs):
//!
//! ```text
//! [ obs (obs_dim) | act (act_dim) | reward | next_obs (obs_dim) | terminated (0.0 or 1.0) ]
//! ```

use iceoryx2::prelude::ZeroCopySend;
use mbpo_core::{Batch, ReplayBuffer, TransitionSink};

#[allow(unused_imports)] // for docs
use crate::names::SCHEMA_VERSION;

/// Nanoseconds since the Unix epoch (CLOCK_REALTIME), for send timestamps.
pub fn now_ns() -> u64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_nanos() as u64)
        .unwrap_or(0)
}

/// User header of a transition batch (`Real` and `Imagined` channels).
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("mbpo::TransitionHeader")]
pub struct TransitionHeader {
    /// Hash of the run id ([`crate::RunIpc::run_hash`]); a receiver of another run rejects it.
    pub run_hash: u64,
    /// Per-producer sequence number, 0, 1, 2, ... stamped by the publisher.
    pub seq: u64,
    /// Version of the policy weights that chose the actions (0: uniform warm-up policy).
    pub policy_version: u64,
    /// Version of the model weights that produced the rows (0: real environment data).
    pub model_version: u64,
    /// The producer's environment-step counter after the last row of this batch.
    pub env_steps: u64,
    /// [`RowLayout::hash`] of the rows.
    pub layout_hash: u64,
    /// Publisher's wall clock at send time, nanoseconds since the Unix epoch.
    pub send_time_ns: u64,
    /// [`SCHEMA_VERSION`] of the writer.
    pub schema_version: u32,
    /// [`crate::ProducerId`] of the writer.
    pub producer_id: u32,
    /// [`crate::Channel::tag`] of the channel the batch was written for.
    pub stream: u32,
    /// Number of rows.
    pub n_rows: u32,
    /// Observation width.
    pub obs_dim: u32,
    /// Action width.
    pub act_dim: u32,
}

/// What a weight snapshot holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[repr(u32)]
pub enum WeightsKind {
    /// SAC actor parameters.
    Policy = 1,
    /// Dynamics ensemble parameters (with normaliser and elites, as laid out by the model crate).
    Model = 2,
    /// A latent world model's parameters (TD-MPC2: encoder, dynamics, reward, Q heads, policy
    /// prior; one flat vector), on the policy channel: what its planning actors act with.
    WorldModel = 3,
}

impl WeightsKind {
    /// The kind with numeric value `v`.
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            1 => Some(WeightsKind::Policy),
            2 => Some(WeightsKind::Model),
            3 => Some(WeightsKind::WorldModel),
            _ => None,
        }
    }
    /// The channel that carries this kind.
    pub fn channel(self) -> crate::Channel {
        match self {
            WeightsKind::Policy | WeightsKind::WorldModel => crate::Channel::Policy,
            WeightsKind::Model => crate::Channel::Model,
        }
    }
}

/// User header of a weight snapshot (`Policy` and `Model` channels); the payload is the flat
/// `[f32]` parameter vector described by a `mbpo_nn::ParamLayout`.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("mbpo::WeightsHeader")]
pub struct WeightsHeader {
    /// Hash of the run id.
    pub run_hash: u64,
    /// Snapshot version, strictly increasing per publisher (1, 2, ...).
    pub version: u64,
    /// `ParamLayout::hash` of the network the parameters belong to.
    pub layout_hash: u64,
    /// Number of `f32` values in the payload.
    pub n_values: u64,
    /// Environment steps (all actors) the writer had seen when it took the snapshot.
    pub env_steps: u64,
    /// SAC gradient updates done when the snapshot was taken.
    pub sac_updates: u64,
    /// Model trainings done when the snapshot was taken.
    pub model_trainings: u64,
    /// Publisher's wall clock at send time, nanoseconds since the Unix epoch.
    pub send_time_ns: u64,
    /// [`SCHEMA_VERSION`] of the writer.
    pub schema_version: u32,
    /// [`WeightsKind`] as `u32`.
    pub kind: u32,
    /// [`crate::ProducerId`] of the writer.
    pub producer_id: u32,
    /// Always 0 (explicit padding).
    pub reserved: u32,
}

/// Counters attached to a weight snapshot.
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct WeightsCounters {
    /// See [`WeightsHeader::env_steps`].
    pub env_steps: u64,
    /// See [`WeightsHeader::sac_updates`].
    pub sac_updates: u64,
    /// See [`WeightsHeader::model_trainings`].
    pub model_trainings: u64,
}

/// User header of the small reliable messages (`Stats` and `Control` channels).
#[derive(Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[repr(C)]
#[type_name("mbpo::MsgHeader")]
pub struct MsgHeader {
    /// Hash of the run id.
    pub run_hash: u64,
    /// Per-producer sequence number stamped by the publisher.
    pub seq: u64,
    /// Publisher's wall clock at send time, nanoseconds since the Unix epoch.
    pub send_time_ns: u64,
    /// [`SCHEMA_VERSION`] of the writer.
    pub schema_version: u32,
    /// [`crate::ProducerId`] of the writer.
    pub producer_id: u32,
}

/// What a [`StatsRecord`] reports; which slot holds which field is defined once, in
/// [`crate::stats::Stats`] (decode records with [`crate::stats::Stats::decode`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[repr(u32)]
pub enum StatsKind {
    /// An actor finished an episode.
    Episode = 1,
    /// A deterministic evaluation finished.
    Eval = 2,
    /// The learner's part of a metrics row.
    Learner = 3,
    /// A model training finished.
    Model = 4,
    /// A rollout branch finished.
    Rollout = 5,
    /// Progress counters, or the final report of a process (`metrics[0]` = 1).
    Heartbeat = 6,
    /// A checkpoint barrier step.
    Checkpoint = 7,
    /// An actor's environment failed (an exception in a Python env): the run checkpoints and
    /// stops.
    EnvFailed = 8,
    /// Part of a paced actor's histogram of step-interval errors (sent before its `Done`).
    Pacing = 9,
}

impl StatsKind {
    /// The kind with numeric value `v`.
    pub fn from_u32(v: u32) -> Option<Self> {
        Some(match v {
            1 => StatsKind::Episode,
            2 => StatsKind::Eval,
            3 => StatsKind::Learner,
            4 => StatsKind::Model,
            5 => StatsKind::Rollout,
            6 => StatsKind::Heartbeat,
            7 => StatsKind::Checkpoint,
            8 => StatsKind::EnvFailed,
            9 => StatsKind::Pacing,
            _ => return None,
        })
    }
}

/// One statistics event, everyone -> supervisor. 88 bytes, fixed size.
#[derive(
    Debug, Default, Clone, Copy, PartialEq, ZeroCopySend, serde::Serialize, serde::Deserialize,
)]
#[repr(C)]
#[type_name("mbpo::StatsRecord")]
pub struct StatsRecord {
    /// Environment steps of the producer (actors) or seen by it (others).
    pub env_steps: u64,
    /// SAC updates done (learner) or seen in the policy version used (others).
    pub sac_updates: u64,
    /// Model trainings done or seen.
    pub model_trainings: u64,
    /// Policy version in use.
    pub policy_version: u64,
    /// Model version in use.
    pub model_version: u64,
    /// Main scalar: episode / evaluation return, holdout loss, ... (see [`StatsKind`]).
    pub value: f64,
    /// Kind-specific extra scalars (see [`StatsKind`]); unused entries are 0.
    pub metrics: [f32; 8],
    /// [`StatsKind`] as `u32`.
    pub kind: u32,
    /// Episode length (Episode), number of evaluation episodes (Eval), else 0.
    pub episode_len: u32,
}

impl StatsRecord {
    /// The [`StatsKind`] if `kind` is a known value.
    pub fn stats_kind(&self) -> Option<StatsKind> {
        StatsKind::from_u32(self.kind)
    }
}

/// What a [`ControlMsg`] asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
#[repr(u32)]
pub enum ControlCommand {
    /// Finish the current step, write nothing more, exit 0.
    Stop = 1,
    /// The cut of a checkpoint barrier: reach the state after env step `step` (= T) with
    /// `request_id` (= K) model trainings, write the role's file into checkpoint T, report it.
    Checkpoint = 2,
    /// Acknowledgement of request `request_id` (`status` 0 = done, else failed).
    Ack = 3,
    /// Start a checkpoint barrier: actors finish their current step and produce nothing more,
    /// the model trainer and rollout generator start no new training or branch; each reports
    /// its counter.
    Pause = 4,
    /// The checkpoint is complete: go on.
    Resume = 5,
}

impl ControlCommand {
    /// The command with numeric value `v`.
    pub fn from_u32(v: u32) -> Option<Self> {
        Some(match v {
            1 => ControlCommand::Stop,
            2 => ControlCommand::Checkpoint,
            3 => ControlCommand::Ack,
            4 => ControlCommand::Pause,
            5 => ControlCommand::Resume,
            _ => return None,
        })
    }
}

/// Why a [`ControlCommand::Stop`] is sent (its `request_id`). Every role stops alike; the
/// difference is for a gateway to other hosts: their actors leave the run only when it is over,
/// and stay to join the next attempt when the supervisor rolls back to a checkpoint.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u64)]
pub enum StopReason {
    /// The run ended (completed, stopped, interrupted or failed).
    RunOver = 1,
    /// A process crashed and `--restart on-failure` starts every role again from the newest
    /// checkpoint: this attempt ends, the run goes on.
    RollBack = 2,
}

/// Target value of a [`ControlMsg`] addressed to every process.
pub const CONTROL_TARGET_ALL: u32 = u32::MAX;

/// A control command or acknowledgement (supervisor <-> everyone). 32 bytes, fixed size.
#[derive(
    Debug, Default, Clone, Copy, PartialEq, Eq, ZeroCopySend, serde::Serialize, serde::Deserialize,
)]
#[repr(C)]
#[type_name("mbpo::ControlMsg")]
pub struct ControlMsg {
    /// Supervisor-assigned id; an `Ack` repeats the id of the request it answers.
    pub request_id: u64,
    /// Counter the command refers to: the env step to checkpoint at, or (in an `Ack`) the
    /// producer's own step counter when it executed the request.
    pub step: u64,
    /// [`ControlCommand`] as `u32`.
    pub command: u32,
    /// [`crate::ProducerId`] the message is for, or [`CONTROL_TARGET_ALL`]. Acks target the
    /// supervisor (`ProducerId::new(Role::Supervisor, 0)`).
    pub target: u32,
    /// For an `Ack`: 0 when the request succeeded, otherwise an error code.
    pub status: u32,
    /// For an `Ack`: the [`ControlCommand`] being acknowledged.
    pub acked_command: u32,
}

impl ControlMsg {
    /// The [`ControlCommand`] if `command` is a known value.
    pub fn control_command(&self) -> Option<ControlCommand> {
        ControlCommand::from_u32(self.command)
    }
    /// True when the message is for `who` (directly or broadcast).
    pub fn is_for(&self, who: crate::ProducerId) -> bool {
        self.target == CONTROL_TARGET_ALL || self.target == who.0
    }
    /// A request `command` with `request_id` for `target` at `step`.
    pub fn request(command: ControlCommand, request_id: u64, target: u32, step: u64) -> Self {
        Self {
            request_id,
            step,
            command: command as u32,
            target,
            status: 0,
            acked_command: 0,
        }
    }
    /// A Stop for everyone at `step`, saying why (see [`StopReason`]).
    pub fn stop(reason: StopReason, step: u64) -> Self {
        Self::request(
            ControlCommand::Stop,
            reason as u64,
            CONTROL_TARGET_ALL,
            step,
        )
    }
    /// Why this Stop was sent; `None` for any other command. (An unknown reason is taken for
    /// the end of the run: actors that leave too early are reported; ones left waiting are not.)
    pub fn stop_reason(&self) -> Option<StopReason> {
        let reason = match self.request_id {
            id if id == StopReason::RollBack as u64 => StopReason::RollBack,
            _ => StopReason::RunOver,
        };
        (self.control_command() == Some(ControlCommand::Stop)).then_some(reason)
    }
    /// The acknowledgement of `req` with the producer's current `step` and `status`.
    pub fn ack(req: &ControlMsg, step: u64, status: u32, supervisor: crate::ProducerId) -> Self {
        Self {
            request_id: req.request_id,
            step,
            command: ControlCommand::Ack as u32,
            target: supervisor.0,
            status,
            acked_command: req.command,
        }
    }
}

/// The row layout of a transition batch: `[obs, act, reward, next_obs, terminated]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize)]
pub struct RowLayout {
    /// Observation width.
    pub obs_dim: usize,
    /// Action width.
    pub act_dim: usize,
}

impl RowLayout {
    /// The layout for observations of width `obs_dim` and actions of width `act_dim`.
    pub const fn new(obs_dim: usize, act_dim: usize) -> Self {
        Self { obs_dim, act_dim }
    }
    /// Floats per row: `2 * obs_dim + act_dim + 2`.
    pub const fn width(&self) -> usize {
        2 * self.obs_dim + self.act_dim + 2
    }
    /// Offset of `act` in a row.
    pub const fn act_offset(&self) -> usize {
        self.obs_dim
    }
    /// Offset of `reward` in a row.
    pub const fn reward_offset(&self) -> usize {
        self.obs_dim + self.act_dim
    }
    /// Offset of `next_obs` in a row.
    pub const fn next_obs_offset(&self) -> usize {
        self.obs_dim + self.act_dim + 1
    }
    /// Offset of `terminated` in a row.
    pub const fn terminated_offset(&self) -> usize {
        2 * self.obs_dim + self.act_dim + 1
    }
    /// FNV-1a of the field order and widths; changes when either dimension or the order changes.
    pub fn hash(&self) -> u64 {
        let text = format!(
            "mbpo.rows.v{SCHEMA_VERSION}:obs[{o}],act[{a}],reward[1],next_obs[{o}],terminated[1]",
            o = self.obs_dim,
            a = self.act_dim
        );
        mbpo_core::rng::fnv1a(text.as_bytes())
    }

    /// Number of rows in a payload of `len` floats, or `None` if `len` is not a multiple of the width.
    pub fn rows_in(&self, len: usize) -> Option<usize> {
        let w = self.width();
        let n = len / w;
        (n * w == len).then_some(n)
    }

    /// Write one transition into `row` (length [`RowLayout::width`]).
    #[inline]
    pub fn write_row(
        &self,
        row: &mut [f32],
        obs: &[f32],
        act: &[f32],
        reward: f32,
        next_obs: &[f32],
        terminated: bool,
    ) {
        let (o, a) = (self.obs_dim, self.act_dim);
        row[..o].copy_from_slice(&obs[..o]);
        row[o..o + a].copy_from_slice(&act[..a]);
        row[o + a] = reward;
        row[o + a + 1..2 * o + a + 1].copy_from_slice(&next_obs[..o]);
        row[2 * o + a + 1] = if terminated { 1.0 } else { 0.0 };
    }

    /// View one row as its fields.
    #[inline]
    pub fn split_row<'a>(&self, row: &'a [f32]) -> RowRef<'a> {
        let (o, a) = (self.obs_dim, self.act_dim);
        RowRef {
            obs: &row[..o],
            act: &row[o..o + a],
            reward: row[o + a],
            next_obs: &row[o + a + 1..2 * o + a + 1],
            terminated: row[2 * o + a + 1] != 0.0,
        }
    }

    /// Write rows `start..start + n` of `batch` into `dst` (`n * width` floats). No allocation.
    pub fn pack(&self, batch: &Batch, start: usize, n: usize, dst: &mut [f32]) {
        assert_eq!(
            (batch.obs_dim, batch.act_dim),
            (self.obs_dim, self.act_dim),
            "batch dimensions differ from the row layout"
        );
        assert!(
            start + n <= batch.len,
            "rows {start}..{} out of a batch of {}",
            start + n,
            batch.len
        );
        let (o, a, w) = (self.obs_dim, self.act_dim, self.width());
        assert_eq!(
            dst.len(),
            n * w,
            "destination holds {} floats, {n} rows need {}",
            dst.len(),
            n * w
        );
        for (i, row) in dst.chunks_exact_mut(w).enumerate() {
            let r = start + i;
            self.write_row(
                row,
                &batch.obs[r * o..(r + 1) * o],
                &batch.act[r * a..(r + 1) * a],
                batch.reward[r],
                &batch.next_obs[r * o..(r + 1) * o],
                batch.terminated[r] != 0.0,
            );
        }
    }

    /// Fill `out` with the rows in `src` (resizing its vectors; no allocation once their
    /// capacity suffices).
    pub fn unpack_into(&self, src: &[f32], out: &mut Batch) {
        let (o, a, w) = (self.obs_dim, self.act_dim, self.width());
        let n = src.len() / w;
        assert_eq!(src.len(), n * w, "payload is not a whole number of rows");
        out.obs_dim = o;
        out.act_dim = a;
        out.len = n;
        out.obs.resize(n * o, 0.0);
        out.act.resize(n * a, 0.0);
        out.reward.resize(n, 0.0);
        out.next_obs.resize(n * o, 0.0);
        out.terminated.resize(n, 0.0);
        for (r, row) in src.chunks_exact(w).enumerate() {
            out.obs[r * o..(r + 1) * o].copy_from_slice(&row[..o]);
            out.act[r * a..(r + 1) * a].copy_from_slice(&row[o..o + a]);
            out.reward[r] = row[o + a];
            out.next_obs[r * o..(r + 1) * o].copy_from_slice(&row[o + a + 1..2 * o + a + 1]);
            out.terminated[r] = row[2 * o + a + 1];
        }
    }

    /// Append every row in `src` to `buf`, in order (no allocation).
    pub fn push_into(&self, src: &[f32], buf: &mut ReplayBuffer) {
        assert_eq!(
            (buf.obs_dim(), buf.act_dim()),
            (self.obs_dim, self.act_dim),
            "replay buffer dimensions differ from the row layout"
        );
        self.push_rows(src, buf);
    }

    /// Hand every row in `src` to `sink`, in order (no allocation).
    pub fn push_rows(&self, src: &[f32], sink: &mut dyn TransitionSink) {
        for row in src.chunks_exact(self.width()) {
            let r = self.split_row(row);
            sink.push(r.obs, r.act, r.reward, r.next_obs, r.terminated);
        }
    }
}

/// One transition row, borrowed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RowRef<'a> {
    /// s
    pub obs: &'a [f32],
    /// a
    pub act: &'a [f32],
    /// r
    pub reward: f32,
    /// s'
    pub next_obs: &'a [f32],
    /// True when s' is terminal.
    pub terminated: bool,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn headers_have_no_hidden_padding() {
        assert_eq!(std::mem::size_of::<TransitionHeader>(), 7 * 8 + 6 * 4);
        assert_eq!(std::mem::size_of::<WeightsHeader>(), 8 * 8 + 4 * 4);
        assert_eq!(std::mem::size_of::<MsgHeader>(), 3 * 8 + 2 * 4);
        assert_eq!(std::mem::size_of::<StatsRecord>(), 6 * 8 + 8 * 4 + 2 * 4);
        assert_eq!(std::mem::size_of::<ControlMsg>(), 2 * 8 + 4 * 4);
    }

    #[test]
    fn batch_round_trips_through_rows() {
        let l = RowLayout::new(3, 1);
        assert_eq!(l.width(), 9);
        let mut b = Batch::new(3, 1, 5);
        for r in 0..5 {
            let v = r as f32;
            b.obs[r * 3..r * 3 + 3].copy_from_slice(&[v, v + 0.1, v + 0.2]);
            b.act[r] = -v;
            b.reward[r] = 10.0 * v;
            b.next_obs[r * 3..r * 3 + 3].copy_from_slice(&[v + 1.0, v + 1.1, v + 1.2]);
            b.terminated[r] = (r % 2) as f32;
        }
        let mut rows = vec![0.0; 5 * 9];
        l.pack(&b, 0, 5, &mut rows);
        assert_eq!(
            &rows[9..18],
            &[1.0, 1.1, 1.2, -1.0, 10.0, 2.0, 2.1, 2.2, 1.0]
        );
        let mut back = Batch::default();
        l.unpack_into(&rows, &mut back);
        assert_eq!(back, b);
        let mut buf = ReplayBuffer::new(3, 1, 8);
        l.push_into(&rows, &mut buf);
        assert_eq!(buf.to_batch(), b);
    }

    #[test]
    fn layout_hash_depends_on_dims() {
        assert_ne!(RowLayout::new(3, 1).hash(), RowLayout::new(1, 3).hash());
        assert_eq!(RowLayout::new(17, 6).hash(), RowLayout::new(17, 6).hash());
    }
}
