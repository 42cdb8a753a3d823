//! The `mbpo` command as a library: [`main`] is the whole command line, and [`supervisor`] the
//! launcher of `mbpo run`. A program that registers an algorithm of its own
//! (`mbpo_train::algorithm::register`) and then calls [`main`] is `mbpo` with that algorithm:
//! `train` runs it in one process, `run` launches its roles -- the role binaries installed
//! beside the program learn it from the run plan. `tests/tests/extension_points.rs` launches
//! one with [`supervisor::launch`].

/// `println!` that returns an error instead of panicking (`mbpo_bench::out!`).
macro_rules! out {
    ($($arg:tt)*) => {
        mbpo_bench::out!($($arg)*)
    };
}

pub mod cli;
mod docs_cmd;
mod env_cmd;
mod logging;
mod run_report;
pub mod supervisor;
mod train_cmd;

use clap::Parser;
use mbpo_bench::stdout::{write_stdout, StdoutClosed};
use std::process::ExitCode;

/// The `mbpo` command: parse this process's command line, set up logging, run the command.
pub fn main() -> ExitCode {
    let cli = cli::Cli::parse();
    logging::init();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) if err.chain().any(|cause| cause.is::<StdoutClosed>()) => ExitCode::SUCCESS,
        Err(err) => {
            eprintln!("error: {}", mbpo_runtime::error_chain(err.as_ref()));
            ExitCode::FAILURE
        }
    }
}

/// This process's arguments after its subcommand `command` (`mbpo` takes no flags before it).
fn arguments_after(command: &str) -> Vec<String> {
    let args = std::env::args().skip_while(|a| a != command).skip(1);
    args.collect()
}

fn run(cli: cli::Cli) -> anyhow::Result<()> {
    match cli.command {
        cli::Command::Train(args) => train_cmd::run(&args),
        cli::Command::Run(args) => supervisor::run(&args),
        // Parsed here for `--help` and for errors; the gateway gets the arguments as given.
        cli::Command::Join(_) => supervisor::gateway("join", &arguments_after("join")),
        cli::Command::Certs(_) => supervisor::gateway("certs", &arguments_after("certs")),
        cli::Command::Env(cmd) => env_cmd::run(cmd),
        cli::Command::Config(cli::ConfigCommand::Show(args)) => {
            let source = &args.source;
            let cfg =
                mbpo_train::ExperimentConfig::resolve(source.config.as_deref(), &source.overrides)?;
            if !args.no_env_check {
                let env = cfg.describe_env()?;
                tracing::info!(
                    "env {}: {env} (made once to check it; --no-env-check skips this)",
                    cfg.env
                );
            }
            write_stdout(format_args!("{}", cfg.to_toml()))
        }
        cli::Command::Eval(args) => {
            let report =
                mbpo_train::policy_file::evaluate_run(&args.run, args.episodes, args.seed)?;
            out!("{}", serde_json::to_string(&report)?)?;
            Ok(())
        }
        cli::Command::Plot(args) => {
            let references = match args.column.as_str() {
                "eval_return" => run_report::references_of(&args.runs, &args.peers)?,
                _ => Vec::new(),
            };
            let curves = mbpo_report::plot_runs(
                &args.runs,
                &args.column,
                &args.title,
                &args.out,
                &references,
            )?;
            let losses = mbpo_report::companion_path(&args.out, "losses");
            let title = format!("{}: training losses", args.title);
            let losses = mbpo_report::plot_losses_if_any(&args.runs, &title, &losses)?;
            let table = args.out.with_extension("md");
            let text = mbpo_report::learning_table(&args.runs, args.table_every, &references)?;
            std::fs::write(&table, format!("### {}\n\n{text}", args.title))?;
            out!(
                "{}",
                serde_json::json!({
                    "plot": curves.out,
                    "losses": losses.as_ref().map(|l| &l.out),
                    "table": table,
                    "references": references.iter().map(|r| &r.label).collect::<Vec<_>>(),
                    "runs": args.runs.len(),
                    "groups": curves.groups,
                    "loss_panels_with_data": losses.map(|l| l.panels_with_data).unwrap_or_default(),
                })
            )?;
            Ok(())
        }
        cli::Command::Bench(cmd) => mbpo_bench::command::run(cmd, train_cmd::bench_run),
        cli::Command::Docs(args) => docs_cmd::run(&args),
        cli::Command::Chaos(args) => {
            mbpo_bench::chaos::run(&args.plan()?, &mut |line| out!("{line}"))
        }
    }
}
