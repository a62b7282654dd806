//! The reward: what the pedestrian is paid for in one decision step (paper §IV,
//! Fig. 1b; docs/design.md §3). Every rule of the reward is here; the numbers are the
//! scene's ([`Rewards`], the `[rewards]` table of the scene file).
//!
//! ```text
//! r(t) = r_m(t) + r_v(t) + r_c(t)
//! ```
//!
//! - **Map reward** `r_m` ([`Rewards::map_reward`]): the value of the region under the
//!   agent *after* the move, read from the rasterised region map
//!   ([`crate::region_map::RegionMap`]). Paper Fig. 1b: goal (area 1) +15, road
//!   (area 3) −3, and the safe regions goal-side sidewalk (area 2) −0.6, zebra
//!   crossing (area 4) −0.8, other sidewalks (area 5) −1.0. The goal reward is
//!   terminal: the step that enters the goal ends the episode
//!   ([`crate::pedestrian::Pedestrian::step`]). The negative values on walkable
//!   ground are the whole time penalty — there is no separate per-step term.
//! - **Speed reward** `r_v = 0.125·v` ([`Rewards::speed_reward`]), with `v` the
//!   *commanded* speed in m/s (the action mapped by [`crate::pedestrian::command_of`],
//!   in [0, 2]), not the distance actually walked: pressing against a wall is paid
//!   its speed and its collision. "Encourages the agent to move fast" (§IV).
//! - **Collision reward** `r_c = −3` on a step in which the character controller
//!   reports a hit, else 0 ([`Rewards::collision_reward`]).
//!
//! [`Rewards::step_reward`] composes the three; [`Rewards::PAPER`] holds the paper's
//! numbers, which the reference scene `scenes/corner.toml` uses (a test in
//! [`crate::scene`] checks it).
//! Other scenes may change the numbers, never the rules.
//!
//! Users: the pedestrian pays [`Rewards::step_reward`]; the region map tabulates
//! [`Rewards::map_reward_table`] per cell label (the state-debug observation reads
//! it); the oracle planner ([`crate::oracle`]) plans with `map_reward + speed_reward`
//! (its motion primitives never collide).
//!
//! Invariants: every term is finite (a scene whose rewards are not is rejected when
//! it is loaded, through [`Rewards::non_finite_term`]); a step's reward is a pure
//! function of (region after the move, commanded speed, collision flag) and the
//! scene's [`Rewards`], summed in the fixed order `(r_m + r_v) + r_c`, so whoever
//! recomputes it gets the same bits.

use serde::{Deserialize, Serialize};

use crate::region_kind::RegionKind;

/// The reward's numbers (paper §IV, Fig. 1b): `r = r_map(region) + speed·v + collision·[hit]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rewards {
    /// Map reward on reaching the goal area (terminal). Paper: +15.
    pub goal: f32,
    /// Map reward per step on the goal-side sidewalk. Paper: −0.6.
    pub goal_sidewalk: f32,
    /// Map reward per step on a zebra crossing. Paper: −0.8.
    pub zebra: f32,
    /// Map reward per step on any other sidewalk. Paper: −1.0.
    pub sidewalk: f32,
    /// Map reward per step on the road. Paper: −3.
    pub road: f32,
    /// Coefficient of the speed reward `speed · v` (v in m/s). Paper: 0.125.
    pub speed: f32,
    /// Reward added on a step with a collision. Paper: −3.
    pub collision: f32,
}

impl Rewards {
    /// The paper's numbers (§IV and Fig. 1b), as in the reference scene.
    pub const PAPER: Rewards = Rewards {
        goal: 15.0,
        goal_sidewalk: -0.6,
        zebra: -0.8,
        sidewalk: -1.0,
        road: -3.0,
        speed: 0.125,
        collision: -3.0,
    };

    /// Map reward `r_m` of a region kind.
    pub fn map_reward(&self, kind: RegionKind) -> f32 {
        match kind {
            RegionKind::Road => self.road,
            RegionKind::Sidewalk => self.sidewalk,
            RegionKind::GoalSidewalk => self.goal_sidewalk,
            RegionKind::Zebra => self.zebra,
            RegionKind::Goal => self.goal,
        }
    }

    /// Map reward of every kind, indexed by its label (`kind as usize`).
    pub fn map_reward_table(&self) -> [f32; RegionKind::ALL.len()] {
        RegionKind::ALL.map(|k| self.map_reward(k))
    }

    /// Speed reward `r_v` of a commanded speed in m/s.
    pub fn speed_reward(&self, speed: f32) -> f32 {
        self.speed * speed
    }

    /// Collision reward `r_c`: [`Rewards::collision`] on a step with a hit, else 0.
    pub fn collision_reward(&self, collided: bool) -> f32 {
        if collided { self.collision } else { 0.0 }
    }

    /// Reward of one decision step: `(r_m + r_v) + r_c` for the region under the agent
    /// after the move, the commanded speed (m/s) and the controller's hit flag.
    pub fn step_reward(&self, region: RegionKind, speed: f32, collided: bool) -> f32 {
        let mut reward = self.map_reward(region) + self.speed_reward(speed);
        // Added only on a hit (not `+ 0.0` otherwise), so a step without one is
        // exactly `r_m + r_v`, as the oracle plans it.
        if collided {
            reward += self.collision;
        }
        reward
    }

    /// The first term that is not finite, as (field name in the scene file, value).
    pub fn non_finite_term(&self) -> Option<(&'static str, f32)> {
        [
            ("goal", self.goal),
            ("goal_sidewalk", self.goal_sidewalk),
            ("zebra", self.zebra),
            ("sidewalk", self.sidewalk),
            ("road", self.road),
            ("speed", self.speed),
            ("collision", self.collision),
        ]
        .into_iter()
        .find(|(_, v)| !v.is_finite())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const P: Rewards = Rewards::PAPER;

    #[test]
    fn map_reward_per_region_is_fig_1b() {
        // Fig. 1b: area 1 (goal) 15, area 3 (street) −3, areas 2, 4, 5 (goal-side
        // sidewalk, zebra, other sidewalks) −0.6, −0.8, −1.
        assert_eq!(P.map_reward(RegionKind::Goal), 15.0);
        assert_eq!(P.map_reward(RegionKind::Road), -3.0);
        assert_eq!(P.map_reward(RegionKind::GoalSidewalk), -0.6);
        assert_eq!(P.map_reward(RegionKind::Zebra), -0.8);
        assert_eq!(P.map_reward(RegionKind::Sidewalk), -1.0);
        let table = P.map_reward_table();
        assert_eq!(table, [-3.0, -1.0, -0.6, -0.8, 15.0], "indexed by label: road, sidewalk, goal side, zebra, goal");
        for k in RegionKind::ALL {
            assert_eq!(table[k.label() as usize], P.map_reward(k));
        }
    }

    #[test]
    fn speed_reward_is_an_eighth_of_the_commanded_speed() {
        // r_v = 0.125·v, v ∈ [0, 2] m/s.
        assert_eq!(P.speed_reward(0.0), 0.0);
        assert_eq!(P.speed_reward(1.0), 0.125);
        assert_eq!(P.speed_reward(2.0), 0.25);
    }

    #[test]
    fn collision_reward_is_minus_three_on_a_hit_only() {
        assert_eq!(P.collision_reward(true), -3.0);
        assert_eq!(P.collision_reward(false), 0.0);
    }

    #[test]
    fn step_reward_sums_the_three_terms() {
        // Full speed on the start sidewalk: −1 + 0.25.
        assert_eq!(P.step_reward(RegionKind::Sidewalk, 2.0, false), -0.75);
        // The same step pressed against a wall: −1 + 0.25 − 3.
        assert_eq!(P.step_reward(RegionKind::Sidewalk, 2.0, true), -3.75);
        // Entering the goal at full speed: 15 + 0.25.
        assert_eq!(P.step_reward(RegionKind::Goal, 2.0, false), 15.25);
        // Standing on the road against an obstacle: −3 + 0 − 3.
        assert_eq!(P.step_reward(RegionKind::Road, 0.0, true), -6.0);
        // Half speed over the zebra: −0.8 + 0.125 (−0.8 is not exact in f32).
        assert!((P.step_reward(RegionKind::Zebra, 1.0, false) - (-0.675)).abs() < 1e-6);
        // Without a hit the step is exactly r_m + r_v (what the oracle plans with).
        for k in RegionKind::ALL {
            for v in [0.0, 0.3, 1.7, 2.0] {
                assert_eq!(P.step_reward(k, v, false).to_bits(), (P.map_reward(k) + P.speed * v).to_bits());
            }
        }
    }

    #[test]
    fn discounted_bounds_of_fig_3() {
        // Fig. 3 (γ = 0.99, T_max = 8000): the worst return without collisions is −300
        // (standing on the road, −3/(1 − γ)); not reaching the goal while staying in the
        // low-penalty regions at rest gives [−80, −60] (zebra −0.8, goal-side −0.6).
        let ret = |r: f32| (0..8000).fold((0.0f64, 1.0f64), |(g, d), _| (g + d * r as f64, d * 0.99)).0;
        assert!((ret(P.step_reward(RegionKind::Road, 0.0, false)) + 300.0).abs() < 1e-3);
        assert!((ret(P.step_reward(RegionKind::Zebra, 0.0, false)) + 80.0).abs() < 1e-3);
        assert!((ret(P.step_reward(RegionKind::GoalSidewalk, 0.0, false)) + 60.0).abs() < 1e-3);
    }

    #[test]
    fn a_non_finite_term_is_named() {
        assert_eq!(P.non_finite_term(), None);
        let bad = Rewards { speed: f32::INFINITY, ..P };
        assert_eq!(bad.non_finite_term(), Some(("speed", f32::INFINITY)));
        let bad = Rewards { zebra: f32::NAN, collision: f32::NAN, ..P };
        assert_eq!(bad.non_finite_term().map(|(name, _)| name), Some("zebra"), "the first in file order");
    }
}
