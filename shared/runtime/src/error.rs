//! Errors of the runtime library.

use std::path::PathBuf;

/// What can go wrong setting up or running a pednav process.
#[derive(Debug, thiserror::Error)]
pub enum RuntimeError {
    /// A configuration value is out of range or inconsistent.
    #[error("config {file}: `{field}` = {value}: {message}")]
    Config {
        /// The config file (or "defaults").
        file: String,
        /// The offending field, dotted (`runtime.envs_per_actor`).
        field: String,
        /// Its value.
        value: String,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// A section's own validation failed (its message names the field).
    #[error("config {file}, section [{section}]: {message}")]
    Section {
        /// The config file (or "defaults").
        file: String,
        /// The section (`sim`, `nets`, `dsac`, `curriculum`).
        section: String,
        /// The section's error, naming field and value.
        message: String,
    },
    /// A file could not be read, parsed or written.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: PathBuf,
        /// What happened.
        message: String,
    },
    /// A file could not be written (the disk may be full).
    #[error("{path}: {source}")]
    Write {
        /// The file.
        path: PathBuf,
        /// The operating system's error.
        source: std::io::Error,
    },
    /// An iceoryx2 operation failed.
    #[error("iceoryx2: {0}")]
    Ipc(String),
    /// A message did not match what the receiver expected.
    #[error("bad message: {0}")]
    Message(String),
    /// Another process did not answer in time.
    #[error("timed out: {0}")]
    Timeout(String),
}

/// Result with [`RuntimeError`].
pub type Result<T> = std::result::Result<T, RuntimeError>;

impl RuntimeError {
    /// Did a write fail because the disk (or the quota) is full?
    pub fn is_disk_full(&self) -> bool {
        matches!(self, RuntimeError::Write { source, .. } if crate::generations::is_disk_full(source))
    }

    pub(crate) fn file(path: impl Into<PathBuf>, message: impl std::fmt::Display) -> RuntimeError {
        RuntimeError::File { path: path.into(), message: message.to_string() }
    }
}
