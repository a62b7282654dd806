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
        features: [f32; 3],
    },
}

/// Result alias of the curriculum library.
pub type Result<T, E = CurriculumError> = std::result::Result<T, E>;
