//! The pednav learner library: the modified DSAC update, the dual replay of the
//! paper's Algorithm 2, the replay-ratio limiter, checkpoints, and the comparison of
//! one update on two devices.

#![warn(missing_docs)]

pub mod checkpoint;
pub mod device_check;
pub mod dsac;
pub mod error;
mod quantile_huber;
pub mod rate;
pub mod replay;

pub use checkpoint::{
    CheckpointMeta, TrainedAgent, acting_files, agent_files, checkpoint_exists, load_acting, load_agent,
    load_checkpoint, load_checkpoint_or_previous, previous_generation, read_meta, save_checkpoint, warm_start,
};
pub use device_check::{DeviceComparison, compare_update, fill_replay};
pub use dsac::{Dsac, UpdateStats, fraction_gradient, quantile_huber_loss, smaller_mean};
pub use error::{LearnerError, Result};
pub use pednav_config::DsacConfig;
pub use rate::RateLimiter;
pub use replay::{Batch, DualReplay, Frame, FrameKind, ReplayConfig, Step, dual_split, n_step_return, shift_frames};
