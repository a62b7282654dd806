//! The one error type of the simulator library.

use std::path::PathBuf;

/// Everything that can go wrong in `pednav-sim`.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A scene file could not be read from disk.
    #[error("cannot read scene file {path}: {source}")]
    SceneIo {
        /// The file that was asked for.
        path: PathBuf,
        /// The underlying I/O error.
        source: std::io::Error,
    },
    /// A scene file is not valid TOML or does not match the scene schema.
    #[error("cannot parse scene {origin}: {message}")]
    SceneParse {
        /// Where the scene came from (a path or `built-in:<name>`).
        origin: String,
        /// The parser's message, which names the offending key and line.
        message: String,
    },
    /// A scene parsed but its contents are inconsistent.
    #[error("invalid scene {origin}: field `{field}`: {message}")]
    SceneInvalid {
        /// Where the scene came from.
        origin: String,
        /// The offending field, e.g. `validation_points[3]`.
        field: String,
        /// What is wrong and how to fix it.
        message: String,
    },
    /// A simulator setting is out of range.
    #[error("invalid simulator setting `{field}` = {value}: {message}")]
    Config {
        /// The offending field.
        field: &'static str,
        /// Its value, as text.
        value: String,
        /// The allowed range.
        message: String,
    },
    /// A task pose cannot be used as an episode start.
    #[error("invalid task pose (x={x:.2}, y={y:.2}): {message}")]
    InvalidTask {
        /// Pose x in metres.
        x: f32,
        /// Pose y in metres.
        y: f32,
        /// Why it is rejected.
        message: String,
    },
    /// `step` was called on an environment whose episode ended, or that was never reset.
    #[error("environment {env} must be reset before it is stepped (episode over or never started)")]
    NeedsReset {
        /// Index of the environment inside the vectorized env.
        env: usize,
    },
    /// The number of actions does not match the number of environments.
    #[error("got {got} actions for {expected} environments")]
    ActionCount {
        /// Number of environments.
        expected: usize,
        /// Number of actions passed.
        got: usize,
    },
    /// An action contains NaN or infinity.
    #[error("action for environment {env} is not finite: {action:?}")]
    NonFiniteAction {
        /// Index of the environment.
        env: usize,
        /// The offending action.
        action: [f32; 3],
    },
    /// The renderer failed (no adapter, device loss, readback failure).
    #[error(transparent)]
    Render(#[from] crate::render::RenderError),
    /// Writing an image or GIF failed.
    #[error("cannot write {path}: {message}")]
    Output {
        /// The output file.
        path: PathBuf,
        /// The encoder's or file system's message.
        message: String,
    },
}

/// Result alias of the simulator library.
pub type Result<T, E = SimError> = std::result::Result<T, E>;
