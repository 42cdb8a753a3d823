//! The run directory's files a gateway writes: checkpoint files and logs that arrive over the
//! link, and the step of a checkpoint directory.

use std::path::{Path, PathBuf};

use mbpo_train::checkpoint;

use crate::GatewayError;

/// Write `bytes` to `path` (its directory made first) the way checkpoint files are written:
/// a crash leaves the old file or the new one, never half of one.
pub(crate) fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), GatewayError> {
    if let Some(dir) = path.parent() {
        std::fs::create_dir_all(dir).map_err(|source| GatewayError::Io {
            path: dir.to_path_buf(),
            source,
        })?;
    }
    Ok(checkpoint::write_atomically(path, bytes)?)
}

/// Append `text` to `dir/file` (both made when missing).
pub(crate) fn append(dir: &Path, file: &str, text: &str) -> Result<(), GatewayError> {
    use std::io::Write;
    let io = |path: PathBuf| move |source| GatewayError::Io { path, source };
    std::fs::create_dir_all(dir).map_err(io(dir.to_path_buf()))?;
    let path = dir.join(file);
    let mut f = std::fs::OpenOptions::new()
        .create(true)
        .append(true)
        .open(&path)
        .map_err(io(path.clone()))?;
    f.write_all(text.as_bytes()).map_err(io(path))
}

/// `name` (a worker's, from the network) usable as a directory name.
pub(crate) fn sanitize(name: &str) -> String {
    let s: String = name
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' || c == '.' {
                c
            } else {
                '_'
            }
        })
        .take(64)
        .collect();
    if s.is_empty() || s.starts_with('.') {
        format!("worker{s}")
    } else {
        s
    }
}

/// Read `path` whole, an error naming it.
pub(crate) fn read(path: &Path) -> Result<Vec<u8>, GatewayError> {
    std::fs::read(path).map_err(|source| GatewayError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The step T of checkpoint directory `dir` (`checkpoints/<T>`).
pub(crate) fn checkpoint_step(dir: &Path) -> Result<u64, GatewayError> {
    dir.file_name()
        .and_then(|n| n.to_str())
        .and_then(|n| n.parse().ok())
        .ok_or_else(|| {
            GatewayError::Failed(format!(
                "{}: not a checkpoint directory (checkpoints/<step>)",
                dir.display()
            ))
        })
}
