//! The classification of the curriculum region that the paper's Fig. 4 shows:
//! every cell of a grid over the region, with the start yaw facing the goal,
//! classified by the task-value net into easy / frontier / hard / neither with
//! the bands of the current t_c; μ and σ fitted on a fresh set of candidate
//! tasks, as the scheduler does (when the signal phase is part of the task, a cell's
//! value is the mean of the net's over 8 evenly spaced positions in the cycle), for a
//! running curriculum or one continued from a saved state of the service process
//! ([`crate::Curriculum::from_saved`]), so snapshots can be drawn after the fact.

use std::collections::BTreeMap;

use pednav_sim::draw::{MapCanvas, draw_map};
use pednav_sim::{Pose, RegionMap, Scene};
use rand::SeedableRng;

use crate::config::CurriculumConfig;
use crate::curriculum::Curriculum;
use crate::error::Result;
use crate::filter::{Category, Fit, bands};
use crate::returns::{TaskFeatures, task_features};
use crate::sampler::TaskSampler;

/// Positions in the signal cycle a cell's value is averaged over, when the phase is
/// part of the task.
const CYCLE_POINTS: usize = 8;

/// Class of one grid cell.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum CellClass {
    /// f > μ + β_e σ.
    Easy,
    /// μ − β_f^l σ < f < μ + β_f^h σ.
    Frontier,
    /// f < μ − β_h σ.
    Hard,
    /// None of the bands.
    Neither,
}

impl CellClass {
    /// Colour used in the pictures.
    pub fn colour(self) -> [u8; 3] {
        match self {
            CellClass::Easy => [40, 170, 60],
            CellClass::Frontier => [240, 190, 30],
            CellClass::Hard => [200, 40, 40],
            CellClass::Neither => [150, 110, 170],
        }
    }
}

/// The classified grid.
#[derive(Debug, Clone)]
pub struct Classification {
    /// μ, σ of the candidates' predictions.
    pub fit: Fit,
    /// Cell centres and classes.
    pub cells: Vec<([f32; 2], CellClass)>,
    /// Cell size in metres.
    pub cell: f32,
    /// t_c of the state.
    pub t_c: u64,
    /// Whether the state is in the ACL phase.
    pub acl: bool,
}

impl Classification {
    /// Cells per class.
    pub fn counts(&self) -> BTreeMap<CellClass, usize> {
        let mut m = BTreeMap::new();
        for (_, c) in &self.cells {
            *m.entry(*c).or_default() += 1;
        }
        m
    }

    /// Draw the grid over the bird's-eye map at `px_per_m`.
    pub fn draw(&self, scene: &Scene, px_per_m: f32) -> MapCanvas {
        let mut canvas = draw_map(scene, &RegionMap::new(scene), px_per_m);
        for &([x, y], class) in &self.cells {
            canvas.disc(x, y, self.cell * px_per_m * 0.5, class.colour());
        }
        let g = scene.goal_center;
        canvas.disc(g[0], g[1], 0.4 * px_per_m, [255, 255, 255]);
        canvas
    }
}

/// Classify the curriculum region of `scene` (with its enlarged areas when
/// `cfg.enlarged_region`) with `curriculum`'s task-value net.
/// `None` for the fixed-start variant (no net).
pub fn classify_region(
    curriculum: &mut Curriculum,
    scene: &Scene,
    cfg: &CurriculumConfig,
    cell: f32,
) -> Result<Option<Classification>> {
    let sampler = TaskSampler::new(scene, cfg.enlarged_region, cfg.max_rejections);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(pednav_config::rng::CLASSIFICATION_CANDIDATES);
    let cycles: Vec<Option<f32>> = if curriculum.has_cycle() {
        (0..CYCLE_POINTS).map(|k| Some(k as f32 / CYCLE_POINTS as f32)).collect()
    } else {
        vec![None]
    };
    let candidates: Vec<TaskFeatures> = (0..cfg.candidates)
        .map(|k| sampler.sample(scene, &mut rng).map(|p| task_features(p, scene.goal_center, cycles[k % cycles.len()])))
        .collect::<Result<_>>()?;
    let Some(predictions) = curriculum.predict(&candidates) else {
        return Ok(None);
    };
    let fit = Fit::of(&predictions).expect("at least two candidates (validated)");
    let t_c = curriculum.scheduler().t_c();
    let b = bands(cfg, fit, t_c);
    let mut points = Vec::new();
    let mut features = Vec::new();
    // One grid over the whole proposal region, so cells where areas overlap come once.
    let r = sampler.bounds();
    let (nx, ny) = ((r.width() / cell).ceil() as usize, (r.height() / cell).ceil() as usize);
    for j in 0..ny {
        let y = r.min[1] + (j as f32 + 0.5) * cell;
        for i in 0..nx {
            let x = r.min[0] + (i as f32 + 0.5) * cell;
            if sampler.contains(x, y) {
                let yaw = (scene.goal_center[1] - y).atan2(scene.goal_center[0] - x);
                points.push([x, y]);
                for &c in &cycles {
                    features.push(task_features(Pose { x, y, yaw }, scene.goal_center, c));
                }
            }
        }
    }
    let per_cell = curriculum.predict(&features).expect("the net exists");
    let values: Vec<f32> =
        per_cell.chunks_exact(cycles.len()).map(|c| c.iter().sum::<f32>() / cycles.len() as f32).collect();
    let cells = points
        .into_iter()
        .zip(values)
        .map(|(p, f)| {
            let class = if b.contains(Category::Easy, f) {
                CellClass::Easy
            } else if b.contains(Category::Frontier, f) {
                CellClass::Frontier
            } else if b.contains(Category::Hard, f) {
                CellClass::Hard
            } else {
                CellClass::Neither
            };
            (p, class)
        })
        .collect();
    Ok(Some(Classification { fit, cells, cell, t_c, acl: curriculum.scheduler().in_acl_phase() }))
}
