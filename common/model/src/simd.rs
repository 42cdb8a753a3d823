//! Element-wise kernels of the dynamics model, compiled three times and chosen at run time.
//!
//! The workspace builds for the x86-64 baseline (SSE2, no FMA), so a plain loop over `exp`
//! runs four lanes at a time. Every kernel here is an `#[inline(always)]` function over slices
//! that the compiler vectorises, wrapped in an AVX-512F and an AVX2+FMA `#[target_feature]`
//! function and once without; [`dispatch!`] picks the widest copy the CPU has (the level rule is
//! [`mbpo_nn::simd`]'s; faer dispatches its GEMM kernels the same way). All copies perform the
//! same IEEE operations in the same order: fused multiply-adds are written as `mul_add`, which is
//! one instruction in the AVX copies and a correctly rounded libm call in the baseline copy
//! (slow, but only CPUs without FMA take it), and rustc never contracts anything else into an
//! FMA; so results do not depend on the path.
//!
//! The kernels fuse what would otherwise be separate passes over the `batch x 200` activations:
//! bias + SiLU in one pass (keeping σ(z) for the backward pass, which then needs no division),
//! the SiLU derivative + the bias-gradient column sums in one pass, and the whole Gaussian NLL
//! with all its gradients in one pass over the outputs.
//!
//! Every helper a kernel calls must be `#[inline(always)]` (and must not be a closure): code that
//! is not inlined into the `#[target_feature]` twin is compiled for the baseline, and a
//! non-inlined `mul_add` there becomes a libm call per element.

/// Call `kernel(args..)` through the copy compiled for [`mbpo_nn::simd::simd_level`]: AVX-512F,
/// AVX2+FMA or the baseline (one rule for the whole workspace).
macro_rules! dispatch {
    ($kernel:ident($($arg:expr),* $(,)?)) => {{
        #[cfg(target_arch = "x86_64")]
        {
            match mbpo_nn::simd::simd_level() {
                // SAFETY: `simd_level` returns a level only on a CPU that supports it.
                mbpo_nn::simd::SimdLevel::Avx512 => unsafe {
                    $crate::simd::avx512::$kernel($($arg),*)
                },
                // SAFETY: as above.
                mbpo_nn::simd::SimdLevel::Avx2 => unsafe { $crate::simd::avx2::$kernel($($arg),*) },
                mbpo_nn::simd::SimdLevel::Baseline => $crate::simd::$kernel($($arg),*),
            }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            $crate::simd::$kernel($($arg),*)
        }
    }};
}
pub(crate) use dispatch;

// The shared vectorisable exp and log1p (one implementation for the whole workspace).
pub use mbpo_nn::math::{exp_neg_f32, log1p_unit};

/// Declares each kernel's AVX2+FMA twin in `mod avx2` and its AVX-512F twin in `mod avx512`,
/// both forwarding to the inline body.
macro_rules! simd_twins {
    ($(fn $name:ident($($arg:ident: $ty:ty),* $(,)?) $(-> $ret:ty)?;)*) => {
        #[cfg(target_arch = "x86_64")]
        pub(crate) mod avx2 {
            #[allow(unused_imports)]
            use super::*;
            $(
                #[target_feature(enable = "avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                pub(crate) unsafe fn $name($($arg: $ty),*) $(-> $ret)? {
                    super::$name($($arg),*)
                }
            )*
        }
        #[cfg(target_arch = "x86_64")]
        pub(crate) mod avx512 {
            #[allow(unused_imports)]
            use super::*;
            $(
                #[target_feature(enable = "avx512f,avx2,fma")]
                #[allow(clippy::too_many_arguments)]
                pub(crate) unsafe fn $name($($arg: $ty),*) $(-> $ret)? {
                    super::$name($($arg),*)
                }
            )*
        }
    };
}

simd_twins! {
    fn bias_silu(z: &mut [f32], sig: Option<&mut [f32]>, bias: &[f32]);
    fn silu_backward_bias_grad(g: &mut [f32], a: &[f32], sig: &[f32], db: &mut [f32]);
    fn add_bias(y: &mut [f32], bias: &[f32]);
    fn standardize_tiled(x: &mut [f32], mean_tile: &[f32], std_tile: &[f32]);
    fn gaussian_head(y: &mut [f32], bias: &[f32], max_lv: &[f32], min_lv: &[f32]);
    fn gaussian_nll_rows(
        y: &mut [f32],
        target: &[f32],
        bias: &[f32],
        bounds: &LogvarBounds,
        scale: f32,
        acc: &mut NllAccumulators,
    ) -> f64;
    fn sample_gaussian_rows(out: &mut [f32], eps: &[f32], d: usize);
    fn box_muller(bits: &[u32; NORMAL_BLOCK], out: &mut [f32; NORMAL_BLOCK]);
}

/// ln x for finite x > 0, branch-free (Cephes `logf`): x = m·2^e with m in [√½, √2), a
/// degree-9 polynomial in m − 1. Absolute error below 1e-7 on [2^-24, 1] (tested).
#[inline(always)]
pub fn ln_f32(x: f32) -> f32 {
    let bits = x.to_bits();
    let mut e = ((bits >> 23) & 0xff) as i32 - 127;
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000); // [1, 2)
                                                                    // Move m into [√½, √2) so the polynomial's argument is small.
    let big = m > std::f32::consts::SQRT_2;
    m = if big { m * 0.5 } else { m };
    e += big as i32;
    let e = e as f32;
    let f = m - 1.0;
    let z = f * f;
    let mut p = 7.037_683_6e-2f32;
    p = p.mul_add(f, -1.151_461e-1);
    p = p.mul_add(f, 1.167_699_9e-1);
    p = p.mul_add(f, -1.242_014_1e-1);
    p = p.mul_add(f, 1.424_932_3e-1);
    p = p.mul_add(f, -1.666_805_8e-1);
    p = p.mul_add(f, 2.000_071_4e-1);
    p = p.mul_add(f, -2.499_999_4e-1);
    p = p.mul_add(f, 3.333_333e-1);
    let y = (p * f * z).mul_add(1.0, e.mul_add(-2.121_944_4e-4, -0.5 * z));
    e.mul_add(0.693_359_4, f + y)
}

/// sin(πx) and cos(πx) for |x| ≤ 1/2 (Taylor polynomials in (πx)², degree 11 and 12; absolute
/// error below 1e-6, tested).
#[inline(always)]
fn sin_cos_pi_half(x: f32) -> (f32, f32) {
    let a = x * std::f32::consts::PI;
    let a2 = a * a;
    let mut s = -1.0f32 / 39_916_800.0;
    s = s.mul_add(a2, 1.0 / 362_880.0);
    s = s.mul_add(a2, -1.0 / 5040.0);
    s = s.mul_add(a2, 1.0 / 120.0);
    s = s.mul_add(a2, -1.0 / 6.0);
    s = s.mul_add(a2, 1.0);
    let mut c = 1.0f32 / 479_001_600.0;
    c = c.mul_add(a2, -1.0 / 3_628_800.0);
    c = c.mul_add(a2, 1.0 / 40_320.0);
    c = c.mul_add(a2, -1.0 / 720.0);
    c = c.mul_add(a2, 1.0 / 24.0);
    c = c.mul_add(a2, -0.5);
    c = c.mul_add(a2, 1.0);
    (a * s, c)
}

/// Normals produced per [`box_muller`] call.
pub(crate) const NORMAL_BLOCK: usize = 64;

/// Standard normals from random bits by the Box-Muller transform, vectorised: pair i turns
/// `u1 = (bits[i] >> 8 + 1)·2^-24 ∈ (0, 1]` and `u2 = (bits[32 + i] >> 8)·2^-24 ∈ [0, 1)` into
/// `out[i] = r·cos θ` and `out[32 + i] = r·sin θ` with `r = √(−2 ln u1)`, `θ = 2π·u2`.
///
/// With 24-bit uniforms the largest |z| is √(2·24·ln 2) ≈ 5.77 (P(|z| > 5.77) ≈ 8e-9 for a true
/// normal), which is immaterial for model rollouts.
#[inline(always)]
pub(crate) fn box_muller(bits: &[u32; NORMAL_BLOCK], out: &mut [f32; NORMAL_BLOCK]) {
    const HALF: usize = NORMAL_BLOCK / 2;
    const SCALE: f32 = 1.0 / (1u32 << 24) as f32;
    let mut r = [0.0f32; HALF];
    let mut sin = [0.0f32; HALF];
    let mut cos = [0.0f32; HALF];
    for i in 0..HALF {
        let u1 = ((bits[i] >> 8) + 1) as f32 * SCALE;
        r[i] = (-2.0 * ln_f32(u1)).sqrt();
        // θ = 2π·u2 = π·x with x = 2·u2 − 1 ∈ [−1, 1) shifted by π, i.e. (cos, sin)(θ) =
        // −(cos, sin)(πx); fold |x| > ½ back with sin(π − φ) = sin φ, cos(π − φ) = −cos φ.
        let x = ((bits[HALF + i] >> 8) as f32).mul_add(2.0 * SCALE, -1.0);
        let fold = x.abs() > 0.5;
        let xf = if fold { x.signum() - x } else { x };
        let (s, c) = sin_cos_pi_half(xf);
        sin[i] = -s;
        cos[i] = if fold { c } else { -c };
    }
    for i in 0..HALF {
        out[i] = r[i] * cos[i];
        out[HALF + i] = r[i] * sin[i];
    }
}

/// Fill `out` with standard normals from `rng` ([`box_muller`] on blocks of
/// [`NORMAL_BLOCK`]; a partial last block still consumes a whole block of bits).
pub(crate) fn fill_standard_normal(rng: &mut mbpo_core::Rng, out: &mut [f32]) {
    use rand::RngCore;
    let mut bits = [0u32; NORMAL_BLOCK];
    let mut block = [0.0f32; NORMAL_BLOCK];
    for chunk in out.chunks_mut(NORMAL_BLOCK) {
        for pair in bits.chunks_exact_mut(2) {
            let v = rng.next_u64();
            pair[0] = v as u32;
            pair[1] = (v >> 32) as u32;
        }
        dispatch!(box_muller(&bits, &mut block));
        chunk.copy_from_slice(&block[..chunk.len()]);
    }
}

/// softplus(x) = ln(1 + eˣ) and σ(x) = 1/(1 + e⁻ˣ) from one exp: with t = e^(−|x|),
/// softplus(x) = max(x, 0) + ln(1 + t) and σ(x) = 1/(1+t) for x ≥ 0, t/(1+t) otherwise.
///
/// `ln(1 + t)` is [`log1p_unit`], accurate when t is tiny.
#[inline(always)]
pub fn softplus_sigmoid(x: f32) -> (f32, f32) {
    let t = exp_neg_f32(x.abs());
    let log1p = log1p_unit(t);
    let r = 1.0 / (1.0 + t);
    let sig = if x >= 0.0 { r } else { t * r };
    (x.max(0.0) + log1p, sig)
}

/// Hidden-layer epilogue, in place on `z` (`rows x n`): z ← z + b, then a = z·σ(z) replaces z
/// and σ(z) goes to `sig` when given (the backward pass needs it; inference does not).
#[inline(always)]
pub(crate) fn bias_silu(z: &mut [f32], sig: Option<&mut [f32]>, bias: &[f32]) {
    let n = bias.len();
    match sig {
        Some(sig) => {
            for (zr, sr) in z.chunks_exact_mut(n).zip(sig.chunks_exact_mut(n)) {
                for ((zv, sv), &b) in zr.iter_mut().zip(sr.iter_mut()).zip(bias) {
                    let x = *zv + b;
                    let s = 1.0 / (1.0 + exp_neg_f32(x));
                    *sv = s;
                    *zv = x * s;
                }
            }
        }
        None => {
            for zr in z.chunks_exact_mut(n) {
                for (zv, &b) in zr.iter_mut().zip(bias) {
                    let x = *zv + b;
                    *zv = x / (1.0 + exp_neg_f32(x));
                }
            }
        }
    }
}

/// SiLU backward, in place on `g` (`rows x n`): ∂L/∂z = ∂L/∂a · (σ + a(1 − σ)) (the derivative
/// of z·σ(z) written with what the forward pass kept), and ∂L/∂b = Σ_rows ∂L/∂z into `db`.
#[inline(always)]
pub(crate) fn silu_backward_bias_grad(g: &mut [f32], a: &[f32], sig: &[f32], db: &mut [f32]) {
    let n = db.len();
    db.fill(0.0);
    for ((gr, ar), sr) in g
        .chunks_exact_mut(n)
        .zip(a.chunks_exact(n))
        .zip(sig.chunks_exact(n))
    {
        for (((gv, &av), &sv), d) in gr.iter_mut().zip(ar).zip(sr).zip(db.iter_mut()) {
            let dz = *gv * (sv + av * (1.0 - sv));
            *gv = dz;
            *d += dz;
        }
    }
}

/// x ← (x − mean)/std over rows of width w, with `mean_tile`/`std_tile` the w parameters
/// repeated 8 times: blocks of 8 rows line up with the tiles, so the loop is a plain vectorised
/// element-wise pass (the last, partial block uses a prefix of the tiles).
#[inline(always)]
pub(crate) fn standardize_tiled(x: &mut [f32], mean_tile: &[f32], std_tile: &[f32]) {
    for block in x.chunks_mut(mean_tile.len()) {
        for ((v, &m), &s) in block.iter_mut().zip(mean_tile).zip(std_tile) {
            *v = (*v - m) / s;
        }
    }
}

/// y ← y + b on every row.
#[inline(always)]
pub(crate) fn add_bias(y: &mut [f32], bias: &[f32]) {
    for row in y.chunks_exact_mut(bias.len()) {
        row.iter_mut().zip(bias).for_each(|(v, &b)| *v += b);
    }
}

/// The soft log-variance bound of one output (PETS/MBPO):
/// `u = max − softplus(max − raw)`, then `logvar = min + softplus(u − min)`.
#[inline(always)]
pub fn bounded_logvar(raw: f32, max_lv: f32, min_lv: f32) -> f32 {
    let u = max_lv - softplus_sigmoid(max_lv - raw).0;
    min_lv + softplus_sigmoid(u - min_lv).0
}

/// Output-layer epilogue for inference, in place on `y` (`rows x 2d`, rows `[μ | raw]` without
/// bias): μ ← μ + b, raw ← bounded logvar of raw + b.
///
/// The d log-variances of a row are done in blocks of 8 (one AVX2 vector) so the two softplus
/// evaluations vectorise fully; when 8 does not divide d, the last block overlaps the previous
/// one, and is computed first from the untouched inputs and stored last, so every element is
/// still computed once from its own input.
#[inline(always)]
pub(crate) fn gaussian_head(y: &mut [f32], bias: &[f32], max_lv: &[f32], min_lv: &[f32]) {
    let d = max_lv.len();
    let (b_mu, b_raw) = (&bias[..d], &bias[d..2 * d]);
    let min_lv = &min_lv[..d];
    for row in y.chunks_exact_mut(2 * d) {
        let (mu, raw) = row.split_at_mut(d);
        mu.iter_mut().zip(b_mu).for_each(|(m, &b)| *m += b);
        if d < 8 {
            for j in 0..d {
                raw[j] = bounded_logvar(raw[j] + b_raw[j], max_lv[j], min_lv[j]);
            }
            continue;
        }
        let last = d - 8;
        let tail = logvar_block(raw, b_raw, max_lv, min_lv, last);
        let mut at = 0;
        while at < last {
            let out = logvar_block(raw, b_raw, max_lv, min_lv, at);
            raw[at..at + 8].copy_from_slice(&out);
            at += 8;
        }
        raw[last..].copy_from_slice(&tail);
    }
}

/// Bounded log-variances of the 8 outputs `at..at + 8` (a function, not a closure: closures are
/// not compiled with the caller's target features unless inlined, and this must be).
#[inline(always)]
fn logvar_block(raw: &[f32], b_raw: &[f32], max_lv: &[f32], min_lv: &[f32], at: usize) -> [f32; 8] {
    let (raw, b_raw) = (&raw[at..at + 8], &b_raw[at..at + 8]);
    let (max_lv, min_lv) = (&max_lv[at..at + 8], &min_lv[at..at + 8]);
    let mut out = [0.0f32; 8];
    for l in 0..8 {
        out[l] = bounded_logvar(raw[l] + b_raw[l], max_lv[l], min_lv[l]);
    }
    out
}

/// The learned log-variance bounds, one per output dimension.
#[derive(Debug, Clone, Copy)]
pub(crate) struct LogvarBounds<'a> {
    /// Upper soft bound `max_logvar`.
    pub max: &'a [f32],
    /// Lower soft bound `min_logvar`.
    pub min: &'a [f32],
}

/// Column accumulators of one member's loss pass (each of length d, or 2d for `db`).
#[derive(Debug)]
pub(crate) struct NllAccumulators<'a> {
    /// ∂L/∂b of the output layer (`2d`: mean part then raw-logvar part).
    pub db: &'a mut [f32],
    /// ∂L/∂max_logvar, accumulated.
    pub d_max: &'a mut [f32],
    /// ∂L/∂min_logvar, accumulated.
    pub d_min: &'a mut [f32],
    /// Scratch of length d.
    pub scratch: &'a mut [f32],
}

/// The Gaussian NLL of one member and its gradient, in one pass over the output rows.
///
/// `y` holds the output layer's `X W` (no bias) as rows `[μ (d) | raw logvar (d)]`; on return it
/// holds `∂L/∂(XW)` for the same rows. With `lv` the bounded log-variance and `scale = 1/(B·d)`:
///
/// ```text
/// L      = scale · Σ (μ − y)²·e^(−lv) + lv
/// ∂L/∂μ  = scale · 2(μ − y)·e^(−lv)
/// ∂L/∂lv = scale · (1 − (μ − y)²·e^(−lv))
/// ∂lv/∂raw = σ(u − min)·σ(max − raw),  ∂lv/∂max = σ(u − min)·(1 − σ(max − raw)),
/// ∂lv/∂min = 1 − σ(u − min)
/// ```
///
/// (softplus' = σ). Bias and bound gradients are summed into `acc`; returns the loss.
///
/// Every per-dimension slice is cut to exactly d first, so the inner loop has no bounds checks
/// and vectorises across the d dimensions of a row; the loss is summed per dimension in f32 and
/// the d column sums are added in f64 at the end.
#[inline(always)]
pub(crate) fn gaussian_nll_rows(
    y: &mut [f32],
    target: &[f32],
    bias: &[f32],
    bounds: &LogvarBounds,
    scale: f32,
    acc: &mut NllAccumulators,
) -> f64 {
    let d = bounds.max.len();
    let (max_lv, min_lv) = (&bounds.max[..d], &bounds.min[..d]);
    let (b_mu, b_raw) = (&bias[..d], &bias[d..2 * d]);
    let (db_mu, db_raw) = acc.db[..2 * d].split_at_mut(d);
    let (d_max, d_min) = (&mut acc.d_max[..d], &mut acc.d_min[..d]);
    let col_loss = &mut acc.scratch[..d];
    db_mu.fill(0.0);
    db_raw.fill(0.0);
    col_loss.fill(0.0);
    for (row, t) in y.chunks_exact_mut(2 * d).zip(target.chunks_exact(d)) {
        let (mu, raw) = row.split_at_mut(d);
        let t = &t[..d];
        for j in 0..d {
            let r = raw[j] + b_raw[j];
            let (sp_hi, s_hi) = softplus_sigmoid(max_lv[j] - r);
            let u = max_lv[j] - sp_hi;
            let (sp_lo, s_lo) = softplus_sigmoid(u - min_lv[j]);
            let lv = min_lv[j] + sp_lo;
            let inv_var = exp_neg_f32(lv);
            let err = mu[j] + b_mu[j] - t[j];
            let e2 = err * err * inv_var;
            col_loss[j] += e2 + lv;
            let g_lv = scale * (1.0 - e2);
            let g_mu = scale * 2.0 * err * inv_var;
            let g_raw = g_lv * s_lo * s_hi;
            mu[j] = g_mu;
            raw[j] = g_raw;
            d_max[j] += g_lv * s_lo * (1.0 - s_hi);
            d_min[j] += g_lv * (1.0 - s_lo);
            db_mu[j] += g_mu;
            db_raw[j] += g_raw;
        }
    }
    col_loss.iter().map(|&v| v as f64).sum::<f64>() * scale as f64
}

/// Sampling epilogue, in place on `out` (`rows x 2d`, rows `[μ | logvar]` with bias and bounds
/// already applied): the first d values of each row become μ + e^(lv/2)·ε with ε from `eps`
/// (`rows x d`).
#[inline(always)]
pub(crate) fn sample_gaussian_rows(out: &mut [f32], eps: &[f32], d: usize) {
    for (row, e) in out.chunks_exact_mut(2 * d).zip(eps.chunks_exact(d)) {
        let (mu, lv) = row.split_at_mut(d);
        for ((m, &l), &z) in mu.iter_mut().zip(lv.iter()).zip(e) {
            *m += exp_neg_f32(-0.5 * l) * z;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ln_is_accurate_on_the_uniform_range() {
        let mut worst = 0.0f64;
        let mut x = 1.0f32 / (1u32 << 24) as f32;
        while x <= 1.0 {
            worst = worst.max((ln_f32(x) as f64 - (x as f64).ln()).abs());
            x *= 1.000_3;
        }
        assert!(worst < 1e-6, "worst absolute error {worst}");
        assert_eq!(ln_f32(1.0), 0.0);
    }

    #[test]
    fn sin_cos_are_accurate() {
        for i in -500..=500 {
            let x = i as f32 / 1000.0;
            let (s, c) = sin_cos_pi_half(x);
            let a = x as f64 * std::f64::consts::PI;
            assert!(
                (s as f64 - a.sin()).abs() < 1e-6 && (c as f64 - a.cos()).abs() < 1e-6,
                "{x}"
            );
        }
    }

    #[test]
    fn box_muller_gives_standard_normals() {
        use rand::RngCore;
        let mut rng = mbpo_core::stream(0, "bm", 0);
        let (mut bits, mut out) = ([0u32; NORMAL_BLOCK], [0.0f32; NORMAL_BLOCK]);
        let mut moments = [0.0f64; 5];
        let mut tail = 0usize;
        let blocks = 20_000;
        for _ in 0..blocks {
            bits.iter_mut().for_each(|b| *b = rng.next_u32());
            dispatch!(box_muller(&bits, &mut out));
            for &z in &out {
                let z = z as f64;
                moments[0] += 1.0;
                moments[1] += z;
                moments[2] += z * z;
                moments[3] += z * z * z;
                moments[4] += z * z * z * z;
                tail += (z.abs() > 1.959_964) as usize;
            }
        }
        let n = moments[0];
        let (m1, m2, m3, m4) = (
            moments[1] / n,
            moments[2] / n,
            moments[3] / n,
            moments[4] / n,
        );
        assert!(
            m1.abs() < 0.005 && (m2 - 1.0).abs() < 0.01,
            "mean {m1}, var {m2}"
        );
        assert!(
            m3.abs() < 0.02 && (m4 - 3.0).abs() < 0.05,
            "skew {m3}, kurtosis {m4}"
        );
        let p = tail as f64 / n;
        assert!((p - 0.05).abs() < 0.002, "P(|z| > 1.96) = {p}");
    }

    #[test]
    fn softplus_and_sigmoid_match_f64_including_extremes() {
        for &x in &[
            -100.0f32, -30.0, -5.0, -1e-3, 0.0, 1e-3, 0.7, 5.0, 30.0, 100.0,
        ] {
            let (sp, s) = softplus_sigmoid(x);
            let xd = x as f64;
            let want_sp = xd.max(0.0) + (-xd.abs()).exp().ln_1p();
            let want_s = 1.0 / (1.0 + (-xd).exp());
            let err = (sp as f64 - want_sp).abs();
            assert!(
                err <= 1e-6 * want_sp.max(1.0),
                "softplus({x}) = {sp}, want {want_sp}"
            );
            if x > -80.0 {
                assert!(err <= 1e-6 * want_sp, "softplus({x}) relative");
            }
            assert!((s as f64 - want_s).abs() < 1e-6, "sigmoid({x})");
        }
    }

    /// Which compiled copy of the kernels a test calls.
    #[derive(Debug, Clone, Copy)]
    enum Copy {
        Baseline,
        #[cfg(target_arch = "x86_64")]
        Avx2,
        #[cfg(target_arch = "x86_64")]
        Avx512,
    }

    /// A hidden layer's bias + SiLU and its backward pass, then the Gaussian NLL pass, through
    /// one compiled copy; every output they write.
    fn hot_kernels(copy: Copy) -> Vec<Vec<f64>> {
        let (rows, width, d) = (5, 200, 12);
        let wave = |n: usize, f: f32, a: f32| -> Vec<f32> {
            (0..n).map(|i| (i as f32 * f).sin() * a).collect()
        };
        let (mut z, bias) = (wave(rows * width, 0.77, 6.0), wave(width, 0.31, 0.5));
        let (mut sig, mut g, mut db) = (
            vec![0.0; rows * width],
            wave(rows * width, 0.13, 1.0),
            vec![0.0; width],
        );
        let (mut y, target, out_bias) = (
            wave(rows * 2 * d, 0.53, 3.0),
            wave(rows * d, 0.29, 2.0),
            wave(2 * d, 0.41, 0.2),
        );
        let (max, min) = (vec![0.5; d], vec![-10.0; d]);
        let (mut ndb, mut d_max, mut d_min, mut scratch) =
            (vec![0.0; 2 * d], vec![0.0; d], vec![0.0; d], vec![0.0; d]);
        let mut acc = NllAccumulators {
            db: &mut ndb,
            d_max: &mut d_max,
            d_min: &mut d_min,
            scratch: &mut scratch,
        };
        let bounds = LogvarBounds {
            max: &max,
            min: &min,
        };
        // SAFETY: the test calls a copy only on a CPU with its features.
        let loss = unsafe {
            match copy {
                Copy::Baseline => {
                    bias_silu(&mut z, Some(&mut sig), &bias);
                    silu_backward_bias_grad(&mut g, &z, &sig, &mut db);
                    gaussian_nll_rows(&mut y, &target, &out_bias, &bounds, 0.01, &mut acc)
                }
                #[cfg(target_arch = "x86_64")]
                Copy::Avx2 => {
                    avx2::bias_silu(&mut z, Some(&mut sig), &bias);
                    avx2::silu_backward_bias_grad(&mut g, &z, &sig, &mut db);
                    avx2::gaussian_nll_rows(&mut y, &target, &out_bias, &bounds, 0.01, &mut acc)
                }
                #[cfg(target_arch = "x86_64")]
                Copy::Avx512 => {
                    avx512::bias_silu(&mut z, Some(&mut sig), &bias);
                    avx512::silu_backward_bias_grad(&mut g, &z, &sig, &mut db);
                    avx512::gaussian_nll_rows(&mut y, &target, &out_bias, &bounds, 0.01, &mut acc)
                }
            }
        };
        let wide = |v: &[f32]| v.iter().map(|&x| x as f64).collect::<Vec<_>>();
        vec![
            wide(&z),
            wide(&sig),
            wide(&g),
            wide(&db),
            wide(&y),
            wide(&ndb),
            wide(&d_max),
            wide(&d_min),
            vec![loss],
        ]
    }

    /// Every compiled copy of the hot kernels (baseline, AVX2+FMA, AVX-512F) gives the same
    /// bits: what a run computes must not depend on the CPU it lands on.
    #[test]
    fn every_compiled_copy_of_the_kernels_agrees_bit_for_bit() {
        let bits = |outs: Vec<Vec<f64>>| -> Vec<Vec<u64>> {
            outs.iter()
                .map(|v| v.iter().map(|x| x.to_bits()).collect())
                .collect()
        };
        let want = bits(hot_kernels(Copy::Baseline));
        #[cfg(target_arch = "x86_64")]
        {
            use mbpo_nn::simd::SimdLevel;
            if SimdLevel::Avx2.supported() {
                assert!(
                    bits(hot_kernels(Copy::Avx2)) == want,
                    "AVX2+FMA copy differs"
                );
            }
            if SimdLevel::Avx512.supported() {
                assert!(
                    bits(hot_kernels(Copy::Avx512)) == want,
                    "AVX-512F copy differs"
                );
            }
        }
    }
}
