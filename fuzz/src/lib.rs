//! Helpers shared by the fuzz targets in `fuzz_targets/` (run them with `bash tools/fuzz.sh`).
//!
//! * [`Pod`] / [`pod`]: a `#[repr(C)]` wire struct read from the fuzzer's bytes exactly as a
//!   subscriber finds it in shared memory (any bit pattern is a value: integers and floats only).
//! * [`floats`]: little-endian `f32`s, as a payload in shared memory.
//! * [`scratch`]: a per-process folder for targets whose decoder reads a file (tmpfs when the
//!   runner gives one in `MBPO_FUZZ_SCRATCH`).
//! * [`write_seeds_if_asked`]: with `MBPO_FUZZ_SEEDS=<dir>` in the environment, a target writes
//!   its seed inputs (valid encodings made with the project's own encoders) there and exits;
//!   `tools/fuzz.sh` does this once per target before fuzzing.

use std::path::PathBuf;
use std::sync::OnceLock;

use mbpo_wire::{ControlMsg, MsgHeader, StatsRecord, TransitionHeader, WeightsHeader};

/// A plain-old-data wire struct: `#[repr(C)]`, integer and float fields only, no padding.
///
/// # Safety
/// Every bit pattern of `size_of::<Self>()` bytes must be a valid value.
pub unsafe trait Pod: Copy + Default + 'static {}

// SAFETY: #[repr(C)] structs of u64/u32/f64/f32 fields only, no padding (checked by the
// wire crate's `headers_have_no_hidden_padding` test).
unsafe impl Pod for TransitionHeader {}
unsafe impl Pod for WeightsHeader {}
unsafe impl Pod for MsgHeader {}
unsafe impl Pod for StatsRecord {}
unsafe impl Pod for ControlMsg {}

/// A `T` from the first `size_of::<T>()` bytes of `data` (missing bytes are zero), and the
/// bytes after it.
pub fn pod<T: Pod>(data: &[u8]) -> (T, &[u8]) {
    let n = std::mem::size_of::<T>();
    let mut buf = vec![0u8; n];
    let k = n.min(data.len());
    buf[..k].copy_from_slice(&data[..k]);
    // SAFETY: `buf` holds size_of::<T>() bytes and every bit pattern is a `T` (trait `Pod`).
    let v = unsafe { std::ptr::read_unaligned(buf.as_ptr() as *const T) };
    (v, &data[k..])
}

/// The bytes of `v` as they lie in shared memory.
pub fn bytes_of<T: Pod>(v: &T) -> Vec<u8> {
    let n = std::mem::size_of::<T>();
    // SAFETY: a `Pod` has no padding, so all its bytes are initialised.
    unsafe { std::slice::from_raw_parts(v as *const T as *const u8, n) }.to_vec()
}

/// `data` as little-endian `f32`s (a trailing partial float is dropped).
pub fn floats(data: &[u8]) -> Vec<f32> {
    data.chunks_exact(4)
        .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

/// The bytes of `v` as little-endian `f32`s.
pub fn float_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|f| f.to_le_bytes()).collect()
}

/// Same value, bit for bit (NaNs with the same payload are equal, 0.0 and -0.0 are not).
pub fn same_bits(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// A folder of this process for files a decoder reads: under `MBPO_FUZZ_SCRATCH` (the runner
/// points it at tmpfs), else the system's temporary folder. Created once.
pub fn scratch() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let base = std::env::var_os("MBPO_FUZZ_SCRATCH")
            .map(PathBuf::from)
            .unwrap_or_else(std::env::temp_dir);
        let dir = base.join(format!("mbpo-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("cannot create the fuzz scratch folder");
        dir
    })
}

/// With `MBPO_FUZZ_SEEDS=<dir>` set: write the inputs `make` returns into `<dir>` (one file
/// each, named `<target>-<i>`) and exit. Without it: nothing.
pub fn write_seeds_if_asked(target: &str, make: impl FnOnce() -> Vec<Vec<u8>>) {
    let Some(dir) = std::env::var_os("MBPO_FUZZ_SEEDS") else {
        return;
    };
    let dir = PathBuf::from(dir);
    std::fs::create_dir_all(&dir).expect("cannot create the seed folder");
    let seeds = make();
    for (i, s) in seeds.iter().enumerate() {
        std::fs::write(dir.join(format!("{target}-{i:03}")), s).expect("cannot write a seed");
    }
    eprintln!("{target}: wrote {} seeds to {}", seeds.len(), dir.display());
    std::process::exit(0);
}

/// A small SAC actor's architecture, as an actor of Pendulum (3 observations, 1 action) with
/// hidden widths [8, 8]: `(layout hash, parameter count)`.
pub fn small_policy() -> (u64, usize) {
    let net = mbpo_sac::TanhGaussianActor::new(3, 1, &[8, 8], -20.0, 2.0);
    (net.layout().hash(), net.num_params())
}

/// A small model (3 observations, 1 action, 3 members of [8, 8], 2 elites), with or without a
/// learned termination rule.
pub fn small_model(learn_termination: bool) -> mbpo_model::ProbabilisticEnsemble {
    let cfg = mbpo_model::ModelConfig {
        members: 3,
        elites: 2,
        hidden: vec![8, 8],
        weight_decay: vec![1e-4; 3],
        learn_termination,
        ..mbpo_model::ModelConfig::default()
    };
    mbpo_model::ProbabilisticEnsemble::new(3, 1, cfg, &mut mbpo_core::rng::stream(0, "fuzz", 0))
        .expect("a valid model config")
}

/// The run hash the wire targets expect (`RunIpc::run_hash` of run id `fuzz`).
pub fn run_hash() -> u64 {
    mbpo_wire::run_hash("fuzz")
}
