//! The observations of all environments as one buffer of bytes, and the range of the
//! state observation.
//!
//! Layout of the buffer, which `pednav_gym` reads with `numpy.frombuffer`:
//! - pixel mode: the M frames one after another, each `image_size²` greyscale bytes,
//!   row-major, top row first — [`pednav_sim::Frames::copy_frame`]'s layout, read from
//!   one render of all M views;
//! - state mode: the M state vectors one after another, each
//!   [`VecEnv::state_dim`] `f32` in the machine's byte order ([`VecEnv::state_obs`]:
//!   22, or 50 with traffic).
//!
//! Invariant: after [`write`] the buffer holds exactly one observation per environment
//! of the world's observation mode, in environment order, and nothing else.

use pednav_sim::{ObsMode, STATE_OBS_DIM, SimError, SimWorld, TRAFFIC_STATE_DIM, VecEnv};

/// Replace the contents of `out` with the current observation of every environment.
pub fn write(envs: &mut VecEnv, out: &mut Vec<u8>) -> Result<(), SimError> {
    let count = envs.num_envs();
    let mode = envs.world().config.obs_mode;
    let side = envs.world().config.image_size as usize;
    out.clear();
    match mode {
        ObsMode::Pixels => {
            out.resize(count * side * side, 0);
            let frames = envs.render()?;
            for (env, frame) in out.chunks_exact_mut(side * side).enumerate() {
                frames.copy_frame(env, frame);
            }
        }
        ObsMode::State => {
            let dim = envs.state_dim();
            out.reserve(count * dim * size_of::<f32>());
            for env in 0..count {
                for value in envs.state_obs(env).into_iter().take(dim) {
                    out.extend_from_slice(&value.to_ne_bytes());
                }
            }
        }
    }
    Ok(())
}

/// Scale of the goal offset in the state observation, metres (`pednav_sim::state_obs`:
/// entries 0–1 are the goal centre in the body frame divided by 20 m).
const GOAL_OFFSET_SCALE_M: f32 = 20.0;
/// Scale of the map rewards in the state observation (`pednav_sim::state_obs`: entries
/// 5–21 are map rewards divided by 3).
const MAP_REWARD_SCALE: f32 = 3.0;
/// How far each bound lies beyond the exact range, so that float rounding in the
/// observation's arithmetic never leaves the box.
const BOUND_SLACK: f32 = 1e-3;

/// Lowest and highest value of each entry of the state observation in `world`, from the
/// layout documented in `pednav_sim::state_obs`: the goal offset is at most the distance
/// from the goal centre to the farthest corner of the world (the pedestrian never leaves
/// it); heading cosine and sine and the head yaw fraction lie in [−1, 1]; the map rewards
/// are the scene's. With traffic: the zebra's ends lie in the world (the same reach
/// from any point of it, the world's diagonal), flags and time fractions in [0, 1],
/// each vehicle slot's centre within its range and its velocity within the drivers'
/// desired speed (IDM never exceeds it; 5 % slack). Checked against real observations by
/// python/tests (`check_env` asserts every observation lies in the space).
pub fn state_bounds(world: &SimWorld) -> (Vec<f32>, Vec<f32>) {
    let [goal_x, goal_y] = world.scene.goal_center;
    let extent = &world.scene.extent;
    let corners = [extent.min, [extent.min[0], extent.max[1]], [extent.max[0], extent.min[1]], extent.max];
    let reach = corners.iter().map(|[x, y]| (x - goal_x).hypot(y - goal_y)).fold(0.0f32, f32::max);
    let goal_offset = reach / GOAL_OFFSET_SCALE_M;
    let table = world.scene.rewards().map_reward_table();
    let lowest_reward = table.iter().copied().fold(f32::INFINITY, f32::min) / MAP_REWARD_SCALE;
    let highest_reward = table.iter().copied().fold(f32::NEG_INFINITY, f32::max) / MAP_REWARD_SCALE;
    use pednav_sim::state_obs::{POSITION_SCALE_M, VEHICLE_RANGE, VEHICLE_SPEED_SCALE};
    let diagonal = (extent.max[0] - extent.min[0]).hypot(extent.max[1] - extent.min[1]) / POSITION_SCALE_M;
    let vehicle_reach = VEHICLE_RANGE / POSITION_SCALE_M;
    let speed = world.traffic.as_ref().map_or(1.0, |(t, _)| 1.05 * t.driver.desired_speed / VEHICLE_SPEED_SCALE);
    let traffic = (0..TRAFFIC_STATE_DIM).map(|entry| match entry {
        0..=3 => (-diagonal, diagonal),
        4..=7 => (0.0, 1.0),
        k if (k - 8) % 5 == 0 => (0.0, 1.0),
        k if (k - 8) % 5 <= 2 => (-vehicle_reach, vehicle_reach),
        _ => (-speed, speed),
    });
    let count = if world.traffic.is_some() { TRAFFIC_STATE_DIM } else { 0 };
    (0..STATE_OBS_DIM)
        .map(|entry| match entry {
            0 | 1 => (-goal_offset, goal_offset),
            2..=4 => (-1.0, 1.0),
            _ => (lowest_reward, highest_reward),
        })
        .chain(traffic.take(count))
        .map(|(low, high)| (low - BOUND_SLACK, high + BOUND_SLACK))
        .unzip()
}
