//! The observations of all environments as one buffer of bytes, and the range of the
//! state observation.
//!
//! Layout of the buffer, which `pednav_gym` reads with `numpy.frombuffer`:
//! - pixel mode: the M frames one after another, each `image_size²` greyscale bytes,
//!   row-major, top row first — [`pednav_sim::Frames::copy_frame`]'s layout, read from
//!   one render of all M views;
//! - state mode: the M state vectors one after another, each
//!   [`STATE_OBS_DIM`] `f32` in the machine's byte order ([`VecEnv::state_obs`]).
//!
//! Invariant: after [`write`] the buffer holds exactly one observation per environment
//! of the world's observation mode, in environment order, and nothing else.

use pednav_sim::{ObsMode, STATE_OBS_DIM, SimError, SimWorld, VecEnv};

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
            out.reserve(count * STATE_OBS_DIM * size_of::<f32>());
            for env in 0..count {
                for value in envs.state_obs(env) {
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
/// are the scene's. Checked against real observations by python/tests (`check_env`
/// asserts every observation lies in the space).
pub fn state_bounds(world: &SimWorld) -> (Vec<f32>, Vec<f32>) {
    let [goal_x, goal_y] = world.scene.goal_center;
    let extent = &world.scene.extent;
    let corners = [extent.min, [extent.min[0], extent.max[1]], [extent.max[0], extent.min[1]], extent.max];
    let reach = corners.iter().map(|[x, y]| (x - goal_x).hypot(y - goal_y)).fold(0.0f32, f32::max);
    let goal_offset = reach / GOAL_OFFSET_SCALE_M;
    let table = world.scene.rewards().map_reward_table();
    let lowest_reward = table.iter().copied().fold(f32::INFINITY, f32::min) / MAP_REWARD_SCALE;
    let highest_reward = table.iter().copied().fold(f32::NEG_INFINITY, f32::max) / MAP_REWARD_SCALE;
    (0..STATE_OBS_DIM)
        .map(|entry| match entry {
            0 | 1 => (-goal_offset, goal_offset),
            2..=4 => (-1.0, 1.0),
            _ => (lowest_reward, highest_reward),
        })
        .map(|(low, high)| (low - BOUND_SLACK, high + BOUND_SLACK))
        .unzip()
}
