//! The scene file's schema: the serde types a scene TOML parses into
//! ([`SceneSpec`] and its parts), exactly as written, before any checking.
//!
//! Invariant: these types only mirror the file — they hold numbers as written and
//! claim nothing about them (a spec may be non-finite, empty or self-crossing);
//! `deny_unknown_fields` makes a misspelt key an error rather than a silent default.
//! Only [`super::Scene::from_spec`] turns a spec into something downstream may trust.

use serde::{Deserialize, Serialize};

use crate::appearance::{Facade, OverheadSpec, PavingSpec};
use crate::geometry::Area;
use crate::region_kind::RegionKind;
use crate::reward::Rewards;

pub use crate::geometry::Axis;

/// A ground region as written in the scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegionSpec {
    /// What the region is.
    pub kind: RegionKind,
    /// Outline as a rectangle `[x_min, y_min, x_max, y_max]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rect: Option<[f32; 4]>,
    /// Outline as a polygon.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub polygon: Option<Vec<[f32; 2]>>,
    /// Zebra crossings only: the axis a pedestrian walks along over the crossing.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub walk_axis: Option<Axis>,
}

/// Kind of a static obstacle; decides its look and how it is drawn on the map.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObstacleKind {
    /// A building block (box).
    Building,
    /// A lamp or traffic-light pole (cylinder).
    Pole,
    /// A bench (box, low).
    Bench,
    /// A tree: the collider is the trunk cylinder; a crown is drawn above head height.
    Tree,
    /// A boundary wall at the edge of the world (generated, not written in files).
    Wall,
}

/// A static obstacle as written in the scene file: either a box
/// (`rect` footprint) or a vertical cylinder (`center` + `radius`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObstacleSpec {
    /// What the obstacle is.
    pub kind: ObstacleKind,
    /// Box footprint `[x_min, y_min, x_max, y_max]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rect: Option<[f32; 4]>,
    /// Cylinder centre `[x, y]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub center: Option<[f32; 2]>,
    /// Cylinder radius in metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radius: Option<f32>,
    /// Height in metres.
    pub height: f32,
    /// Grey level in [0, 1] of its lit faces.
    pub shade: f32,
    /// Buildings only: how its walls look (default: a plain grid of windows).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub facade: Option<Facade>,
    /// Trees only: radius of the crown drawn above head height, metres (default 1.4).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crown_radius: Option<f32>,
}

/// Crown radius of a tree whose scene entry gives none, metres.
pub const DEFAULT_CROWN_RADIUS: f32 = 1.4;

/// A painted line on the road (lane divider); purely visual.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Marking {
    /// Start point.
    pub from: [f32; 2],
    /// End point.
    pub to: [f32; 2],
    /// Line width in metres.
    pub width: f32,
    /// Painted length of each dash in metres (0 = solid line).
    #[serde(default)]
    pub dash: f32,
    /// Gap between dashes in metres.
    #[serde(default)]
    pub gap: f32,
}

/// A start pose as written in the scene file (yaw in degrees).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseSpec {
    /// x in metres.
    pub x: f32,
    /// y in metres.
    pub y: f32,
    /// Yaw in degrees, 0 = east, counter-clockwise.
    pub yaw_deg: f32,
}

/// One of the validation points of the paper's §V-C / Fig. 5a.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValidationPoint {
    /// Index 0..13; 0–7 are interpolated (inside the curriculum region,
    /// difficulty rising with the index), 8–13 extrapolated (outside it).
    pub id: u32,
    /// x in metres.
    pub x: f32,
    /// y in metres.
    pub y: f32,
    /// The favourable yaw in degrees (used for the documented oracle figure).
    pub favourable_yaw_deg: f32,
}

/// The scene file's schema.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSpec {
    /// Short name, used in logs and output names.
    pub name: String,
    /// One-paragraph description.
    #[serde(default)]
    pub description: String,
    /// World bounds `[x_min, y_min, x_max, y_max]`; boundary walls stand on its edges.
    pub extent: [f32; 4],
    /// Cell size of the region (reward) map and the ground texture, in metres.
    pub cell_size: f32,
    /// Height of the generated boundary walls in metres.
    #[serde(default = "default_wall_height")]
    pub wall_height: f32,
    /// The reward's numbers (the rules are in [`crate::reward`]).
    pub rewards: Rewards,
    /// Ground regions in paint order: a later region overrides an earlier one where
    /// they overlap. Cells covered by none are road.
    pub regions: Vec<RegionSpec>,
    /// Static obstacles.
    #[serde(default)]
    pub obstacles: Vec<ObstacleSpec>,
    /// Painted road markings (visual only).
    #[serde(default)]
    pub markings: Vec<Marking>,
    /// Paved areas of sidewalk in paint order (visual only: a later one overrides an
    /// earlier one; sidewalk cells covered by none get the default slabs).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub paving: Vec<PavingSpec>,
    /// Details hung over the pedestrians' heads: awnings, signs, canopies, balconies
    /// (visual only, no collider).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub overhead: Vec<OverheadSpec>,
    /// The easiest pose, used before the curriculum's PassFirstTask gate opens.
    pub first_task: PoseSpec,
    /// The fixed start of the Non-ACL variants (validation point 3).
    pub fixed_start: PoseSpec,
    /// The region the curriculum samples start positions from (union of areas). It
    /// also defines the protocol's classes: validation points 0–7 lie inside it
    /// (interpolated), 8–13 outside (extrapolated).
    pub curriculum_region: Vec<Area>,
    /// Further areas the curriculum may propose starts in when a run sets
    /// `curriculum.enlarged_region = true` — the paper's "enlarged ACL-proposed
    /// regions" (§V-C), which bring the extrapolated points' surroundings into
    /// training. They do not change which validation points count as extrapolated.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub enlarged_curriculum_region: Vec<Area>,
    /// The 14 validation points.
    pub validation_points: Vec<ValidationPoint>,
    /// Signals, vehicles and other pedestrians (used only when a run sets
    /// `sim.traffic` to a level other than `off`; checked at load either way).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub traffic: Option<crate::traffic::TrafficSpec>,
}

fn default_wall_height() -> f32 {
    3.0
}
