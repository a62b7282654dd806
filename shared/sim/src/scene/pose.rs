//! Agent poses on the ground plane: [`Pose`] (yaw in radians, as all code uses
//! it), its construction from the scene file's degrees, and [`wrap_angle`].
//!
//! Invariant: a [`Pose`]'s yaw is in radians, 0 facing +x (east), counter-clockwise
//! positive; the scene file's degrees ([`super::PoseSpec`]) become radians only
//! through [`Pose::from_degrees`]. [`wrap_angle`] returns an angle in (−π, π].

use serde::{Deserialize, Serialize};

use super::spec::PoseSpec;

/// Wrap an angle to (−π, π].
pub fn wrap_angle(a: f32) -> f32 {
    let two_pi = std::f32::consts::TAU;
    let mut r = a.rem_euclid(two_pi);
    if r > std::f32::consts::PI {
        r -= two_pi;
    }
    r
}

/// An agent pose on the ground plane (yaw in radians).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    /// x in metres.
    pub x: f32,
    /// y in metres.
    pub y: f32,
    /// Body yaw in radians, 0 = east, counter-clockwise.
    pub yaw: f32,
}

impl Pose {
    /// A pose from metres and degrees.
    pub fn from_degrees(x: f32, y: f32, yaw_deg: f32) -> Pose {
        Pose { x, y, yaw: yaw_deg.to_radians() }
    }
}

impl From<PoseSpec> for Pose {
    fn from(p: PoseSpec) -> Pose {
        Pose::from_degrees(p.x, p.y, p.yaw_deg)
    }
}
