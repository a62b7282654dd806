//! The state-debug observation: a small vector for fast algorithm tests and
//! debugging. It is **not** the paper's task (which is pixels only) and never the
//! default; configs must ask for `obs_mode = "state"`. It is privileged (the
//! simulator's own state): a debugging aid, never a headline.
//!
//! Layout: [`STATE_OBS_DIM`] = 22 floats of the static scene, and with traffic on
//! [`TRAFFIC_STATE_DIM`] = 28 more ([`state_obs_dim`]: 22 or 50).
//! - `[0..2]`  goal centre in the body frame (forward, left), divided by 20 m;
//! - `[2..4]`  cos and sin of the body yaw;
//! - `[4]`     head yaw offset / max head yaw;
//! - `[5]`     map reward under the agent / 3;
//! - `[6..22]` map reward / 3 at 8 body-relative bearings (0°, 45°, …, 315°,
//!   counter-clockwise from straight ahead), first at 1 m then at 3 m.
//!
//! With traffic, about the zebra nearest the agent (by distance to its outline's
//! bounding rectangle) and the vehicles nearest it:
//! - `[22..24]` the zebra's nearer kerb end, body frame / 20 m;
//! - `[24..26]` its farther kerb end, body frame / 20 m;
//! - `[26]`     1 while its heads show WALK, else 0;
//! - `[27]`     1 during its flashing clearance, else 0;
//! - `[28]`     seconds until its next WALK / the cycle (0 during WALK);
//! - `[29]`     seconds until its steady DON'T WALK / (walk + clearance) (0 when shown);
//! - `[30..50]` the [`NEAREST_VEHICLES`] vehicles nearest the agent (footprint
//!   centres within [`VEHICLE_RANGE`] m), nearest first, 5 floats each: 1 (present),
//!   centre in the body frame / 20 m (forward, left), velocity in the body frame /
//!   14 m/s (the drivers' desired speed, ≈ 50 km/h); all 0 for an empty slot.
//!
//! Invariant: the first 22 entries are computed exactly as before traffic existed,
//! whatever the traffic; with traffic off the observation has 22 entries (runs and
//! checkpoints of the state preset are unchanged).

use crate::config::SimConfig;
use crate::pedestrian::Pedestrian;
use crate::traffic::{PedestrianSignal, Traffic, TrafficState};
use crate::world::SimWorld;

/// Length of the static part of the state observation (all of it with traffic off).
pub const STATE_OBS_DIM: usize = 22;

/// Entries the traffic adds.
pub const TRAFFIC_STATE_DIM: usize = 28;

/// Longest state observation: static part and traffic.
pub const STATE_OBS_MAX: usize = STATE_OBS_DIM + TRAFFIC_STATE_DIM;

/// Vehicle slots of the traffic part.
pub const NEAREST_VEHICLES: usize = 4;

/// Vehicles farther than this (metres, to their footprint centre) fill no slot.
pub const VEHICLE_RANGE: f32 = 40.0;

/// Positions of the traffic part are divided by this, metres.
pub const POSITION_SCALE_M: f32 = 20.0;

/// Vehicle velocities are divided by this, m/s.
pub const VEHICLE_SPEED_SCALE: f32 = 14.0;

/// Length of the state observation of a run with these settings.
pub fn state_obs_dim(cfg: &SimConfig) -> usize {
    if cfg.traffic.is_on() { STATE_OBS_MAX } else { STATE_OBS_DIM }
}

/// Compute the state-debug observation of a pedestrian: the first
/// [`state_obs_dim`] entries filled, the rest 0.
pub fn state_observation(world: &SimWorld, p: &Pedestrian, traffic: Option<&TrafficState>) -> [f32; STATE_OBS_MAX] {
    let mut o = [0.0f32; STATE_OBS_MAX];
    let (c, s) = (p.pose.yaw.cos(), p.pose.yaw.sin());
    let dx = world.scene.goal_center[0] - p.pose.x;
    let dy = world.scene.goal_center[1] - p.pose.y;
    o[0] = (c * dx + s * dy) / 20.0;
    o[1] = (-s * dx + c * dy) / 20.0;
    o[2] = c;
    o[3] = s;
    let head_max = world.config.max_head_yaw_deg.to_radians();
    o[4] = if head_max > 0.0 { p.head_yaw / head_max } else { 0.0 };
    o[5] = world.map.reward_at(p.pose.x, p.pose.y) / 3.0;
    let mut k = 6;
    for radius in [1.0f32, 3.0] {
        for b in 0..8 {
            let a = p.pose.yaw + b as f32 * std::f32::consts::FRAC_PI_4;
            o[k] = world.map.reward_at(p.pose.x + radius * a.cos(), p.pose.y + radius * a.sin()) / 3.0;
            k += 1;
        }
    }
    if let (Some((t, _)), Some(state)) = (&world.traffic, traffic) {
        traffic_part(t, state, p, &mut o[STATE_OBS_DIM..]);
    }
    o
}

/// Fill the traffic entries (see the module docs) into `o` (length [`TRAFFIC_STATE_DIM`]).
fn traffic_part(traffic: &Traffic, state: &TrafficState, p: &Pedestrian, o: &mut [f32]) {
    let (x, y, (c, s)) = (p.pose.x, p.pose.y, (p.pose.yaw.cos(), p.pose.yaw.sin()));
    let body = |v: [f32; 2]| [c * v[0] + s * v[1], -s * v[0] + c * v[1]];
    let rel = |q: [f32; 2]| body([q[0] - x, q[1] - y]);
    let gap = |z: &crate::traffic::Zebra| z.bounds.distance(x, y);
    if let Some((zi, zebra)) = traffic.zebras.iter().enumerate().min_by(|a, b| gap(a.1).total_cmp(&gap(b.1))) {
        let mut ends = zebra.ends();
        let d = |e: [f32; 2]| (e[0] - x).hypot(e[1] - y);
        if d(ends[1]) < d(ends[0]) {
            ends.swap(0, 1);
        }
        let (near, far) = (rel(ends[0]), rel(ends[1]));
        o[0..4].copy_from_slice(&[near[0], near[1], far[0], far[1]].map(|v| v / POSITION_SCALE_M));
        let plan = &traffic.plan;
        let shown = plan.pedestrian(zi, state.t);
        o[4] = f32::from(shown == PedestrianSignal::Walk);
        o[5] = f32::from(shown == PedestrianSignal::Clearance);
        o[6] = (plan.until_walk(zi, state.t) / plan.cycle_s) as f32;
        let crossing = plan.phases.iter().find(|ph| ph.walk.contains(&zi)).map_or(1.0, |ph| ph.walk_s + ph.clearance_s);
        o[7] = (plan.until_dont_walk(zi, state.t) / crossing.max(1e-9)) as f32;
    }
    let mut near: Vec<(f32, [f32; 2], [f32; 2])> = Vec::new();
    for (lane, lt) in traffic.lanes.iter().zip(&state.lanes) {
        for v in &lt.vehicles {
            let centre = v.center(lane);
            let dist = (centre[0] - x).hypot(centre[1] - y);
            if dist <= VEHICLE_RANGE {
                near.push((dist, rel(centre), body([lane.dir[0] * v.v, lane.dir[1] * v.v])));
            }
        }
    }
    near.sort_by(|a, b| a.0.total_cmp(&b.0));
    for (slot, (_, pos, vel)) in o[8..].chunks_exact_mut(5).zip(near) {
        let (p, v) = (POSITION_SCALE_M, VEHICLE_SPEED_SCALE);
        slot.copy_from_slice(&[1.0, pos[0] / p, pos[1] / p, vel[0] / v, vel[1] / v]);
    }
}
