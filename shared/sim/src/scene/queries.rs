//! What the rest of the simulator asks a validated [`Scene`]: whether a pose can
//! start an episode, which region kind lies under a point, whether it is on a zebra
//! stripe or inside the curriculum region, and the scene's starts, validation points
//! and reward numbers.
//!
//! Invariant: these queries only read the scene — none changes it or re-checks what
//! [`Scene::from_spec`] guaranteed (see the parent module's docs), and
//! [`Scene::region_kind_exact`] is the exact answer the region map rasterises.

use super::{Axis, Pose, Scene, ValidationPoint};
use crate::error::{Result, SimError};
use crate::geometry::Polygon;
use crate::region_kind::RegionKind;
use crate::reward::Rewards;

impl Scene {
    /// Agent radius used to decide whether a start pose is clear of obstacles.
    pub const START_CLEARANCE: f32 = 0.35;

    /// Check that a pose can start an episode: inside the world, clear of
    /// obstacles by [`Scene::START_CLEARANCE`], not inside the goal.
    pub fn check_task(&self, pose: Pose) -> Result<()> {
        let err = |message: String| SimError::InvalidTask { x: pose.x, y: pose.y, message };
        if !(pose.x.is_finite() && pose.y.is_finite() && pose.yaw.is_finite()) {
            return Err(err("pose is not finite".into()));
        }
        if !self.extent.contains(pose.x, pose.y) {
            return Err(err(format!("outside the world {:?}..{:?}", self.extent.min, self.extent.max)));
        }
        if let Some(o) = self.obstacles.iter().find(|o| o.footprint.distance(pose.x, pose.y) < Self::START_CLEARANCE) {
            return Err(err(format!("inside or touching a {:?} obstacle", o.kind)));
        }
        if self.region_kind_exact(pose.x, pose.y) == RegionKind::Goal {
            return Err(err("already inside the goal area".into()));
        }
        Ok(())
    }

    /// Region kind at a point by exact polygon tests (the region map rasterises this).
    pub fn region_kind_exact(&self, x: f32, y: f32) -> RegionKind {
        self.regions.iter().rev().find(|r| r.polygon.contains(x, y)).map(|r| r.kind).unwrap_or(RegionKind::Road)
    }

    /// Is the point on a painted (white) stripe of a zebra crossing? Stripes are
    /// 0.5 m wide and alternate with 0.5 m of asphalt along the crossing's walking
    /// axis; the zebra is the last one in paint order containing the point.
    pub fn on_zebra_stripe(&self, x: f32, y: f32) -> bool {
        let zebra = self.regions.iter().rev().find(|r| r.kind == RegionKind::Zebra && r.polygon.contains(x, y));
        let Some(axis) = zebra.and_then(|r| r.walk_axis) else { return false };
        let along = match axis {
            Axis::X => x,
            Axis::Y => y,
        };
        along.rem_euclid(1.0) < 0.5
    }

    /// Is the point inside the curriculum region?
    pub fn in_curriculum_region(&self, x: f32, y: f32) -> bool {
        self.curriculum_region.iter().any(|p| p.contains(x, y))
    }

    /// The areas the curriculum proposes starts in: the curriculum region, plus the
    /// enlarged region's areas when `enlarged` (empty when the scene has none).
    pub fn proposal_region(&self, enlarged: bool) -> Vec<Polygon> {
        let extra = if enlarged { &self.enlarged_curriculum_region[..] } else { &[] };
        self.curriculum_region.iter().chain(extra).cloned().collect()
    }

    /// The first task (easiest pose before PassFirstTask).
    pub fn first_task(&self) -> Pose {
        self.spec.first_task.into()
    }

    /// The fixed start of the Non-ACL variants.
    pub fn fixed_start(&self) -> Pose {
        self.spec.fixed_start.into()
    }

    /// The validation points.
    pub fn validation_points(&self) -> &[ValidationPoint] {
        &self.spec.validation_points
    }

    /// The reward's numbers of this scene (see [`crate::reward`]).
    pub fn rewards(&self) -> &Rewards {
        &self.spec.rewards
    }
}
