//! Member-grouped inference: every sample is predicted by one member (a rollout's random
//! elite, a planner's particle member), so the samples are sorted by member ([`Grouping`]) and
//! each member runs once over its own rows, in chunks of [`INFER_CHUNK`] rows. This is the
//! rollout's speed lever: every sample costs one member's forward pass, not E.
//!
//! The chunks are a fixed function of the members drawn, and a chunk's result depends only on
//! its rows, so the chunks can be computed in any order and on any thread: a sampled
//! prediction on several threads ([`sample_block`], [`ChunkBlock`]) gives the same bits as on
//! one.

use crate::network::{member_forward, InferBuffers, Net, INFER_CHUNK};
use crate::normalizer::InputNormalizer;
use crate::simd::dispatch;
use std::ops::Range;

/// Samples ordered by member (a counting sort), so each member runs once on its own rows.
#[derive(Debug, Clone, Default)]
pub(crate) struct Grouping {
    /// Sample indices, member 0's first; stable within a member.
    pub(crate) order: Vec<u32>,
    /// `starts[e]..starts[e + 1]` is member e's part of `order`.
    pub(crate) starts: Vec<usize>,
}

impl Grouping {
    pub(crate) fn build(&mut self, members: &[usize], n_members: usize) {
        self.starts.clear();
        self.starts.resize(n_members + 1, 0);
        for &m in members {
            self.starts[m + 1] += 1;
        }
        for e in 0..n_members {
            self.starts[e + 1] += self.starts[e];
        }
        self.order.resize(members.len(), 0);
        // `starts[e]` is used as member e's write cursor, then restored.
        for (i, &m) in members.iter().enumerate() {
            self.order[self.starts[m]] = i as u32;
            self.starts[m] += 1;
        }
        for e in (0..n_members).rev() {
            self.starts[e + 1] = self.starts[e];
        }
        self.starts[0] = 0;
    }

    /// The chunks in grouped order: (member, position of the chunk's first sample in
    /// `order`, the chunk's sample indices). Member 0's chunks first; consecutive chunks are
    /// consecutive positions.
    pub(crate) fn chunks(&self) -> impl Iterator<Item = (usize, usize, &[u32])> + '_ {
        self.starts.windows(2).enumerate().flat_map(move |(e, w)| {
            self.order[w[0]..w[1]]
                .chunks(INFER_CHUNK)
                .enumerate()
                .map(move |(c, idx)| (e, w[0] + c * INFER_CHUNK, idx))
        })
    }

    /// How many chunks [`Grouping::chunks`] yields.
    pub(crate) fn chunk_count(&self) -> usize {
        self.starts
            .windows(2)
            .map(|w| (w[1] - w[0]).div_ceil(INFER_CHUNK))
            .sum()
    }

    /// The position of chunk `c`'s first sample (the number of samples when `c` is past the
    /// last chunk).
    pub(crate) fn chunk_position(&self, c: usize) -> usize {
        self.chunks()
            .nth(c)
            .map_or(self.order.len(), |(_, pos, _)| pos)
    }
}

/// Standardised inputs of one inference chunk, built vectorised: the raw `[obs, act]` rows are
/// copied in, then `(x − mean)/std` runs over blocks of 8 rows against mean and std tiled 8
/// times (so every lane's column parameter sits at the same offset). Same IEEE operations as
/// [`InputNormalizer::transform_into`], hence the same values as the training path.
#[derive(Debug, Clone, Default)]
pub(crate) struct InputChunk {
    x: Vec<f32>,
    mean_tile: Vec<f32>,
    std_tile: Vec<f32>,
}

impl InputChunk {
    pub(crate) fn prepare(&mut self, normalizer: &InputNormalizer) {
        let in_dim = normalizer.dim();
        self.x.resize(INFER_CHUNK * in_dim, 0.0);
        self.mean_tile.clear();
        self.std_tile.clear();
        for _ in 0..8 {
            self.mean_tile.extend_from_slice(&normalizer.mean);
            self.std_tile.extend_from_slice(&normalizer.std);
        }
    }
}

/// What a member-grouped pass reads: the network, its parameters, the samples' inputs.
pub(crate) struct GroupedInputs<'a> {
    pub net: &'a Net,
    pub theta: &'a [f32],
    pub group: &'a Grouping,
    /// Observations of the samples (`n x obs_dim`), in sample order.
    pub obs: &'a [f32],
    /// Actions of the samples (`n x act_dim`), in sample order.
    pub act: &'a [f32],
}

/// Member `e`'s `[μ | logvar]` rows of the samples `idx` (one chunk), left in `infer.y`;
/// `input` must be [`InputChunk::prepare`]d with the model's normaliser.
fn chunk_forward<'b>(
    g: &GroupedInputs,
    e: usize,
    idx: &[u32],
    input: &mut InputChunk,
    infer: &'b mut InferBuffers,
) -> &'b mut [f32] {
    let in_dim = g.net.in_dim();
    let o = g.net.d() - 1;
    let a = in_dim - o;
    let rows = idx.len();
    for (&i, x) in idx.iter().zip(input.x.chunks_exact_mut(in_dim)) {
        let i = i as usize;
        x[..o].copy_from_slice(&g.obs[i * o..(i + 1) * o]);
        x[o..].copy_from_slice(&g.act[i * a..(i + 1) * a]);
    }
    let x = &mut input.x[..rows * in_dim];
    dispatch!(standardize_tiled(x, &input.mean_tile, &input.std_tile));
    member_forward(g.net, g.theta, e, x, rows, infer, true);
    &mut infer.y[..rows * 2 * g.net.d()]
}

/// Run every chunk in grouped order on the calling thread and hand each chunk's position,
/// sample indices and `[μ | logvar]` rows to `sink`.
pub(crate) fn forward_grouped(
    g: &GroupedInputs,
    normalizer: &InputNormalizer,
    input: &mut InputChunk,
    infer: &mut InferBuffers,
    mut sink: impl FnMut(usize, &[u32], &mut [f32]),
) {
    input.prepare(normalizer);
    for (e, pos, idx) in g.group.chunks() {
        let y = chunk_forward(g, e, idx, input, infer);
        sink(pos, idx, y);
    }
}

/// One thread's share of a sampled prediction: the chunks `chunks` (indices into
/// [`Grouping::chunks`]), whose samples sit at positions `first..` of the grouped order, and
/// where their sampled `[reward, Δobs]` rows go (`rows x d`, grouped order).
pub(crate) struct ChunkBlock<'a> {
    pub chunks: Range<usize>,
    pub first: usize,
    pub out: &'a mut [f32],
}

/// The sampled `[reward, Δobs]` = μ + σ·ε of the block's chunks into `block.out`, with ε in
/// grouped order (`n x d`); `input` must be prepared.
pub(crate) fn sample_block(
    g: &GroupedInputs,
    eps: &[f32],
    block: ChunkBlock,
    input: &mut InputChunk,
    infer: &mut InferBuffers,
) {
    let d = g.net.d();
    let ChunkBlock { chunks, first, out } = block;
    for (e, pos, idx) in g.group.chunks().skip(chunks.start).take(chunks.len()) {
        let y = chunk_forward(g, e, idx, input, infer);
        let eps = &eps[pos * d..(pos + idx.len()) * d];
        dispatch!(sample_gaussian_rows(y, eps, d));
        let out = &mut out[(pos - first) * d..(pos - first + idx.len()) * d];
        for (dst, row) in out.chunks_exact_mut(d).zip(y.chunks_exact(2 * d)) {
            dst.copy_from_slice(&row[..d]);
        }
    }
}
