//! Adapter selection: which wgpu backend and device a renderer runs on.
//!
//! Holds the user's [`BackendChoice`], the ranking of the adapters found, the
//! environment preparation of a headless process ([`prepare_headless_env`]) and
//! the one-line description of an adapter used in logs and errors.
//!
//! Invariant: the ranking prefers a real GPU (discrete, integrated, virtual) over
//! Mesa's CPU rasterisers, Vulkan over GL on a GPU and GL (llvmpipe) over Vulkan
//! (lavapipe) on the CPU; only backends the [`BackendChoice`] allows are ever
//! enumerated, and finding none is a [`RenderError::NoAdapter`] naming them.

use crate::error::RenderError;

/// Which wgpu backend to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum BackendChoice {
    /// Best adapter found: a real GPU first, then Mesa's CPU rasterisers.
    #[default]
    Auto,
    /// Vulkan only (a GPU driver, or lavapipe).
    Vulkan,
    /// OpenGL ES through EGL only (a GPU driver, or llvmpipe).
    Gl,
}

impl BackendChoice {
    /// The choice named by the `PEDNAV_BACKEND` environment variable (`auto`,
    /// `vulkan` or `gl`), or `Auto` when it is unset. Lets a user or a test run pin
    /// a backend without a flag; an unknown value is an error naming the variable.
    pub fn from_env() -> Result<BackendChoice, String> {
        match std::env::var("PEDNAV_BACKEND") {
            Err(_) => Ok(BackendChoice::Auto),
            Ok(v) => match v.to_ascii_lowercase().as_str() {
                "" | "auto" => Ok(BackendChoice::Auto),
                "vulkan" => Ok(BackendChoice::Vulkan),
                "gl" => Ok(BackendChoice::Gl),
                other => Err(format!("PEDNAV_BACKEND={other} is not one of auto, vulkan, gl")),
            },
        }
    }
}

fn device_rank(info: &wgpu::AdapterInfo) -> (u8, u8) {
    let kind = match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Cpu => 3,
        wgpu::DeviceType::Other => 4,
    };
    // On a real GPU prefer Vulkan; on Mesa's CPU rasterisers GL (llvmpipe) measured
    // faster than Vulkan (lavapipe) for our batched 84×84 views (README, Performance).
    let backend = match (info.backend, info.device_type) {
        (wgpu::Backend::Gl, wgpu::DeviceType::Cpu) => 0,
        (wgpu::Backend::Vulkan, _) => 1,
        (wgpu::Backend::Gl, _) => 2,
        _ => 3,
    };
    (kind, backend)
}

/// Give the graphics stack a private runtime directory when the environment names
/// none, so probing for a window system on a headless machine does not print
/// `error: XDG_RUNTIME_DIR is invalid or not set in the environment.` (libwayland,
/// loaded by Mesa) for every renderer; with a valid directory and no compositor the
/// probe fails quietly and real errors still show.
///
/// Call it first thing in `main` of a process that renders, before any thread
/// starts: changing the environment is only sound while no other thread can read it,
/// so with other threads running it leaves the environment alone. Does nothing when
/// `XDG_RUNTIME_DIR` already names a directory.
pub fn prepare_headless_env() {
    if std::env::var_os("XDG_RUNTIME_DIR").is_some_and(|d| std::path::Path::new(&d).is_dir()) {
        return;
    }
    let single_threaded = std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| s.lines().find_map(|l| l.strip_prefix("Threads:")).and_then(|v| v.trim().parse::<u32>().ok()))
        == Some(1);
    if !single_threaded {
        tracing::debug!("prepare_headless_env after other threads started: XDG_RUNTIME_DIR left unset");
        return;
    }
    // SAFETY: getuid has no preconditions.
    let dir = std::env::temp_dir().join(format!("pednav-runtime-{}", unsafe { libc::getuid() }));
    use std::os::unix::fs::{DirBuilderExt, PermissionsExt};
    let made = std::fs::DirBuilder::new().recursive(true).mode(0o700).create(&dir);
    let private = std::fs::metadata(&dir).is_ok_and(|m| m.is_dir() && m.permissions().mode() & 0o077 == 0);
    if made.is_ok() && private {
        // SAFETY: this is the process's only thread (checked above).
        unsafe { std::env::set_var("XDG_RUNTIME_DIR", &dir) };
    }
}

/// Pick the best adapter for a backend choice.
pub(super) fn pick_adapter(choice: BackendChoice) -> Result<wgpu::Adapter, RenderError> {
    let backends = match choice {
        BackendChoice::Auto => wgpu::Backends::VULKAN | wgpu::Backends::GL,
        BackendChoice::Vulkan => wgpu::Backends::VULKAN,
        BackendChoice::Gl => wgpu::Backends::GL,
    };
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = backends;
    let instance = wgpu::Instance::new(desc);
    let mut adapters = pollster::block_on(instance.enumerate_adapters(backends));
    adapters.sort_by_key(|a| device_rank(&a.get_info()));
    adapters.into_iter().next().ok_or_else(|| RenderError::NoAdapter {
        backend: format!("{choice:?}").to_lowercase(),
        tried: format!("{backends:?}"),
    })
}

/// "name (backend, device type)" of an adapter, for logs and errors.
pub(super) fn describe(info: &wgpu::AdapterInfo) -> String {
    format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type)
}
