//! The state-debug observation: a small vector for fast algorithm tests and
//! debugging. It is **not** the paper's task (which is pixels only) and never the
//! default; configs must ask for `obs_mode = "state"`.
//!
//! Layout (`STATE_OBS_DIM` = 22 floats):
//! - `[0..2]`  goal centre in the body frame (forward, left), divided by 20 m;
//! - `[2..4]`  cos and sin of the body yaw;
//! - `[4]`     head yaw offset / max head yaw;
//! - `[5]`     map reward under the agent / 3;
//! - `[6..22]` map reward / 3 at 8 body-relative bearings (0°, 45°, …, 315°,
//!   counter-clockwise from straight ahead), first at 1 m then at 3 m.

use crate::pedestrian::Pedestrian;
use crate::world::SimWorld;

/// Length of the state-debug observation.
pub const STATE_OBS_DIM: usize = 22;

/// Compute the state-debug observation of a pedestrian.
pub fn state_observation(world: &SimWorld, p: &Pedestrian) -> [f32; STATE_OBS_DIM] {
    let mut o = [0.0f32; STATE_OBS_DIM];
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
    o
}
