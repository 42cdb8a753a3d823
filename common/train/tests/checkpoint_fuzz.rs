//! Checkpoint files are bytes from outside the process: whatever a file holds, reading it
//! returns a typed error (or the value it holds) and never panics, hangs or allocates from a
//! length it has not checked (issue 24 item 5). Random files, random damage to a real one, and
//! payloads whose checksum matches but whose content lies.

use mbpo_core::rng::{index, stream};
use mbpo_train::checkpoint::{self, CheckpointError};

const KIND: &str = "mbpo.test.fuzz";

fn scratch(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("mbpo-ckpt-fuzz-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Iterations per case: `MBPO_FUZZ_ITERS` (default 2000, as in the normal suite).
fn iters() -> usize {
    std::env::var("MBPO_FUZZ_ITERS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(2000)
}

#[test]
fn random_and_damaged_files_are_refused_without_a_panic() {
    let dir = scratch("damage");
    let path = dir.join("file");
    let good: (Vec<f32>, u64, String) = ((0..64).map(|i| i as f32).collect(), 7, "x".into());
    checkpoint::write(&path, KIND, &good).unwrap();
    let valid = std::fs::read(&path).unwrap();
    let mut rng = stream(0, "fuzz.checkpoint", 0);
    let (mut refused, mut read_back) = (0, 0);
    for i in 0..iters() {
        let mut bytes = valid.clone();
        match i % 4 {
            // Random bytes of a random length, sometimes behind a valid magic and version.
            0 => {
                let n = index(&mut rng, 200);
                bytes = (0..n).map(|_| index(&mut rng, 256) as u8).collect();
                if i % 8 == 0 {
                    bytes.splice(0..0, valid[..12].iter().copied());
                }
            }
            // Truncated anywhere.
            1 => bytes.truncate(index(&mut rng, valid.len())),
            // 1-4 bytes changed anywhere.
            2 => {
                for _ in 0..1 + index(&mut rng, 4) {
                    let at = index(&mut rng, bytes.len());
                    bytes[at] ^= 1 + index(&mut rng, 255) as u8;
                }
            }
            // Junk appended.
            _ => bytes.extend((0..1 + index(&mut rng, 64)).map(|_| index(&mut rng, 256) as u8)),
        }
        std::fs::write(&path, &bytes).unwrap();
        match checkpoint::read::<(Vec<f32>, u64, String)>(&path, KIND) {
            Ok(v) => {
                assert_eq!(v, good, "case {i}: a damaged file read as another value");
                read_back += 1;
            }
            Err(_) => refused += 1,
        }
    }
    assert!(
        refused > iters() * 7 / 10,
        "{refused} refused, {read_back} read back"
    );
    let _ = std::fs::remove_dir_all(dir);
}

/// A payload whose checksum is right but whose lengths lie (a forged or buggy writer): a
/// vector "of" 2^61 floats is refused, not allocated.
#[test]
fn a_payload_with_a_matching_checksum_but_a_lying_length_is_refused() {
    let dir = scratch("lying");
    let path = dir.join("file");
    let mut rng = stream(0, "fuzz.forged", 0);
    for huge in [u64::MAX, u64::MAX / 4, 1 << 61, 1 << 40, 1 << 31] {
        checkpoint::write(&path, KIND, &huge).unwrap();
        let err = checkpoint::read::<Vec<f32>>(&path, KIND).unwrap_err();
        assert!(
            matches!(err, CheckpointError::Decode { .. }),
            "{huge}: {err}"
        );
    }
    // Random payloads behind a valid header and checksum.
    for _ in 0..iters() {
        let n = index(&mut rng, 64);
        let payload: Vec<u8> = (0..n).map(|_| index(&mut rng, 256) as u8).collect();
        checkpoint::write(&path, KIND, &payload).unwrap();
        // Any outcome but a panic or an abort is fine: the bytes are not such a value.
        let _ = checkpoint::read::<(Vec<f32>, String, Option<Vec<u64>>)>(&path, KIND);
    }
    let _ = std::fs::remove_dir_all(dir);
}
