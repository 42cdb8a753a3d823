//! Forward products in bf16 on Intel AMX, for inference where a product's rounding is noise
//! next to what it is used for (a planner scoring hundreds of sampled action sequences).
//!
//! AMX's `TDPBF16PS` multiplies a 16 x 32 tile of bf16 by a 32 x 16 one and adds the products
//! into a 16 x 16 tile of f32 sums: 16,384 flops per instruction, several times what f32
//! AVX-512 FMAs give a core (`mbpo bench gemm` prints both where the CPU has AMX; figures in
//! results/measurements.md, 2026-12-06). The inputs are rounded to bf16 (8 significant bits, the f32
//! exponent range); every sum is f32.
//!
//! Layouts: the weights `W` (`k x n`, row-major f32) are packed once per parameter change into
//! [`PackedBf16`]: blocks of 32 output columns, each a run of `k / 32` pairs of tiles, a tile
//! being 16 rows of (two consecutive `k`) x 16 columns -- the "VNNI" pairing `TDPBF16PS` reads.
//! The rows `A` are converted per product into [`Bf16Scratch`], padded with zeros to multiples
//! of 32 rows and 32 columns. Each 32 x 32 block of `C` is four accumulator tiles
//! (`tmm0..tmm3`) fed by two row tiles of `A` (`tmm4`, `tmm5`) and two column tiles of `W`
//! (`tmm6`, `tmm7`).
//!
//! Using AMX needs the CPU's `amx_tile` and `amx_bf16` and the kernel's leave (Linux 5.16+:
//! `arch_prctl(ARCH_REQ_XCOMP_PERM, XTILEDATA)`, asked once per process by [`available`]).
//! Elsewhere [`available`] says no and callers keep f32.

/// Rows and columns of a block of `C`, and the depth of one tile step.
const BLOCK: usize = 32;

/// `n` rounded up to a multiple of [`BLOCK`].
fn padded(n: usize) -> usize {
    n.div_ceil(BLOCK) * BLOCK
}

/// f32 → bf16, rounding to nearest even (no NaNs reach here: a network's weights and
/// activations are finite, and the planner checks its values).
#[inline(always)]
fn to_bf16(x: f32) -> u16 {
    let bits = x.to_bits();
    (bits.wrapping_add(0x7fff + ((bits >> 16) & 1)) >> 16) as u16
}

/// bf16 → f32 (exact).
#[inline(always)]
pub fn from_bf16(h: u16) -> f32 {
    f32::from_bits((h as u32) << 16)
}

/// `x` rounded to bf16 and back: what an AMX product sees of an input.
pub fn round_to_bf16(x: f32) -> f32 {
    from_bf16(to_bf16(x))
}

/// A weight matrix `k x n` in AMX's tile layout (see the module docs).
#[derive(Debug, Clone)]
pub struct PackedBf16 {
    k: usize,
    n: usize,
    tiles: Vec<u16>,
}

impl PackedBf16 {
    /// Room for a `k x n` matrix (all zeros until [`PackedBf16::pack`]).
    pub fn new(k: usize, n: usize) -> Self {
        Self {
            k,
            n,
            tiles: vec![0; padded(k) * padded(n)],
        }
    }

    /// Rows of the matrix (the product's depth).
    pub fn k(&self) -> usize {
        self.k
    }

    /// Columns of the matrix (the product's output width).
    pub fn n(&self) -> usize {
        self.n
    }

    /// Packs the row-major `w` (`k x n`), rounding to bf16; no allocation.
    pub fn pack(&mut self, w: &[f32]) {
        let (k, n) = (self.k, self.n);
        assert_eq!(w.len(), k * n, "a {k} x {n} matrix");
        let k_blocks = padded(k) / BLOCK;
        let mut out = self.tiles.iter_mut();
        for col_block in 0..padded(n) / BLOCK {
            for k_block in 0..k_blocks {
                for half in 0..2 {
                    for pair in 0..BLOCK / 2 {
                        for col in 0..16 {
                            let j = col_block * BLOCK + half * 16 + col;
                            for e in 0..2 {
                                let i = k_block * BLOCK + 2 * pair + e;
                                let v = match i < k && j < n {
                                    true => to_bf16(w[i * n + j]),
                                    false => 0,
                                };
                                *out.next().expect("sized for the padded matrix") = v;
                            }
                        }
                    }
                }
            }
        }
    }
}

/// The rows of `A` in bf16 and, for outputs that are not whole blocks, a padded `C`; sized
/// once for the largest product a network makes.
#[derive(Debug, Clone)]
pub struct Bf16Scratch {
    a: Vec<u16>,
    c: Vec<f32>,
}

impl Bf16Scratch {
    /// Room for products of up to `rows` rows, depth `k` and width `n`.
    pub fn new(rows: usize, k: usize, n: usize) -> Self {
        Self {
            a: vec![0; padded(rows) * padded(k)],
            c: vec![0.0; padded(rows) * padded(n)],
        }
    }
}

/// Whether this CPU and kernel run AMX bf16 products (asks the kernel's leave on first call).
pub fn available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        static GRANTED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
        *GRANTED.get_or_init(amx::request)
    }
    #[cfg(not(target_arch = "x86_64"))]
    false
}

/// `C = A W` for `m` rows of `a` (`m x w.k()`, row-major) into `c` (`m x w.n()`), through
/// bf16 inputs and f32 sums. No allocation.
///
/// # Panics
/// If [`available`] is false, or a slice or the scratch is smaller than the shapes need.
pub fn gemm_bf16(c: &mut [f32], a: &[f32], m: usize, w: &PackedBf16, scratch: &mut Bf16Scratch) {
    assert!(available(), "AMX bf16 products need amx_tile and amx_bf16");
    let (k, n) = (w.k, w.n);
    if m == 0 {
        return;
    }
    let (m_pad, k_pad, n_pad) = (padded(m), padded(k), padded(n));
    assert!(
        a.len() >= m * k && c.len() >= m * n,
        "slices fit the shapes"
    );
    assert!(
        scratch.a.len() >= m_pad * k_pad && scratch.c.len() >= m_pad * n_pad,
        "scratch sized for {m} x {k} x {n}"
    );
    let rows = &mut scratch.a[..m_pad * k_pad];
    for (r, row) in rows.chunks_exact_mut(k_pad).enumerate() {
        match r < m {
            true => convert_row(&a[r * k..(r + 1) * k], row),
            false => row.fill(0),
        }
    }
    // Whole blocks are stored straight into `c`; anything else through the padded scratch.
    let direct = m == m_pad && n == n_pad;
    #[cfg(target_arch = "x86_64")]
    {
        let (out, ldc) = match direct {
            true => (&mut c[..m * n], n),
            false => (&mut scratch.c[..m_pad * n_pad], n_pad),
        };
        // SAFETY: `available` checked the CPU and the kernel's leave; the slices hold the
        // padded shapes (asserted above).
        unsafe { amx::product(out, ldc, rows, k_pad, m_pad / BLOCK, w) };
    }
    if !direct {
        for (dst, src) in c[..m * n].chunks_exact_mut(n).zip(scratch.c.chunks(n_pad)) {
            dst.copy_from_slice(&src[..n]);
        }
    }
}

/// One row of `A` into bf16, zeros after its `k` values.
fn convert_row(src: &[f32], dst: &mut [u16]) {
    let (head, tail) = dst.split_at_mut(src.len());
    head.iter_mut().zip(src).for_each(|(h, &x)| *h = to_bf16(x));
    tail.fill(0);
}

#[cfg(target_arch = "x86_64")]
mod amx {
    use std::arch::asm;

    use super::{PackedBf16, BLOCK};

    /// Linux's `arch_prctl` request for leave to use an extended state component, and AMX's
    /// tile data component.
    const ARCH_REQ_XCOMP_PERM: libc::c_ulong = 0x1023;
    const XFEATURE_XTILEDATA: libc::c_ulong = 18;

    /// The CPU has AMX bf16 and the kernel lets this process use it.
    pub(super) fn request() -> bool {
        // CPUID leaf 7: EDX bit 22 is AMX-BF16, bit 24 AMX-TILE (std's detection of them is
        // not stable). Leaf 7 exists on every CPU with AVX-512, and on others reads as zeros.
        #[allow(unused_unsafe)]
        // SAFETY: CPUID is available on every x86_64 CPU.
        let edx = unsafe { std::arch::x86_64::__cpuid_count(7, 0) }.edx;
        if edx & (1 << 22) == 0 || edx & (1 << 24) == 0 {
            return false;
        }
        // SAFETY: a syscall with integer arguments; it changes only this process's permission.
        let status = unsafe {
            libc::syscall(
                libc::SYS_arch_prctl,
                ARCH_REQ_XCOMP_PERM,
                XFEATURE_XTILEDATA,
            )
        };
        status == 0
    }

    /// The tile configuration `LDTILECFG` reads: palette 1, eight tiles of 16 rows x 64 bytes.
    #[repr(C, align(64))]
    struct TileConfig {
        palette: u8,
        start_row: u8,
        reserved: [u8; 14],
        bytes_per_row: [u16; 16],
        rows: [u8; 16],
    }

    const CONFIG: TileConfig = TileConfig {
        palette: 1,
        start_row: 0,
        reserved: [0; 14],
        bytes_per_row: [64, 64, 64, 64, 64, 64, 64, 64, 0, 0, 0, 0, 0, 0, 0, 0],
        rows: [16, 16, 16, 16, 16, 16, 16, 16, 0, 0, 0, 0, 0, 0, 0, 0],
    };

    /// `C = A W` over `row_blocks` blocks of 32 rows: `a` is bf16 rows `k_pad` wide, `c` has
    /// rows `ldc` floats apart and room for every padded block.
    ///
    /// # Safety
    /// AMX must be available and granted ([`request`]); the slices must hold the padded shapes.
    pub(super) unsafe fn product(
        c: &mut [f32],
        ldc: usize,
        a: &[u16],
        k_pad: usize,
        row_blocks: usize,
        w: &PackedBf16,
    ) {
        let k_blocks = k_pad / BLOCK;
        let col_blocks = w.tiles.len() / (k_pad * BLOCK);
        debug_assert!(a.len() >= row_blocks * BLOCK * k_pad);
        debug_assert!(c.len() >= ((row_blocks - 1) * BLOCK + BLOCK - 1) * ldc + col_blocks * BLOCK);
        asm!("ldtilecfg [{}]", in(reg) &CONFIG, options(nostack, readonly));
        for row_block in 0..row_blocks {
            let a_rows = a.as_ptr().add(row_block * BLOCK * k_pad);
            for col_block in 0..col_blocks {
                let w_tiles = w.tiles.as_ptr().add(col_block * k_blocks * BLOCK * BLOCK);
                let c_block = c
                    .as_mut_ptr()
                    .add(row_block * BLOCK * ldc + col_block * BLOCK);
                block(a_rows, k_pad * 2, w_tiles, k_blocks, c_block, ldc * 4);
            }
        }
        asm!("tilerelease", options(nostack, nomem));
    }

    /// One 32 x 32 block of `C`: four accumulator tiles over `k_blocks` steps of 32, stored
    /// with rows `ldc_bytes` apart. `lda_bytes` is the distance between rows of `A`.
    #[inline(always)]
    unsafe fn block(
        a: *const u16,
        lda_bytes: usize,
        w: *const u16,
        k_blocks: usize,
        c: *mut f32,
        ldc_bytes: usize,
    ) {
        asm!(
            "tilezero tmm0",
            "tilezero tmm1",
            "tilezero tmm2",
            "tilezero tmm3",
            "2:",
            "tileloadd tmm4, [{a0} + {lda}*1]",
            "tileloadd tmm6, [{w} + {ldw}*1]",
            "tileloadd tmm7, [{w} + {ldw}*1 + 1024]",
            "tdpbf16ps tmm0, tmm4, tmm6",
            "tileloadd tmm5, [{a1} + {lda}*1]",
            "tdpbf16ps tmm1, tmm4, tmm7",
            "tdpbf16ps tmm2, tmm5, tmm6",
            "tdpbf16ps tmm3, tmm5, tmm7",
            "add {a0}, 64",
            "add {a1}, 64",
            "add {w}, 2048",
            "dec {steps}",
            "jnz 2b",
            "tilestored [{c0} + {ldc}*1], tmm0",
            "tilestored [{c0} + {ldc}*1 + 64], tmm1",
            "tilestored [{c1} + {ldc}*1], tmm2",
            "tilestored [{c1} + {ldc}*1 + 64], tmm3",
            a0 = inout(reg) a => _,
            a1 = inout(reg) a.byte_add(16 * lda_bytes) => _,
            lda = in(reg) lda_bytes,
            w = inout(reg) w => _,
            ldw = in(reg) 64usize,
            steps = inout(reg) k_blocks => _,
            c0 = in(reg) c,
            c1 = in(reg) c.byte_add(16 * ldc_bytes),
            ldc = in(reg) ldc_bytes,
            options(nostack),
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A deterministic spread of values in [-1, 1).
    fn values(len: usize, seed: u64) -> Vec<f32> {
        let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
        (0..len)
            .map(|_| {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                (s >> 40) as f32 / (1u64 << 23) as f32 - 1.0
            })
            .collect()
    }

    /// The product of the bf16-rounded inputs in f64: what AMX computes up to f32 summation.
    fn rounded_product(a: &[f32], w: &[f32], m: usize, k: usize, n: usize) -> Vec<f64> {
        let mut c = vec![0.0f64; m * n];
        for i in 0..m {
            for p in 0..k {
                let x = round_to_bf16(a[i * k + p]) as f64;
                for j in 0..n {
                    c[i * n + j] += x * round_to_bf16(w[p * n + j]) as f64;
                }
            }
        }
        c
    }

    #[test]
    fn bf16_rounding_is_to_nearest_even() {
        assert_eq!(round_to_bf16(1.0), 1.0);
        // 1 + 2^-8 is halfway between 1 and 1 + 2^-7: ties go to the even mantissa, 1.
        assert_eq!(round_to_bf16(1.0 + 2f32.powi(-8)), 1.0);
        assert_eq!(
            round_to_bf16(1.0 + 3.0 * 2f32.powi(-8)),
            1.0 + 2f32.powi(-6)
        );
        assert_eq!(round_to_bf16(-2.5), -2.5);
        let x = 0.123_456_79f32;
        assert!((round_to_bf16(x) - x).abs() <= x * 2f32.powi(-8));
    }

    #[test]
    fn packed_products_equal_the_rounded_inputs_product_for_whole_and_ragged_shapes() {
        if !available() {
            eprintln!("skipped: this CPU or kernel has no AMX bf16 (the f32 path is used there)");
            return;
        }
        for &(m, k, n) in &[
            (512, 518, 512),
            (24, 128, 512),
            (64, 512, 101),
            (37, 33, 12),
            (1, 7, 3),
        ] {
            let (a, w) = (values(m * k, 1), values(k * n, 2));
            let mut packed = PackedBf16::new(k, n);
            packed.pack(&w);
            let mut scratch = Bf16Scratch::new(m, k, n);
            let mut c = vec![f32::NAN; m * n];
            gemm_bf16(&mut c, &a, m, &packed, &mut scratch);
            let exact = rounded_product(&a, &w, m, k, n);
            for (i, (&got, &want)) in c.iter().zip(&exact).enumerate() {
                // f32 sums of k products of size <= 1: a few ulps of k.
                let tol = 4.0 * k as f64 * f32::EPSILON as f64;
                assert!(
                    (got as f64 - want).abs() <= tol,
                    "{m} x {k} x {n}, element {i}: {got} vs {want}"
                );
            }
        }
    }

    #[test]
    fn a_repack_replaces_every_weight_and_scratch_rows_past_m_are_ignored() {
        if !available() {
            eprintln!("skipped: this CPU or kernel has no AMX bf16");
            return;
        }
        let (m, k, n) = (40, 64, 48);
        let a = values(m * k, 3);
        let mut packed = PackedBf16::new(k, n);
        let mut scratch = Bf16Scratch::new(64, k, n);
        packed.pack(&values(k * n, 4));
        let mut c = vec![0.0; 64 * n];
        gemm_bf16(&mut c, &values(64 * k, 9), 64, &packed, &mut scratch);
        let w = values(k * n, 5);
        packed.pack(&w);
        let mut c = vec![0.0; m * n];
        gemm_bf16(&mut c, &a, m, &packed, &mut scratch);
        let exact = rounded_product(&a, &w, m, k, n);
        for (&got, &want) in c.iter().zip(&exact) {
            assert!((got as f64 - want).abs() <= 1e-4, "{got} vs {want}");
        }
    }
}
