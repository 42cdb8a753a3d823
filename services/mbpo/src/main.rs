//! `mbpo`: the command-line entry point. It parses the command line, sets up logging and calls
//! the command's `run`; everything testable lives in the `common/` crates.

mod bench;
mod cli;
mod env_cmd;
mod supervisor;
mod train_cmd;

use clap::Parser;
use std::process::ExitCode;

fn main() -> ExitCode {
    let cli = cli::Cli::parse();
    init_logging();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: cli::Cli) -> anyhow::Result<()> {
    match cli.command {
        cli::Command::Train(args) => train_cmd::run(&args),
        cli::Command::Run(args) => supervisor::run(&args),
        cli::Command::Env(cmd) => env_cmd::run(cmd),
        cli::Command::Config(cli::ConfigCommand::Show(source)) => {
            let cfg =
                mbpo_train::ExperimentConfig::resolve(source.config.as_deref(), &source.overrides)?;
            print!("{}", cfg.to_toml());
            Ok(())
        }
        cli::Command::Eval(args) => {
            let report = mbpo_train::eval::evaluate_run(&args.run, args.episodes, args.seed)?;
            println!("{}", serde_json::to_string(&report)?);
            Ok(())
        }
        cli::Command::Plot(args) => {
            mbpo_report::plot_runs(&args.runs, &args.column, &args.title, &args.out)?;
            println!(
                "{}",
                serde_json::json!({"plot": args.out, "runs": args.runs.len()})
            );
            Ok(())
        }
        cli::Command::Bench(cmd) => bench::run(cmd),
    }
}

/// Logs go to stderr (stdout carries machine-readable output); `RUST_LOG` overrides the level.
fn init_logging() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("info"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::IsTerminal::is_terminal(&std::io::stderr()))
        .init();
}
