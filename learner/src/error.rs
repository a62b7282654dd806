//! The one error type of the learner library.

use std::path::PathBuf;

/// Everything that can go wrong in `pednav-learner`.
#[derive(Debug, thiserror::Error)]
pub enum LearnerError {
    /// A network or tensor operation failed.
    #[error(transparent)]
    Net(#[from] pednav_nets::NetError),
    /// A learner setting is out of range.
    #[error(transparent)]
    Config(#[from] pednav_config::ConfigError),
    /// The replay cannot serve the request.
    #[error("replay: {0}")]
    Replay(String),
    /// A checkpoint could not be written or read.
    #[error("checkpoint {path}: {message}")]
    Checkpoint {
        /// The file or directory.
        path: PathBuf,
        /// What went wrong and how to fix it.
        message: String,
    },
    /// A checkpoint save failed at one of its steps; both generations on disk are as
    /// they were before it (the learner keeps training and saves again later).
    #[error("checkpoint {dir}: {}", .halt.describe())]
    CheckpointSave {
        /// The checkpoint directory.
        dir: PathBuf,
        /// The step that failed and its error.
        halt: pednav_runtime::generations::Halt,
    },
}

impl LearnerError {
    /// Did a checkpoint save fail because the disk (or the quota) is full?
    pub fn is_disk_full(&self) -> bool {
        matches!(self, LearnerError::CheckpointSave { halt: pednav_runtime::generations::Halt::Failed { error, .. }, .. }
            if pednav_runtime::generations::is_disk_full(error))
    }
}

impl From<candle_core::Error> for LearnerError {
    fn from(e: candle_core::Error) -> Self {
        LearnerError::Net(e.into())
    }
}

/// Result alias of the library.
pub type Result<T, E = LearnerError> = std::result::Result<T, E>;

pub(crate) fn config_error(field: &'static str, value: impl ToString, message: impl Into<String>) -> LearnerError {
    LearnerError::Config(pednav_config::ConfigError::learner(field, value, message))
}
