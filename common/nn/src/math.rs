//! Branch-free f32 elementary functions that vectorise.
//!
//! libm's `expf`, `tanhf` and `log1pf` are calls per element, so a loop over them runs one lane
//! at a time. These are `#[inline(always)]` straight-line code (no branches, no calls, no
//! `as i32` casts, every multiply-add written as `mul_add`) so that a loop over a slice becomes
//! SIMD code, and in an AVX2+FMA copy of the loop (see [`crate::simd`]) each `mul_add` is one
//! FMA instruction. `mul_add` is a correctly rounded fused multiply-add on every target (a libm
//! call without FMA hardware), so the baseline and AVX2 copies give the same bits.
//!
//! Users: the SiLU/sigmoid activations here, the dynamics model's kernels
//! (`mbpo-model`'s `simd.rs`) and SAC's tanh-Gaussian head.

/// e^(−x) for f32, branch-free and vectorisable (the exponentials on the hot paths are of
/// negated quantities: σ(z) = 1/(1 + e^(−z)), softplus through e^(−|x|), tanh through e^(−2|u|),
/// the precision e^(−logvar)). Range reduction −x = n·ln2 + r with |r| ≤ ln2/2, a fitted
/// polynomial for e^r, and 2^n built from exponent bits; x is clamped to [−88, 87], so the
/// result is never a denormal, zero or infinity. Relative error below 5e-7 (tested).
///
/// Details that matter for speed under AVX2:
/// * 2^n comes from integer arithmetic on the bits of the rounded float (adding 1.5·2^23 leaves
///   n in the low mantissa bits) instead of an `f32 as i32` cast, whose saturating semantics
///   LLVM does not vectorise (it emits a compare-and-select per lane);
/// * one fused reduction step: n·ln2(f32) is exact inside the FMA, so r is off by at most
///   127·|ln2 − ln2(f32)| ≈ 2.4e-7 (no second Cody-Waite constant);
/// * e^r ≈ 1 + r + r²·p(r) with p a cubic fitted for minimal relative error on |r| ≤ ln2/2
///   (1.1e-7 exactly, 1.9e-7 evaluated in f32; Cephes `expf` spends two more terms for no gain
///   at f32 precision), by Estrin's scheme: a shorter dependency chain than Horner's, which is
///   what bounds the loop (the FP scheduler cannot hold enough iterations to hide a long one);
/// * the negation is folded into the constants (r̃ = −r is what the FMA produces).
#[inline(always)]
pub fn exp_neg_f32(x: f32) -> f32 {
    const LOG2E: f32 = std::f32::consts::LOG2_E;
    const LN2: f32 = std::f32::consts::LN_2;
    const ROUND: f32 = 12_582_912.0; // 1.5·2^23
                                     // bits(t) − bits(ROUND) = n; adding the exponent bias 127 folds into one constant.
    const BIAS_BITS: u32 = 127u32.wrapping_sub(0x4b40_0000);
    let x = x.clamp(-88.0, 87.0);
    let t = x.mul_add(-LOG2E, ROUND); // ROUND + n, n = round(−x·log2 e)
    let n = t - ROUND;
    let rn = n.mul_add(LN2, x); // −r, with −x = n·ln2 + r
    let r2 = rn * rn;
    // p(r) = (c0 + c1 r) + r²(c2 + c3 r) at r = −rn.
    let p01 = rn.mul_add(-0.166_671_14, 0.499_992_3);
    let p23 = rn.mul_add(-0.008_312_558, 0.041_890_107);
    let p = r2.mul_add(p23, p01);
    let er = r2.mul_add(p, 1.0 - rn);
    let scale = f32::from_bits(t.to_bits().wrapping_add(BIAS_BITS) << 23);
    er * scale
}

/// Lanes of the row reductions: 16 running sums (or maxima), combined at the end in a fixed
/// order, so the loops vectorise (one AVX-512 register, two AVX2 ones) and give the same bits at
/// every SIMD level. One running sum per row had made LayerNorm a quarter of a plan's time, and
/// the two-hot decode a tenth (each add waiting for the last).
pub const LANES: usize = 16;

/// Σ f(i, xᵢ) over `x` in [`LANES`] running sums.
#[inline(always)]
pub fn lane_sum(x: &[f32], f: impl Fn(usize, f32) -> f32) -> f32 {
    let mut acc = [0.0f32; LANES];
    lane_fold(x, |i, v, l| acc[l] += f(i, v));
    tree_sum(acc)
}

/// max xᵢ over `x` in [`LANES`] running maxima (−∞ for an empty `x`).
#[inline(always)]
pub fn lane_max(x: &[f32]) -> f32 {
    let mut acc = [f32::NEG_INFINITY; LANES];
    lane_fold(x, |_, v, l| acc[l] = acc[l].max(v));
    acc.into_iter().fold(f32::NEG_INFINITY, f32::max)
}

/// Calls `f(i, xᵢ, lane)` for every element, lane = i mod [`LANES`] over the whole chunks and
/// the tail's own index after them: the shape every lane reduction here shares.
#[inline(always)]
pub fn lane_fold(x: &[f32], mut f: impl FnMut(usize, f32, usize)) {
    let full = x.len() / LANES * LANES;
    for (c, chunk) in x[..full].chunks_exact(LANES).enumerate() {
        for (l, &v) in chunk.iter().enumerate() {
            f(c * LANES + l, v, l);
        }
    }
    for (l, &v) in x[full..].iter().enumerate() {
        f(full + l, v, l);
    }
}

/// The lanes' sums added in a fixed tree: 16 → 8 → 4 → 2 → 1 (f32 sums, or f64 ones).
#[inline(always)]
pub fn tree_sum<T: Copy + std::ops::AddAssign>(mut acc: [T; LANES]) -> T {
    let mut width = LANES;
    while width > 1 {
        width /= 2;
        for l in 0..width {
            acc[l] += acc[l + width];
        }
    }
    acc[0]
}

/// ln(1 + t) for t in [0, 1], as 2·atanh(s) with s = t/(2 + t) ∈ [0, 1/3]:
/// `2s·(1 + s²/3 + s⁴/5 + … + s¹²/13)`. The first omitted term is below 1.4e-8 of the result,
/// and the form stays accurate for tiny t (no `1 + t` cancellation); one division and eight
/// multiply-adds, about half the work of a general logarithm plus a log1p correction.
#[inline(always)]
pub fn log1p_unit(t: f32) -> f32 {
    let s = t / (2.0 + t);
    let z = s * s;
    let mut p = 1.0f32 / 13.0;
    p = p.mul_add(z, 1.0 / 11.0);
    p = p.mul_add(z, 1.0 / 9.0);
    p = p.mul_add(z, 1.0 / 7.0);
    p = p.mul_add(z, 1.0 / 5.0);
    p = p.mul_add(z, 1.0 / 3.0);
    p = p.mul_add(z, 1.0);
    2.0 * s * p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_matches_std_to_a_few_ulps_and_saturates() {
        let mut worst = 0.0f64;
        let mut x = -87.0f32;
        while x <= 88.0 {
            let want = (x as f64).exp();
            worst = worst.max(((exp_neg_f32(-x) as f64 - want) / want).abs());
            x += 0.000_71;
        }
        assert!(worst < 5e-7, "worst relative error {worst}");
        assert_eq!(exp_neg_f32(0.0), 1.0);
        assert!(exp_neg_f32(1e4) > 0.0 && exp_neg_f32(-1e4).is_finite());
        assert!(exp_neg_f32(f32::NAN).is_nan());
    }

    #[test]
    fn log1p_is_accurate_on_the_unit_interval() {
        let mut worst = 0.0f64;
        for i in 0..=100_000 {
            let t = if i == 0 { 1e-30 } else { i as f32 * 1e-5 };
            let want = (t as f64).ln_1p();
            worst = worst.max((log1p_unit(t) as f64 - want).abs() / want);
        }
        assert!(worst < 3e-7, "worst relative error {worst}");
        assert_eq!(log1p_unit(0.0), 0.0);
    }
}
