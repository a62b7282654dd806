//! # pednav-sim — the built-in urban crossing simulator
//!
//! Replaces CARLA for pednav (docs/design.md §3): a scene described as data
//! ([`Scene`], the reference corner in `scenes/corner.toml`), the paper's reward
//! r = r_m + r_v + r_c in one place ([`reward`]) and the reward map derived from
//! it ([`RegionMap`]), a rapier3d kinematic pedestrian
//! ([`physics::StaticWorld`], [`Pedestrian`]), a headless wgpu renderer of
//! first-person 84×84 greyscale views that draws all views of a process in one
//! submission ([`render::Renderer`]), Gymnasium-style environments ([`VecEnv`],
//! [`PedestrianEnv`], [`Env`]), the oracle planner ([`oracle::Oracle`]), the
//! [`Policy`] trait every acting loop drives (with the random, oracle and fixed
//! reference policies, [`policy`]) and the
//! pictures a person looks at ([`draw`]); traffic — signals, vehicles and other
//! pedestrians — when a run asks for it ([`traffic`]).
//!
//! Everything is deterministic: the only randomness (optional domain
//! randomisation of the look, the traffic) comes from the seed passed to `reset`.

#![warn(missing_docs)]

pub mod appearance;
pub mod config;
pub mod draw;
pub mod env;
pub mod error;
pub mod geometry;
pub mod oracle;
pub mod pedestrian;
pub mod physics;
pub mod policy;
pub mod recognisability;
pub mod region_kind;
pub mod region_map;
pub mod render;
pub mod returns;
pub mod reward;
pub mod scene;
pub mod state_obs;
pub mod traffic;
pub mod world;

pub use config::{GroundSignals, ObsMode, SimConfig, TrafficLevel};
pub use env::{Env, Info, Observation, PedestrianEnv, StepOutcome, VecEnv};
pub use error::{Result, SimError};
pub use pedestrian::{Action, Pedestrian, Transition, command_of};
pub use policy::{Policy, PolicyError};
pub use region_kind::RegionKind;
pub use region_map::RegionMap;
pub use render::{BackendChoice, CameraView, Frames, Look, Renderer, RendererConfig, prepare_headless_env};
pub use returns::DiscountedReturn;
pub use reward::Rewards;
pub use scene::{Pose, Scene};
pub use state_obs::{STATE_OBS_DIM, STATE_OBS_MAX, TRAFFIC_STATE_DIM, state_obs_dim};
pub use traffic::{SafetyEvents, Traffic, TrafficState};
pub use world::SimWorld;
