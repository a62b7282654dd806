//! Networks shared by the learner and the actors: encoders (3D-TCN, frame
//! stacking, MLP), the Cholesky-Gaussian policy, the FQF fraction proposal and the
//! NDQFN quantile net, on a fused channel-last CPU convolution kernel; a streaming
//! cache for the actors' 3D-TCN inference; AdamW with checkpointable state.
//!
//! Call [`init_cpu_runtime`] once at process start-up.

#![warn(missing_docs)]

pub mod config;
pub mod cpu;
pub mod device;
pub mod encoder;
pub mod error;
pub mod heads;
pub mod layers;
pub mod nets;
pub mod ops;
pub mod optim;
pub mod params;
pub mod stream;

pub use config::{ACTION_DIM, ConvPrecision, EncoderKind, NetsConfig};
pub use cpu::init_cpu_runtime;
pub use device::{CUDA_BUILT, DeviceSpec};
pub use encoder::{Encoder, Obs, Transitions, temporal_plan};
pub use error::{NetError, Result};
pub use heads::{CholeskyGaussian, FractionNet, Fractions, PolicyNet, PolicySample, QuantileGrid, QuantileNet};
pub use nets::{ContrastHead, DsacNets, NetParts, OnlineFeatures, StateHead, TransitionFeatures, TwinCritic};
pub use optim::{AdamW, AdamWConfig, OptimStep};
pub use params::ParamStore;
pub use stream::PolicyStream;
