//! NumPy's summation order, so sums over arrays round exactly as `np.sum` does.
//!
//! Gymnasium's MuJoCo rewards contain `np.sum(np.square(action))` (float32) and
//! `np.sum(np.square(np.clip(cfrc_ext, -1, 1)))` (float64). Floating-point addition is not
//! associative, so a plain left-to-right loop can differ from NumPy in the last bit. NumPy reduces
//! contiguous float arrays with pairwise summation (`numpy/_core/src/umath/loops_utils.h.src`,
//! `pairwise_sum`):
//!
//! - fewer than 8 values: a sequential sum starting from −0.0;
//! - up to 128 values: eight running partial sums `r[j] += a[i + j]` over whole blocks of 8, then
//!   `((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))`, then the leftover values one by one;
//! - more: split at `n/2` rounded down to a multiple of 8 and add the two halves' sums.

/// `np.sum(a)` for a contiguous float32 or float64 array `a`.
pub fn pairwise_sum<T>(a: &[T]) -> T
where
    T: Copy + std::ops::Add<Output = T> + std::ops::Neg<Output = T> + Default,
{
    const BLOCK: usize = 128;
    let n = a.len();
    if n < 8 {
        // -0.0 (a negated zero) keeps np.sum([-0.0]) == -0.0.
        let mut res = -T::default();
        for &x in a {
            res = res + x;
        }
        res
    } else if n <= BLOCK {
        let mut r = [T::default(); 8];
        r.copy_from_slice(&a[..8]);
        let whole = n - n % 8;
        let mut i = 8;
        while i < whole {
            for (j, rj) in r.iter_mut().enumerate() {
                *rj = *rj + a[i + j];
            }
            i += 8;
        }
        let mut res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        for &x in &a[whole..] {
            res = res + x;
        }
        res
    } else {
        let mut half = n / 2;
        half -= half % 8;
        pairwise_sum(&a[..half]) + pairwise_sum(&a[half..])
    }
}

/// `np.sum(np.square(a))` for a float32 action: squares and sum in float32, as NumPy does.
/// At most 16 values (the largest action here is Ant's 8), so the squares live on the stack.
pub fn sum_of_squares_f32(a: &[f32]) -> f32 {
    let mut sq = [0.0f32; 16];
    assert!(a.len() <= sq.len(), "at most 16 values, got {}", a.len());
    for (s, &x) in sq.iter_mut().zip(a) {
        *s = x * x;
    }
    pairwise_sum(&sq[..a.len()])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn short_sums_are_sequential_from_negative_zero() {
        assert_eq!(pairwise_sum::<f64>(&[]).to_bits(), (-0.0f64).to_bits());
        assert_eq!(pairwise_sum(&[-0.0f64]).to_bits(), (-0.0f64).to_bits());
        // (1e16 + 1) + 1 loses both ones in sequence; a different order would keep them.
        assert_eq!(pairwise_sum(&[1e16f64, 1.0, 1.0]), 1e16);
    }

    #[test]
    fn blocks_of_eight_use_eight_partial_sums() {
        // 16 values: r[j] = a[j] + a[8 + j]; a sequential sum would give a different rounding.
        let mut a = [1.0f32; 16];
        a[0] = 1e8;
        a[8] = -1e8;
        // r0 = 1e8 + -1e8 = 0, r1..r7 = 2: total 14. Sequential: 1e8 + 1 + ... loses the ones.
        assert_eq!(pairwise_sum(&a), 14.0);
        let sequential = a.iter().fold(-0.0f32, |s, &x| s + x);
        assert_ne!(sequential, 14.0);
        // Leftovers (n = 11) are added one by one after the tree.
        let b: Vec<f64> = (0..11).map(|i| i as f64 * 0.1).collect();
        let r: Vec<f64> = (0..8).map(|j| b[j]).collect();
        let tree = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]));
        assert_eq!(pairwise_sum(&b), tree + b[8] + b[9] + b[10]);
    }

    #[test]
    fn long_sums_split_at_a_multiple_of_eight() {
        let a: Vec<f64> = (0..300).map(|i| 1.0 / (i as f64 + 1.0)).collect();
        // n = 300: half = 150 -> 144.
        assert_eq!(
            pairwise_sum(&a),
            pairwise_sum(&a[..144]) + pairwise_sum(&a[144..])
        );
    }

    #[test]
    fn sum_of_squares_is_float32() {
        let a = [0.1f32, -0.7, 0.33, 1.0, -1.0, 0.25, 0.5, 0.9];
        let sq: Vec<f32> = a.iter().map(|x| x * x).collect();
        assert_eq!(sum_of_squares_f32(&a), pairwise_sum(&sq));
        assert_eq!(sum_of_squares_f32(&[3.0]), 9.0);
    }
}
