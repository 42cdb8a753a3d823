//! The pipeline's runtime: everything a role needs to run as a service, generic over the
//! iceoryx2 service type, so the same loops run as separate processes (`ipc::Service`, the
//! binaries under `services/`) or as threads of one process (`local::Service`, the in-process
//! pipeline of the tests).
//!
//! * [`args`]: [`ServiceArgs`], the command line every service takes; [`Mode`] and [`Slack`].
//! * [`process`]: [`Process`] (config, schedule, sizes of what crosses, run IPC, node), process
//!   start and exit code.
//! * [`inbox`]: [`ControlInbox`] (stops, acknowledgements, barriers), [`RealInbox`] (real
//!   transitions held back until a role may see them) and [`wait_for`], the one way to sleep.
//! * [`pipeline`]: which roles a run has (the one list every launcher and count reads).
//! * [`remote`]: which roles can run on another host behind the gateways, and why not.
//! * [`run_plan`]: the run resolved once by its launcher ([`ResolvedRun`]), which every
//!   process reads and trusts.
//! * [`serving`]: the one serving loop every role runs on, and the [`serving::Worker`]
//!   interface a role implements ([`services`]: the seven roles).
//! * [`pacer`]: stepping on a clock (a paced actor's absolute deadlines, its step-interval
//!   errors).
//! * [`realtime`]: a paced run's scheduling (SCHED_FIFO and a core for a paced actor,
//!   SCHED_BATCH for the learning roles), or why the system refused it.
//! * [`barrier`]: checkpoints of the running pipeline (the protocol and the files).
//! * [`error`]: the one error type, [`RuntimeError`].
//! * [`hosts`]: which hosts a multi-host run's actors are on (files the head's gateway writes).
//!
//! What crosses shared memory (stats records, the model-weights layout) is defined in
//! `mbpo-wire`; when things happen (train points, eval points, updates owed) in
//! `mbpo_train::Schedule`.
#![warn(missing_docs)]

pub mod args;
pub mod barrier;
pub mod coordinator;
pub mod error;
pub mod hosts;
pub mod in_process;
pub mod inbox;
pub mod pacer;
pub mod pipeline;
pub mod process;
pub mod realtime;
pub mod remote;
pub mod run_plan;
pub mod services;
pub mod serving;

pub use args::{Mode, ServiceArgs, Slack};
pub use error::{Result, RuntimeError};
pub use hosts::{LiveHosts, HOSTS_FILE, LIVE_HOSTS_FILE};
pub use inbox::{send_ack, wait_for, ControlInbox, RealInbox};
pub use pipeline::{PipelineSpec, RoleKind};
pub use process::{
    actor_steps, configure_run, error_chain, exit_code, global_step, init_logging,
    init_service_process, load_config, pids_in_log, processes_mentioning, Process,
};
pub use run_plan::{Dims, ResolvedRun};
