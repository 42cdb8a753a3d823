//! `mbpo-model-trainer`: keeps its own copy of the real data and, at every train point t,
//! trains the ensemble and publishes model version v (latest value, one flat `[f32]`, see
//! `ModelWireLayout`).
//!
//! Lockstep: trains on exactly the first t − 1 real transitions (transition t may already have
//! arrived; it is held back). Pipelined: trains on every transition received by then (≥ t − 1).
//! In an MPC run (algo = "mpc") the same loop feeds the planning actors; in lockstep it also
//! waits for the planning evaluator's acknowledgements before replacing a model version.
//!
//! The loop is `mbpo_runtime::services::model_trainer`; this binary runs it in its own process.

use std::process::ExitCode;

use clap::Parser;
use mbpo_runtime::services::service_loop;
use mbpo_runtime::ServiceArgs;
use mbpo_wire::ipc;

#[derive(Debug, Parser)]
// The command is named after its package, the role table's binary name.
#[command(about = "MBPO pipeline model trainer")]
struct Args {
    #[command(flatten)]
    svc: ServiceArgs,
}

fn main() -> ExitCode {
    let args = Args::parse();
    mbpo_runtime::init_service_process();
    mbpo_runtime::exit_code(service_loop::<ipc::Service>(
        mbpo_runtime::RoleKind::ModelTrainer,
    )(&args.svc))
}
