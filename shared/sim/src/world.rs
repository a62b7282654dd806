//! [`SimWorld`]: everything immutable that all environments of a process share —
//! the validated scene, its region (reward) map, its static colliders and the
//! simulator settings.
//!
//! Invariant: built once, never mutated; environments hold it behind an `Arc`.

use crate::config::SimConfig;
use crate::error::Result;
use crate::physics::{AgentBody, StaticWorld};
use crate::region_map::RegionMap;
use crate::scene::Scene;

/// The shared, immutable part of the simulator.
pub struct SimWorld {
    /// The validated scene.
    pub scene: Scene,
    /// Its rasterised reward map.
    pub map: RegionMap,
    /// Its static colliders and the character controller.
    pub physics: StaticWorld,
    /// Simulator settings.
    pub config: SimConfig,
}

impl SimWorld {
    /// Validate the settings and derive the map and colliders from the scene.
    pub fn new(scene: Scene, config: SimConfig) -> Result<SimWorld> {
        config.validate()?;
        let map = RegionMap::new(&scene);
        let physics = StaticWorld::new(&scene, AgentBody { radius: config.agent_radius, height: config.agent_height });
        Ok(SimWorld { scene, map, physics, config })
    }
}
