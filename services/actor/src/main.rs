//! `mbpo-actor`: acts in the real environment with the newest policy it is allowed to use and
//! publishes every transition (reliable, sequence-numbered). With `--eval` it is the
//! evaluation actor: deterministic policy, stream `eval.env`, evaluating policy version t at
//! the sequential evaluation points.
//!
//! Lockstep: the actor of global step t waits for policy version exactly t − 1. Pipelined: any
//! version ≥ t − 1 − policy_lag. With `--plan` (MPC) both plan on the model trainer's ensemble
//! instead (`mbpo_runtime::services::planning`).
//!
//! The loops are `mbpo_runtime::services::{actor, planning}`; this binary runs one in its own
//! process.

use std::process::ExitCode;

use clap::Parser;
use mbpo_runtime::{RoleKind, ServiceArgs};
use mbpo_wire::ipc;

#[derive(Debug, Parser)]
// The command is named after its package, the role table's binary name.
#[command(about = "MBPO pipeline actor")]
struct Args {
    #[command(flatten)]
    svc: ServiceArgs,
    /// Be the evaluation actor.
    #[arg(long)]
    eval: bool,
    /// Plan on the model trainer's ensemble (MPC) instead of acting with the SAC policy.
    #[arg(long)]
    plan: bool,
    /// Plan in the latent space of the world-model learner's parameters (TD-MPC2).
    #[arg(long)]
    latent: bool,
}

fn main() -> ExitCode {
    let args = Args::parse();
    mbpo_runtime::init_service_process();
    let flags = [
        (args.eval, "--eval"),
        (args.plan, "--plan"),
        (args.latent, "--latent"),
    ];
    let flags: Vec<&str> = flags.iter().filter(|f| f.0).map(|f| f.1).collect();
    let role = RoleKind::of_binary(env!("CARGO_PKG_NAME"), &flags)
        .expect("every flag combination of mbpo-actor is a role of the role table");
    let service_loop = mbpo_runtime::services::service_loop::<ipc::Service>(role);
    mbpo_runtime::exit_code(service_loop(&args.svc))
}
