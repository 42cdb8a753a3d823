//! The SAC-update benchmark behind `mbpo bench sac-update`.

use crate::{Sac, SacConfig};
use mbpo_core::rng::{normal_f32, stream};
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
    /// Threads used (always 1).
    pub threads: usize,
    /// Updates timed.
    pub updates: u64,
    /// Median milliseconds per update over the timed rounds.
    pub ms_per_update: f64,
    /// GEMM flops of one update.
    pub gflop_per_update: f64,
    /// Achieved GFLOP/s (GEMM flops / wall time).
    pub gflops: f64,
    /// Single-thread faer GEMM peak at 256x256x256 measured in the same run.
    pub roofline_gflops: f64,
    /// gflops / roofline_gflops.
    pub fraction_of_roofline: f64,
}

/// GEMM flops of one [`Sac::update`]: actor forward on s' and s plus its backward; per critic a
/// target forward, a forward and backward with parameter gradients (critic step), and a forward
/// and input-only backward (actor step).
pub fn update_flops(sac: &Sac, batch: usize) -> u64 {
    let (a, q) = (sac.actor.mlp(), sac.critic.mlp());
    let actor = 2 * a.forward_flops(batch) + a.backward_flops(batch, true, false);
    let critic = 3 * q.forward_flops(batch)
        + q.backward_flops(batch, true, false)
        + q.backward_flops(batch, false, true);
    actor + 2 * critic
}

/// Time SAC updates at the given dims for about `duration` (after a warm-up).
pub fn sac_update(
    obs_dim: usize,
    act_dim: usize,
    hidden: &[usize],
    batch: usize,
    duration: Duration,
) -> SacUpdateBench {
    let config = SacConfig {
        batch_size: batch,
        hidden: hidden.to_vec(),
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
    let mut per_round = Vec::with_capacity(rounds);
    let mut updates = 0u64;
    for _ in 0..rounds {
        let start = Instant::now();
        let mut n = 0u64;
        while start.elapsed() < duration / rounds as u32 {
            sac.update(&data, &mut rng);
            n += 1;
        }
        per_round.push(start.elapsed().as_secs_f64() / n as f64);
        updates += n;
    }
    per_round.sort_by(f64::total_cmp);
    let secs = per_round[rounds / 2];
    let flops = update_flops(&sac, batch) as f64;
    let roofline = mbpo_nn::bench::gemm_gflops(256, 256, 256, Duration::from_millis(500));
    let gflops = flops / secs / 1e9;
    SacUpdateBench {
        bench: "sac-update",
        obs_dim,
        act_dim,
        hidden: hidden.to_vec(),
        batch,
        threads: 1,
        updates,
        ms_per_update: secs * 1e3,
        gflop_per_update: flops / 1e9,
        gflops,
        roofline_gflops: roofline,
        fraction_of_roofline: gflops / roofline,
    }
}
