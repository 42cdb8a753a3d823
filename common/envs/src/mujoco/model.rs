//! Loading Gymnasium's MJCF models and routing MuJoCo's messages to `tracing`.

use std::cell::Cell;
use std::path::{Path, PathBuf};
use std::sync::Once;

use mujoco_rs::prelude::{set_log_handler, MjLogMessage, MjModel, MjtLogLevel};

use crate::EnvError;

/// Environment variable that overrides where the MJCF files are read from.
pub const ASSETS_ENV_VAR: &str = "MBPO_MUJOCO_ASSETS";

/// Where `deploy/setup_mujoco.sh` links Gymnasium's `envs/mujoco/assets` folder.
const DEFAULT_ASSETS: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../.mujoco/assets");

/// The folder holding Gymnasium's MJCF files: `$MBPO_MUJOCO_ASSETS`, else `<repo>/.mujoco/assets`.
pub fn assets_dir() -> PathBuf {
    std::env::var_os(ASSETS_ENV_VAR)
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(DEFAULT_ASSETS))
}

thread_local! {
    /// Set while this thread compiles a model: the compiler's warnings (e.g. Hopper's deprecated
    /// `settotalmass`) are expected and logged at debug level instead of warn.
    static LOADING: Cell<bool> = const { Cell::new(false) };
}

/// MuJoCo's messages go to `tracing` (stderr), never to stdout, where commands print JSON.
fn log_to_tracing(message: &MjLogMessage) {
    let text = match message.body() {
        Some(body) if !body.is_empty() => format!("{}: {body}", message.subject()),
        _ => message.subject().to_string(),
    };
    match message.level() {
        MjtLogLevel::mjLOG_ERROR => tracing::error!(target: "mujoco", "{text}"),
        MjtLogLevel::mjLOG_WARNING if !LOADING.with(Cell::get) => {
            tracing::warn!(target: "mujoco", "{text}")
        }
        _ => tracing::debug!(target: "mujoco", "{text}"),
    }
}

static LOG_HANDLER: Once = Once::new();

/// Load `file` from the folder `assets` for environment `env`.
pub fn load(env: &'static str, assets: &Path, file: &str) -> Result<MjModel, EnvError> {
    // SAFETY: `set_log_handler` must not race with other MuJoCo use. Every MuJoCo object in this
    // crate is made by this function, after the `Once` has completed (a second thread waits in
    // `call_once`), so no thread can be using MuJoCo while the handler is installed.
    LOG_HANDLER.call_once(|| unsafe { set_log_handler(log_to_tracing) });
    let path = assets.join(file);
    if !path.is_file() {
        return Err(EnvError::Model {
            env,
            message: format!(
                "MJCF file {} not found; run `bash deploy/setup_mujoco.sh` (it links Gymnasium's \
                 envs/mujoco/assets to <repo>/.mujoco/assets) or set {ASSETS_ENV_VAR} to a folder \
                 holding Gymnasium's MJCF files",
                path.display()
            ),
        });
    }
    LOADING.with(|l| l.set(true));
    let model = MjModel::from_xml(&path);
    LOADING.with(|l| l.set(false));
    model.map_err(|e| EnvError::Model {
        env,
        message: format!("{}: {e}", path.display()),
    })
}
