//! The error types of the simulator library: [`SimError`] and the renderer's
//! [`RenderError`] it wraps.
//!
//! Invariant: this module imports no other module of the crate (every module
//! imports it), so it cannot close an import circle.

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
    /// A task set the start's position in the signal cycle where there is no traffic,
    /// or outside [0, 1).
    #[error(
        "a task's position in the signal cycle ({cycle}) needs traffic (on: {traffic}) and a value in [0, 1) \
         (curriculum.signal_phase = \"task\" needs sim.traffic on)"
    )]
    CyclePosition {
        /// The position given.
        cycle: f32,
        /// Whether the world has traffic.
        traffic: bool,
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
    Render(#[from] RenderError),
    /// Writing an image or GIF failed.
    #[error("cannot write {path}: {message}")]
    Output {
        /// The output file.
        path: PathBuf,
        /// The encoder's or file system's message.
        message: String,
    },
}

/// Errors of the renderer ([`crate::render`], which re-exports this type as
/// `render::RenderError`). Defined here, with plain-data fields only, so that this
/// module — which every other one imports — imports none of them.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// No graphics adapter of the requested backends exists.
    #[error(
        "no graphics adapter found for backend `{backend}` (tried: {tried}). On a machine without a GPU install Mesa: \
         `apt-get install -y libegl1 libegl-mesa0 libgl1-mesa-dri` (OpenGL through EGL, llvmpipe) or \
         `apt-get install -y mesa-vulkan-drivers libvulkan1` (Vulkan, lavapipe); with a GPU, install its driver"
    )]
    NoAdapter {
        /// The backend choice that was asked for.
        backend: String,
        /// The wgpu backends that were searched.
        tried: String,
    },
    /// The adapter refused to create a device.
    #[error("cannot create a device on adapter {adapter}: {message}")]
    Device {
        /// The adapter's name and backend.
        adapter: String,
        /// wgpu's message.
        message: String,
    },
    /// A batch of moving things does not match the cameras it is drawn with.
    #[error("the batch of moving things has {batch} views for {views} cameras")]
    BatchViews {
        /// Views in the batch.
        batch: usize,
        /// Cameras asked for.
        views: usize,
    },
    /// More views were asked for than the renderer was built for.
    #[error("asked to render {asked} views, but the renderer was built for at most {max}")]
    TooManyViews {
        /// Views asked for.
        asked: usize,
        /// Capacity.
        max: usize,
    },
    /// The atlas would exceed the adapter's texture size limit.
    #[error(
        "an atlas of {views} views of {size}×{size} needs {needed} pixels per side, over the adapter limit {limit}"
    )]
    AtlasTooLarge {
        /// Number of views.
        views: usize,
        /// View side in pixels.
        size: u32,
        /// Needed atlas side.
        needed: u32,
        /// Adapter limit.
        limit: u32,
    },
    /// The scene's ground texture (one texel per region-map cell) exceeds the
    /// adapter's texture size limit.
    #[error(
        "the scene's ground texture is {width}×{height} texels (one per cell), over this adapter's limit {limit} \
         a side: enlarge the scene's `cell_size` or shrink its `extent`"
    )]
    GroundTooLarge {
        /// Texels along x.
        width: u32,
        /// Texels along y.
        height: u32,
        /// Adapter limit.
        limit: u32,
    },
    /// Mapping the readback buffer or waiting for the device failed.
    #[error("GPU readback failed: {0}")]
    Readback(String),
}

/// Result alias of the simulator library.
pub type Result<T, E = SimError> = std::result::Result<T, E>;
