//! One pedestrian episode: action mapping, kinematics, rewards, termination.
//!
//! Invariant: [`Pedestrian::step`] is a pure function of (pose, head yaw, step
//! count, action) and the immutable scene — no randomness — so the same task and
//! actions give bit-identical trajectories and rewards.
//!
//! Step order (one decision step of `dt` seconds):
//! 1. clip the action to [−1, 1]³ and map it: `v = (a₀+1)/2 · v_max`,
//!    `ω = a₁ · ω_max`, head yaw offset `= a₂ · head_max` (absolute, relative to the body);
//! 2. turn the body by `ω·dt` and walk `v·dt` along the mid-step heading
//!    `yaw + ω·dt/2`, through the character controller (slides along walls);
//! 3. reward `r = r_m(region at the new position) + r_v(v) + r_c(hit)`, with `v`
//!    the commanded speed — [`Rewards::step_reward`](crate::reward::Rewards::step_reward),
//!    the paper's reward (terms, values and invariants in [`crate::reward`]);
//! 4. terminated when the new position is in the goal area; otherwise truncated
//!    when the step count reaches `t_max`.

use serde::{Deserialize, Serialize};

use crate::config::SimConfig;
use crate::region_kind::RegionKind;
use crate::scene::{Pose, wrap_angle};
use crate::world::SimWorld;

/// An action in [−1, 1]³: (speed, yaw rate, head yaw). Values outside are clipped.
pub type Action = [f32; 3];

/// What happened in one step.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Transition {
    /// Reward of this step.
    pub reward: f32,
    /// The episode ended in the goal (do not bootstrap).
    pub terminated: bool,
    /// The episode hit `t_max` without reaching the goal (bootstrap).
    pub truncated: bool,
    /// The character controller reported a hit during the move.
    pub collided: bool,
    /// Region under the agent after the move.
    pub region: RegionKind,
    /// Pose after the move.
    pub pose: Pose,
    /// Head yaw offset after the step, radians.
    pub head_yaw: f32,
    /// Steps taken in this episode, including this one.
    pub step: u32,
}

/// Mapped physical command of an action.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    /// Forward speed in m/s.
    pub speed: f32,
    /// Yaw rate in rad/s.
    pub yaw_rate: f32,
    /// Head yaw offset in rad.
    pub head_yaw: f32,
}

/// Map an action in [−1, 1]³ (clipped) to physical commands.
pub fn command_of(action: Action, cfg: &SimConfig) -> Command {
    let a = action.map(|v| v.clamp(-1.0, 1.0));
    Command {
        speed: (a[0] + 1.0) * 0.5 * cfg.max_speed,
        yaw_rate: a[1] * cfg.max_yaw_rate_deg.to_radians(),
        head_yaw: a[2] * cfg.max_head_yaw_deg.to_radians(),
    }
}

/// State of one pedestrian episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pedestrian {
    /// Current body pose.
    pub pose: Pose,
    /// Current head yaw offset relative to the body, radians.
    pub head_yaw: f32,
    /// Steps taken in the current episode.
    pub step: u32,
    /// Has the episode ended (terminated or truncated)? True before the first reset.
    pub done: bool,
}

impl Default for Pedestrian {
    fn default() -> Self {
        Pedestrian { pose: Pose { x: 0.0, y: 0.0, yaw: 0.0 }, head_yaw: 0.0, step: 0, done: true }
    }
}

impl Pedestrian {
    /// Start an episode at `task` (already checked by the caller).
    pub fn reset(&mut self, task: Pose) {
        self.pose = Pose { yaw: wrap_angle(task.yaw), ..task };
        self.head_yaw = 0.0;
        self.step = 0;
        self.done = false;
    }

    /// Camera yaw = body yaw + head yaw offset.
    pub fn camera_yaw(&self) -> f32 {
        self.pose.yaw + self.head_yaw
    }

    /// Advance one decision step (see the module docs for the order).
    pub fn step(&mut self, action: Action, world: &SimWorld) -> Transition {
        let cfg = &world.config;
        let cmd = command_of(action, cfg);
        let turn = cmd.yaw_rate * cfg.dt;
        let heading = self.pose.yaw + 0.5 * turn;
        let dist = cmd.speed * cfg.dt;
        let mv = world.physics.move_agent(self.pose.x, self.pose.y, dist * heading.cos(), dist * heading.sin(), cfg.dt);
        self.pose = Pose { x: mv.x, y: mv.y, yaw: wrap_angle(self.pose.yaw + turn) };
        self.head_yaw = cmd.head_yaw;
        self.step += 1;
        let region = world.map.kind_at(mv.x, mv.y);
        let reward = world.scene.rewards().step_reward(region, cmd.speed, mv.collided);
        let terminated = region == RegionKind::Goal;
        let truncated = !terminated && self.step >= cfg.t_max;
        self.done = terminated || truncated;
        Transition {
            reward,
            terminated,
            truncated,
            collided: mv.collided,
            region,
            pose: self.pose,
            head_yaw: self.head_yaw,
            step: self.step,
        }
    }
}
