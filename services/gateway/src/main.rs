//! `mbpo-gateway`: a host's gateway of a multi-host run (`mbpo_net`).
//!
//! * `mbpo-gateway head <service args> --listen E --local-actors L`: started by `mbpo run
//!   --listen E --remote-actors M [--remote-roles evaluator]`; stands in for actors L..L+M and
//!   the run plan's remote roles on the head.
//! * `mbpo-gateway join E --actors N [--roles evaluator]`: what `mbpo join` runs on a worker
//!   host.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use clap::{Parser, Subcommand};
use mbpo_net::{NetOptions, DEFAULT_PORT};
use mbpo_runtime::args::{CertsArgs, JoinArgs};
use mbpo_runtime::ServiceArgs;

#[derive(Debug, Parser)]
#[command(
    name = "mbpo-gateway",
    about = "A host's gateway of a multi-host MBPO run"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// The head's gateway (started by `mbpo run --listen`).
    Head {
        #[command(flatten)]
        svc: ServiceArgs,
        /// Zenoh endpoint to listen on.
        #[arg(long)]
        listen: String,
        /// Credentials directory (`mbpo certs`).
        #[arg(long)]
        credentials: Option<PathBuf>,
        /// Actors running on the head; the rest of --actors are remote.
        #[arg(long)]
        local_actors: u16,
        /// Seconds a worker may be silent before its actors' state is taken for lost.
        #[arg(long, default_value_t = 30.0)]
        worker_timeout: f64,
    },
    /// A worker host's gateway (`mbpo join`).
    Join(JoinArgs),
    /// Make a run's credentials (`mbpo certs`): DIR/head and DIR/worker.
    Certs(CertsArgs),
}

fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "worker".into())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    mbpo_runtime::init_service_process();
    match cli.command {
        Cmd::Head {
            svc,
            listen,
            credentials,
            local_actors,
            worker_timeout,
        } => {
            let opts = mbpo_net::HeadOptions {
                service: svc,
                net: NetOptions {
                    endpoint: listen,
                    credentials,
                },
                local_actors,
                worker_timeout: Duration::from_secs_f64(worker_timeout),
            };
            match mbpo_net::run_head(&opts) {
                Ok(()) => ExitCode::SUCCESS,
                Err(e) => {
                    tracing::error!("gateway failed: {e}");
                    ExitCode::FAILURE
                }
            }
        }
        Cmd::Certs(CertsArgs { out }) => match mbpo_net::certs::make_credentials(&out) {
            Ok(()) => {
                println!(
                    "made {0}/head and {0}/worker: on the head `mbpo run --listen tls/<address>:{1} --credentials {0}/head ...`, on each worker (a copy of {0}/worker) `mbpo join tls/<head address>:{1} --credentials <its copy>`",
                    out.display(),
                    DEFAULT_PORT
                );
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("error: {e}");
                ExitCode::FAILURE
            }
        },
        Cmd::Join(j) => {
            let cores = std::thread::available_parallelism().map_or(1, |n| n.get() as u16);
            let name = j.name.unwrap_or_else(host_name);
            let opts = mbpo_net::WorkerOptions {
                net: NetOptions {
                    endpoint: j.head,
                    credentials: j.credentials,
                },
                actors: j
                    .actors_per_core
                    .map_or(j.actors, |k| k.saturating_mul(cores)),
                roles: j.roles,
                dir: j
                    .dir
                    .unwrap_or_else(|| std::env::temp_dir().join(format!("mbpo-worker-{name}"))),
                name,
                ipc_root: j.ipc_root,
                bin_dir: std::env::current_exe()
                    .ok()
                    .and_then(|p| p.parent().map(PathBuf::from))
                    .unwrap_or_default(),
                head_timeout: Duration::from_secs_f64(j.head_timeout),
            };
            match mbpo_net::run_worker(&opts) {
                Ok(report) => {
                    println!("{}", serde_json::to_string(&report).unwrap_or_default());
                    ExitCode::SUCCESS
                }
                Err(e) => {
                    tracing::error!("worker failed: {e}");
                    ExitCode::from(3)
                }
            }
        }
    }
}
