//! Task features and the discounted returns f^r is trained on (paper §III-B).
//!
//! Invariant: `discounted_returns(r, γ, b)[t]` is
//! `Σ_{k=0}^{T−t−1} γ^k r_{t+k+1} + γ^{T−t}·b` for every state `s_t`, `t < T`,
//! with `b = f^r(h_T)` when the episode was truncated at T_max and `b = 0` when it
//! ended in the goal — the paper's G_{t:T}.

use pednav_sim::Pose;
use pednav_sim::scene::wrap_angle;

/// Task features φ(s, s_g) = (dx, dy, yaw): the goal's offset from the pose along
/// x and y in metres, and the pose's yaw in radians in (−π, π].
pub fn task_features(pose: Pose, goal: [f32; 2]) -> [f32; 3] {
    [goal[0] - pose.x, goal[1] - pose.y, wrap_angle(pose.yaw)]
}

/// Discounted return of every step of an episode. `rewards[i]` is r_{i+1}, the
/// reward received on leaving s_i; `bootstrap` is f^r(h_T) for a truncated episode
/// and `None` for one that reached the goal.
pub fn discounted_returns(rewards: &[f32], gamma: f32, bootstrap: Option<f32>) -> Vec<f32> {
    let mut out = vec![0.0; rewards.len()];
    let mut g = bootstrap.unwrap_or(0.0);
    for (t, r) in rewards.iter().enumerate().rev() {
        g = r + gamma * g;
        out[t] = g;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn returns_match_hand_computed_values() {
        // Terminated: r = [-1, -1, 15], γ = 0.5 → G2 = 15, G1 = -1 + 7.5 = 6.5, G0 = -1 + 3.25 = 2.25.
        assert_eq!(discounted_returns(&[-1.0, -1.0, 15.0], 0.5, None), vec![2.25, 6.5, 15.0]);
        // Truncated with f^r(h_T) = -8: G2 = -1 + 0.5·(-8) = -5, G1 = -1 - 2.5 = -3.5, G0 = -1 - 1.75 = -2.75.
        assert_eq!(discounted_returns(&[-1.0, -1.0, -1.0], 0.5, Some(-8.0)), vec![-2.75, -3.5, -5.0]);
        assert!(discounted_returns(&[], 0.99, Some(3.0)).is_empty());
    }

    #[test]
    fn features_are_the_goal_offset_and_yaw() {
        let f = task_features(Pose { x: 12.0, y: 7.0, yaw: 3.0 * std::f32::consts::PI }, [20.0, 7.0]);
        assert_eq!(f[0], 8.0);
        assert_eq!(f[1], 0.0);
        assert!((f[2] - std::f32::consts::PI).abs() < 1e-5);
    }
}
