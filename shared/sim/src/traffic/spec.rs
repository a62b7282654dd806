//! The `[traffic]` section of a scene file: the serde types it parses into, exactly
//! as written, before any checking.
//!
//! Invariant: like the rest of the scene schema ([`crate::scene::SceneSpec`]),
//! these types only mirror the file; `deny_unknown_fields` turns a misspelt key
//! into an error. Only [`super::Traffic::resolve`] turns a spec into something the
//! simulator trusts.

use serde::{Deserialize, Serialize};

/// Everything a scene says about traffic; read only when a run sets a
/// [`crate::TrafficLevel`] other than `off`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrafficSpec {
    /// The fixed-time signal plan shared by the intersection's lanes and zebras.
    pub signal: SignalSpec,
    /// Vehicle lanes: straight centrelines that run from beyond the world's edge,
    /// over the crossing, to beyond the other edge.
    pub lanes: Vec<LaneSpec>,
    /// The kinds of vehicle that enter the lanes, with their shares.
    pub vehicle_kinds: Vec<VehicleKindSpec>,
    /// How drivers drive (Intelligent Driver Model) and whether they yield.
    pub driver: DriverSpec,
    /// The other pedestrians: the sidewalk network they walk on.
    pub walkers: WalkerSpec,
    /// The three levels a run may pick (`sim.traffic`).
    pub levels: LevelsSpec,
    /// Signal heads (each on a pole at `pole`): drawn with their lit lamps.
    pub heads: Vec<HeadSpec>,
    /// Poles that carry heads where the scene has none (cylinders of radius
    /// 0.12 m, 4.5 m tall; colliders like any pole, present only with traffic on).
    #[serde(default)]
    pub extra_poles: Vec<[f32; 2]>,
    /// The reward terms traffic adds.
    pub rewards: TrafficRewards,
    /// Traffic sub-steps per decision step (vehicles and walkers advance `dt / substeps`
    /// at a time). Default 2 (0.125 s at the paper's 0.25 s step).
    #[serde(default = "default_substeps")]
    pub substeps: u32,
    /// Seconds of traffic simulated before an episode starts, so that queues and
    /// platoons are in their steady state when the agent first looks. Default 120.
    #[serde(default = "default_warmup")]
    pub warmup_s: f32,
}

fn default_substeps() -> u32 {
    2
}

fn default_warmup() -> f32 {
    120.0
}

/// A fixed-time signal plan: phases run in order, each a green for some roads
/// (then amber and all-red) during which some zebras walk.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SignalSpec {
    /// Amber after every green, seconds (ITE practice: 3–6 s).
    pub amber_s: f32,
    /// All-red after every amber, seconds.
    pub all_red_s: f32,
    /// The phases, in the order the controller runs them.
    pub phases: Vec<PhaseSpec>,
}

/// One phase of the plan.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhaseSpec {
    /// Roads (names of [`LaneSpec::road`]) whose lanes have green in this phase.
    pub green: Vec<String>,
    /// Zebras (their order among the scene's zebra regions, from 0) that show WALK
    /// at the start of this phase's green.
    #[serde(default)]
    pub walk: Vec<usize>,
    /// Green time, seconds.
    pub green_s: f32,
    /// Steady WALK, seconds from the start of the green (MUTCD: at least 7 s).
    #[serde(default)]
    pub walk_s: f32,
    /// Flashing DON'T WALK after the walk, seconds (at least the crossing length
    /// over the MUTCD walking speed 1.07 m/s).
    #[serde(default)]
    pub clearance_s: f32,
}

/// One vehicle lane.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LaneSpec {
    /// The road the lane belongs to: the name signal phases give green to.
    pub road: String,
    /// Where vehicles enter (may lie beyond the world's edge: queues form there).
    pub from: [f32; 2],
    /// Where vehicles leave.
    pub to: [f32; 2],
    /// The stop line: a point on the centreline where vehicles stop on red.
    pub stop_line: [f32; 2],
}

/// How a vehicle is drawn.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VehicleStyle {
    /// Low body, glazed cabin set back from the nose, dark wheels.
    Car,
    /// Tall box body with a window band (vans, buses, trucks).
    Boxy,
}

/// A kind of vehicle.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VehicleKindSpec {
    /// Name, for reports.
    pub name: String,
    /// Relative share among arrivals (the shares need not sum to 1).
    pub share: f32,
    /// Length, metres.
    pub length: f32,
    /// Width, metres.
    pub width: f32,
    /// Height, metres.
    pub height: f32,
    /// How it is drawn.
    pub style: VehicleStyle,
}

/// The drivers (Treiber, Hennecke & Helbing 2000's Intelligent Driver Model).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DriverSpec {
    /// Desired speed v₀, m/s (urban 50 km/h = 13.9 m/s).
    pub desired_speed: f32,
    /// Safe time headway T, seconds (≈ 1.5).
    pub time_headway: f32,
    /// Minimum gap s₀ to the vehicle ahead, metres (≈ 2).
    pub min_gap: f32,
    /// Maximum acceleration a, m/s².
    pub max_accel: f32,
    /// Comfortable deceleration b, m/s²: also decides, at amber, who stops (those who
    /// can stop before the line at b) and who goes on.
    pub comfortable_decel: f32,
    /// The most a driver brakes, m/s² (a physical limit: IDM asks for more only
    /// when a stop cannot be made in time).
    pub max_decel: f32,
    /// Share of drivers who do not yield to a pedestrian on a zebra (default
    /// small, not zero: real drivers do not all yield).
    pub non_yielding_share: f32,
}

/// The other pedestrians and the network they walk on.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WalkerSpec {
    /// Body radius, metres.
    pub radius: f32,
    /// Preferred walking speed range `[min, max]`, m/s, drawn per walker.
    pub speed: [f32; 2],
    /// Nodes of the network: points on sidewalks.
    pub nodes: Vec<[f32; 2]>,
    /// Edges between nodes (walked both ways).
    pub edges: Vec<WalkerEdgeSpec>,
}

/// One edge of the walkers' network.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WalkerEdgeSpec {
    /// Index of one end.
    pub a: usize,
    /// Index of the other end.
    pub b: usize,
    /// The zebra (order among zebra regions) this edge crosses; a walker starts over
    /// it only on steady WALK.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub crossing: Option<usize>,
}

/// The numbers of one traffic level.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LevelSpec {
    /// Arrivals per lane, vehicles per hour (a Poisson process).
    pub flow: f32,
    /// Number of other pedestrians.
    pub walkers: u32,
}

/// The levels `light`, `medium` and `heavy`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LevelsSpec {
    /// `sim.traffic = "light"`.
    pub light: LevelSpec,
    /// `sim.traffic = "medium"`.
    pub medium: LevelSpec,
    /// `sim.traffic = "heavy"`.
    pub heavy: LevelSpec,
}

/// A signal head.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeadSpec {
    /// The pole it hangs on (a pole of the scene or of `extra_poles`).
    pub pole: [f32; 2],
    /// The direction its lamps face, degrees (0 = east, counter-clockwise).
    pub facing_deg: f32,
    /// A pedestrian head: the zebra whose WALK / DON'T WALK it shows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub zebra: Option<usize>,
    /// A vehicle head: the road whose green / amber / red it shows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub road: Option<String>,
}

/// Rewards traffic adds to the paper's (which stay as they are for the static parts).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrafficRewards {
    /// Added on the step a vehicle hits the agent; the episode ends there.
    pub vehicle_hit: f32,
    /// Added once on the step the agent steps onto a zebra that does not show WALK,
    /// beside the road's pay for every step on it (docs/simulator.md, *Traffic*).
    /// Default 0: the crossing against the signal costs only the road's pay.
    #[serde(default)]
    pub dont_walk_entry: f32,
}
