//! The oracle: the best discounted return from any pose, planned over the reward map.
//!
//! Method. Value iteration on a grid over (x, y, heading) — `cell` metres and
//! `headings` directions — with the simulator's own motion model: each action turns
//! by a multiple of the heading step (at most the yaw-rate limit × dt) and walks
//! `v·dt` along the mid-step heading, `v` ∈ {0, v_max}. Successor values are
//! interpolated bilinearly in (x, y) (semi-Lagrangian scheme), so headings other
//! than the axes are represented faithfully. A successor whose grid cell is within
//! the agent's radius (+ a 5 cm margin) of an obstacle is forbidden: the optimal
//! pedestrian never collides. Entering the goal ends the episode. Gauss–Seidel
//! sweeps in four alternating orders (fast sweeping) run until the largest change is
//! below `tolerance`.
//!
//! The planned values are then used by [`Oracle::rollout`]: a greedy one-step
//! lookahead through the **real** simulator step (rapier collisions and all) over a
//! finer action set. The oracle return of a pose is that rollout's discounted return:
//! a return the simulator really yields, so a learned policy can match but never
//! beat it by more than the planner's discretisation error.
//!
//! Invariant: the value table is computed once per (scene, config) and is read-only.

use crate::pedestrian::{Action, Pedestrian};
use crate::returns::DiscountedReturn;
use crate::scene::{Pose, RegionKind};
use crate::world::SimWorld;

/// Planner settings.
#[derive(Debug, Clone, PartialEq)]
pub struct OracleConfig {
    /// Discount factor. Paper: 0.99.
    pub gamma: f32,
    /// Grid cell in metres.
    pub cell: f32,
    /// Number of heading bins over 360°.
    pub headings: usize,
    /// Stop sweeping when no value changes by more than this.
    pub tolerance: f32,
    /// Upper bound on sweeps.
    pub max_sweeps: usize,
}

impl Default for OracleConfig {
    fn default() -> Self {
        OracleConfig { gamma: 0.99, cell: 0.25, headings: 36, tolerance: 1e-3, max_sweeps: 400 }
    }
}

/// Result of a greedy rollout.
#[derive(Debug, Clone, PartialEq)]
pub struct Rollout {
    /// Discounted return of the rollout.
    pub discounted_return: f32,
    /// Whether it reached the goal.
    pub success: bool,
    /// Number of steps.
    pub steps: u32,
    /// Poses visited, starting with the start pose.
    pub trajectory: Vec<Pose>,
}

/// Planned values over (x, y, heading).
pub struct Oracle {
    cfg: OracleConfig,
    x0: f32,
    y0: f32,
    nx: usize,
    ny: usize,
    /// `values[(j * nx + i) * headings + h]`.
    values: Vec<f32>,
    sweeps: usize,
}

/// Value of blocked cells and the initial value of free ones: the worst return
/// (road and a collision every step, forever) is −6/(1−γ) = −600 at γ = 0.99; −350 is
/// below every return that avoids collisions, which is all the planner allows.
const BLOCKED: f32 = -350.0;

/// A motion primitive from a cell centre, with its precomputed successor stencil.
struct Motion {
    /// Heading bin after the step.
    hn: usize,
    /// Offset of the grid cell containing the successor.
    cell_di: isize,
    cell_dj: isize,
    /// Offset of the lower-left node of the successor's bilinear stencil.
    base_di: isize,
    base_dj: isize,
    /// Bilinear weights of the successor inside its stencil.
    tx: f32,
    ty: f32,
    /// Speed reward of the primitive.
    speed_reward: f32,
}

impl Oracle {
    /// Plan over the world's scene with the world's motion limits.
    pub fn plan(world: &SimWorld, cfg: OracleConfig) -> Oracle {
        let scene = &world.scene;
        let sim = &world.config;
        let rewards = scene.rewards();
        let nx = (scene.extent.width() / cfg.cell).ceil() as usize;
        let ny = (scene.extent.height() / cfg.cell).ceil() as usize;
        let (x0, y0) = (scene.extent.min[0], scene.extent.min[1]);
        let hcount = cfg.headings;
        let clearance = sim.agent_radius + 0.05;
        // Per planner cell: is it clear of obstacles, and its region at the centre
        // (the planner resolves region borders to one cell; rollouts use the exact map).
        let mut free = vec![false; nx * ny];
        let mut kind = vec![RegionKind::Road; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                let (x, y) = (x0 + (i as f32 + 0.5) * cfg.cell, y0 + (j as f32 + 0.5) * cfg.cell);
                free[j * nx + i] = scene.extent.contains(x, y)
                    && scene.obstacles.iter().all(|o| o.footprint.distance(x, y) > clearance);
                kind[j * nx + i] = world.map.kind_at(x, y);
            }
        }
        // Motion primitives per heading bin: turns up to the yaw-rate limit, speed 0 or
        // max. On a uniform grid the successor of a cell centre lies at a constant
        // offset, so its cell and bilinear stencil are precomputed per primitive.
        let hstep = std::f32::consts::TAU / hcount as f32;
        let max_turn = sim.max_yaw_rate_deg.to_radians() * sim.dt;
        let kmax = (max_turn / hstep + 1e-4).floor() as isize;
        let mut motions: Vec<Vec<Motion>> = Vec::with_capacity(hcount);
        for h in 0..hcount {
            let mut m = Vec::new();
            for k in -kmax..=kmax {
                for speed in [0.0, sim.max_speed] {
                    if speed == 0.0 && k == 0 {
                        continue;
                    }
                    let mid = (h as f32 + 0.5 * k as f32) * hstep;
                    let d = speed * sim.dt;
                    let (dx, dy) = (d * mid.cos(), d * mid.sin());
                    let (fx, fy) = (dx / cfg.cell, dy / cfg.cell);
                    m.push(Motion {
                        hn: (h as isize + k).rem_euclid(hcount as isize) as usize,
                        cell_di: (0.5 + fx).floor() as isize,
                        cell_dj: (0.5 + fy).floor() as isize,
                        base_di: fx.floor() as isize,
                        base_dj: fy.floor() as isize,
                        tx: fx - fx.floor(),
                        ty: fy - fy.floor(),
                        speed_reward: rewards.speed * speed,
                    });
                }
            }
            motions.push(m);
        }
        let region_reward = RegionKind::ALL.map(|k| rewards.map_reward(k));
        let mut values = vec![BLOCKED; nx * ny * hcount];
        let mut sweeps = 0;
        let (nxi, nyi) = (nx as isize, ny as isize);
        let inside = |i: isize, j: isize| i >= 0 && j >= 0 && i < nxi && j < nyi;
        for sweep in 0..cfg.max_sweeps {
            let mut max_delta = 0.0f32;
            let (rev_i, rev_j) = (sweep % 2 == 1, (sweep / 2) % 2 == 1);
            for jj in 0..ny {
                let j = if rev_j { ny - 1 - jj } else { jj };
                for ii in 0..nx {
                    let i = if rev_i { nx - 1 - ii } else { ii };
                    if !free[j * nx + i] {
                        continue;
                    }
                    let (ii, ji) = (i as isize, j as isize);
                    for (h, primitives) in motions.iter().enumerate() {
                        let mut best = f32::NEG_INFINITY;
                        for m in primitives {
                            let (ci, cj) = (ii + m.cell_di, ji + m.cell_dj);
                            if !inside(ci, cj) || !free[cj as usize * nx + ci as usize] {
                                continue;
                            }
                            let kind = kind[cj as usize * nx + ci as usize];
                            let r = region_reward[kind as usize] + m.speed_reward;
                            let q = if kind == RegionKind::Goal {
                                r
                            } else {
                                let (bi, bj) = (ii + m.base_di, ji + m.base_dj);
                                let v = |di: isize, dj: isize| {
                                    let (a, b) =
                                        ((bi + di).clamp(0, nxi - 1) as usize, (bj + dj).clamp(0, nyi - 1) as usize);
                                    values[(b * nx + a) * hcount + m.hn]
                                };
                                let lo = v(0, 0) * (1.0 - m.tx) + v(1, 0) * m.tx;
                                let hi = v(0, 1) * (1.0 - m.tx) + v(1, 1) * m.tx;
                                r + cfg.gamma * (lo * (1.0 - m.ty) + hi * m.ty)
                            };
                            best = best.max(q);
                        }
                        if best > f32::NEG_INFINITY {
                            let idx = (j * nx + i) * hcount + h;
                            max_delta = max_delta.max((best - values[idx]).abs());
                            values[idx] = best;
                        }
                    }
                }
            }
            sweeps = sweep + 1;
            if max_delta < cfg.tolerance && sweep >= 3 {
                break;
            }
        }
        Oracle { cfg, x0, y0, nx, ny, values, sweeps }
    }

    /// Bilinear interpolation of V in (x, y) at heading bin `h`. Blocked cells hold
    /// the worst possible return, so values fall off within one cell of an obstacle:
    /// plans keep clear of walls and poles by up to one extra cell, and the greedy
    /// rollout is never lured into pressing against an obstacle.
    #[inline]
    fn interp_xy(&self, x: f32, y: f32, h: usize) -> f32 {
        let fx = ((x - self.x0) / self.cfg.cell - 0.5).clamp(0.0, (self.nx - 1) as f32);
        let fy = ((y - self.y0) / self.cfg.cell - 0.5).clamp(0.0, (self.ny - 1) as f32);
        let (i0, j0) = (fx.floor() as usize, fy.floor() as usize);
        let (i1, j1) = ((i0 + 1).min(self.nx - 1), (j0 + 1).min(self.ny - 1));
        let (tx, ty) = (fx - i0 as f32, fy - j0 as f32);
        let hc = self.cfg.headings;
        let v = |i: usize, j: usize| self.values[(j * self.nx + i) * hc + h];
        let c = [v(i0, j0), v(i1, j0), v(i0, j1), v(i1, j1)];
        let a = c[0] * (1.0 - tx) + c[1] * tx;
        let b = c[2] * (1.0 - tx) + c[3] * tx;
        a * (1.0 - ty) + b * ty
    }

    /// Planned value at a continuous pose (interpolated in x, y and heading).
    pub fn value(&self, pose: Pose) -> f32 {
        let hc = self.cfg.headings;
        let f = pose.yaw.rem_euclid(std::f32::consts::TAU) / std::f32::consts::TAU * hc as f32;
        let h0 = (f.floor() as usize) % hc;
        let h1 = (h0 + 1) % hc;
        let t = f - f.floor();
        self.interp_xy(pose.x, pose.y, h0) * (1.0 - t) + self.interp_xy(pose.x, pose.y, h1) * t
    }

    /// Number of planning sweeps used.
    pub fn sweeps(&self) -> usize {
        self.sweeps
    }

    /// The greedy action at a pedestrian's state: among 5 speeds × 9 yaw rates
    /// (head straight), the one maximising `r + γ·V(next pose)` through the real
    /// simulator step (`r` alone on reaching the goal).
    pub fn best_action(&self, world: &SimWorld, p: &Pedestrian) -> Action {
        const SPEEDS: [f32; 5] = [-1.0, -0.5, 0.0, 0.5, 1.0];
        const TURNS: [f32; 9] = [-1.0, -0.75, -0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0];
        let mut best = ([1.0, 0.0, 0.0], f32::NEG_INFINITY);
        for a0 in SPEEDS {
            for a1 in TURNS {
                let a = [a0, a1, 0.0];
                let mut q = *p;
                let t = q.step(a, world);
                let v = if t.terminated { t.reward } else { t.reward + self.cfg.gamma * self.value(t.pose) };
                if v > best.1 {
                    best = (a, v);
                }
            }
        }
        best.0
    }

    /// Greedy rollout ([`Oracle::best_action`] at every step) from `start`
    /// through the real simulator for at most `t_max` steps.
    pub fn rollout(&self, world: &SimWorld, start: Pose, t_max: u32) -> Rollout {
        let mut p = Pedestrian::default();
        p.reset(start);
        let mut ret = DiscountedReturn::new(self.cfg.gamma as f64);
        let mut trajectory = vec![p.pose];
        let mut success = false;
        for _ in 0..t_max {
            let t = p.step(self.best_action(world, &p), world);
            ret.add(t.reward);
            trajectory.push(p.pose);
            if t.terminated {
                success = true;
                break;
            }
        }
        Rollout { discounted_return: ret.value() as f32, success, steps: trajectory.len() as u32 - 1, trajectory }
    }
}
