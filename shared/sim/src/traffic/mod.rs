//! Traffic at the crossing: a fixed-time signal plan, vehicles on lanes driven by
//! the Intelligent Driver Model, and other pedestrians on a sidewalk network —
//! described as data in a scene's `[traffic]` section and switched on by a run's
//! `sim.traffic` level (off by default).
//!
//! Two halves, as for the static scene:
//! - [`Traffic`] — the validated description (lanes, zebras, plan, drivers, walker
//!   network, heads), resolved once per scene and shared by every environment,
//!   never mutated;
//! - [`TrafficState`] — one environment's dynamic state (clock, vehicles, walkers,
//!   its random stream), seeded from the episode seed at reset and advanced by the
//!   environment's step. The static world ([`crate::physics::StaticWorld`]) stays
//!   shared and immutable.
//!
//! Invariant: a [`Traffic`] that exists passed [`Traffic::resolve`] — every number
//! finite and in range, every lane on the road, the signal plan through the conflict
//! monitor ([`signal`]), every walker node on a sidewalk, every crossing edge ending
//! at its zebra's kerbs. The same scene, settings and episode seed give the same
//! traffic, step for step (no other randomness; tested).
//!
//! The model, its parameters and the reasoning behind the rewards are in
//! `docs/simulator.md` (section *Traffic*).

pub mod measure;
mod resolve;
pub mod signal;
pub mod spec;
mod state;
pub mod vehicle;
pub mod walker;

use crate::config::{GroundSignals, SimConfig, TrafficLevel};
use crate::geometry::{Axis, Polygon, Rect};

pub use signal::{PedestrianSignal, SignalPlan, VehicleSignal};
pub use spec::{TrafficSpec, VehicleStyle};
pub use state::{AgentContact, SafetyCounts, SafetyEvents, TrafficStart, TrafficState};

/// What moving bodies walk through: the static world's colliders. Implemented by
/// [`crate::physics::StaticWorld`] (rapier's character controller); traffic only
/// needs this one question answered, so it does not depend on the physics module.
pub trait Ground {
    /// Where a body of the agent's size ends up moving from `(x, y)` by `(dx, dy)`
    /// in `dt` seconds, sliding along obstacles.
    fn move_body(&self, x: f32, y: f32, dx: f32, dy: f32, dt: f32) -> [f32; 2];
}

/// Walking speed the clearance interval is timed for (MUTCD 2009, 4E.06: 3.5 ft/s).
pub const MUTCD_WALKING_SPEED: f32 = 1.07;

/// Shortest steady WALK a plan may give, seconds (MUTCD 4E.06).
pub const MIN_WALK_S: f32 = 7.0;

/// Radius and height of the poles of `extra_poles`.
pub const EXTRA_POLE: (f32, f32) = (0.12, 4.5);

/// One resolved vehicle lane: a straight centreline with a coordinate `s` in metres
/// from its entry.
#[derive(Debug, Clone, PartialEq)]
pub struct Lane {
    /// Index of its road in [`Traffic::roads`].
    pub road: usize,
    /// Entry point.
    pub origin: [f32; 2],
    /// Unit direction of travel.
    pub dir: [f32; 2],
    /// Length from entry to exit, metres.
    pub length: f32,
    /// `s` of the stop line.
    pub stop_s: f32,
    /// Zebras the lane crosses: (zebra index, `s` where it enters, `s` where it leaves).
    pub zebras: Vec<(usize, f32, f32)>,
    /// Where other lanes cross this one: (other lane, `s` here, `s` on the other lane).
    pub conflicts: Vec<(usize, f32, f32)>,
    /// `s` past the last conflict (2 m beyond it): the end of the crossing box,
    /// for lanes that cross another.
    pub box_exit: Option<f32>,
}

/// Half the width of the strip around a lane's centreline that a crossing vehicle
/// must keep clear of, metres.
pub const CONFLICT_HALF_WIDTH: f32 = 1.5;

impl Lane {
    /// The point at coordinate `s`.
    pub fn point(&self, s: f32) -> [f32; 2] {
        [self.origin[0] + self.dir[0] * s, self.origin[1] + self.dir[1] * s]
    }

    /// (along, across) coordinates of a point: `s` and the signed offset to the left.
    pub fn local(&self, p: [f32; 2]) -> (f32, f32) {
        let (dx, dy) = (p[0] - self.origin[0], p[1] - self.origin[1]);
        (dx * self.dir[0] + dy * self.dir[1], -dx * self.dir[1] + dy * self.dir[0])
    }

    /// Yaw of the direction of travel, radians.
    pub fn yaw(&self) -> f32 {
        self.dir[1].atan2(self.dir[0])
    }
}

/// One zebra crossing, in the order of the scene's zebra regions.
#[derive(Debug, Clone, PartialEq)]
pub struct Zebra {
    /// Its outline.
    pub polygon: Polygon,
    /// Its bounding rectangle.
    pub bounds: Rect,
    /// The axis a pedestrian walks along.
    pub walk_axis: Axis,
    /// Length of the crossing along the walking axis, metres.
    pub length: f32,
}

impl Zebra {
    /// Is a point on this zebra?
    pub fn contains(&self, x: f32, y: f32) -> bool {
        self.bounds.contains(x, y) && self.polygon.contains(x, y)
    }

    /// The two kerb ends: midpoints of the sides a pedestrian steps on from.
    pub fn ends(&self) -> [[f32; 2]; 2] {
        let b = self.bounds;
        let (cx, cy) = ((b.min[0] + b.max[0]) * 0.5, (b.min[1] + b.max[1]) * 0.5);
        match self.walk_axis {
            Axis::X => [[b.min[0], cy], [b.max[0], cy]],
            Axis::Y => [[cx, b.min[1]], [cx, b.max[1]]],
        }
    }

    /// Where `sim.traffic_ground_signals` draws this zebra's lights: [`GroundSignals::Kerb`],
    /// a band as wide as the zebra on the sidewalk at each end, from
    /// [`KERB_SIGNAL_SET_BACK`] behind the zebra's end (past the kerb stones) to
    /// [`KERB_SIGNAL_DEPTH`] further; [`GroundSignals::Edges`], a line
    /// [`EDGE_SIGNAL_WIDTH`] wide along each side, from kerb to kerb. `None` when off.
    pub fn ground_signal_bands(&self, kind: GroundSignals) -> Option<[Rect; 2]> {
        let b = self.bounds;
        // (min, max) along the walking axis, then across it.
        let (along, across) = match self.walk_axis {
            Axis::X => ([b.min[0], b.max[0]], [b.min[1], b.max[1]]),
            Axis::Y => ([b.min[1], b.max[1]], [b.min[0], b.max[0]]),
        };
        let bands: [([f32; 2], [f32; 2]); 2] = match kind {
            GroundSignals::Off => return None,
            GroundSignals::Kerb => {
                let (near, far) = (KERB_SIGNAL_SET_BACK, KERB_SIGNAL_SET_BACK + KERB_SIGNAL_DEPTH);
                [([along[0] - far, along[0] - near], across), ([along[1] + near, along[1] + far], across)]
            }
            GroundSignals::Edges => [
                (along, [across[0] - EDGE_SIGNAL_WIDTH, across[0]]),
                (along, [across[1], across[1] + EDGE_SIGNAL_WIDTH]),
            ],
        };
        let rect = |(a, c): ([f32; 2], [f32; 2])| match self.walk_axis {
            Axis::X => Rect { min: [a[0], c[0]], max: [a[1], c[1]] },
            Axis::Y => Rect { min: [c[0], a[0]], max: [c[1], a[1]] },
        };
        Some(bands.map(rect))
    }
}

/// How far behind a zebra's end its kerb signal band starts, metres: past the 0.2 m
/// band of kerb stones the ground texture draws there.
pub const KERB_SIGNAL_SET_BACK: f32 = 0.2;

/// Depth of a kerb signal band, metres.
pub const KERB_SIGNAL_DEPTH: f32 = 0.5;

/// Width of an edge signal line, metres.
pub const EDGE_SIGNAL_WIDTH: f32 = 0.2;

/// A resolved vehicle kind.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleKind {
    /// Name.
    pub name: String,
    /// Cumulative share in (0, 1]: a uniform draw below it (and above the previous
    /// kind's) picks this kind.
    pub cumulative_share: f32,
    /// Length, metres.
    pub length: f32,
    /// Width, metres.
    pub width: f32,
    /// Height, metres.
    pub height: f32,
    /// How it is drawn.
    pub style: VehicleStyle,
}

/// What a signal head shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum HeadKind {
    /// WALK / DON'T WALK of a zebra.
    Pedestrian(usize),
    /// Green / amber / red of a road.
    Vehicle(usize),
}

/// A resolved signal head: its housing's centre on the ground plane and facing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Head {
    /// Centre of the housing (0.25 m out from the pole's axis towards `facing`).
    pub center: [f32; 2],
    /// Unit vector the lamps face.
    pub facing: [f32; 2],
    /// What it shows.
    pub kind: HeadKind,
}

/// Heights of the heads' parts, metres: (housing base, housing top, lamp centres top to bottom).
pub const PEDESTRIAN_HEAD: (f32, f32, [f32; 2]) = (2.2, 2.9, [2.72, 2.38]);
/// Vehicle head: housing base, top and the red, amber and green lamp centres.
pub const VEHICLE_HEAD: (f32, f32, [f32; 3]) = (2.35, 3.35, [3.12, 2.85, 2.58]);
/// Housing width across its facing and depth along it, metres.
pub const HEAD_SIZE: [f32; 2] = [0.36, 0.22];

/// The walkers' network, resolved.
#[derive(Debug, Clone, PartialEq)]
pub struct WalkerNetwork {
    /// Body radius.
    pub radius: f32,
    /// Preferred speed range.
    pub speed: [f32; 2],
    /// Node positions.
    pub nodes: Vec<[f32; 2]>,
    /// Edges: (a, b, crossed zebra).
    pub edges: Vec<(usize, usize, Option<usize>)>,
    /// For each node, the indices of its edges.
    pub adjacency: Vec<Vec<usize>>,
}

/// The numbers a run's level resolves to (the level's, then the run's overrides).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrafficSettings {
    /// Arrivals per lane, vehicles per hour.
    pub flow: f32,
    /// Number of other pedestrians.
    pub walkers: u32,
    /// Share of drivers who do not yield.
    pub non_yielding: f32,
    /// Reward on entering a zebra outside WALK.
    pub dont_walk_entry: f32,
}

/// The validated traffic description of a scene; see the module docs.
#[derive(Debug, Clone, PartialEq)]
pub struct Traffic {
    /// Road names (the signal plan's movements), in order of first appearance among the lanes.
    pub roads: Vec<String>,
    /// Lanes.
    pub lanes: Vec<Lane>,
    /// Zebras, in the scene's order of zebra regions.
    pub zebras: Vec<Zebra>,
    /// The signal plan.
    pub plan: SignalPlan,
    /// Vehicle kinds.
    pub kinds: Vec<VehicleKind>,
    /// Drivers.
    pub driver: spec::DriverSpec,
    /// Walkers' network.
    pub walkers: WalkerNetwork,
    /// The three levels.
    pub levels: spec::LevelsSpec,
    /// Signal heads.
    pub heads: Vec<Head>,
    /// Poles added with traffic on.
    pub extra_poles: Vec<[f32; 2]>,
    /// Reward added on a vehicle hit.
    pub vehicle_hit: f32,
    /// Reward added on entering a zebra outside WALK (the scene's; `sim.traffic_dont_walk_entry`
    /// overrides it, [`Traffic::settings`]).
    pub dont_walk_entry: f32,
    /// Sub-steps per decision step.
    pub substeps: u32,
    /// Warm-up before an episode, seconds.
    pub warmup_s: f32,
}

impl Traffic {
    /// The numbers of a level with the run's overrides (`sim.traffic_flow`, …);
    /// `None` for `off`.
    pub fn settings(&self, cfg: &SimConfig) -> Option<TrafficSettings> {
        let level = match cfg.traffic {
            TrafficLevel::Off => return None,
            TrafficLevel::Light => &self.levels.light,
            TrafficLevel::Medium => &self.levels.medium,
            TrafficLevel::Heavy => &self.levels.heavy,
        };
        Some(TrafficSettings {
            flow: cfg.traffic_flow.unwrap_or(level.flow),
            walkers: cfg.traffic_walkers.unwrap_or(level.walkers),
            non_yielding: cfg.traffic_non_yielding.unwrap_or(self.driver.non_yielding_share),
            dont_walk_entry: cfg.traffic_dont_walk_entry.unwrap_or(self.dont_walk_entry),
        })
    }

    /// The zebra containing a point, if any.
    pub fn zebra_at(&self, x: f32, y: f32) -> Option<usize> {
        self.zebras.iter().position(|z| z.contains(x, y))
    }
}
