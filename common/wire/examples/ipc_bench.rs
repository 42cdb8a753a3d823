//! Runs the full `mbpo_wire::bench::run_ipc_bench` and prints the report as JSON
//! (`cargo run --release -p mbpo-wire --example ipc_bench`).
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let report = mbpo_wire::bench::run_ipc_bench(&mbpo_wire::bench::IpcBenchConfig::default())?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
