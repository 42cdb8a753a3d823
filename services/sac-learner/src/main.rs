//! `mbpo-sac-learner`: consumes real transitions one env step at a time and imagined batches,
//! runs G SAC updates per env step after the warm-up, and publishes policy version r (= env
//! steps consumed) once those updates are paid.
//!
//! The G ratio is a Reverb-style [`RateLimiter`] between steps consumed (inserts) and updates
//! (samples): lockstep = zero slack (consume t, G updates, publish t, consume t + 1: Algorithm 2);
//! pipelined = ± `update_buffer` updates. Before consuming step t the imagined batches of every
//! train point ≤ t − model_lag must be in D_model (lockstep: the one branched for t itself).
//! Lockstep also waits, before publishing version t + 1, until the evaluator confirmed it
//! copied version t at an eval point (latest-value weights would otherwise skip it).
//!
//! The loop is `mbpo_runtime::services::learner`; this binary runs it in its own process.

use std::process::ExitCode;

use clap::Parser;
use mbpo_runtime::services::service_loop;
use mbpo_runtime::{RoleKind, ServiceArgs};
use mbpo_wire::ipc;

#[derive(Debug, Parser)]
// The command is named after its package, the role table's binary name.
#[command(about = "MBPO pipeline SAC learner")]
struct Args {
    #[command(flatten)]
    svc: ServiceArgs,
    /// Be TD-MPC2's world-model learner instead (`mbpo_runtime::services::world_model`).
    #[arg(long)]
    world_model: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    mbpo_runtime::init_service_process();
    let flags: &[&str] = match args.world_model {
        true => &["--world-model"],
        false => &[],
    };
    let role = RoleKind::of_binary(env!("CARGO_PKG_NAME"), flags)
        .expect("every flag combination of mbpo-sac-learner is a role of the role table");
    mbpo_runtime::exit_code(service_loop::<ipc::Service>(role)(&args.svc))
}
