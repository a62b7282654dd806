//! Curriculum settings: defined once in `pednav-config` (the launcher's check and
//! this library read the same struct and the same validation), re-exported here.

pub use pednav_config::{CurriculumConfig, SignalPhase, TaskNetConfig, Variant};
