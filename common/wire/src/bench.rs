//! The IPC benchmark (`cargo run --release -p mbpo-wire --example ipc_bench`): transition throughput and weight-broadcast latency over iceoryx2.
//!
//! Each measurement runs a producer in the calling thread and a consumer in a second thread,
//! each with its own node on [`ipc::Service`](crate::ipc::Service) (the same shared-memory path
//! as between processes), in a fresh run that is removed afterwards.
//!
//! * Transitions: the producer packs a prepared [`mbpo_core::Batch`] into shared memory
//!   ([`TransitionPublisher::send_batch`]) as fast as backpressure allows; the consumer sleeps in
//!   a [`Waiter`] and pushes every batch into a [`ReplayBuffer`] (what a learner does). Reported
//!   per case: batches/s, rows/s and MB/s of payload, plus how often the producer blocked.
//! * Weights: the producer publishes a snapshot every `interval`; the consumer sleeps in a
//!   [`Waiter`] and takes the newest snapshot. Latency is from the publisher's send timestamp
//!   (after the copy into shared memory) to the consumer holding the snapshot, CLOCK_REALTIME.

use std::time::{Duration, Instant};

use mbpo_core::{Batch, ReplayBuffer};

use crate::names::{Channel, Role};
use crate::run::RunIpc;
use crate::schema::{now_ns, RowLayout, WeightsCounters, WeightsKind};
use crate::transitions::{TransitionMeta, TransitionPublisher, TransitionSubscriber};
use crate::waiter::{WaitOutcome, Waiter};
use crate::weights::{WeightsPublisher, WeightsSubscriber};

type Ipc = iceoryx2::service::ipc::Service;

/// One transition-throughput case.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct TransitionCase {
    /// Label in the report.
    pub name: String,
    /// Observation width.
    pub obs_dim: usize,
    /// Action width.
    pub act_dim: usize,
    /// Rows per batch.
    pub rows: usize,
    /// Batches to send.
    pub batches: usize,
}

/// One weight-latency case.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct WeightsCase {
    /// Label in the report.
    pub name: String,
    /// Parameters per snapshot.
    pub n_values: usize,
    /// Snapshots to publish.
    pub samples: usize,
    /// Time between two publishes, microseconds.
    pub interval_us: u64,
}

/// What to measure.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct IpcBenchConfig {
    /// Base directory of the temporary run (short: see [`RunIpc::new`]).
    pub base_dir: String,
    /// Transition cases.
    pub transitions: Vec<TransitionCase>,
    /// Weight cases; the first one is also reported as [`IpcBenchReport::weights`].
    pub weights: Vec<WeightsCase>,
}

impl Default for IpcBenchConfig {
    /// Pendulum-size rows (9 floats) in 1000-row batches, MuJoCo-size rows (42 floats),
    /// 100k-row imagined batches of 45-float rows; a 70k-parameter policy at 100 Hz and a
    /// 1M-parameter model at 20 Hz.
    fn default() -> Self {
        let t = |name: &str, obs_dim, act_dim, rows, batches| TransitionCase {
            name: name.into(),
            obs_dim,
            act_dim,
            rows,
            batches,
        };
        Self {
            base_dir: "/tmp/mbpo-ipc".into(),
            transitions: vec![
                t("real-pendulum-1000x9", 3, 1, 1000, 3000),
                t("real-mujoco-1000x42", 17, 6, 1000, 1000),
                t("imagined-100000x45", 17, 9, 100_000, 40),
            ],
            weights: vec![
                WeightsCase {
                    name: "policy-70k".into(),
                    n_values: 70_000,
                    samples: 300,
                    interval_us: 10_000,
                },
                WeightsCase {
                    name: "model-1M".into(),
                    n_values: 1_000_000,
                    samples: 60,
                    interval_us: 50_000,
                },
            ],
        }
    }
}

impl IpcBenchConfig {
    /// A fast variant for tests (about a second).
    pub fn quick() -> Self {
        let mut c = Self {
            base_dir: "/tmp/mbpo-ipc-quick".into(),
            ..Self::default()
        };
        for t in &mut c.transitions {
            t.batches = (t.batches / 20).max(5);
        }
        c.weights.truncate(1);
        c.weights[0].samples = 30;
        c
    }
}

/// Throughput of one transition case.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct TransitionResult {
    /// The case.
    pub case: TransitionCase,
    /// Floats per row.
    pub floats_per_row: usize,
    /// Payload bytes per batch.
    pub bytes_per_batch: usize,
    /// Wall time from the first send to the last batch consumed.
    pub seconds: f64,
    /// Batches per second.
    pub batches_per_s: f64,
    /// Rows per second.
    pub rows_per_s: f64,
    /// Payload megabytes (1e6 bytes) per second.
    pub mb_per_s: f64,
    /// Times the producer blocked on the consumer (backpressure).
    pub producer_blocked: u64,
    /// Sequence gaps seen by the consumer (must be 0).
    pub gaps: u64,
}

/// Latency of one weights case.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct LatencyResult {
    /// The case.
    pub case: WeightsCase,
    /// Snapshots received (the newest-only semantics may skip some under load).
    pub received: usize,
    /// Median latency, microseconds.
    pub p50_us: f64,
    /// 90th percentile, microseconds.
    pub p90_us: f64,
    /// 99th percentile, microseconds.
    pub p99_us: f64,
    /// Maximum, microseconds.
    pub max_us: f64,
    /// Median time to copy the snapshot into shared memory and send it, microseconds.
    pub publish_p50_us: f64,
}

/// Everything the IPC benchmark reports.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct IpcBenchReport {
    /// iceoryx2 version linked.
    pub iceoryx2: String,
    /// Transition throughput per case.
    pub transitions: Vec<TransitionResult>,
    /// The first weights case.
    pub weights: LatencyResult,
    /// Every weights case.
    pub weights_cases: Vec<LatencyResult>,
}

/// Why the benchmark failed.
#[derive(Debug, thiserror::Error)]
#[error("ipc benchmark failed: {0}")]
pub struct BenchError(String);

fn e<E: std::fmt::Display>(x: E) -> BenchError {
    BenchError(x.to_string())
}

/// Run every case of `cfg` and report.
pub fn run_ipc_bench(cfg: &IpcBenchConfig) -> Result<IpcBenchReport, BenchError> {
    let id = format!("bench-{}-{:x}", std::process::id(), now_ns() & 0xffff_ffff);
    let run = RunIpc::new(&id, &cfg.base_dir).map_err(e)?;
    let result = (|| {
        let mut transitions = Vec::new();
        for case in &cfg.transitions {
            transitions.push(transition_case(&run, case)?);
        }
        let mut weights_cases = Vec::new();
        for case in &cfg.weights {
            weights_cases.push(weights_case(&run, case)?);
        }
        let weights = weights_cases
            .first()
            .cloned()
            .ok_or_else(|| BenchError("no weights case configured".into()))?;
        Ok(IpcBenchReport {
            iceoryx2: "0.10.0".into(),
            transitions,
            weights,
            weights_cases,
        })
    })();
    run.remove_all::<Ipc>().map_err(e)?;
    result
}

fn transition_case(run: &RunIpc, case: &TransitionCase) -> Result<TransitionResult, BenchError> {
    let layout = RowLayout::new(case.obs_dim, case.act_dim);
    let channel = if case.rows > 10_000 {
        Channel::Imagined
    } else {
        Channel::Real
    };
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), String>>();
    let run2 = run.clone();
    let case2 = case.clone();
    let consumer = std::thread::spawn(move || -> Result<(Instant, u64), String> {
        let node = run2
            .node::<Ipc>(Role::Learner, 0)
            .map_err(|x| x.to_string())?;
        let rx = TransitionSubscriber::create(&node, channel, layout).map_err(|x| x.to_string())?;
        let mut buf = ReplayBuffer::new(layout.obs_dim, layout.act_dim, (case2.rows * 4).max(1));
        let mut waiter = Waiter::new().map_err(|x| x.to_string())?;
        waiter.attach(&rx);
        let _ = ready_tx.send(Ok(()));
        let mut got = 0;
        while got < case2.batches {
            match waiter
                .wait(Duration::from_secs(30))
                .map_err(|x| x.to_string())?
            {
                WaitOutcome::Terminate => return Err("terminated".into()),
                WaitOutcome::TimedOut => {
                    return Err(format!("no data for 30 s after {got} batches"))
                }
                WaitOutcome::Notified => {}
            }
            got += rx.drain_into(&mut buf).map_err(|x| x.to_string())?.batches;
        }
        Ok((Instant::now(), rx.stats().gaps))
    });
    ready_rx
        .recv()
        .map_err(|_| BenchError("consumer thread died".into()))?
        .map_err(BenchError)?;
    let node = run.node::<Ipc>(Role::Tool, 0).map_err(e)?;
    let tx = TransitionPublisher::create(&node, channel, layout, case.rows).map_err(e)?;
    tx.wait_for_subscribers(1, Duration::from_secs(10))
        .map_err(e)?;
    let batch = Batch::new(layout.obs_dim, layout.act_dim, case.rows);
    let start = Instant::now();
    for k in 0..case.batches {
        let meta = TransitionMeta {
            policy_version: 1,
            model_version: 0,
            env_steps: (k + 1) as u64 * case.rows as u64,
        };
        tx.send_batch(&batch, meta).map_err(e)?;
    }
    let (end, gaps) = consumer
        .join()
        .map_err(|_| BenchError("consumer thread panicked".into()))?
        .map_err(BenchError)?;
    let seconds = (end - start).as_secs_f64();
    let bytes = case.rows * layout.width() * 4;
    Ok(TransitionResult {
        case: case.clone(),
        floats_per_row: layout.width(),
        bytes_per_batch: bytes,
        seconds,
        batches_per_s: case.batches as f64 / seconds,
        rows_per_s: (case.batches * case.rows) as f64 / seconds,
        mb_per_s: (case.batches * bytes) as f64 / seconds / 1e6,
        producer_blocked: tx.stats().blocked,
        gaps,
    })
}

fn weights_case(run: &RunIpc, case: &WeightsCase) -> Result<LatencyResult, BenchError> {
    let (ready_tx, ready_rx) = std::sync::mpsc::channel::<Result<(), String>>();
    let run2 = run.clone();
    let case2 = case.clone();
    let hash = 0x5eed_u64;
    let consumer = std::thread::spawn(move || -> Result<Vec<f64>, String> {
        let node = run2
            .node::<Ipc>(Role::Actor, 0)
            .map_err(|x| x.to_string())?;
        let rx = WeightsSubscriber::create(&node, WeightsKind::Policy, hash, case2.n_values)
            .map_err(|x| x.to_string())?;
        let mut dst = vec![0.0f32; case2.n_values];
        let mut waiter = Waiter::new().map_err(|x| x.to_string())?;
        waiter.attach(&rx);
        let _ = ready_tx.send(Ok(()));
        let mut lat = Vec::new();
        loop {
            match waiter
                .wait(Duration::from_secs(2))
                .map_err(|x| x.to_string())?
            {
                WaitOutcome::Terminate => return Err("terminated".into()),
                WaitOutcome::TimedOut => break,
                WaitOutcome::Notified => {}
            }
            if let Some(s) = rx.receive_latest().map_err(|x| x.to_string())? {
                let t = now_ns();
                lat.push(t.saturating_sub(s.header().send_time_ns) as f64 / 1e3);
                dst.copy_from_slice(s.params());
                if s.version() == case2.samples as u64 {
                    break;
                }
            }
        }
        Ok(lat)
    });
    ready_rx
        .recv()
        .map_err(|_| BenchError("consumer thread died".into()))?
        .map_err(BenchError)?;
    let node = run.node::<Ipc>(Role::Learner, 0).map_err(e)?;
    let tx =
        WeightsPublisher::create(&node, WeightsKind::Policy, hash, case.n_values).map_err(e)?;
    tx.wait_for_subscribers(1, Duration::from_secs(10))
        .map_err(e)?;
    let params: Vec<f32> = (0..case.n_values).map(|i| i as f32).collect();
    let mut publish = Vec::with_capacity(case.samples);
    let mut next = Instant::now();
    for v in 1..=case.samples as u64 {
        next += Duration::from_micros(case.interval_us);
        let t = Instant::now();
        tx.publish(&params, v, WeightsCounters::default())
            .map_err(e)?;
        publish.push(t.elapsed().as_secs_f64() * 1e6);
        std::thread::sleep(next.saturating_duration_since(Instant::now()));
    }
    let mut lat = consumer
        .join()
        .map_err(|_| BenchError("consumer thread panicked".into()))?
        .map_err(BenchError)?;
    if lat.is_empty() {
        return Err(BenchError("no weights received".into()));
    }
    lat.sort_by(f64::total_cmp);
    publish.sort_by(f64::total_cmp);
    Ok(LatencyResult {
        case: case.clone(),
        received: lat.len(),
        p50_us: pct(&lat, 0.5),
        p90_us: pct(&lat, 0.9),
        p99_us: pct(&lat, 0.99),
        max_us: *lat.last().unwrap(),
        publish_p50_us: pct(&publish, 0.5),
    })
}

fn pct(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}
