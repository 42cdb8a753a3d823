//! The model benchmarks from the command line, until `mbpo bench model-train|model-rollout`
//! wires [`mbpo_model::bench`] into the CLI:
//!
//! ```text
//! cargo run --release -p mbpo-model --example model_bench [train|rollout] [--quick-roofline]
//! ```
//!
//! Prints one JSON object per benchmark. `--quick-roofline` shortens the roofline measurement
//! (for profiling runs, where only the timed calls matter).
use mbpo_model::bench::{model_rollout, model_train, ModelBenchConfig};
use std::time::Duration;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut cfg = ModelBenchConfig::default();
    if args.iter().any(|a| a == "--quick-roofline") {
        cfg.roofline_time = Duration::from_millis(100);
    }
    let which = args
        .iter()
        .find(|a| !a.starts_with("--"))
        .map(String::as_str);
    if matches!(which, None | Some("train")) {
        println!("{}", serde_json::to_string(&model_train(10_000, &cfg)?)?);
    }
    if matches!(which, None | Some("rollout")) {
        println!("{}", serde_json::to_string(&model_rollout(100_000, &cfg)?)?);
    }
    Ok(())
}
