//! Start poses the Python side offers by name: the paper's validation starts (every
//! validation point of the scene at each of the protocol's eight yaws), the first
//! task and the fixed start.
//!
//! Invariant: poses leave this module in the scene file's units — metres and degrees,
//! read from the scene's spec, never converted from radians — so a start handed back
//! to `Simulator.reset` becomes a `Pose` through `Pose::from_degrees` only, as in
//! `pednav-eval` and `pednav-sim`.

use pednav_sim::Scene;
use pednav_sim::scene::PoseSpec;

/// A start as Python sees it: `(point, x m, y m, yaw °)` for a validation start.
pub type StartPose = (u32, f32, f32, f32);

/// The eight start yaws of the paper's validation protocol (§V-C), degrees, in the
/// protocol's order. Owned by `pednav_experiments::protocol::YAWS_DEG`, which this
/// crate cannot depend on without linking the learner into the extension; the two
/// must stay equal (python/tests/test_starts.py checks the set against the paper's).
pub const VALIDATION_YAWS_DEG: [f32; 8] = [0.0, 45.0, -45.0, 90.0, -90.0, 135.0, -135.0, 180.0];

/// Every validation point of `scene` at each of [`VALIDATION_YAWS_DEG`]: points outer,
/// yaws inner, as `pednav_experiments::protocol::validation_tasks` lists one run.
pub fn validation(scene: &Scene) -> Vec<StartPose> {
    scene
        .validation_points()
        .iter()
        .flat_map(|p| VALIDATION_YAWS_DEG.iter().map(move |&yaw_deg| (p.id, p.x, p.y, yaw_deg)))
        .collect()
}

/// A pose of the scene file as `(x m, y m, yaw °)`.
pub fn degrees(pose: PoseSpec) -> (f32, f32, f32) {
    (pose.x, pose.y, pose.yaw_deg)
}
