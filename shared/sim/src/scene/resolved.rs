//! The resolved shapes of a scene: its ground [`Region`]s and static [`Obstacle`]s
//! with their [`Footprint`]s, as [`super::Scene::from_spec`] makes them from the spec.
//!
//! Invariant: every value of these types inside a [`super::Scene`] has passed its
//! checks — a simple polygon or a finite box or cylinder that touches the world, a
//! height in (0, [`crate::geometry::MAX_HEIGHT`]]; [`Footprint::distance`] is never
//! negative and is 0 exactly on or inside the footprint.

use super::spec::{Axis, ObstacleKind};
use crate::appearance::Facade;
use crate::geometry::{Polygon, Rect};
use crate::region_kind::RegionKind;

/// A resolved ground region (polygon form).
#[derive(Debug, Clone, PartialEq)]
pub struct Region {
    /// What the region is.
    pub kind: RegionKind,
    /// Its outline.
    pub polygon: Polygon,
    /// Zebra crossings only: walking axis (stripes alternate along it).
    pub walk_axis: Option<Axis>,
}

/// Footprint of a resolved obstacle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Footprint {
    /// Axis-aligned box.
    Box(Rect),
    /// Vertical cylinder.
    Cylinder {
        /// Centre on the ground.
        center: [f32; 2],
        /// Radius in metres.
        radius: f32,
    },
}

impl Footprint {
    /// Bounding box on the ground.
    pub fn bounds(&self) -> Rect {
        match *self {
            Footprint::Box(r) => r,
            Footprint::Cylinder { center, radius } => {
                Rect { min: [center[0] - radius, center[1] - radius], max: [center[0] + radius, center[1] + radius] }
            }
        }
    }

    /// Distance from a point to the footprint (0 inside).
    pub fn distance(&self, x: f32, y: f32) -> f32 {
        match *self {
            Footprint::Box(r) => {
                let dx = (r.min[0] - x).max(0.0).max(x - r.max[0]);
                let dy = (r.min[1] - y).max(0.0).max(y - r.max[1]);
                (dx * dx + dy * dy).sqrt()
            }
            Footprint::Cylinder { center, radius } => {
                (((x - center[0]).powi(2) + (y - center[1]).powi(2)).sqrt() - radius).max(0.0)
            }
        }
    }
}

/// A resolved static obstacle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Obstacle {
    /// What it is.
    pub kind: ObstacleKind,
    /// Where it stands.
    pub footprint: Footprint,
    /// Height in metres.
    pub height: f32,
    /// Grey level of lit faces.
    pub shade: f32,
    /// How its walls look (buildings; the default for everything else).
    pub facade: Facade,
    /// Radius of the drawn crown (trees; 0 for everything else).
    pub crown_radius: f32,
}
