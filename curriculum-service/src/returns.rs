//! Task features and the discounted returns f^r is trained on (paper §III-B).
//!
//! Invariant: `discounted_returns(r, γ, b)[t]` is
//! `Σ_{k=0}^{T−t−1} γ^k r_{t+k+1} + γ^{T−t}·b` for every state `s_t`, `t < T`,
//! with `b = f^r(h_T)` when the episode was truncated at T_max and `b = 0` when it
//! ended in the goal — the paper's G_{t:T}.

use pednav_sim::Pose;
use pednav_sim::scene::wrap_angle;

/// Task features φ(s, s_g): the pose part (dx, dy, yaw) — the goal's offset from the
/// pose along x and y in metres, and the pose's yaw in radians in (−π, π] — and, when
/// the signal phase is part of the task (`curriculum.signal_phase = "task"`), the
/// position in the signal cycle in [0, 1).
///
/// Saved as a list of three or four numbers (the three of states written before the
/// cycle existed read back unchanged).
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(try_from = "Vec<f32>", into = "Vec<f32>")]
pub struct TaskFeatures {
    /// (dx, dy, yaw).
    pub pose: [f32; 3],
    /// Position in the signal cycle, [0, 1), when it is part of the task.
    pub cycle: Option<f32>,
}

impl From<[f32; 3]> for TaskFeatures {
    fn from(pose: [f32; 3]) -> Self {
        TaskFeatures { pose, cycle: None }
    }
}

impl TryFrom<Vec<f32>> for TaskFeatures {
    type Error = String;
    fn try_from(v: Vec<f32>) -> Result<Self, String> {
        match v[..] {
            [dx, dy, yaw] => Ok(TaskFeatures { pose: [dx, dy, yaw], cycle: None }),
            [dx, dy, yaw, c] => Ok(TaskFeatures { pose: [dx, dy, yaw], cycle: Some(c) }),
            _ => Err(format!("task features are 3 or 4 numbers (dx, dy, yaw[, cycle]), got {}", v.len())),
        }
    }
}

impl From<TaskFeatures> for Vec<f32> {
    fn from(f: TaskFeatures) -> Vec<f32> {
        let mut v = f.pose.to_vec();
        v.extend(f.cycle);
        v
    }
}

/// The features of a task at `pose`, `cycle` into the signal cycle when that is part of the task.
pub fn task_features(pose: Pose, goal: [f32; 2], cycle: Option<f32>) -> TaskFeatures {
    TaskFeatures { pose: [goal[0] - pose.x, goal[1] - pose.y, wrap_angle(pose.yaw)], cycle }
}

/// Position in the signal cycle `steps` decision steps after `start`, each step
/// `step` of the cycle (dt / cycle length): in [0, 1).
pub fn cycle_after(start: f32, steps: usize, step: f32) -> f32 {
    let c = (start as f64 + steps as f64 * step as f64).rem_euclid(1.0) as f32;
    // An f64 just below 1 can round to 1.0 in f32.
    if c >= 1.0 { 0.0 } else { c }
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
        let f = task_features(Pose { x: 12.0, y: 7.0, yaw: 3.0 * std::f32::consts::PI }, [20.0, 7.0], None).pose;
        assert_eq!(f[0], 8.0);
        assert_eq!(f[1], 0.0);
        assert!((f[2] - std::f32::consts::PI).abs() < 1e-5);
    }

    #[test]
    fn features_save_as_three_or_four_numbers() {
        let old: TaskFeatures = serde_json::from_str("[1.5, -2.0, 0.25]").unwrap();
        assert_eq!(old, TaskFeatures { pose: [1.5, -2.0, 0.25], cycle: None });
        let with = TaskFeatures { pose: [1.0, 2.0, 3.0], cycle: Some(0.5) };
        assert_eq!(serde_json::to_string(&with).unwrap(), "[1.0,2.0,3.0,0.5]");
        assert_eq!(serde_json::from_str::<TaskFeatures>("[1.0,2.0,3.0,0.5]").unwrap(), with);
        let err = serde_json::from_str::<TaskFeatures>("[1.0, 2.0]").unwrap_err().to_string();
        assert!(err.contains("3 or 4 numbers"), "{err}");
    }

    #[test]
    fn the_cycle_advances_a_step_at_a_time_and_wraps() {
        // A 76 s cycle at 0.25 s a step: 304 steps go round once.
        let step = 0.25 / 76.0;
        assert_eq!(cycle_after(0.5, 0, step), 0.5);
        assert!((cycle_after(0.5, 152, step) - 0.0).abs() < 1e-6, "half a cycle on from 0.5 is 0");
        assert!((cycle_after(0.9, 304 * 3 + 76, step) - 0.15).abs() < 1e-5);
        for k in 0..2000 {
            let c = cycle_after(0.999_999, k, step);
            assert!((0.0..1.0).contains(&c), "{c}");
        }
    }
}
