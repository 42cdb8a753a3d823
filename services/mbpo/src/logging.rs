//! Logging of the `mbpo` command: every event goes to stderr (above any progress bar) and,
//! once the run directory is known, also to a log file in it (`<run>/logs/train.log` for
//! `mbpo train`, `<run>/logs/supervisor.log` for `mbpo run`, next to the services' logs).
//!
//! The log file is attached after logging starts because the run directory is only known
//! once the config is resolved; events before that (argument errors) go to stderr only.

use std::fs::File;
use std::io::{IsTerminal, Write};
use std::path::Path;
use std::sync::Mutex;

use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{fmt, EnvFilter};

/// The run's log file, once attached.
static LOG_FILE: Mutex<Option<File>> = Mutex::new(None);

/// stderr, written with the progress bars cleared so a line never lands inside a bar.
struct Stderr;

impl Write for Stderr {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        mbpo_train::progress::suspend(|| std::io::stderr().write_all(buf))?;
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        std::io::stderr().flush()
    }
}

/// The attached log file (unbuffered: one write per event, so a crash loses nothing logged);
/// a sink until one is attached.
struct LogFile;

impl Write for LogFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let mut file = LOG_FILE.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(f) = file.as_mut() {
            f.write_all(buf)?;
        }
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Log to stderr (ANSI colours only on a terminal) and to the log file once attached;
/// `RUST_LOG` overrides the level (default `info`). stdout stays for machine-readable output.
pub fn init() {
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new("info"));
    tracing_subscriber::registry()
        .with(filter)
        .with(
            fmt::layer()
                .with_writer(|| Stderr)
                .with_ansi(std::io::stderr().is_terminal()),
        )
        .with(fmt::layer().with_writer(|| LogFile).with_ansi(false))
        .init();
}

/// From now on, also append every event to `path` (its directory is created).
pub fn also_to_file(path: &Path) -> anyhow::Result<()> {
    use anyhow::Context;
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    }
    let file = File::options()
        .create(true)
        .append(true)
        .open(path)
        .with_context(|| format!("opening the log file {}", path.display()))?;
    *LOG_FILE.lock().unwrap_or_else(|e| e.into_inner()) = Some(file);
    Ok(())
}
