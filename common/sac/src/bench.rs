//! The SAC-update benchmark behind `mbpo bench sac-update`.

use crate::{Sac, SacConfig};
use mbpo_core::rng::{normal_f32, stream};
use mbpo_core::stats::median;
use mbpo_core::Batch;
use serde::Serialize;
use std::time::{Duration, Instant};

/// Figures of the SAC-update benchmark.
#[derive(Debug, Clone, Serialize)]
pub struct SacUpdateBench {
    /// Benchmark name.
    pub bench: &'static str,
    /// Observation width.
    pub obs_dim: usize,
    /// Action width.
    pub act_dim: usize,
    /// Hidden widths.
    pub hidden: Vec<usize>,
    /// Batch size.
    pub batch: usize,
    /// Threads one update runs on (`sac.threads`).
    pub threads: usize,
    /// Updates timed.
    pub updates: u64,
    /// Median milliseconds per update over the timed rounds.
    pub ms_per_update: f64,
    /// Median CPU milliseconds per update of the whole process (all threads) over the same
    /// rounds: close to `ms_per_update` x `threads` on an idle machine, and much less
    /// sensitive than wall time to other processes sharing the cores.
    pub cpu_ms_per_update: f64,
    /// GEMM flops of one update as the textbook computes it (every pass on every row, as
    /// PyTorch runs it): the figure the targets are stated in.
    pub gflop_per_update: f64,
    /// GEMM flops this implementation executes (the actor's loss back-propagates each row
    /// through the one critic that is the minimum, and only into the action columns).
    pub gflop_executed: f64,
    /// Achieved GFLOP/s: `gflop_per_update` / wall time.
    pub gflops: f64,
    /// Single-thread faer GEMM peak at 256x256x256 measured in the same run.
    pub roofline_gflops: f64,
    /// gflops / (roofline_gflops x threads).
    pub fraction_of_roofline: f64,
}

/// GEMM flops of one SAC update as textbook code runs it: actor forward on s' and s plus its
/// backward; per critic a target forward, a forward and backward with parameter gradients
/// (critic step), and a forward and full input backward (actor step).
pub fn update_flops(sac: &Sac, batch: usize) -> u64 {
    let (a, q) = (sac.actor.mlp(), sac.critic.mlp());
    let actor = 2 * a.forward_flops(batch) + a.backward_flops(batch, true, false);
    let critic = 3 * q.forward_flops(batch)
        + q.backward_flops(batch, true, false)
        + q.backward_flops(batch, false, true);
    actor + 2 * critic
}

/// GEMM flops [`Sac::update`] executes: as [`update_flops`], except that the actor step's
/// backward through the critics covers each row once (in the critic that is the minimum) and
/// its first layer only the action columns.
pub fn executed_flops(sac: &Sac, batch: usize) -> u64 {
    let q = sac.critic.mlp();
    let act = sac.actor.act_dim() as u64;
    let first = q.dims()[1] as u64;
    let textbook_input_backward = 2 * q.backward_flops(batch, false, true);
    let one_pass_on_actions =
        q.backward_flops(batch, false, false) + 2 * batch as u64 * first * act;
    update_flops(sac, batch) - textbook_input_backward + one_pass_on_actions
}

/// Time SAC updates at the given dims for about `duration` (after a warm-up), the critics
/// LayerNormed when `critic_layer_norm` (its element-wise work is not in the flop counts).
pub fn sac_update(
    obs_dim: usize,
    act_dim: usize,
    hidden: &[usize],
    batch: usize,
    threads: usize,
    critic_layer_norm: bool,
    duration: Duration,
) -> SacUpdateBench {
    let config = SacConfig {
        batch_size: batch,
        hidden: hidden.to_vec(),
        threads,
        critic_layer_norm,
        ..SacConfig::default()
    };
    let mut sac = Sac::new(
        obs_dim,
        act_dim,
        config,
        &mut stream(0, "bench.sac.init", 0),
    );
    let mut g = stream(0, "bench.sac.data", 0);
    let mut data = Batch::new(obs_dim, act_dim, batch);
    for v in data
        .obs
        .iter_mut()
        .chain(&mut data.next_obs)
        .chain(&mut data.reward)
    {
        *v = normal_f32(&mut g);
    }
    data.act
        .iter_mut()
        .for_each(|v| *v = normal_f32(&mut g).tanh());
    let mut rng = stream(0, "bench.sac.update", 0);
    for _ in 0..20 {
        sac.update(&data, &mut rng);
    }
    let rounds = 7;
    let (mut wall, mut cpu) = (Vec::with_capacity(rounds), Vec::with_capacity(rounds));
    let mut updates = 0u64;
    for _ in 0..rounds {
        let (start, cpu_start) = (Instant::now(), process_cpu_seconds());
        let mut n = 0u64;
        while start.elapsed() < duration / rounds as u32 {
            sac.update(&data, &mut rng);
            n += 1;
        }
        wall.push(start.elapsed().as_secs_f64() / n as f64);
        cpu.push((process_cpu_seconds() - cpu_start) / n as f64);
        updates += n;
    }
    let secs = median(&mut wall).expect("at least one round");
    let flops = update_flops(&sac, batch) as f64;
    let roofline = mbpo_nn::bench::gemm_gflops(256, 256, 256, Duration::from_millis(500));
    let gflops = flops / secs / 1e9;
    SacUpdateBench {
        bench: "sac-update",
        obs_dim,
        act_dim,
        hidden: hidden.to_vec(),
        batch,
        threads: sac.threads(),
        updates,
        ms_per_update: secs * 1e3,
        cpu_ms_per_update: median(&mut cpu).expect("at least one round") * 1e3,
        gflop_per_update: flops / 1e9,
        gflop_executed: executed_flops(&sac, batch) as f64 / 1e9,
        gflops,
        roofline_gflops: roofline,
        fraction_of_roofline: gflops / (roofline * sac.threads() as f64),
    }
}

/// CPU time of the whole process (every thread) in seconds.
fn process_cpu_seconds() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant Linux knows.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    assert_eq!(rc, 0, "clock_gettime(CLOCK_PROCESS_CPUTIME_ID) failed");
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}
