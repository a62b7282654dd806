//! Simulator settings (docs/design.md §3) with the paper's defaults.

use serde::{Deserialize, Serialize};

use crate::error::{Result, SimError};

/// Highest camera the renderer's mesh is built for: tops of objects taller than this
/// are never visible and are not drawn; [`SimConfig::validate`] keeps the eye below it.
pub const MAX_EYE_HEIGHT: f32 = 3.0;

/// Longest episode [`SimConfig::validate`] accepts, in decision steps (≈ 69 h at the
/// paper's 0.25 s; the paper trains with 8000).
pub const MAX_T_MAX: u32 = 1_000_000;

/// What an environment returns as its observation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum ObsMode {
    /// First-person greyscale frames (the paper's setting; the default).
    #[default]
    Pixels,
    /// The simulator's state instead of pixels: the goal's position in the body
    /// frame, heading, head yaw and the map rewards around the agent (see
    /// [`crate::state_obs`]) — a privileged observation, for algorithm tests, the
    /// state preset and comparisons; not the paper's task. Written `"state"`
    /// (`"state_debug"`, its first name, still reads).
    #[serde(alias = "state_debug")]
    #[value(alias = "state-debug")]
    State,
}

/// How much traffic the crossing carries: vehicles, signals and other pedestrians
/// (the numbers of each level are the scene's `[traffic.levels]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum TrafficLevel {
    /// An empty intersection: no vehicle, no signal, no other pedestrian (the
    /// paper's task; every figure before traffic existed).
    #[default]
    Off,
    /// Light traffic (reference scene: 200 vehicles/h/lane, 4 walkers).
    Light,
    /// Medium traffic (reference scene: 450 vehicles/h/lane, 8 walkers).
    Medium,
    /// Heavy traffic, near a lane's capacity (reference scene: 750 vehicles/h/lane, 16 walkers).
    Heavy,
}

impl TrafficLevel {
    /// Is there any traffic?
    pub fn is_on(self) -> bool {
        self != TrafficLevel::Off
    }
}

/// Pedestrian signals set in the ground, lit with the zebra's heads (an option beyond
/// the paper, for a camera that cannot resolve the heads: their lamps are a quarter of
/// a pixel at 42², docs/simulator.md). Each is a flat band of lights, bright on WALK,
/// dim while the head's hand is lit (a red lamp through a greyscale camera) and dark
/// between the hand's flashes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, clap::ValueEnum)]
#[serde(rename_all = "snake_case")]
pub enum GroundSignals {
    /// None: the heads on their poles only (the default; every figure before the option).
    #[default]
    Off,
    /// A band in the paving behind the kerb stones at both ends of every zebra, as
    /// wide as the zebra and 0.5 m deep, as Seoul's floor-type pedestrian signals and
    /// Augsburg's "Bodenampeln" show the signal at a waiting walker's feet.
    Kerb,
    /// A 0.2 m line along both sides of every zebra from kerb to kerb, as LED-lit
    /// crossings light a crossing's edges: seen from anywhere short of the kerb.
    Edges,
}

impl GroundSignals {
    /// Are any ground signals drawn?
    pub fn is_on(self) -> bool {
        self != GroundSignals::Off
    }
}

/// Settings of the pedestrian simulator. Defaults are the paper's (§IV) and docs/design.md §3.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SimConfig {
    /// Seconds per decision step. Paper: 0.25. Range: (0, 5].
    pub dt: f32,
    /// Episode length limit in decision steps (truncation, bootstrapped by learners).
    /// Paper: 8000 in training, 2000 in validation. Range: 1 ..= 1000000.
    pub t_max: u32,
    /// Top walking speed in m/s; action a₀ ∈ [−1, 1] maps linearly to [0, max_speed]. Paper: 2.
    /// Range: (0, 20].
    pub max_speed: f32,
    /// Top yaw rate in degrees/s; a₁ ∈ [−1, 1] maps to [−max_yaw_rate, max_yaw_rate]. Paper: 80.
    /// Range: [0, 720].
    pub max_yaw_rate_deg: f32,
    /// Head-yaw range in degrees: a₂ ∈ [−1, 1] sets the head's yaw offset relative
    /// to the body to a₂ · max_head_yaw (absolute offset, not a rate). Default 60: the
    /// paper gives no range (docs/design.md §9). Range: [0, 90].
    pub max_head_yaw_deg: f32,
    /// Capsule radius of the pedestrian in metres. Range: (0.05, 1).
    pub agent_radius: f32,
    /// Capsule height of the pedestrian in metres. Range: (2 × `agent_radius`, 3].
    pub agent_height: f32,
    /// Camera height above the ground in metres. Range: (0.1, 3).
    pub eye_height: f32,
    /// Horizontal (and, with square images, vertical) field of view in degrees. Paper: 135.
    /// Range: (10, 170).
    pub fov_deg: f32,
    /// Side of the square greyscale observation in pixels (84 in the paper; 42 for reduced presets).
    /// Range: 8 ..= 1024 (at least 21 for the convolutional encoders).
    pub image_size: u32,
    /// Observation mode.
    pub obs_mode: ObsMode,
    /// Randomise brightness, contrast and haze of the rendering per episode (from the
    /// episode seed). Off by default, as in the paper.
    pub domain_randomization: bool,
    /// Traffic at the crossing: `"off"` (default), `"light"`, `"medium"` or
    /// `"heavy"` — signals, vehicles and other pedestrians from the scene's
    /// `[traffic]` section.
    pub traffic: TrafficLevel,
    /// Overrides the level's vehicle arrivals per lane, vehicles/h. Range: [0, 2400].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub traffic_flow: Option<f32>,
    /// Overrides the level's number of other pedestrians. Range: 0 ..= 64.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub traffic_walkers: Option<u32>,
    /// Overrides the scene's share of drivers who do not yield at zebras. Range: [0, 1].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub traffic_non_yielding: Option<f32>,
    /// Overrides the scene's reward for stepping onto a zebra that does not show WALK
    /// (`rewards.dont_walk_entry`, 0 in the built-in scenes), paid once per entry beside
    /// the road's pay for every step on that zebra. Range: [-1000, 0].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub traffic_dont_walk_entry: Option<f32>,
    /// Pedestrian signals set in the ground (an option beyond the paper): `"off"`
    /// (default), `"kerb"` (a band behind each kerb) or `"edges"` (lines along each
    /// zebra's sides); see [`GroundSignals`]. Needs traffic.
    #[serde(skip_serializing_if = "is_off")]
    pub traffic_ground_signals: GroundSignals,
}

impl Default for SimConfig {
    fn default() -> Self {
        SimConfig {
            dt: 0.25,
            t_max: 8000,
            max_speed: 2.0,
            max_yaw_rate_deg: 80.0,
            max_head_yaw_deg: 60.0,
            agent_radius: 0.3,
            agent_height: 1.8,
            eye_height: 1.6,
            fov_deg: 135.0,
            image_size: 84,
            obs_mode: ObsMode::Pixels,
            domain_randomization: false,
            traffic: TrafficLevel::Off,
            traffic_flow: None,
            traffic_walkers: None,
            traffic_non_yielding: None,
            traffic_dont_walk_entry: None,
            traffic_ground_signals: GroundSignals::Off,
        }
    }
}

impl SimConfig {
    /// Check every field's range; the error names the field.
    pub fn validate(&self) -> Result<()> {
        fn check(ok: bool, field: &'static str, value: impl ToString, message: &str) -> Result<()> {
            if ok {
                Ok(())
            } else {
                Err(SimError::Config { field, value: value.to_string(), message: message.to_string() })
            }
        }
        check(self.dt > 0.0 && self.dt <= 5.0, "dt", self.dt, "must lie in (0, 5] seconds")?;
        check((1..=MAX_T_MAX).contains(&self.t_max), "t_max", self.t_max, "must lie in [1, 1000000] steps")?;
        check(self.max_speed > 0.0 && self.max_speed <= 20.0, "max_speed", self.max_speed, "must lie in (0, 20] m/s")?;
        check(
            (0.0..=720.0).contains(&self.max_yaw_rate_deg),
            "max_yaw_rate_deg",
            self.max_yaw_rate_deg,
            "must lie in [0, 720]",
        )?;
        check(
            (0.0..=90.0).contains(&self.max_head_yaw_deg),
            "max_head_yaw_deg",
            self.max_head_yaw_deg,
            "must lie in [0, 90]",
        )?;
        check(
            self.agent_radius > 0.05 && self.agent_radius < 1.0,
            "agent_radius",
            self.agent_radius,
            "must lie in (0.05, 1) m",
        )?;
        check(
            self.agent_height > 2.0 * self.agent_radius && self.agent_height <= MAX_EYE_HEIGHT,
            "agent_height",
            self.agent_height,
            "must exceed twice agent_radius and be at most 3 m (a pedestrian)",
        )?;
        let max_eye = MAX_EYE_HEIGHT;
        check(
            self.eye_height > 0.1 && self.eye_height < max_eye,
            "eye_height",
            self.eye_height,
            "must lie in (0.1, 3) m (the mesh omits tops above 3 m)",
        )?;
        check(self.fov_deg > 10.0 && self.fov_deg < 170.0, "fov_deg", self.fov_deg, "must lie in (10, 170) degrees")?;
        check((8..=1024).contains(&self.image_size), "image_size", self.image_size, "must lie in [8, 1024] pixels")?;
        if let Some(f) = self.traffic_flow {
            if let Err((_, m)) = check_level(f, 0) {
                return Err(SimError::Config { field: "traffic_flow", value: f.to_string(), message: m });
            }
        }
        if let Some(w) = self.traffic_walkers {
            if let Err((_, m)) = check_level(0.0, w) {
                return Err(SimError::Config { field: "traffic_walkers", value: w.to_string(), message: m });
            }
        }
        if let Some(n) = self.traffic_non_yielding {
            check((0.0..=1.0).contains(&n), "traffic_non_yielding", n, "must lie in [0, 1]")?;
        }
        if let Some(r) = self.traffic_dont_walk_entry {
            if let Err(m) = check_dont_walk_entry(r) {
                return Err(SimError::Config { field: "traffic_dont_walk_entry", value: r.to_string(), message: m });
            }
        }
        check(
            !self.traffic_ground_signals.is_on() || self.traffic.is_on(),
            "traffic_ground_signals",
            format!("{:?}", self.traffic_ground_signals).to_lowercase(),
            "needs traffic (sim.traffic = \"light\", \"medium\" or \"heavy\"): the lights show the signal plan, which runs only with traffic",
        )?;
        Ok(())
    }
}

fn is_off(g: &GroundSignals) -> bool {
    !g.is_on()
}

/// Range check of a level's numbers: (field, message) on failure.
pub(crate) fn check_level(flow: f32, walkers: u32) -> std::result::Result<(), (&'static str, String)> {
    if !(flow >= 0.0 && flow <= 2400.0) {
        return Err((
            "flow",
            format!("{flow} must lie in [0, 2400] vehicles/h/lane (a lane carries at most ≈ 1,900 at green)"),
        ));
    }
    if walkers > 64 {
        return Err(("walkers", format!("{walkers} must be at most 64")));
    }
    Ok(())
}

/// Range check of the reward for entering a zebra outside WALK (the scene's
/// `traffic.rewards.dont_walk_entry` and the run's override): the message on failure.
pub(crate) fn check_dont_walk_entry(reward: f32) -> std::result::Result<(), String> {
    if (-1000.0..=0.0).contains(&reward) { Ok(()) } else { Err(format!("{reward} must lie in [-1000, 0]")) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_state_observation_reads_under_both_of_its_names() {
        #[derive(Deserialize)]
        struct Sim {
            obs_mode: ObsMode,
        }
        for name in ["state", "state_debug"] {
            let s: Sim = toml::from_str(&format!("obs_mode = \"{name}\"")).unwrap();
            assert_eq!(s.obs_mode, ObsMode::State, "{name}");
        }
        let written = toml::to_string(&SimConfig { obs_mode: ObsMode::State, ..SimConfig::default() }).unwrap();
        assert!(written.contains("obs_mode = \"state\""), "{written}");
    }

    /// Each out-of-range value alone is refused naming its field; each boundary alone
    /// is accepted.
    #[test]
    fn values_outside_the_documented_ranges_are_refused_naming_the_field() {
        let refused: [(&str, fn(&mut SimConfig)); 15] = [
            ("dt", |c| c.dt = 0.0),
            ("dt", |c| c.dt = f32::NAN),
            ("t_max", |c| c.t_max = 0),
            ("t_max", |c| c.t_max = MAX_T_MAX + 1),
            ("max_speed", |c| c.max_speed = 1e15),
            ("max_yaw_rate_deg", |c| c.max_yaw_rate_deg = f32::NAN),
            ("max_head_yaw_deg", |c| c.max_head_yaw_deg = 91.0),
            ("fov_deg", |c| c.fov_deg = f32::NAN),
            ("image_size", |c| c.image_size = 4096),
            ("traffic_flow", |c| c.traffic_flow = Some(f32::NAN)),
            ("traffic_walkers", |c| c.traffic_walkers = Some(65)),
            ("traffic_non_yielding", |c| c.traffic_non_yielding = Some(1.5)),
            ("traffic_dont_walk_entry", |c| c.traffic_dont_walk_entry = Some(1.0)),
            ("traffic_dont_walk_entry", |c| c.traffic_dont_walk_entry = Some(f32::NAN)),
            ("traffic_ground_signals", |c| c.traffic_ground_signals = GroundSignals::Edges),
        ];
        for (field, set) in refused {
            let mut cfg = SimConfig::default();
            set(&mut cfg);
            match cfg.validate() {
                Err(SimError::Config { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{field}: {other:?}"),
            }
        }
        let accepted: [fn(&mut SimConfig); 7] = [
            |c| c.dt = 5.0,
            |c| c.t_max = MAX_T_MAX,
            |c| c.max_head_yaw_deg = 90.0,
            |c| c.traffic_flow = Some(2400.0),
            |c| c.traffic_walkers = Some(64),
            |c| c.traffic_dont_walk_entry = Some(-1000.0),
            |c| {
                c.traffic = TrafficLevel::Light;
                c.traffic_ground_signals = GroundSignals::Kerb;
            },
        ];
        for set in accepted {
            let mut cfg = SimConfig::default();
            set(&mut cfg);
            cfg.validate().unwrap();
        }
    }
}
