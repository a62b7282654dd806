//! Where the networks run: `cpu`, `cuda` or `cuda:N`, as configs and flags name it.
//!
//! A CUDA device needs a binary built with this crate's `cuda` feature
//! (`deploy/build_cuda.sh` builds one on a machine without a GPU) and a usable GPU;
//! asking for one otherwise is an error that says which of the two is missing,
//! raised by [`DeviceSpec::open`] before any network exists.
//!
//! Invariant: a [`DeviceSpec`] prints as the text it parses from, so a config that
//! is written back keeps its device.

use std::fmt;
use std::str::FromStr;

use candle_core::Device;
use serde::{Deserialize, Serialize};

use crate::error::NetError;

/// Whether this binary was built with CUDA support (the `cuda` feature).
pub const CUDA_BUILT: bool = cfg!(feature = "cuda");

/// A compute device by name.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub enum DeviceSpec {
    /// The CPU kernels of this crate (the default).
    #[default]
    Cpu,
    /// CUDA GPU number N (`cuda` is `cuda:0`).
    Cuda(usize),
}

impl DeviceSpec {
    /// Open the device: the CPU always; a CUDA GPU when this binary has CUDA support
    /// and the GPU can be used, otherwise an error naming what is missing.
    pub fn open(self) -> Result<Device, NetError> {
        match self {
            DeviceSpec::Cpu => Ok(Device::Cpu),
            DeviceSpec::Cuda(n) => open_cuda(self, n),
        }
    }

    /// True for a GPU.
    pub fn is_gpu(self) -> bool {
        matches!(self, DeviceSpec::Cuda(_))
    }
}

#[cfg(feature = "cuda")]
fn open_cuda(spec: DeviceSpec, n: usize) -> Result<Device, NetError> {
    Device::new_cuda(n).map_err(|e| NetError::Device {
        device: spec.to_string(),
        message: format!(
            "cannot use CUDA device {n}: {e} (check that `nvidia-smi` lists it, that the driver supports \
             CUDA 13, and CUDA_VISIBLE_DEVICES)"
        ),
    })
}

#[cfg(not(feature = "cuda"))]
fn open_cuda(spec: DeviceSpec, _n: usize) -> Result<Device, NetError> {
    Err(NetError::Device {
        device: spec.to_string(),
        message: "this binary was built without CUDA support: build the CUDA binaries with \
                  `deploy/build_cuda.sh` (no GPU needed to build) and run those, or use `cpu`"
            .into(),
    })
}

impl fmt::Display for DeviceSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            DeviceSpec::Cpu => f.write_str("cpu"),
            DeviceSpec::Cuda(0) => f.write_str("cuda"),
            DeviceSpec::Cuda(n) => write!(f, "cuda:{n}"),
        }
    }
}

impl FromStr for DeviceSpec {
    type Err = String;

    fn from_str(s: &str) -> Result<DeviceSpec, String> {
        let t = s.trim().to_ascii_lowercase();
        let bad = || format!("unknown device {s:?}: expected \"cpu\", \"cuda\" or \"cuda:N\" (N = 0, 1, …)");
        match t.as_str() {
            "cpu" => Ok(DeviceSpec::Cpu),
            "cuda" => Ok(DeviceSpec::Cuda(0)),
            _ => t.strip_prefix("cuda:").and_then(|n| n.parse().ok()).map(DeviceSpec::Cuda).ok_or_else(bad),
        }
    }
}

impl TryFrom<String> for DeviceSpec {
    type Error = String;
    fn try_from(s: String) -> Result<DeviceSpec, String> {
        s.parse()
    }
}

impl From<DeviceSpec> for String {
    fn from(d: DeviceSpec) -> String {
        d.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_parse_and_print_back() {
        for (text, spec) in [("cpu", DeviceSpec::Cpu), ("cuda", DeviceSpec::Cuda(0)), ("cuda:3", DeviceSpec::Cuda(3))] {
            assert_eq!(text.parse::<DeviceSpec>().unwrap(), spec);
            assert_eq!(spec.to_string(), text);
        }
        assert_eq!(" CUDA:0 ".parse::<DeviceSpec>().unwrap(), DeviceSpec::Cuda(0));
        for bad in ["gpu", "cuda:", "cuda:x", "cuda:-1", ""] {
            let err = bad.parse::<DeviceSpec>().unwrap_err();
            assert!(err.contains("cuda:N"), "{err}");
        }
    }

    #[test]
    fn the_cpu_always_opens_and_a_gpu_error_says_what_is_missing() {
        assert!(DeviceSpec::Cpu.open().unwrap().is_cpu());
        if !CUDA_BUILT {
            let err = DeviceSpec::Cuda(0).open().unwrap_err().to_string();
            assert!(err.contains("build_cuda.sh") && err.contains("`cuda`"), "{err}");
        }
    }
}
