//! Row-major GEMM on faer.
//!
//! All matrices in this crate are row-major `[f32]` slices: a batch is `rows x features`, a
//! weight matrix is `in x out`, so a dense layer is `Y = X W + b`. faer views a row-major slice
//! as the transpose of a column-major one at no cost, so transposed operands (`X^T dY`,
//! `dY W^T`) are free views, never copies.

use faer::linalg::matmul::matmul;
use faer::{Accum, MatMut, MatRef, Par};

/// Whether an operand is used as stored or transposed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Op {
    /// Use the matrix as stored.
    N,
    /// Use its transpose.
    T,
}

/// `C = A' B'` (or `C += A' B'` when `accumulate`), where `A'` is `m x k` and `B'` is `k x n`
/// after applying `op_a` / `op_b` to the stored row-major matrices.
///
/// `a` holds `m x k` (or `k x m` when transposed), `b` holds `k x n` (or `n x k`), `c` holds `m x n`.
#[allow(clippy::too_many_arguments)]
#[inline]
pub fn gemm(
    c: &mut [f32],
    a: &[f32],
    op_a: Op,
    b: &[f32],
    op_b: Op,
    m: usize,
    k: usize,
    n: usize,
    accumulate: bool,
) {
    if k == 1 {
        // An outer product (the backward pass through a scalar-output layer, e.g. a critic's
        // Q head): faer takes its generic rank-update path for it, which cost 1.5 % of a SAC
        // update; this loop is a fraction of that. Each element is one product, as in faer.
        return outer(&mut c[..m * n], &a[..m], &b[..n], accumulate);
    }
    let c = MatMut::from_row_major_slice_mut(&mut c[..m * n], m, n);
    let a = match op_a {
        Op::N => MatRef::from_row_major_slice(&a[..m * k], m, k),
        Op::T => MatRef::from_row_major_slice(&a[..m * k], k, m).transpose(),
    };
    let b = match op_b {
        Op::N => MatRef::from_row_major_slice(&b[..k * n], k, n),
        Op::T => MatRef::from_row_major_slice(&b[..k * n], n, k).transpose(),
    };
    let accum = if accumulate {
        Accum::Add
    } else {
        Accum::Replace
    };
    matmul(c, accum, a, b, 1.0f32, Par::Seq);
}

/// `C = a bᵀ` (or `C += a bᵀ`) for vectors a (m) and b (n): both layouts of a `m x 1` or
/// `1 x n` operand are the same contiguous vector.
fn outer(c: &mut [f32], a: &[f32], b: &[f32], accumulate: bool) {
    crate::simd::dispatch!(outer_kernel(c, a, b, accumulate))
}

#[inline(always)]
fn outer_kernel(c: &mut [f32], a: &[f32], b: &[f32], accumulate: bool) {
    for (row, &ai) in c.chunks_exact_mut(b.len()).zip(a) {
        if accumulate {
            row.iter_mut().zip(b).for_each(|(c, &bj)| *c += ai * bj);
        } else {
            row.iter_mut().zip(b).for_each(|(c, &bj)| *c = ai * bj);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn naive(a: &[f32], b: &[f32], m: usize, k: usize, n: usize) -> Vec<f32> {
        let mut c = vec![0.0; m * n];
        for i in 0..m {
            for j in 0..n {
                c[i * n + j] = (0..k).map(|p| a[i * k + p] * b[p * n + j]).sum();
            }
        }
        c
    }

    fn transpose(x: &[f32], r: usize, c: usize) -> Vec<f32> {
        let mut t = vec![0.0; r * c];
        for i in 0..r {
            for j in 0..c {
                t[j * r + i] = x[i * c + j];
            }
        }
        t
    }

    #[test]
    fn all_transpose_combinations_match_naive_product() {
        for (m, k, n) in [(5, 7, 3), (6, 1, 4)] {
            check_shape(m, k, n);
        }
    }

    fn check_shape(m: usize, k: usize, n: usize) {
        let a: Vec<f32> = (0..m * k).map(|i| (i as f32 * 0.37).sin()).collect();
        let b: Vec<f32> = (0..k * n).map(|i| (i as f32 * 0.11).cos()).collect();
        let want = naive(&a, &b, m, k, n);
        let at = transpose(&a, m, k);
        let bt = transpose(&b, k, n);
        for (aa, oa) in [(&a, Op::N), (&at, Op::T)] {
            for (bb, ob) in [(&b, Op::N), (&bt, Op::T)] {
                let mut c = vec![1.0; m * n];
                gemm(&mut c, aa, oa, bb, ob, m, k, n, false);
                for (x, y) in c.iter().zip(&want) {
                    assert!((x - y).abs() < 1e-5, "{oa:?}{ob:?}");
                }
                gemm(&mut c, aa, oa, bb, ob, m, k, n, true);
                for (x, y) in c.iter().zip(&want) {
                    assert!((x - 2.0 * y).abs() < 1e-5, "accumulate {oa:?}{ob:?}");
                }
            }
        }
    }
}
