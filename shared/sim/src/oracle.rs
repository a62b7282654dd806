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

use crate::pedestrian::{Pedestrian, Transition};
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
    free: Vec<bool>,
    /// Number of sweeps used.
    pub sweeps: usize,
}

const BLOCKED: f32 = -1.0e4;

struct Motion {
    dh: isize,
    dx: f32,
    dy: f32,
    speed: f32,
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
        let mut free = vec![false; nx * ny];
        for j in 0..ny {
            for i in 0..nx {
                let (x, y) = (x0 + (i as f32 + 0.5) * cfg.cell, y0 + (j as f32 + 0.5) * cfg.cell);
                free[j * nx + i] = scene.extent.contains(x, y)
                    && scene.obstacles.iter().all(|o| o.footprint.distance(x, y) > clearance);
            }
        }
        // Motion primitives per heading bin: turns up to the yaw-rate limit, speed 0 or max.
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
                    m.push(Motion { dh: k, dx: d * mid.cos(), dy: d * mid.sin(), speed });
                }
            }
            motions.push(m);
        }
        let mut values = vec![BLOCKED; nx * ny * hcount];
        for (c, f) in free.iter().enumerate() {
            if *f {
                for v in &mut values[c * hcount..(c + 1) * hcount] {
                    *v = -1.0 / (1.0 - cfg.gamma) * 3.5; // below any achievable return
                }
            }
        }
        let mut oracle = Oracle { cfg, x0, y0, nx, ny, values, free, sweeps: 0 };
        let gamma = oracle.cfg.gamma;
        for sweep in 0..oracle.cfg.max_sweeps {
            let mut max_delta = 0.0f32;
            let (rev_i, rev_j) = (sweep % 2 == 1, (sweep / 2) % 2 == 1);
            for jj in 0..ny {
                let j = if rev_j { ny - 1 - jj } else { jj };
                for ii in 0..nx {
                    let i = if rev_i { nx - 1 - ii } else { ii };
                    if !oracle.free[j * nx + i] {
                        continue;
                    }
                    let (x, y) = oracle.center(i, j);
                    for h in 0..hcount {
                        let mut best = f32::NEG_INFINITY;
                        for m in &motions[h] {
                            let (xn, yn) = (x + m.dx, y + m.dy);
                            let (ci, cj) = oracle.cell_of(xn, yn);
                            if !oracle.free[cj * nx + ci] {
                                continue;
                            }
                            let kind = world.map.kind_at(xn, yn);
                            let r = rewards.map_reward(kind) + rewards.speed * m.speed;
                            let q = if kind == RegionKind::Goal {
                                r
                            } else {
                                let hn = (h as isize + m.dh).rem_euclid(hcount as isize) as usize;
                                r + gamma * oracle.interp_xy(xn, yn, hn)
                            };
                            best = best.max(q);
                        }
                        if best > f32::NEG_INFINITY {
                            let idx = (j * nx + i) * hcount + h;
                            max_delta = max_delta.max((best - oracle.values[idx]).abs());
                            oracle.values[idx] = best;
                        }
                    }
                }
            }
            oracle.sweeps = sweep + 1;
            if max_delta < oracle.cfg.tolerance && sweep >= 3 {
                break;
            }
        }
        oracle
    }

    #[inline]
    fn center(&self, i: usize, j: usize) -> (f32, f32) {
        (self.x0 + (i as f32 + 0.5) * self.cfg.cell, self.y0 + (j as f32 + 0.5) * self.cfg.cell)
    }

    #[inline]
    fn cell_of(&self, x: f32, y: f32) -> (usize, usize) {
        let i = (((x - self.x0) / self.cfg.cell).floor().max(0.0) as usize).min(self.nx - 1);
        let j = (((y - self.y0) / self.cfg.cell).floor().max(0.0) as usize).min(self.ny - 1);
        (i, j)
    }

    /// Bilinear interpolation of V in (x, y) at heading bin `h`; blocked corners
    /// are replaced by the best free corner so walls do not leak huge penalties.
    #[inline]
    fn interp_xy(&self, x: f32, y: f32, h: usize) -> f32 {
        let fx = ((x - self.x0) / self.cfg.cell - 0.5).clamp(0.0, (self.nx - 1) as f32);
        let fy = ((y - self.y0) / self.cfg.cell - 0.5).clamp(0.0, (self.ny - 1) as f32);
        let (i0, j0) = (fx.floor() as usize, fy.floor() as usize);
        let (i1, j1) = ((i0 + 1).min(self.nx - 1), (j0 + 1).min(self.ny - 1));
        let (tx, ty) = (fx - i0 as f32, fy - j0 as f32);
        let hc = self.cfg.headings;
        let v = |i: usize, j: usize| self.values[(j * self.nx + i) * hc + h];
        let corners = [v(i0, j0), v(i1, j0), v(i0, j1), v(i1, j1)];
        let best = corners.iter().cloned().fold(f32::NEG_INFINITY, f32::max);
        let c = corners.map(|c| if c <= BLOCKED * 0.5 { best } else { c });
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

    /// Best planned value over all headings at a position.
    pub fn best_value_at(&self, x: f32, y: f32) -> (f32, f32) {
        let hc = self.cfg.headings;
        (0..hc)
            .map(|h| {
                let yaw = h as f32 / hc as f32 * std::f32::consts::TAU;
                (self.value(Pose { x, y, yaw }), yaw)
            })
            .fold((f32::NEG_INFINITY, 0.0), |a, b| if b.0 > a.0 { b } else { a })
    }

    /// Number of planning sweeps used.
    pub fn sweeps(&self) -> usize {
        self.sweeps
    }

    /// Greedy rollout from `start` through the real simulator for at most `t_max`
    /// steps: at each step pick, among 5 speeds × 9 yaw rates (head straight), the
    /// action maximising `r + γ·V(next pose)` (`r` alone on reaching the goal).
    pub fn rollout(&self, world: &SimWorld, start: Pose, t_max: u32) -> Rollout {
        let mut p = Pedestrian::default();
        p.reset(start);
        let gamma = self.cfg.gamma;
        let mut ret = 0.0f32;
        let mut discount = 1.0f32;
        let mut traj = vec![p.pose];
        let mut success = false;
        let speeds = [-1.0f32, -0.5, 0.0, 0.5, 1.0];
        let turns = [-1.0f32, -0.75, -0.5, -0.25, 0.0, 0.25, 0.5, 0.75, 1.0];
        for _ in 0..t_max {
            let mut best: Option<(f32, Pedestrian, Transition)> = None;
            for &a0 in &speeds {
                for &a1 in &turns {
                    let mut q = p;
                    let t = q.step([a0, a1, 0.0], world);
                    let v = if t.terminated { t.reward } else { t.reward + gamma * self.value(t.pose) };
                    if best.as_ref().is_none_or(|b| v > b.0) {
                        best = Some((v, q, t));
                    }
                }
            }
            let (_, q, t) = best.expect("at least one action");
            p = q;
            ret += discount * t.reward;
            discount *= gamma;
            traj.push(p.pose);
            if t.terminated {
                success = true;
                break;
            }
        }
        Rollout { discounted_return: ret, success, steps: traj.len() as u32 - 1, trajectory: traj }
    }

    /// The oracle return of a pose: the greedy rollout's discounted return.
    pub fn oracle_return(&self, world: &SimWorld, start: Pose, t_max: u32) -> f32 {
        self.rollout(world, start, t_max).discounted_return
    }
}
