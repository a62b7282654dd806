//! Other pedestrians: walkers that follow the scene's sidewalk network, wait at a
//! kerb for WALK, cross, and keep apart from each other and from the agent with a
//! social force (Helbing & Molnár 1995, the circular form).
//!
//! Invariant: a walker never ends a sub-step overlapping the agent (a move that
//! would is not made), and it moves through the same static world as the agent
//! (rapier's character controller), so it never stands inside an obstacle. It
//! starts over a zebra only on steady WALK.
//!
//! Per sub-step of `h` seconds, for each walker:
//! `v ← v + h·((v_desired − v)/τ + Σ A·exp((r_ij − d_ij)/B)·n_ij)`, capped at 1.3×
//! its preferred speed, with τ = 0.5 s, A = 2 m/s², B = 0.3 m over the other
//! walkers and the agent (r_ij the sum of radii, n_ij the unit vector away); a
//! body ahead (in the walker's desired direction) also pushes it sideways, away
//! from the side the body is on (to the right when dead ahead), with half that
//! strength, so that two people meeting head-on pass each other instead of
//! standing nose to nose.

use rand::Rng;

use super::{Ground, PedestrianSignal, Traffic};

const TAU: f32 = 0.5;
const FORCE_A: f32 = 2.0;
const FORCE_B: f32 = 0.3;
const ARRIVED: f32 = 0.4;

/// One walker.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Walker {
    /// Position, metres.
    pub pos: [f32; 2],
    /// Velocity, m/s.
    pub vel: [f32; 2],
    /// Preferred speed, m/s.
    pub speed: f32,
    /// The edge being walked.
    pub edge: usize,
    /// The node walked towards.
    pub to: usize,
    /// Waiting at the kerb for WALK (the edge is a crossing not yet started).
    pub waiting: bool,
    /// Grey multiplier of the clothes.
    pub tint: f32,
}

impl Walker {
    /// A walker somewhere along a random sidewalk edge, at least `clear` metres
    /// from `agent` (up to 32 draws, then wherever the last one fell).
    pub fn spawn(traffic: &Traffic, rng: &mut impl Rng, agent: [f32; 2], clear: f32) -> Walker {
        let net = &traffic.walkers;
        let sidewalk: Vec<usize> = (0..net.edges.len()).filter(|&e| net.edges[e].2.is_none()).collect();
        let mut w = None;
        for _ in 0..32 {
            let edge = if sidewalk.is_empty() {
                rng.random_range(0..net.edges.len())
            } else {
                sidewalk[rng.random_range(0..sidewalk.len())]
            };
            let (a, b, _) = net.edges[edge];
            let (from, to) = if rng.random::<bool>() { (a, b) } else { (b, a) };
            let f: f32 = rng.random();
            let (p, q) = (net.nodes[from], net.nodes[to]);
            let pos = [p[0] + f * (q[0] - p[0]), p[1] + f * (q[1] - p[1])];
            let speed = rng.random_range(net.speed[0]..=net.speed[1]);
            let tint = rng.random_range(0.3..1.4f32);
            let candidate = Walker { pos, vel: [0.0; 2], speed, edge, to, waiting: false, tint };
            let far = (pos[0] - agent[0]).hypot(pos[1] - agent[1]) >= clear;
            w = Some(candidate);
            if far {
                break;
            }
        }
        w.expect("at least one draw")
    }

    /// Heading of the body, radians (the velocity's, or towards the target when standing).
    pub fn yaw(&self, traffic: &Traffic) -> f32 {
        if self.vel[0].hypot(self.vel[1]) > 0.05 {
            self.vel[1].atan2(self.vel[0])
        } else {
            let q = traffic.walkers.nodes[self.to];
            (q[1] - self.pos[1]).atan2(q[0] - self.pos[0])
        }
    }
}

/// Advance every walker by `h` seconds at time `t` (signals read at `t`).
#[allow(clippy::too_many_arguments)]
pub fn advance(
    walkers: &mut [Walker],
    traffic: &Traffic,
    ground: &dyn Ground,
    agent: [f32; 2],
    agent_radius: f32,
    t: f64,
    h: f32,
    rng: &mut impl Rng,
) {
    let net = &traffic.walkers;
    let r = net.radius;
    for i in 0..walkers.len() {
        let mut w = walkers[i];
        // Arrival at the target node: pick the next edge (not straight back, unless a dead end).
        let target = net.nodes[w.to];
        if (target[0] - w.pos[0]).hypot(target[1] - w.pos[1]) < ARRIVED && !w.waiting {
            let here = w.to;
            let options: Vec<usize> = net.adjacency[here].iter().copied().filter(|&e| e != w.edge).collect();
            let edge = if options.is_empty() { w.edge } else { options[rng.random_range(0..options.len())] };
            let (a, b, crossing) = net.edges[edge];
            w.edge = edge;
            w.to = if a == here { b } else { a };
            w.waiting = crossing.is_some();
        }
        if w.waiting {
            let z = net.edges[w.edge].2.expect("only crossings wait");
            if traffic.plan.pedestrian(z, t) == PedestrianSignal::Walk {
                w.waiting = false;
            }
        }
        let target = net.nodes[w.to];
        let (tx, ty) = (target[0] - w.pos[0], target[1] - w.pos[1]);
        let dist = tx.hypot(ty).max(1e-6);
        let desired = if w.waiting { [0.0, 0.0] } else { [tx / dist * w.speed, ty / dist * w.speed] };
        let mut f = [(desired[0] - w.vel[0]) / TAU, (desired[1] - w.vel[1]) / TAU];
        let heading = [tx / dist, ty / dist];
        let mut push = |p: [f32; 2], rij: f32| {
            let (dx, dy) = (w.pos[0] - p[0], w.pos[1] - p[1]);
            let d = dx.hypot(dy).max(1e-3);
            if d < 3.0 {
                let m = FORCE_A * ((rij - d) / FORCE_B).exp();
                f[0] += m * dx / d;
                f[1] += m * dy / d;
                if -(dx * heading[0] + dy * heading[1]) > 0.0 {
                    // Ahead: step aside, away from its side (right when dead ahead).
                    let left_of_me = heading[0] * -dy - heading[1] * -dx > 0.0;
                    let side = if left_of_me { 1.0 } else { -1.0 };
                    f[0] += 0.5 * m * side * heading[1];
                    f[1] -= 0.5 * m * side * heading[0];
                }
            }
        };
        for (j, o) in walkers.iter().enumerate() {
            if j != i {
                push(o.pos, 2.0 * r);
            }
        }
        push(agent, r + agent_radius);
        w.vel = [w.vel[0] + h * f[0], w.vel[1] + h * f[1]];
        let sp = w.vel[0].hypot(w.vel[1]);
        let cap = 1.3 * w.speed;
        if sp > cap {
            w.vel = [w.vel[0] * cap / sp, w.vel[1] * cap / sp];
        }
        let reach = r + agent_radius;
        let mv = ground.move_body(w.pos[0], w.pos[1], w.vel[0] * h, w.vel[1] * h, h);
        if (mv[0] - agent[0]).hypot(mv[1] - agent[1]) >= reach {
            w.pos = mv;
        } else {
            // Slide around the agent: keep only the part of the velocity that does not close in.
            let (nx, ny) = (w.pos[0] - agent[0], w.pos[1] - agent[1]);
            let d = nx.hypot(ny).max(1e-6);
            let (nx, ny) = (nx / d, ny / d);
            let closing = (w.vel[0] * nx + w.vel[1] * ny).min(0.0);
            w.vel = [w.vel[0] - closing * nx, w.vel[1] - closing * ny];
            let mv = ground.move_body(w.pos[0], w.pos[1], w.vel[0] * h, w.vel[1] * h, h);
            if (mv[0] - agent[0]).hypot(mv[1] - agent[1]) >= reach {
                w.pos = mv;
            } else {
                w.vel = [0.0, 0.0];
            }
        }
        walkers[i] = w;
    }
}
