//! A run's results do not depend on which x86-64 CPU with AVX2 and FMA it runs on: the same
//! MBPO run, on this machine and on a Haswell (AVX2 and FMA, no AVX-512) that QEMU's user mode
//! emulates, gives the same policy and every metric bit for bit. On this machine's widest
//! level (AVX-512 where it has it) the element-wise kernels and the GEMMs of ragged widths take
//! other code than on the Haswell (`mbpo_nn::simd`, `mbpo_nn::gemm`), and faer picks other
//! kernels. On a CPU without FMA (a Nehalem) faer takes other GEMM kernels that round
//! differently; the run warns so in its log (`mbpo_train::cpu`).
//!
//! Needs `qemu-x86_64` (Debian's qemu-user; deploy/test.sh installs it when run as root).

#![cfg(target_arch = "x86_64")]

use std::path::Path;
use std::process::Command;

use mbpo_integration_tests::{bin_dir, metrics_without_timing, scratch};

/// A short MBPO run whose layers are 104 wide (a ragged width: not a multiple of 16, at least
/// 96), with members and critics cut across two threads: one model training, 30 SAC updates.
const RUN: &[&str] = &[
    "train",
    "--config",
    "../deploy/configs/pendulum-tiny.toml",
    "--steps",
    "230",
    "--set",
    "model.hidden=[104,104]",
    "--set",
    "sac.hidden=[104,104]",
    "--set",
    "model.threads=2",
    "--set",
    "sac.threads=2",
    "--set",
    "model.max_epochs=2",
    "--set",
    "mbpo.updates_per_step=1",
    "--set",
    "eval.every=100",
    "--set",
    "eval.episodes=1",
];

/// QEMU's user mode for x86-64 (Debian's qemu-user).
const QEMU: &str = "qemu-x86_64";

fn qemu_installed() -> bool {
    let found = Command::new(QEMU).arg("--version").output();
    found.is_ok_and(|o| o.status.success())
}

/// The run in `out`, natively (`cpu` None) or on the emulated `cpu`: its summary's policy hash
/// and its log.
fn run(cpu: Option<&str>, out: &Path) -> (String, String) {
    let mbpo = bin_dir().join("mbpo");
    let mut cmd = match cpu {
        None => Command::new(&mbpo),
        Some(cpu) => {
            let mut c = Command::new(QEMU);
            c.args(["-cpu", cpu]).arg(&mbpo);
            c
        }
    };
    let done = cmd
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .args(RUN)
        .arg("--out")
        .arg(out)
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&done.stderr).into_owned();
    assert!(done.status.success(), "{cpu:?}: {:?}\n{log}", done.status);
    let summary: serde_json::Value = serde_json::from_slice(&done.stdout).unwrap();
    assert_eq!(summary["status"], "completed", "{cpu:?}");
    (summary["policy_sha256"].as_str().unwrap().to_owned(), log)
}

#[test]
fn a_run_is_the_same_bits_on_avx2_and_on_this_cpu_and_a_cpu_without_fma_says_it_differs() {
    if !qemu_installed() {
        eprintln!("SKIPPED: no {QEMU} (Debian's qemu-user) to emulate other CPUs");
        return;
    }
    let dir = scratch("cross-cpu");
    let (here, here_log) = run(None, &dir.join("here"));
    let (haswell, haswell_log) = run(Some("Haswell"), &dir.join("haswell"));
    let level = |log: &str| {
        log.lines().find_map(|l| {
            Some(
                l.split("CPU kernels: ")
                    .nth(1)?
                    .split(',')
                    .next()?
                    .to_owned(),
            )
        })
    };
    let here_level = level(&here_log).expect("the run logs its CPU kernels");
    eprintln!("this machine: {here_level}");
    assert_eq!(
        level(&haswell_log).as_deref(),
        Some("avx2"),
        "the emulated Haswell takes the AVX2 kernels:\n{haswell_log}"
    );
    assert_eq!(
        here, haswell,
        "the policy differs between {here_level} and AVX2"
    );
    assert_eq!(
        metrics_without_timing(&dir.join("here")),
        metrics_without_timing(&dir.join("haswell")),
        "a metric differs between {here_level} and AVX2"
    );

    let (_, nehalem_log) = run(Some("Nehalem"), &dir.join("nehalem"));
    assert!(
        nehalem_log.lines().any(|l| l.contains("WARN")
            && l.contains("CPU kernels: baseline on x86_64, without faer's x86 GEMM kernels")),
        "a CPU without FMA is named in the log:\n{nehalem_log}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
