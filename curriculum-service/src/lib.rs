//! # pednav-curriculum — NavACL⁺ (Slope, Hard), NavACL and fixed-start curricula
//!
//! The curriculum logic of the paper's §III-A/B and Algorithm 1, independent of
//! any network and of IPC: task features and discounted returns ([`returns`]),
//! the PassFirstTask gate ([`gate`]), adaptive filtering and the per-variant
//! schedules ([`filter`]), uniform task sampling from the scene's curriculum
//! region ([`sampler`]) and the [`TaskScheduler`] that proposes tasks, with the
//! return/success predictor behind the [`ReturnPredictor`] trait.
//!
//! [`Curriculum`] runs Algorithm 1 around them with the task-value net ([`net`], on
//! `pednav-nets`): f^r trained on the augmented tasks of every step (NavACL⁺) or f^s on
//! initial tasks (NavACL), every Δ_ep episodes.
//!
//! [`classify`] draws the task classification over the region (Fig. 4);
//! [`state_file`] holds the service's saved state (checksummed, two generations);
//! the service process itself is the `pednav-curriculum` binary
//! (`src/bin/pednav-curriculum/`).

#![warn(missing_docs)]

pub mod classify;
pub mod config;
pub mod curriculum;
pub mod error;
pub mod filter;
pub mod gate;
pub mod net;
pub mod returns;
pub mod sampler;
pub mod scheduler;
pub mod state_file;

pub use classify::{CellClass, Classification, classify_region};
pub use config::{CurriculumConfig, Variant};
pub use curriculum::{Curriculum, CurriculumState, EpisodeOutcome, ReportSummary};
pub use error::{CurriculumError, Result};
pub use filter::{Bands, Category, Fit};
pub use gate::PassFirstTask;
pub use net::{NetState, Target, TaskNetConfig, TaskValueNet};
pub use returns::{TaskFeatures, discounted_returns, task_features};
pub use sampler::TaskSampler;
pub use scheduler::{Proposal, ReturnPredictor, SchedulerState, TaskScheduler};
pub use state_file::ServiceState;
