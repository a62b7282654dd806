//! Uniform task sampling from the areas the curriculum proposes starts in (the
//! scene's curriculum region, enlarged on request).
//!
//! Invariant: every pose returned lies inside those areas and passes the scene's
//! start-pose check (inside the world, clear of obstacles, not in the goal).

use pednav_sim::scene::{Polygon, Rect};
use pednav_sim::{Pose, Scene};
use rand::Rng;

use crate::error::{CurriculumError, Result};

/// Draws start poses uniformly (in area and yaw) from a union of areas.
#[derive(Debug, Clone)]
pub struct TaskSampler {
    areas: Vec<Polygon>,
    bounds: Rect,
    max_rejections: usize,
}

impl TaskSampler {
    /// A sampler over the scene's proposal region: the curriculum region, plus its
    /// enlarged areas when `enlarged` (`curriculum.enlarged_region`).
    pub fn new(scene: &Scene, enlarged: bool, max_rejections: usize) -> TaskSampler {
        let areas = scene.proposal_region(enlarged);
        let mut bounds = Rect { min: [f32::INFINITY; 2], max: [f32::NEG_INFINITY; 2] };
        for p in &areas {
            let b = p.bounds();
            bounds.min = [bounds.min[0].min(b.min[0]), bounds.min[1].min(b.min[1])];
            bounds.max = [bounds.max[0].max(b.max[0]), bounds.max[1].max(b.max[1])];
        }
        TaskSampler { areas, bounds, max_rejections }
    }

    /// The bounding box of the areas (what rejection sampling draws from).
    pub fn bounds(&self) -> Rect {
        self.bounds
    }

    /// Is the point inside one of the areas?
    pub fn contains(&self, x: f32, y: f32) -> bool {
        self.areas.iter().any(|p| p.contains(x, y))
    }

    /// One pose by rejection sampling in the region's bounding box; yaw uniform in [−π, π).
    pub fn sample(&self, scene: &Scene, rng: &mut impl Rng) -> Result<Pose> {
        for _ in 0..self.max_rejections {
            let x = rng.random_range(self.bounds.min[0]..self.bounds.max[0]);
            let y = rng.random_range(self.bounds.min[1]..self.bounds.max[1]);
            let yaw = rng.random_range(-std::f32::consts::PI..std::f32::consts::PI);
            let pose = Pose { x, y, yaw };
            if self.contains(x, y) && scene.check_task(pose).is_ok() {
                return Ok(pose);
            }
        }
        Err(CurriculumError::NoValidTask { tries: self.max_rejections })
    }
}
