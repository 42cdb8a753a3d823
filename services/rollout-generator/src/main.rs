//! `mbpo-rollout-generator`: at every train point t, loads model version v (the v-th training)
//! and the newest allowed policy, branches M · model_train_freq k-step rollouts from start
//! states drawn from its copy of the real data, and publishes them as one imagined batch
//! (reliable; header `env_steps` = t − 1 names the train point, versions say what made it).
//!
//! Lockstep: model version exactly v, policy version exactly t − 1, exactly t − 1 real
//! transitions. Pipelined: policy ≥ t − 1 − policy_lag, every real transition received.
//!
//! The loop is `mbpo_runtime::services::rollout`; this binary runs it in its own process.

use std::process::ExitCode;

use clap::Parser;
use mbpo_runtime::services::service_loop;
use mbpo_runtime::ServiceArgs;
use mbpo_wire::ipc;

#[derive(Debug, Parser)]
// The command is named after its package, the role table's binary name.
#[command(about = "MBPO pipeline rollout generator")]
struct Args {
    #[command(flatten)]
    svc: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    mbpo_runtime::init_service_process();
    mbpo_runtime::exit_code(service_loop::<ipc::Service>(
        mbpo_runtime::RoleKind::RolloutGenerator,
    )(&args.svc))
}
