//! What `mbpo`'s commands print: one line at a time on stdout, where a reader that went away
//! (`mbpo bench gemm | head -1`) ends the command quietly rather than with a panic trace.

/// `println!` that returns an error instead of panicking: a closed pipe becomes
/// [`StdoutClosed`] (see [`write_stdout`]).
#[macro_export]
macro_rules! out {
    ($($arg:tt)*) => {
        $crate::stdout::write_stdout(format_args!("{}\n", format_args!($($arg)*)))
    };
}

/// The reader of stdout went away (as `head` does once it has its lines): the output the
/// command still had is unwanted, so it ends with success. Only a write to stdout reports this;
/// a broken pipe anywhere else (a child process, the Python env bridge) stays an error.
#[derive(Debug)]
pub struct StdoutClosed;

impl std::fmt::Display for StdoutClosed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("stdout was closed by its reader")
    }
}

impl std::error::Error for StdoutClosed {}

/// Write to stdout; a closed pipe becomes [`StdoutClosed`], any other failure (a full disk)
/// its own error.
pub fn write_stdout(text: std::fmt::Arguments<'_>) -> anyhow::Result<()> {
    use std::io::Write as _;
    match std::io::stdout().lock().write_fmt(text) {
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Err(StdoutClosed.into()),
        other => Ok(other?),
    }
}
