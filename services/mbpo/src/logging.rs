//! Logging of the `mbpo` command: every event goes to stderr (above any progress bar) and,
//! once the run directory is known, also to a log file in it (`<run>/logs/train.log` for
//! `mbpo train`, `<run>/logs/supervisor.log` for `mbpo run`, next to the services' logs).
//!
//! The log file is attached after logging starts because the run directory is only known
//! once the config is resolved; events before that (argument errors) go to stderr only.
//! `mbpo bench learning` runs several seeds in one process, on their own threads: each seed's
//! thread logs into its own run's file ([`thread_also_to_file`]).

use std::cell::RefCell;
use std::fs::File;
use std::io::{IsTerminal, Write};
use std::path::Path;
use std::sync::Mutex;

use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{fmt, EnvFilter};

/// The run's log file, once attached.
static LOG_FILE: Mutex<Option<File>> = Mutex::new(None);

thread_local! {
    /// This thread's own log file, in place of the process's (one seed of a benchmark).
    static THREAD_LOG: RefCell<Option<File>> = const { RefCell::new(None) };
}

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

/// The attached log file: the thread's own if it has one, else the process's (unbuffered: one
/// write per event, so a crash loses nothing logged); a sink until one is attached.
struct LogFile;

impl Write for LogFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let own = THREAD_LOG.with_borrow_mut(|f| f.as_mut().map(|f| f.write_all(buf)));
        if let Some(written) = own {
            return written.map(|()| buf.len());
        }
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
    let file =
        open_log(path).with_context(|| format!("opening the log file {}", path.display()))?;
    *LOG_FILE.lock().unwrap_or_else(|e| e.into_inner()) = Some(file);
    Ok(())
}

/// Open `path` for appending (its directory is created).
fn open_log(path: &Path) -> std::io::Result<File> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir)?;
    }
    File::options().create(true).append(true).open(path)
}

/// While the returned guard lives, append this thread's events to `path` (instead of the
/// process's log file): the log of one seed of `mbpo bench learning`.
pub fn thread_also_to_file(path: &Path) -> std::io::Result<ThreadLog> {
    let file = open_log(path).map_err(|e| {
        std::io::Error::new(
            e.kind(),
            format!("opening the log file {}: {e}", path.display()),
        )
    })?;
    let previous = THREAD_LOG.replace(Some(file));
    Ok(ThreadLog {
        previous,
        this_thread: std::marker::PhantomData,
    })
}

/// Ends [`thread_also_to_file`] when dropped (on the thread that made it: it is not `Send`),
/// putting back the thread's previous log file.
pub struct ThreadLog {
    previous: Option<File>,
    this_thread: std::marker::PhantomData<*const ()>,
}

impl Drop for ThreadLog {
    fn drop(&mut self) {
        let previous = self.previous.take();
        let _ = THREAD_LOG.try_with(|f| *f.borrow_mut() = previous);
    }
}
