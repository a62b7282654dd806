//! Uniform task sampling from the scene's curriculum region.
//!
//! Invariant: every pose returned lies inside the curriculum region and passes
//! the scene's start-pose check (inside the world, clear of obstacles, not in the goal).

use pednav_sim::scene::Rect;
use pednav_sim::{Pose, Scene};
use rand::Rng;

use crate::error::{CurriculumError, Result};

/// Draws start poses uniformly (in area and yaw) from a scene's curriculum region.
#[derive(Debug, Clone)]
pub struct TaskSampler {
    bounds: Rect,
    max_rejections: usize,
}

impl TaskSampler {
    /// A sampler over the scene's curriculum region.
    pub fn new(scene: &Scene, max_rejections: usize) -> TaskSampler {
        let mut bounds = Rect { min: [f32::INFINITY; 2], max: [f32::NEG_INFINITY; 2] };
        for p in &scene.curriculum_region {
            let b = p.bounds();
            bounds.min = [bounds.min[0].min(b.min[0]), bounds.min[1].min(b.min[1])];
            bounds.max = [bounds.max[0].max(b.max[0]), bounds.max[1].max(b.max[1])];
        }
        TaskSampler { bounds, max_rejections }
    }

    /// One pose by rejection sampling in the region's bounding box; yaw uniform in [−π, π).
    pub fn sample(&self, scene: &Scene, rng: &mut impl Rng) -> Result<Pose> {
        for _ in 0..self.max_rejections {
            let x = rng.random_range(self.bounds.min[0]..self.bounds.max[0]);
            let y = rng.random_range(self.bounds.min[1]..self.bounds.max[1]);
            let yaw = rng.random_range(-std::f32::consts::PI..std::f32::consts::PI);
            let pose = Pose { x, y, yaw };
            if scene.in_curriculum_region(x, y) && scene.check_task(pose).is_ok() {
                return Ok(pose);
            }
        }
        Err(CurriculumError::NoValidTask { tries: self.max_rejections })
    }
}
