//! Errors of the experiments library.

use std::path::{Path, PathBuf};

/// What can go wrong running an evaluation or drawing a plot.
#[derive(Debug, thiserror::Error)]
pub enum ExperimentError {
    /// A file could not be read, parsed or written.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: PathBuf,
        /// What happened.
        message: String,
    },
    /// Drawing failed.
    #[error("plot: {0}")]
    Plot(String),
    /// A probe could not be set up.
    #[error("probe: {0}")]
    Probe(String),
    /// A diagnosis could not be computed.
    #[error("diagnosis: {0}")]
    Diagnosis(String),
    /// The simulator refused something.
    #[error(transparent)]
    Sim(#[from] pednav_sim::SimError),
    /// The networks failed.
    #[error(transparent)]
    Nets(#[from] pednav_nets::NetError),
    /// The acting policy failed.
    #[error("policy: {0}")]
    Policy(#[source] pednav_sim::PolicyError),
    /// A tensor operation failed.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

impl ExperimentError {
    pub(crate) fn file(path: &Path, message: impl std::fmt::Display) -> ExperimentError {
        ExperimentError::File { path: path.to_path_buf(), message: message.to_string() }
    }
}

/// Result with [`ExperimentError`].
pub type Result<T> = std::result::Result<T, ExperimentError>;
