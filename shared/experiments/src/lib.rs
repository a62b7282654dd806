//! # pednav-experiments — reproducing the paper's evaluation and figures
//!
//! - [`protocol`]: the validation protocol of §V-C (14 points × 8 yaws × 10 runs,
//!   T_max 2000) and custom start lists;
//! - [`evaluate`]: running the episodes with a checkpoint's policy (or random,
//!   or the oracle), batched, deterministic per task;
//! - [`bootstrap`]: confidence intervals of a difference between two variants'
//!   averages, over runs and their episodes;
//! - [`diagnose`]: what a trained agent learned along its evaluation episodes
//!   (a linear probe of the encoder for pose and return, the critic against
//!   Monte-Carlo returns);
//! - [`probe`]: what a frame or a short history shows — a small CNN trained on
//!   held-out examples (which corner: `pednav-recognisability`, with the simulator's
//!   aliasing measure);
//! - [`traffic_probe`]: at the kerb with traffic on, can the signal's WALK and a
//!   vehicle about to cross be read from the pixels (`pednav-traffic-probe`);
//! - [`table`]: Table III's aggregation (mean ± std per point, Avg.Int, Avg.Ext,
//!   success rate, oracle);
//! - [`plots`]: Fig. 3 (return and episodes vs decision steps), Fig. 4 snapshots,
//!   Fig. 5 trajectories, multi-run comparisons.

#![warn(missing_docs)]

pub mod bootstrap;
pub mod diagnose;
pub mod error;
pub mod evaluate;
pub mod plots;
pub mod probe;
pub mod protocol;
pub mod table;
pub mod traffic_probe;

pub use error::{ExperimentError, Result};
