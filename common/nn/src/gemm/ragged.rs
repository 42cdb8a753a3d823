//! An AVX-512 GEMM for row-major products whose output width is not a multiple of 16, such as
//! the dynamics model's 200-wide layers.
//!
//! faer's AVX-512 micro-kernel computes 96 rows of its column-major output at a time; a
//! row-major `C` is its transpose, so faer's rows are our output columns, and a 200-wide layer
//! becomes 96 + 96 + an 8-row tail that runs at a fraction of the speed (`perf` put 9 % of a
//! model-training thread in that tail, issue 23). Here the output columns are the vector lanes
//! instead: panels of up to 3 × 16 columns, the last 16 lanes masked, so a ragged width costs
//! only its unused lanes. Rows go 8 at a time, each element of `A` broadcast from where it is
//! stored (no packing: `A` is read in place, row-major or transposed, and `B`'s rows are
//! contiguous).
//!
//! Every output element is the same chain of fused multiply-adds over `p = 0..k` in order,
//! starting from zero, that faer computes for these shapes, so results are bit-identical to
//! faer's (the tests below check it); blocking `k` in [`KC`] only parks the running sums in `C`.

use std::arch::x86_64::{
    __m512, __mmask16, _mm512_fmadd_ps, _mm512_mask_storeu_ps, _mm512_maskz_loadu_ps,
    _mm512_set1_ps, _mm512_setzero_ps,
};

/// Rows of `C` per micro-kernel call.
const MR: usize = 8;
/// 16-lane vectors of `C` columns per panel.
const NR: usize = 3;
/// Depth of one pass: the panel of `B` it reads (`KC x 48` floats, 24 KiB) is meant to stay in
/// L1 across row blocks.
const KC: usize = 128;

/// Whether [`gemm`] runs on this CPU.
pub(crate) fn available() -> bool {
    std::arch::is_x86_feature_detected!("avx512f")
}

/// `C = A' B` for row-major `C` (`m x n`, rows `ldc` apart) and `B` (`k x n`, rows `ldb`
/// apart), where `A'(i, p)` is `a[i·rs_a + p·cs_a]` (row-major `A`: `(k, 1)`; a stored
/// `k x m` matrix used transposed: `(1, m)`).
///
/// # Panics
/// If a slice is shorter than its shape needs.
///
/// # Safety
/// The CPU must support AVX-512F ([`available`]).
#[target_feature(enable = "avx512f")]
#[allow(clippy::too_many_arguments)]
pub(crate) unsafe fn gemm(
    c: &mut [f32],
    ldc: usize,
    a: &[f32],
    rs_a: usize,
    cs_a: usize,
    b: &[f32],
    ldb: usize,
    m: usize,
    k: usize,
    n: usize,
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(ldc >= n && c.len() >= (m - 1) * ldc + n);
    if k == 0 {
        c.chunks_mut(ldc).take(m).for_each(|row| row[..n].fill(0.0));
        return;
    }
    assert!(ldb >= n && b.len() >= (k - 1) * ldb + n);
    assert!(a.len() > (m - 1) * rs_a + (k - 1) * cs_a);
    let (a, b, c) = (a.as_ptr(), b.as_ptr(), c.as_mut_ptr());
    let mut p0 = 0;
    while p0 < k {
        let kc = KC.min(k - p0);
        let mut j = 0;
        while j < n {
            let width = (n - j).min(16 * NR);
            let vectors = width.div_ceil(16);
            let last = width - 16 * (vectors - 1);
            let mask: __mmask16 = if last == 16 { !0 } else { (1 << last) - 1 };
            let panel = Panel {
                a: a.add(p0 * cs_a),
                rs_a,
                cs_a,
                b: b.add(p0 * ldb + j),
                ldb,
                c: c.add(j),
                ldc,
                kc,
                mask,
                resume: p0 > 0,
            };
            match vectors {
                1 => panel.rows::<1>(m),
                2 => panel.rows::<2>(m),
                _ => panel.rows::<NR>(m),
            }
            j += width;
        }
        p0 += kc;
    }
}

/// One pass of depth `kc` over a panel of columns, for every row block.
struct Panel {
    a: *const f32,
    rs_a: usize,
    cs_a: usize,
    b: *const f32,
    ldb: usize,
    c: *mut f32,
    ldc: usize,
    kc: usize,
    /// Lanes of the panel's last vector that are columns of `C`.
    mask: __mmask16,
    /// Continue the sums parked in `C` by the previous pass (else start from zero).
    resume: bool,
}

impl Panel {
    #[inline(always)]
    unsafe fn rows<const V: usize>(&self, m: usize) {
        let mut i = 0;
        while i + MR <= m {
            self.block::<MR, V>(i);
            i += MR;
        }
        match m - i {
            0 => {}
            1 => self.block::<1, V>(i),
            2 => self.block::<2, V>(i),
            3 => self.block::<3, V>(i),
            4 => self.block::<4, V>(i),
            5 => self.block::<5, V>(i),
            6 => self.block::<6, V>(i),
            _ => self.block::<7, V>(i),
        }
    }

    /// Rows `i0..i0 + R` of the panel: `R x V` accumulators in registers.
    #[inline(always)]
    unsafe fn block<const R: usize, const V: usize>(&self, i0: usize) {
        let lanes = |v: usize| if v + 1 == V { self.mask } else { !0 };
        let c = self.c.add(i0 * self.ldc);
        let mut acc = [[_mm512_setzero_ps(); V]; R];
        if self.resume {
            for (r, row) in acc.iter_mut().enumerate() {
                for (v, x) in row.iter_mut().enumerate() {
                    *x = _mm512_maskz_loadu_ps(lanes(v), c.add(r * self.ldc + 16 * v));
                }
            }
        }
        let a = self.a.add(i0 * self.rs_a);
        for p in 0..self.kc {
            let mut bv: [__m512; V] = [_mm512_setzero_ps(); V];
            for (v, x) in bv.iter_mut().enumerate() {
                *x = _mm512_maskz_loadu_ps(lanes(v), self.b.add(p * self.ldb + 16 * v));
            }
            for (r, row) in acc.iter_mut().enumerate() {
                let ar = _mm512_set1_ps(*a.add(r * self.rs_a + p * self.cs_a));
                for (x, &bx) in row.iter_mut().zip(&bv) {
                    *x = _mm512_fmadd_ps(ar, bx, *x);
                }
            }
        }
        for (r, row) in acc.iter().enumerate() {
            for (v, &x) in row.iter().enumerate() {
                _mm512_mask_storeu_ps(c.add(r * self.ldc + 16 * v), lanes(v), x);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gemm::{operand, strides, Op};
    use faer::linalg::matmul::matmul;
    use faer::{Accum, MatMut, Par};

    #[test]
    fn equals_faer_bit_for_bit_on_ragged_and_blocked_shapes() {
        if !available() {
            eprintln!("skipped: no AVX-512F on this CPU");
            return;
        }
        // Row tails of every size, ragged and whole panels, depths below, at and above KC.
        for (m, k, n) in [
            (128, 200, 200),
            (256, 14, 200),
            (200, 128, 200),
            (13, 300, 104),
            (7, 129, 100),
            (9, 1, 120),
        ] {
            let a: Vec<f32> = (0..m * k)
                .map(|i| ((i * 7919 % 1009) as f32 - 504.0) * 1e-3)
                .collect();
            let b: Vec<f32> = (0..k * n)
                .map(|i| ((i * 104_729 % 997) as f32 - 498.0) * 1e-3)
                .collect();
            for op_a in [Op::N, Op::T] {
                let (rs, cs) = strides(op_a, m, k);
                let mut c = vec![f32::NAN; m * n];
                // SAFETY: AVX-512F checked above.
                unsafe { gemm(&mut c, n, &a, rs, cs, &b, n, m, k, n) };
                let mut want = vec![0.0; m * n];
                let (a, b) = (operand(&a, op_a, m, k), operand(&b, Op::N, k, n));
                let out = MatMut::from_row_major_slice_mut(&mut want, m, n);
                matmul(out, Accum::Replace, a, b, 1.0, Par::Seq);
                let same = c.iter().zip(&want).all(|(x, y)| x.to_bits() == y.to_bits());
                assert!(same, "{m}x{k}x{n} {op_a:?}: differs from faer");
            }
        }
    }
}
