//! # pednav-config — the settings every pednav process agrees on
//!
//! - [`dsac`]: the `[dsac]` section (Table IV);
//! - [`replay`]: the `[replay]` section, [`FrameKind`] (what one stored frame is) and
//!   [`ReplayFootprint`] (the bytes the replay holds per step and per terminal entry);
//! - [`curriculum`]: the `[curriculum]` section, its [`Variant`] and the task-value
//!   net's [`TaskNetConfig`];
//! - [`category`]: the curriculum's task [`Category`] and its wire code;
//! - [`rng`]: the random streams of a run's one seed, named once.
//!
//! Invariant: this crate is a leaf — it depends on no other pednav crate — so the
//! learner, the curriculum and the runtime (and through it the launcher's `check`)
//! all read one definition of each setting and apply one validation of it.

#![warn(missing_docs)]

pub mod category;
pub mod curriculum;
pub mod dsac;
pub mod error;
pub mod replay;
pub mod rng;

pub use category::Category;
pub use curriculum::{CurriculumConfig, SignalPhase, TaskNetConfig, Variant};
pub use dsac::DsacConfig;
pub use error::{ConfigError, Result};
pub use replay::{FrameKind, ReplayConfig, ReplayFootprint};
