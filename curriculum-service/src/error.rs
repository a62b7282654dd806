//! The one error type of the curriculum library.

/// Everything that can go wrong in `pednav-curriculum`.
#[derive(Debug, thiserror::Error)]
pub enum CurriculumError {
    /// A setting is out of range.
    #[error(transparent)]
    Config(#[from] pednav_config::ConfigError),
    /// No valid start pose was found in the curriculum region.
    #[error(
        "no valid task found in the curriculum region (enlarged, if configured) after {tries} draws; \
         is the region free of obstacles?"
    )]
    NoValidTask {
        /// Draws made.
        tries: usize,
    },
    /// The task-value network failed (candle error).
    #[error("task-value network: {0}")]
    Net(String),
    /// An episode report is inconsistent.
    #[error("bad episode report: {0}")]
    Report(String),
    /// The return predictor produced a non-finite value.
    #[error("the return predictor produced a non-finite value ({value}) for task {features:?}")]
    NonFinitePrediction {
        /// The value.
        value: f32,
        /// The task's features.
        features: crate::returns::TaskFeatures,
    },
    /// A save of the service's state failed at one of its steps; both generations on
    /// disk are as they were (the service keeps serving and saves again later).
    #[error("curriculum state {path}: {}", .halt.describe())]
    StateSave {
        /// The state file.
        path: std::path::PathBuf,
        /// The step that failed and its error.
        halt: pednav_runtime::generations::Halt,
    },
}

impl CurriculumError {
    /// Did a state save fail because the disk (or the quota) is full?
    pub fn is_disk_full(&self) -> bool {
        matches!(self, CurriculumError::StateSave { halt: pednav_runtime::generations::Halt::Failed { error, .. }, .. }
            if pednav_runtime::generations::is_disk_full(error))
    }
}

/// Result alias of the curriculum library.
pub type Result<T, E = CurriculumError> = std::result::Result<T, E>;
