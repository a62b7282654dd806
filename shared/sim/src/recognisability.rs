//! Can a pedestrian tell where it stands from one frame? The scene-side half of
//! the recognisability measures (the classifier half lives in
//! `pednav-experiments`, which has the networks).
//!
//! The reference intersection is laid out around the origin, the centre of the
//! crossing: rotating a pose by a quarter turn about it lands on the same spot of
//! another corner. A scene whose corners look alike shows nearly the same frame
//! there, and a policy acting from pixels cannot know which way the goal lies.
//! Two measures, over seeded random sidewalk poses a pedestrian can reach (on a
//! sidewalk, clear of obstacles, connected to the first task — not, say, inside a
//! fenced park):
//! - **aliasing** ([`aliasing`]): the share of poses whose frame is closer (L2) to
//!   one of its three rotated twins than to the frame after its own small step
//!   (0.5 m ahead and 10° to the left) — a share near 0 means the corners differ
//!   more than one step of the agent changes the view;
//! - **which corner** (classifier, elsewhere): the held-out accuracy of a small CNN
//!   naming a frame's [`quadrant`].
//!
//! Invariant: a [`PoseSet`] is a pure function of (scene, count, seed) — the poses,
//! their order and their looks — so two scenes are measured on the same protocol.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::SimError;
use crate::render::{CameraView, Look, Renderer};
use crate::scene::{Pose, RegionKind, Scene, wrap_angle};

/// The agent's own small step the twins are compared with: metres ahead.
pub const STEP_METRES: f32 = 0.5;
/// ... and degrees turned (counter-clockwise).
pub const STEP_DEGREES: f32 = 10.0;

/// Seeded random poses on the sidewalks, each with the look it is rendered with.
#[derive(Debug, Clone, PartialEq)]
pub struct PoseSet {
    /// Camera poses (the head looks straight ahead).
    pub poses: Vec<Pose>,
    /// The look of each pose (its rotated twins and its step share it).
    pub looks: Vec<Look>,
}

/// The quadrant of the intersection a point lies in: 0 north-east (x > 0, y > 0),
/// 1 north-west, 2 south-west, 3 south-east.
pub fn quadrant(x: f32, y: f32) -> usize {
    match (x > 0.0, y > 0.0) {
        (true, true) => 0,
        (false, true) => 1,
        (false, false) => 2,
        (true, false) => 3,
    }
}

/// Names of the quadrants, in [`quadrant`]'s order.
pub const QUADRANT_NAMES: [&str; 4] = ["north-east", "north-west", "south-west", "south-east"];

/// `pose` turned by `quarters` quarter turns counter-clockwise about the origin.
pub fn rotated(pose: Pose, quarters: u32) -> Pose {
    let (x, y) = match quarters % 4 {
        0 => (pose.x, pose.y),
        1 => (-pose.y, pose.x),
        2 => (-pose.x, -pose.y),
        _ => (pose.y, -pose.x),
    };
    Pose { x, y, yaw: wrap_angle(pose.yaw + quarters as f32 * std::f32::consts::FRAC_PI_2) }
}

/// `pose` after the agent's small step: [`STEP_METRES`] ahead, then [`STEP_DEGREES`] to the left.
pub fn stepped(pose: Pose) -> Pose {
    Pose {
        x: pose.x + STEP_METRES * pose.yaw.cos(),
        y: pose.y + STEP_METRES * pose.yaw.sin(),
        yaw: wrap_angle(pose.yaw + STEP_DEGREES.to_radians()),
    }
}

/// Half the side of the square about the origin whose quarter-turn rotations stay
/// inside the world: poses are drawn inside it.
pub fn symmetric_half_side(scene: &Scene) -> f32 {
    let e = scene.extent;
    [-e.min[0], -e.min[1], e.max[0], e.max[1]].into_iter().fold(f32::INFINITY, f32::min)
}

/// Where a pedestrian can walk: the cells of a grid over the world that lie clear of
/// every obstacle by [`Scene::START_CLEARANCE`] and connect (4-neighbours) to the
/// first task's cell.
pub struct Walkable {
    x0: f32,
    y0: f32,
    cell: f32,
    nx: usize,
    ny: usize,
    reached: Vec<bool>,
}

impl Walkable {
    /// Grid cell of the flood fill, metres.
    pub const CELL: f32 = 0.25;

    /// Flood-fill the scene from its first task.
    pub fn of(scene: &Scene) -> Walkable {
        let cell = Self::CELL;
        let (x0, y0) = (scene.extent.min[0], scene.extent.min[1]);
        let nx = (scene.extent.width() / cell).ceil() as usize;
        let ny = (scene.extent.height() / cell).ceil() as usize;
        let centre = |i: usize, j: usize| (x0 + (i as f32 + 0.5) * cell, y0 + (j as f32 + 0.5) * cell);
        let clear: Vec<bool> = (0..nx * ny)
            .map(|k| {
                let (x, y) = centre(k % nx, k / nx);
                scene.obstacles.iter().all(|o| o.footprint.distance(x, y) >= Scene::START_CLEARANCE)
            })
            .collect();
        let mut reached = vec![false; nx * ny];
        let start = scene.first_task();
        let (si, sj) = (((start.x - x0) / cell) as usize, ((start.y - y0) / cell) as usize);
        let mut queue = std::collections::VecDeque::from([(si.min(nx - 1), sj.min(ny - 1))]);
        while let Some((i, j)) = queue.pop_front() {
            let k = j * nx + i;
            if reached[k] || !clear[k] {
                continue;
            }
            reached[k] = true;
            if i > 0 {
                queue.push_back((i - 1, j));
            }
            if i + 1 < nx {
                queue.push_back((i + 1, j));
            }
            if j > 0 {
                queue.push_back((i, j - 1));
            }
            if j + 1 < ny {
                queue.push_back((i, j + 1));
            }
        }
        Walkable { x0, y0, cell, nx, ny, reached }
    }

    /// Can a pedestrian walk to `(x, y)` from the first task?
    pub fn contains(&self, x: f32, y: f32) -> bool {
        let (i, j) = ((x - self.x0) / self.cell, (y - self.y0) / self.cell);
        i >= 0.0
            && j >= 0.0
            && (i as usize) < self.nx
            && (j as usize) < self.ny
            && self.reached[j as usize * self.nx + i as usize]
    }
}

impl PoseSet {
    /// `count` poses drawn uniformly on the sidewalks (both kinds) inside the
    /// rotation-safe square, where an episode could start (clear of obstacles) and
    /// a pedestrian can walk to ([`Walkable`]), with uniform yaw; each rendered with
    /// the plain look, or a domain-randomised one (as an episode's) when `randomize`.
    /// An error when the scene has no rotation-safe square around the origin, or when
    /// too few draws land on a walkable sidewalk (a scene whose sidewalks are out of
    /// reach of the first task, or smaller than [`Scene::START_CLEARANCE`]).
    pub fn sidewalks(scene: &Scene, count: usize, seed: u64, randomize: bool) -> crate::Result<PoseSet> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let half = symmetric_half_side(scene);
        let invalid =
            |message: String| SimError::SceneInvalid { origin: scene.origin.clone(), field: "extent".into(), message };
        if half.is_nan() || half <= 0.0 {
            return Err(invalid(format!(
                "the recognisability poses lie in the square |x|, |y| < {half} m, which is empty: the world must contain the origin (the intersection's centre)"
            )));
        }
        let walkable = Walkable::of(scene);
        let (mut poses, mut looks) = (Vec::with_capacity(count), Vec::with_capacity(count));
        // A sidewalk covers a sizeable share of the reference square (about a third);
        // a thousand draws per pose leaves room for scenes with far less.
        let max_draws = 1000 * count.max(10);
        let mut draws = 0;
        while poses.len() < count {
            draws += 1;
            if draws > max_draws {
                return Err(invalid(format!(
                    "only {} of {count} poses found on walkable sidewalks in {max_draws} uniform draws over |x|, |y| < {half} m",
                    poses.len()
                )));
            }
            let pose = Pose {
                x: rng.random_range(-half..half),
                y: rng.random_range(-half..half),
                yaw: rng.random_range(-std::f32::consts::PI..std::f32::consts::PI),
            };
            let look_seed: u64 = rng.random();
            let kind = scene.region_kind_exact(pose.x, pose.y);
            if matches!(kind, RegionKind::Sidewalk | RegionKind::GoalSidewalk)
                && walkable.contains(pose.x, pose.y)
                && scene.check_task(pose).is_ok()
            {
                poses.push(pose);
                looks.push(if randomize { Look::randomized(look_seed) } else { Look::default() });
            }
        }
        Ok(PoseSet { poses, looks })
    }

    /// The quadrant of every pose.
    pub fn quadrants(&self) -> Vec<usize> {
        self.poses.iter().map(|p| quadrant(p.x, p.y)).collect()
    }
}

/// Render the frames of `poses` with `looks` (one per pose) at eye height `eye`, in
/// batches of at most the renderer's capacity; frame `i` belongs to pose `i`.
pub fn render_frames(renderer: &mut Renderer, poses: &[Pose], looks: &[Look], eye: f32) -> crate::Result<Vec<Vec<u8>>> {
    assert_eq!(poses.len(), looks.len(), "one look per pose");
    let batch = renderer.config().max_views.max(1);
    let mut frames = Vec::with_capacity(poses.len());
    for (p, l) in poses.chunks(batch).zip(looks.chunks(batch)) {
        let views: Vec<CameraView> =
            p.iter().zip(l).map(|(p, &look)| CameraView { x: p.x, y: p.y, z: eye, yaw: p.yaw, look }).collect();
        let out = renderer.render(&views)?;
        frames.extend((0..views.len()).map(|i| out.frame(i)));
    }
    Ok(frames)
}

/// Euclidean distance between two frames, in grey levels.
pub fn l2(a: &[u8], b: &[u8]) -> f64 {
    a.iter().zip(b).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum::<f64>().sqrt()
}

/// The aliasing measure over a pose set.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Aliasing {
    /// Poses measured.
    pub poses: usize,
    /// Poses whose nearest rotated twin is closer than their own step.
    pub aliased: usize,
    /// `aliased / poses`.
    pub share: f64,
    /// The share per quadrant of the pose ([`quadrant`]'s order).
    pub share_by_quadrant: [f64; 4],
    /// Median over poses of (nearest twin distance) / (step distance): above 1, the
    /// corners differ more than a step changes the view.
    pub median_twin_over_step: f64,
    /// Every pose's distances, in the set's order.
    pub per_pose: Vec<PoseDistances>,
}

/// One pose of the aliasing measure.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct PoseDistances {
    /// Pose x, metres.
    pub x: f32,
    /// Pose y, metres.
    pub y: f32,
    /// Camera yaw, degrees.
    pub yaw_deg: f32,
    /// L2 distance to the nearest rotated twin (grey levels).
    pub twin: f64,
    /// Which twin is nearest: quarter turns 1–3.
    pub nearest_twin: u32,
    /// L2 distance to the frame after the pose's own step.
    pub step: f64,
}

/// Measure aliasing (module docs) over `set` at eye height `eye`.
pub fn aliasing(renderer: &mut Renderer, set: &PoseSet, eye: f32) -> crate::Result<Aliasing> {
    // Five views per pose: itself, its three twins, its step — all with its look.
    let mut poses = Vec::with_capacity(set.poses.len() * 5);
    let mut looks = Vec::with_capacity(set.poses.len() * 5);
    for (&p, &look) in set.poses.iter().zip(&set.looks) {
        poses.extend([p, rotated(p, 1), rotated(p, 2), rotated(p, 3), stepped(p)]);
        looks.extend([look; 5]);
    }
    let frames = render_frames(renderer, &poses, &looks, eye)?;
    let mut aliased = 0;
    let (mut hit, mut total) = ([0usize; 4], [0usize; 4]);
    let mut ratios = Vec::with_capacity(set.poses.len());
    let mut per_pose = Vec::with_capacity(set.poses.len());
    for (k, f) in frames.chunks_exact(5).enumerate() {
        let (nearest_twin, twin) =
            (1..4u32).map(|t| (t, l2(&f[0], &f[t as usize]))).min_by(|a, b| a.1.total_cmp(&b.1)).expect("three twins");
        let step = l2(&f[0], &f[4]);
        let p = set.poses[k];
        per_pose.push(PoseDistances { x: p.x, y: p.y, yaw_deg: p.yaw.to_degrees(), twin, nearest_twin, step });
        let q = quadrant(p.x, p.y);
        total[q] += 1;
        if twin < step {
            aliased += 1;
            hit[q] += 1;
        }
        ratios.push(if step > 0.0 { twin / step } else { f64::INFINITY });
    }
    ratios.sort_by(f64::total_cmp);
    let n = set.poses.len();
    Ok(Aliasing {
        poses: n,
        aliased,
        share: aliased as f64 / n.max(1) as f64,
        share_by_quadrant: std::array::from_fn(|q| hit[q] as f64 / total[q].max(1) as f64),
        median_twin_over_step: ratios.get(n / 2).copied().unwrap_or(f64::NAN),
        per_pose,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn four_quarter_turns_are_the_identity_and_quadrants_rotate() {
        let p = Pose { x: 12.0, y: -7.0, yaw: 0.3 };
        let back = rotated(rotated(rotated(rotated(p, 1), 1), 1), 1);
        assert!((back.x - p.x).abs() < 1e-5 && (back.y - p.y).abs() < 1e-5 && (back.yaw - p.yaw).abs() < 1e-5);
        // South-east → north-east → north-west → south-west.
        assert_eq!(
            (0..4)
                .map(|k| {
                    let r = rotated(p, k);
                    quadrant(r.x, r.y)
                })
                .collect::<Vec<_>>(),
            [3, 0, 1, 2]
        );
    }

    #[test]
    fn pose_sets_are_seeded_and_lie_on_sidewalks_clear_of_obstacles() {
        let scene = Scene::reference();
        let a = PoseSet::sidewalks(&scene, 50, 7, false).unwrap();
        assert_eq!(a, PoseSet::sidewalks(&scene, 50, 7, false).unwrap());
        assert_ne!(a, PoseSet::sidewalks(&scene, 50, 8, false).unwrap());
        let half = symmetric_half_side(&scene);
        for p in &a.poses {
            assert!(matches!(scene.region_kind_exact(p.x, p.y), RegionKind::Sidewalk | RegionKind::GoalSidewalk));
            assert!(scene.check_task(*p).is_ok());
            assert!(p.x.abs() < half && p.y.abs() < half);
        }
        // Nothing behind the park's fence; all four corners sampled.
        let walkable = Walkable::of(&scene);
        assert!(!walkable.contains(-20.0, 25.0) && walkable.contains(-20.0, 7.0));
        let q = a.quadrants();
        assert!((0..4).all(|k| q.contains(&k)), "{q:?}");
    }

    #[test]
    fn a_step_moves_half_a_metre_and_turns_ten_degrees() {
        let s = stepped(Pose { x: 1.0, y: 2.0, yaw: std::f32::consts::FRAC_PI_2 });
        assert!((s.x - 1.0).abs() < 1e-5 && (s.y - 2.5).abs() < 1e-5);
        assert!((s.yaw - (90f32 + 10.0).to_radians()).abs() < 1e-5);
    }
}
