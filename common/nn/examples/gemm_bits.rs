//! Prints one line per GEMM shape and orientation with a hash of the product's bits, so that
//! two machines (or a machine and one QEMU emulates) can be compared with `diff`:
//!
//!     cargo run --release -p mbpo-nn --example gemm_bits > here.txt
//!
//! `tools/compare_aarch64.sh` runs it natively and for AArch64. The operands come from integer
//! arithmetic, not libm, so that they are the same bits everywhere.

use mbpo_nn::gemm::{gemm, Op};

/// Sizes of every dimension: the shapes of SAC, the ensemble and their tails and minibatches.
const DIMS: [usize; 13] = [1, 2, 3, 4, 5, 7, 8, 16, 17, 33, 104, 200, 256];

/// FNV-1a over the elements' bits.
fn hash(c: &[f32]) -> u64 {
    c.iter().fold(0xcbf2_9ce4_8422_2325, |h, x| {
        (h ^ u64::from(x.to_bits())).wrapping_mul(0x100_0000_01b3)
    })
}

/// `len` values in [-1, 1) from a multiplicative hash of the index.
fn operand(len: usize, mul: u64, modulus: u64) -> Vec<f32> {
    (0..len as u64)
        .map(|i| (i * mul % modulus) as f32 / (modulus / 2) as f32 - 1.0)
        .collect()
}

fn main() {
    for m in DIMS {
        for k in DIMS {
            for n in DIMS {
                let a = operand(m * k, 2_654_435_761, 1999);
                let b = operand(k * n, 40_503, 1013);
                for (op_a, op_b) in [
                    (Op::N, Op::N),
                    (Op::T, Op::N),
                    (Op::N, Op::T),
                    (Op::T, Op::T),
                ] {
                    let mut c = vec![0.0f32; m * n];
                    gemm(&mut c, &a, op_a, &b, op_b, m, k, n, false);
                    println!("{m} {k} {n} {op_a:?}{op_b:?} {:016x}", hash(&c));
                }
            }
        }
    }
}
