//! [`SimWorld`]: everything immutable that all environments of a process share —
//! the validated scene, its region (reward) map, its static colliders, the
//! simulator settings and, with traffic on, the traffic description and its level.
//!
//! Invariant: built once, never mutated; environments hold it behind an `Arc`.
//! Each environment's moving traffic lives beside it, in its own
//! [`crate::traffic::TrafficState`].

use std::sync::Arc;

use crate::config::SimConfig;
use crate::error::Result;
use crate::physics::{AgentBody, StaticWorld};
use crate::region_map::RegionMap;
use crate::scene::Scene;
use crate::traffic::{Traffic, TrafficSettings};

/// The shared, immutable part of the simulator.
pub struct SimWorld {
    /// The validated scene (with its traffic fixtures when traffic is on).
    pub scene: Scene,
    /// Its rasterised reward map.
    pub map: RegionMap,
    /// Its static colliders and the character controller.
    pub physics: StaticWorld,
    /// Simulator settings.
    pub config: SimConfig,
    /// The traffic and its level's numbers; `None` with `traffic = "off"`.
    pub traffic: Option<(Arc<Traffic>, TrafficSettings)>,
}

impl SimWorld {
    /// Validate the settings and derive the map and colliders from the scene (with
    /// the traffic fixtures when the settings turn traffic on).
    pub fn new(scene: Scene, config: SimConfig) -> Result<SimWorld> {
        config.validate()?;
        let scene = scene.with_traffic(config.traffic)?;
        let traffic = scene.traffic.as_ref().and_then(|t| t.settings(&config).map(|s| (t.clone(), s)));
        let map = RegionMap::new(&scene);
        let physics = StaticWorld::new(&scene, AgentBody { radius: config.agent_radius, height: config.agent_height });
        Ok(SimWorld { scene, map, physics, config, traffic })
    }
}
