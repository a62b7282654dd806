//! [`StepBatch`]: what one `Simulator.reset` or `Simulator.step` call did to each
//! environment, as columns that Python turns into NumPy arrays or an `info` dict.
//!
//! Invariants: every column has one entry per environment, in environment order. An
//! environment stepped in the call reports its transition; one that was not — restarted
//! instead, or left alone by a reset — reports a reward of 0 in every part and is
//! neither terminated, truncated nor collided. Every environment reports its pose, head
//! yaw, step count and region as they are after the call. The reward's parts come from
//! the [`Rewards`](pednav_sim::Rewards) methods whose sum the pedestrian's step pays, so
//! `reward == ((reward_map + reward_speed) + reward_collision) + reward_traffic` in
//! `f32`, bit for bit (`reward_traffic` is 0 without traffic, so the last addition
//! changes nothing there).

use pednav_sim::{Action, Transition, VecEnv, command_of};
use pyo3::prelude::*;

/// Per-environment results of one reset or step (see the module docs). Angles are in
/// degrees, positions in metres, as in the scene file.
#[pyclass(module = "pednav_gym._pednav", frozen, get_all)]
#[derive(Debug, Clone, Default)]
pub struct StepBatch {
    /// Reward of the step: `(reward_map + reward_speed) + reward_collision`.
    pub reward: Vec<f32>,
    /// `r_m`: the map reward of the region entered (the goal's on reaching it).
    pub reward_map: Vec<f32>,
    /// `r_v`: the speed reward of the commanded speed.
    pub reward_speed: Vec<f32>,
    /// `r_c`: the collision reward (0 without a hit).
    pub reward_collision: Vec<f32>,
    /// The step reached the goal (do not bootstrap).
    pub terminated: Vec<bool>,
    /// The step reached `t_max` without the goal (bootstrap).
    pub truncated: Vec<bool>,
    /// The character controller reported a hit during the step (or, with traffic,
    /// the agent ran into a walker or a vehicle).
    pub collided: Vec<bool>,
    /// Traffic: the vehicle-hit reward (0 without a hit).
    pub reward_traffic: Vec<f32>,
    /// Traffic: a vehicle hit the agent (the episode ends, terminated, not a success).
    pub vehicle_hit: Vec<bool>,
    /// Traffic: the agent stepped onto a zebra that did not show WALK.
    pub dont_walk_entry: Vec<bool>,
    /// Traffic: the agent bumped into another pedestrian.
    pub pedestrian_bump: Vec<bool>,
    /// Traffic: the agent stood waiting at a kerb.
    pub kerb_wait: Vec<bool>,
    /// Body position x after the call, metres.
    pub x: Vec<f32>,
    /// Body position y after the call, metres.
    pub y: Vec<f32>,
    /// Body yaw after the call, degrees in (−180, 180], 0 = east, counter-clockwise.
    pub yaw_deg: Vec<f32>,
    /// Head yaw relative to the body after the call, degrees.
    pub head_yaw_deg: Vec<f32>,
    /// Steps taken in the episode so far.
    pub step: Vec<u32>,
    /// Name of the region under the pedestrian (`RegionKind::name`).
    pub region: Vec<&'static str>,
}

/// What happened to one environment in a call: stepped with this action and this
/// result, or not stepped.
pub type Stepped = Option<(Action, Transition)>;

impl StepBatch {
    /// The batch of `envs` after a call in which environment `e` was stepped as
    /// `stepped[e]` says.
    pub fn collect(envs: &VecEnv, stepped: &[Stepped]) -> StepBatch {
        let world = envs.world();
        let rewards = world.scene.rewards();
        let mut batch = StepBatch::default();
        for (env, outcome) in stepped.iter().enumerate() {
            let hit_reward = world.traffic.as_ref().map_or(0.0, |(t, _)| t.vehicle_hit);
            let (reward, parts, flags, safety) = match outcome {
                Some((action, t)) => {
                    let speed = command_of(*action, &world.config).speed;
                    let parts = [
                        rewards.map_reward(t.paid_region()),
                        rewards.speed_reward(speed),
                        rewards.collision_reward(t.collided),
                        if t.safety.vehicle_hit { hit_reward } else { 0.0 },
                    ];
                    (t.reward, parts, [t.terminated, t.truncated, t.collided], t.safety)
                }
                None => (0.0, [0.0; 4], [false; 3], Default::default()),
            };
            batch.reward.push(reward);
            batch.reward_map.push(parts[0]);
            batch.reward_speed.push(parts[1]);
            batch.reward_collision.push(parts[2]);
            batch.terminated.push(flags[0]);
            batch.truncated.push(flags[1]);
            batch.collided.push(flags[2]);
            batch.reward_traffic.push(parts[3]);
            batch.vehicle_hit.push(safety.vehicle_hit);
            batch.dont_walk_entry.push(safety.dont_walk_entry);
            batch.pedestrian_bump.push(safety.pedestrian_bump);
            batch.kerb_wait.push(safety.kerb_wait);
            let p = envs.pedestrian(env);
            batch.x.push(p.pose.x);
            batch.y.push(p.pose.y);
            batch.yaw_deg.push(p.pose.yaw.to_degrees());
            batch.head_yaw_deg.push(p.head_yaw.to_degrees());
            batch.step.push(p.step);
            batch.region.push(world.map.kind_at(p.pose.x, p.pose.y).name());
        }
        batch
    }
}

#[pymethods]
impl StepBatch {
    /// Number of environments reported.
    fn __len__(&self) -> usize {
        self.reward.len()
    }
}
