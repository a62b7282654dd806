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
//!
//! With traffic on ([`Pedestrian::step_in_traffic`]) the step also: stops the move
//! short of any walker or vehicle it would run into (a bump: the collision reward,
//! as for a wall); advances the traffic by `dt` (a moving vehicle that reaches the
//! agent is a hit: the scene's `vehicle_hit` reward and the episode ends,
//! terminated); pays a zebra entered outside WALK at the road's rate for as long as
//! the agent stays on it (walking on the road against the signal), plus the run's
//! `dont_walk_entry` reward once on the step it steps on (0 unless set); and records the
//! step's [`SafetyEvents`]. The invariant above then holds with the episode's
//! [`TrafficState`] as part of the state.

use serde::{Deserialize, Serialize};

use crate::config::SimConfig;
use crate::region_kind::RegionKind;
use crate::scene::{Pose, wrap_angle};
use crate::traffic::{AgentContact, SafetyEvents, Traffic, TrafficState};
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
    /// What traffic did to the agent in this step (all false with traffic off).
    #[serde(default)]
    pub safety: SafetyEvents,
}

impl Transition {
    /// Did this step end the episode in the goal (not by a vehicle hit)?
    pub fn reached_goal(&self) -> bool {
        self.terminated && !self.safety.vehicle_hit
    }

    /// The region whose map reward the step paid: the road for a zebra entered
    /// outside WALK, else the region under the agent.
    pub fn paid_region(&self) -> RegionKind {
        if self.safety.against_signal { RegionKind::Road } else { self.region }
    }
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

    /// The step's command, turn (rad), mid-step heading (rad) and distance (m).
    fn motion(&self, action: Action, cfg: &SimConfig) -> (Command, f32, f32, f32) {
        let cmd = command_of(action, cfg);
        let turn = cmd.yaw_rate * cfg.dt;
        (cmd, turn, self.pose.yaw + 0.5 * turn, cmd.speed * cfg.dt)
    }

    /// Camera yaw = body yaw + head yaw offset.
    pub fn camera_yaw(&self) -> f32 {
        self.pose.yaw + self.head_yaw
    }

    /// Advance one decision step (see the module docs for the order).
    pub fn step(&mut self, action: Action, world: &SimWorld) -> Transition {
        let cfg = &world.config;
        let (cmd, turn, heading, dist) = self.motion(action, cfg);
        let mv = world.physics.move_agent(self.pose.x, self.pose.y, dist * heading.cos(), dist * heading.sin(), cfg.dt);
        self.pose = Pose { x: mv.x, y: mv.y, yaw: wrap_angle(self.pose.yaw + turn) };
        self.head_yaw = cmd.head_yaw;
        self.step += 1;
        let region = world.map.kind_at(mv.x, mv.y);
        let reward = world.scene.rewards().step_reward(region, cmd.speed, mv.collided);
        self.finish(reward, region == RegionKind::Goal, mv.collided, region, SafetyEvents::default(), cfg.t_max)
    }

    /// Advance one decision step among traffic (see the module docs).
    pub fn step_in_traffic(
        &mut self,
        action: Action,
        world: &SimWorld,
        traffic: &Traffic,
        state: &mut TrafficState,
    ) -> Transition {
        let cfg = &world.config;
        let (cmd, turn, heading, dist) = self.motion(action, cfg);
        let from = [self.pose.x, self.pose.y];
        let mv = world.physics.move_agent(from[0], from[1], dist * heading.cos(), dist * heading.sin(), cfg.dt);
        let (p, contact) = state.block_agent(traffic, from, [mv.x, mv.y], cfg.agent_radius);
        let t0 = state.t;
        let vehicle_hit = state.advance(traffic, &world.physics, cfg.dt, p, cfg.agent_radius);
        self.pose = Pose { x: p[0], y: p[1], yaw: wrap_angle(self.pose.yaw + turn) };
        self.head_yaw = cmd.head_yaw;
        self.step += 1;
        let region = world.map.kind_at(p[0], p[1]);
        let (legal, dont_walk_entry) = state.track_zebra(traffic, p, t0);
        let paid = if region == RegionKind::Zebra && !legal { RegionKind::Road } else { region };
        let collided = mv.collided || contact != AgentContact::None;
        let mut reward = world.scene.rewards().step_reward(paid, cmd.speed, collided);
        if vehicle_hit {
            reward += traffic.vehicle_hit;
        }
        if dont_walk_entry {
            reward += state.settings.dont_walk_entry;
        }
        let moved = (p[0] - from[0]).hypot(p[1] - from[1]);
        let safety = SafetyEvents {
            vehicle_hit,
            dont_walk_entry,
            against_signal: paid != region,
            pedestrian_bump: contact == AgentContact::Walker,
            vehicle_bump: contact == AgentContact::Vehicle,
            kerb_wait: moved < 0.1 && TrafficState::at_kerb(traffic, p, region),
        };
        self.finish(reward, vehicle_hit || region == RegionKind::Goal, collided, region, safety, cfg.t_max)
    }

    /// Close a step already counted in `self.step`: truncated at `t_max` unless
    /// terminated, `done` set, the transition at the new pose.
    fn finish(
        &mut self,
        reward: f32,
        terminated: bool,
        collided: bool,
        region: RegionKind,
        safety: SafetyEvents,
        t_max: u32,
    ) -> Transition {
        let truncated = !terminated && self.step >= t_max;
        self.done = terminated || truncated;
        Transition {
            reward,
            terminated,
            truncated,
            collided,
            region,
            pose: self.pose,
            head_yaw: self.head_yaw,
            step: self.step,
            safety,
        }
    }
}
