//! How a scene looks beyond its geometry: the paving of each sidewalk, the facade
//! of each building and the details mounted overhead (awnings, signs, canopies,
//! balconies). All of it is visual only.
//!
//! Invariant: nothing here changes what the agent can do or earn. Paving recolours
//! sidewalk cells of the ground texture but never their region label (the reward
//! map is built from the regions alone); facades paint the walls of a building whose
//! collider stays its box; overhead details start at least [`MIN_OVERHEAD_BASE`]
//! above the ground, over a pedestrian's head, and have no collider. So a scene's
//! rewards, its oracle and its random walk's figures do not depend on its looks —
//! which is what lets the reference scene be made recognisable (each corner looks
//! like itself, as a real intersection does) without changing the task.

use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::geometry::{Area, MAX_HEIGHT, Polygon, Rect, invalid, resolve_rect};

/// Lowest base of an overhead detail, in metres: above the default pedestrian
/// (1.8 m) with room to spare, like the 2.3 m of a tree's crown.
pub const MIN_OVERHEAD_BASE: f32 = 2.2;

/// The pattern of a paved sidewalk.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PavingStyle {
    /// Square slabs of side `size` with dark joints (the default sidewalk).
    #[default]
    Slabs,
    /// Bricks `size` long and `size / 2` wide in running bond (rows along x).
    Bricks,
    /// Small square setts of side `size` with wide joints and a tone that varies
    /// from sett to sett.
    Cobbles,
    /// Large poured-concrete panels of side `size` with thin joints.
    Concrete,
    /// Grass behind a fence or hedge: no joints, mottled in patches of side `size`.
    Lawn,
}

/// A paved area of sidewalk, as written in the scene file (`[[paving]]`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PavingSpec {
    /// Outline as a rectangle `[x_min, y_min, x_max, y_max]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rect: Option<[f32; 4]>,
    /// Outline as a polygon.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub polygon: Option<Vec<[f32; 2]>>,
    /// Pattern.
    #[serde(default)]
    pub style: PavingStyle,
    /// Grey level in [0, 1] of the paving stones.
    pub tone: f32,
    /// Module of the pattern in metres (slab side, brick length, sett side, panel side).
    #[serde(default = "default_paving_size")]
    pub size: f32,
    /// Grey level in [0, 1] of the joints (default: the tone darkened by 0.14).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub joint: Option<f32>,
    /// Grey level in [0, 1] of the kerb stones where this paving meets the road
    /// (default 0.85, bright granite).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub kerb: Option<f32>,
}

/// Grey level of a kerb whose paving names none.
pub const DEFAULT_KERB: f32 = 0.85;

fn default_paving_size() -> f32 {
    0.6
}

/// A resolved paved area.
#[derive(Debug, Clone, PartialEq)]
pub struct Paving {
    /// Where it lies (only its sidewalk cells are recoloured).
    pub area: Polygon,
    /// Its bounding box, for a quick rejection.
    pub bounds: Rect,
    /// Pattern.
    pub style: PavingStyle,
    /// Grey level of the stones.
    pub tone: f32,
    /// Module of the pattern in metres.
    pub size: f32,
    /// Grey level of the joints.
    pub joint: f32,
    /// Grey level of its kerb stones.
    pub kerb: f32,
}

impl Paving {
    /// The look of a sidewalk nobody paved: 0.6 m slabs of grey 0.62, joints 0.48,
    /// bright kerb stones.
    pub const DEFAULT: PavingLook =
        PavingLook { style: PavingStyle::Slabs, tone: 0.62, size: 0.6, joint: 0.48, kerb: DEFAULT_KERB };

    /// Its look.
    pub fn look(&self) -> PavingLook {
        PavingLook { style: self.style, tone: self.tone, size: self.size, joint: self.joint, kerb: self.kerb }
    }
}

/// Pattern, tone, module and joint of a paving (what the ground texture needs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PavingLook {
    /// Pattern.
    pub style: PavingStyle,
    /// Grey level of the stones.
    pub tone: f32,
    /// Module in metres.
    pub size: f32,
    /// Grey level of the joints.
    pub joint: f32,
    /// Grey level of the kerb stones.
    pub kerb: f32,
}

/// The windows of a building's upper floors (from 3 m up to 0.8 m under the roof).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum WindowStyle {
    /// A grid of square-ish windows, 40 % of the bay wide (the default).
    #[default]
    Grid,
    /// Narrow, tall windows of an older town house.
    Tall,
    /// Continuous horizontal bands of glass, one per storey (an office block).
    Ribbon,
    /// Glass everywhere but thin mullions and spandrels (a curtain wall).
    Curtain,
    /// A blank wall (a warehouse, a gable).
    Blank,
}

/// The ground floor of a building (0–3 m: a pedestrian's eye level).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum GroundFloor {
    /// A plain wall (the default).
    #[default]
    Plain,
    /// Shop windows (glass from 0.3 to 2.4 m, one per bay) under a bright sign band.
    Shop,
    /// Deep, dark arcade openings, one per bay.
    Arcade,
}

/// The walls of a building (`facade = { … }` on a building obstacle).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Facade {
    /// Upper floors' windows.
    #[serde(default)]
    pub windows: WindowStyle,
    /// Ground floor.
    #[serde(default)]
    pub ground_floor: GroundFloor,
    /// Width of one bay (the horizontal period of windows and shop fronts), metres.
    #[serde(default = "default_bay")]
    pub bay: f32,
    /// Height of one storey (the vertical period of the windows), metres.
    #[serde(default = "default_storey")]
    pub storey: f32,
    /// Grey level of the glass; default: the wall's own shade × 0.45.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub glass: Option<f32>,
    /// Grey level of the shop fronts' sign band.
    #[serde(default = "default_trim")]
    pub trim: f32,
}

fn default_bay() -> f32 {
    3.0
}
fn default_storey() -> f32 {
    3.5
}
fn default_trim() -> f32 {
    0.92
}

impl Default for Facade {
    fn default() -> Self {
        Facade {
            windows: WindowStyle::Grid,
            ground_floor: GroundFloor::Plain,
            bay: default_bay(),
            storey: default_storey(),
            glass: None,
            trim: default_trim(),
        }
    }
}

impl Facade {
    /// Check the numbers; `field` names the facade in errors.
    pub(crate) fn validate(&self, field: &str, origin: &str) -> Result<()> {
        for (name, v, lo, hi) in [("bay", self.bay, 0.5, 50.0), ("storey", self.storey, 1.0, 20.0)] {
            if !(v >= lo && v <= hi) {
                return Err(invalid(
                    origin,
                    &format!("{field}.{name}"),
                    format!("{v} must lie in [{lo}, {hi}] metres"),
                ));
            }
        }
        for (name, v) in [("glass", self.glass), ("trim", Some(self.trim))] {
            if let Some(v) = v.filter(|v| !(0.0..=1.0).contains(v)) {
                return Err(invalid(origin, &format!("{field}.{name}"), format!("{v} must lie in [0, 1]")));
            }
        }
        Ok(())
    }
}

/// A visual-only box overhead, as written in the scene file (`[[overhead]]`): an
/// awning, a canopy, a shop sign, a balcony, a billboard.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OverheadSpec {
    /// Footprint `[x_min, y_min, x_max, y_max]`.
    pub rect: [f32; 4],
    /// Height of its underside above the ground, metres (at least [`MIN_OVERHEAD_BASE`]).
    pub base: f32,
    /// Height of its top, metres.
    pub top: f32,
    /// Grey level in [0, 1] of its lit faces.
    pub shade: f32,
}

/// A resolved overhead detail.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Overhead {
    /// Footprint.
    pub rect: Rect,
    /// Underside height.
    pub base: f32,
    /// Top height.
    pub top: f32,
    /// Grey level.
    pub shade: f32,
}

/// Resolve and check the scene's paved areas; `extent` is the world.
pub(crate) fn resolve_paving(specs: &[PavingSpec], extent: &Rect, origin: &str) -> Result<Vec<Paving>> {
    let mut out = Vec::with_capacity(specs.len());
    for (i, p) in specs.iter().enumerate() {
        let field = format!("paving[{i}]");
        let area = Area { rect: p.rect, polygon: p.polygon.clone() }.resolve(&field, origin)?;
        let bounds = area.bounds();
        if !bounds.intersects(extent) {
            return Err(invalid(origin, &field, "lies wholly outside the world".into()));
        }
        let joint = p.joint.unwrap_or((p.tone - 0.14).max(0.0));
        let kerb = p.kerb.unwrap_or(DEFAULT_KERB);
        for (name, v) in [("tone", p.tone), ("joint", joint), ("kerb", kerb)] {
            if !(0.0..=1.0).contains(&v) {
                return Err(invalid(origin, &format!("{field}.{name}"), format!("{v} must lie in [0, 1]")));
            }
        }
        if !(p.size >= 0.1 && p.size <= 10.0) {
            return Err(invalid(origin, &format!("{field}.size"), format!("{} must lie in [0.1, 10] metres", p.size)));
        }
        out.push(Paving { area, bounds, style: p.style, tone: p.tone, size: p.size, joint, kerb });
    }
    Ok(out)
}

/// Resolve and check the scene's overhead details.
pub(crate) fn resolve_overhead(specs: &[OverheadSpec], extent: &Rect, origin: &str) -> Result<Vec<Overhead>> {
    let mut out = Vec::with_capacity(specs.len());
    for (i, o) in specs.iter().enumerate() {
        let field = format!("overhead[{i}]");
        let rect = resolve_rect(&o.rect, &format!("{field}.rect"), origin)?;
        if !rect.intersects(extent) {
            return Err(invalid(origin, &field, "lies wholly outside the world".into()));
        }
        if !(o.base >= MIN_OVERHEAD_BASE && o.base < MAX_HEIGHT) {
            return Err(invalid(
                origin,
                &format!("{field}.base"),
                format!(
                    "{} must lie in [{MIN_OVERHEAD_BASE}, {MAX_HEIGHT}) metres: overhead details have no collider, \
                     so they must hang over a pedestrian's head",
                    o.base
                ),
            ));
        }
        if !(o.top > o.base && o.top <= MAX_HEIGHT) {
            return Err(invalid(
                origin,
                &format!("{field}.top"),
                format!("{} must lie above `base` ({}) and at most {MAX_HEIGHT} metres", o.top, o.base),
            ));
        }
        if !(0.0..=1.0).contains(&o.shade) {
            return Err(invalid(origin, &format!("{field}.shade"), format!("{} must lie in [0, 1]", o.shade)));
        }
        out.push(Overhead { rect, base: o.base, top: o.top, shade: o.shade });
    }
    Ok(out)
}
