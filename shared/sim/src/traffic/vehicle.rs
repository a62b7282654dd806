//! Vehicles on one lane: arrivals, the Intelligent Driver Model, stop lines and
//! yielding at zebras.
//!
//! Invariant: a lane's vehicles are ordered front first (`s` decreasing) and never
//! overlap — each front bumper stays at least 0.1 m behind the rear of the vehicle
//! ahead, whatever the model asks (the hard constraint after every update); no
//! vehicle drives backwards.
//!
//! The model (Treiber, Hennecke & Helbing 2000):
//! ```text
//! a_IDM = a · [1 − (v/v₀)⁴ − (s*(v, Δv) / gap)²],   s* = s₀ + max(0, v·T + v·Δv / (2√(a·b)))
//! ```
//! with the vehicle ahead as the leader, or a standing obstacle at the stop line
//! (red; amber when the driver can stop at `b` before it), 1 m before a zebra
//! that a pedestrian is on (yielding drivers, when they can stop at `max_decel`),
//! or before a crossing lane's strip that a vehicle of that lane claims — it stands
//! across it, or is past its own stop line on its way there — when that vehicle
//! would reach the strip first (ties to the lower lane index: a strict order, so
//! two vehicles never wait for each other); and no vehicle passes its stop line
//! while the room after the crossing box (behind a slow leader, or before a zebra
//! it yields at) is shorter than itself plus s₀ ("don't block the box");
//! the smallest of these accelerations wins, clipped to `[−max_decel, a]`. Positions
//! advance ballistically (constant acceleration over the sub-step, stopping at
//! v = 0), the update Treiber & Kanagaraj (2015) recommend for steps of this size.

use std::collections::VecDeque;

use rand::Rng;

use super::spec::DriverSpec;
use super::{Lane, Traffic, VehicleSignal};

/// One vehicle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vehicle {
    /// Position of its front bumper along the lane, metres.
    pub s: f32,
    /// Speed, m/s.
    pub v: f32,
    /// Speed before the last sub-step, m/s (a hit needs a moving vehicle).
    pub v_prev: f32,
    /// Index of its kind in [`Traffic::kinds`].
    pub kind: u8,
    /// Length, metres.
    pub length: f32,
    /// Width, metres.
    pub width: f32,
    /// Height, metres.
    pub height: f32,
    /// Grey multiplier of its body (paint).
    pub tint: f32,
    /// Does its driver yield to pedestrians on zebras?
    pub yields: bool,
}

impl Vehicle {
    /// Centre of its footprint given its lane.
    pub fn center(&self, lane: &Lane) -> [f32; 2] {
        lane.point(self.s - 0.5 * self.length)
    }

    /// Does its footprint overlap a disc of radius `r` at `p`?
    pub fn overlaps_disc(&self, lane: &Lane, p: [f32; 2], r: f32) -> bool {
        let (s, off) = lane.local(p);
        let ds = ((self.s - self.length) - s).max(s - self.s).max(0.0);
        let dn = (off.abs() - 0.5 * self.width).max(0.0);
        ds * ds + dn * dn < r * r
    }
}

/// IDM acceleration towards a leader `gap` metres ahead that is `dv` m/s slower.
pub fn idm_accel(d: &DriverSpec, v: f32, gap: f32, dv: f32) -> f32 {
    let s_star =
        d.min_gap + (v * d.time_headway + v * dv / (2.0 * (d.max_accel * d.comfortable_decel).sqrt())).max(0.0);
    let free = 1.0 - (v / d.desired_speed).powi(4);
    d.max_accel * (free - (s_star / gap.max(0.01)).powi(2))
}

/// IDM acceleration on a free road.
pub fn free_accel(d: &DriverSpec, v: f32) -> f32 {
    d.max_accel * (1.0 - (v / d.desired_speed).powi(4))
}

/// A crossing lane's claim on a conflict point of this lane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Claim {
    /// `s` on this lane to stop before.
    pub stop: f32,
    /// Seconds until the claiming vehicle reaches the strip (0 when on it).
    pub time: f32,
    /// The claiming vehicle's lane.
    pub lane: usize,
}

/// Stop-line crossings recorded for measurement: (time, speed) of each front bumper.
pub type Crossings = Vec<(f64, f32)>;

/// The vehicles of one lane and its arrival process.
#[derive(Debug, Clone, PartialEq)]
pub struct LaneTraffic {
    /// Vehicles, front first.
    pub vehicles: VecDeque<Vehicle>,
    /// Arrivals that could not enter yet (the entry is blocked by a queue).
    pub backlog: u32,
    /// Time of the next arrival, seconds (infinite at zero flow).
    pub next_arrival: f64,
    /// Vehicles that entered the lane.
    pub entered: u64,
    /// Vehicles that left it at its end.
    pub exited: u64,
    /// When `Some`, every stop-line crossing is recorded (the `traffic` command).
    pub crossings: Option<Crossings>,
}

/// Draw the gap to the next Poisson arrival at `flow` vehicles per hour.
pub fn next_gap(rng: &mut impl Rng, flow: f32) -> f64 {
    if flow <= 0.0 {
        return f64::INFINITY;
    }
    let u: f64 = rng.random_range(f64::EPSILON..1.0);
    -u.ln() * 3600.0 / flow as f64
}

impl LaneTraffic {
    /// An empty lane whose first arrival is drawn from `t`.
    pub fn new(rng: &mut impl Rng, flow: f32, t: f64) -> LaneTraffic {
        LaneTraffic {
            vehicles: VecDeque::new(),
            backlog: 0,
            next_arrival: t + next_gap(rng, flow),
            entered: 0,
            exited: 0,
            crossings: None,
        }
    }

    /// Advance the lane by `h` seconds ending at time `t + h`: arrivals, entries,
    /// IDM, exits. `signal` is what the lane's heads show at `t`; `occupied[z]`
    /// says whether a pedestrian is on zebra `z`; `claims` are the crossing lanes'
    /// claims on this lane (`index` is this lane's index, for ties).
    #[allow(clippy::too_many_arguments)]
    pub fn advance(
        &mut self,
        lane: &Lane,
        traffic: &Traffic,
        flow: f32,
        non_yielding: f32,
        signal: VehicleSignal,
        occupied: &[bool],
        claims: &[Claim],
        index: usize,
        t: f64,
        h: f32,
        rng: &mut impl Rng,
    ) {
        let d = &traffic.driver;
        // Arrivals up to the end of the sub-step, then one entry if there is room.
        while self.next_arrival <= t + h as f64 {
            self.backlog += 1;
            self.next_arrival += next_gap(rng, flow);
        }
        if self.backlog > 0 {
            let (gap, v_lead) = match self.vehicles.back() {
                Some(last) => (last.s - last.length, last.v),
                None => (f32::INFINITY, d.desired_speed),
            };
            let v = d.desired_speed.min(v_lead);
            if gap >= d.min_gap + v * d.time_headway {
                let u: f32 = rng.random();
                let k = traffic.kinds.iter().position(|k| u < k.cumulative_share).unwrap_or(traffic.kinds.len() - 1);
                let kind = &traffic.kinds[k];
                let tint = rng.random_range(0.35..1.6f32);
                let yields = rng.random::<f32>() >= non_yielding;
                self.vehicles.push_back(Vehicle {
                    s: 0.0,
                    v,
                    v_prev: v,
                    kind: k as u8,
                    length: kind.length,
                    width: kind.width,
                    height: kind.height,
                    tint,
                    yields,
                });
                self.backlog -= 1;
                self.entered += 1;
            }
        }

        let mut ahead: Option<(f32, f32)> = None; // (rear s, speed) of the vehicle in front
        for veh in self.vehicles.iter_mut() {
            let v = veh.v;
            let mut acc = match ahead {
                Some((rear, v_lead)) => idm_accel(d, v, rear - veh.s, v - v_lead),
                None => free_accel(d, v),
            };
            // The stop line.
            let to_line = lane.stop_s - veh.s;
            if to_line > -0.01 {
                let can_stop = to_line >= v * v / (2.0 * d.max_decel);
                let mut stop = match signal {
                    VehicleSignal::Green => false,
                    VehicleSignal::Amber => to_line >= v * v / (2.0 * d.comfortable_decel),
                    VehicleSignal::Red => can_stop,
                };
                if let (false, Some(exit)) = (stop, lane.box_exit) {
                    let mut room = match ahead {
                        Some((rear, v_lead)) if v_lead < 3.0 => rear,
                        _ => f32::INFINITY,
                    };
                    if veh.yields {
                        for &(z, enter, _) in &lane.zebras {
                            if enter >= exit - 2.0 && occupied[z] {
                                room = room.min(enter - 1.0);
                            }
                        }
                    }
                    stop = can_stop && room - exit < veh.length + d.min_gap;
                }
                if stop {
                    acc = acc.min(idm_accel(d, v, to_line.max(0.01), v));
                }
            }
            // Zebras ahead with a pedestrian on them.
            if veh.yields {
                for &(z, enter, _) in &lane.zebras {
                    let to_yield = enter - 1.0 - veh.s;
                    if occupied[z] && to_yield > -0.01 && to_yield >= v * v / (2.0 * d.max_decel) {
                        acc = acc.min(idm_accel(d, v, to_yield.max(0.01), v));
                    }
                }
            }
            // Crossing lanes' claims that come first.
            for c in claims {
                let to_stop = c.stop - veh.s;
                let mine = (to_stop.max(0.0) / v.max(0.5), index);
                if to_stop > -0.01 && (c.time, c.lane) < mine && to_stop >= v * v / (2.0 * d.max_decel) {
                    acc = acc.min(idm_accel(d, v, to_stop.max(0.01), v));
                }
            }
            let acc = acc.clamp(-d.max_decel, d.max_accel);
            let (mut s, mut nv) = if v + acc * h < 0.0 {
                (veh.s - v * v / (2.0 * acc), 0.0)
            } else {
                (veh.s + v * h + 0.5 * acc * h * h, v + acc * h)
            };
            if let Some((rear, v_lead)) = ahead {
                if s > rear - 0.1 {
                    s = (rear - 0.1).max(veh.s);
                    nv = nv.min(v_lead);
                }
            }
            if let Some(c) = self.crossings.as_mut() {
                if veh.s < lane.stop_s && s >= lane.stop_s {
                    c.push((t + h as f64, nv));
                }
            }
            veh.v_prev = v;
            veh.s = s;
            veh.v = nv;
            ahead = Some((veh.s - veh.length, veh.v));
        }
        while self.vehicles.front().is_some_and(|f| f.s - f.length > lane.length) {
            self.vehicles.pop_front();
            self.exited += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn driver() -> DriverSpec {
        DriverSpec {
            desired_speed: 13.9,
            time_headway: 1.5,
            min_gap: 2.0,
            max_accel: 1.0,
            comfortable_decel: 2.0,
            max_decel: 6.0,
            non_yielding_share: 0.0,
        }
    }

    #[test]
    fn idm_is_the_published_formula() {
        let d = driver();
        // Free road at rest: full acceleration; at v₀: none.
        assert_eq!(free_accel(&d, 0.0), 1.0);
        assert!(free_accel(&d, 13.9).abs() < 1e-6);
        // Hand-computed: v = 10, gap 30, leader 2 m/s slower:
        // s* = 2 + 10·1.5 + 10·2/(2·√2) = 17 + 7.0711 = 24.0711;
        // a = 1 − (10/13.9)⁴ − (24.0711/30)² = 1 − 0.26787 − 0.64377 = 0.08836.
        let a = idm_accel(&d, 10.0, 30.0, 2.0);
        assert!((a - 0.08836).abs() < 1e-4, "{a}");
        // Standing behind a standing leader: no pull at exactly s₀, a push back of
        // a·(1 − 4) at half of it.
        assert!(idm_accel(&d, 0.0, 2.0, 0.0).abs() < 1e-6);
        assert!((idm_accel(&d, 0.0, 1.0, 0.0) + 3.0).abs() < 1e-6);
    }

    #[test]
    fn a_footprint_overlaps_a_disc_only_where_the_vehicle_is() {
        let lane = Lane {
            road: 0,
            origin: [0.0, 0.0],
            dir: [1.0, 0.0],
            length: 100.0,
            stop_s: 50.0,
            zebras: vec![],
            conflicts: vec![],
            box_exit: None,
        };
        // Front bumper at s = 20, 4.5 m long, 1.8 m wide: covers x ∈ [15.5, 20], y ∈ [−0.9, 0.9].
        let v = Vehicle {
            s: 20.0,
            v: 5.0,
            v_prev: 5.0,
            kind: 0,
            length: 4.5,
            width: 1.8,
            height: 1.5,
            tint: 1.0,
            yields: true,
        };
        for (p, inside) in [
            ([18.0, 0.0], true),
            ([20.25, 0.0], true),   // 0.25 ahead of the bumper, radius 0.3
            ([20.35, 0.0], false),  // 0.35 ahead
            ([15.3, 0.0], true),    // 0.2 behind the rear
            ([10.0, 0.0], false),   // well behind
            ([-50.0, 0.0], false),  // far behind on the same lane
            ([18.0, 1.15], true),   // 0.25 off the side
            ([18.0, -1.25], false), // 0.35 off the side
            ([40.0, 0.0], false),   // far ahead
        ] {
            assert_eq!(v.overlaps_disc(&lane, p, 0.3), inside, "{p:?}");
        }
    }

    #[test]
    fn the_equilibrium_gap_holds_a_platoon_at_speed() {
        // At the equilibrium gap s_e(v) = (s₀ + vT) / √(1 − (v/v₀)⁴) the IDM asks for no acceleration.
        let d = driver();
        for v in [3.0f32, 7.0, 11.0] {
            let se = (d.min_gap + v * d.time_headway) / (1.0 - (v / d.desired_speed).powi(4)).sqrt();
            assert!(idm_accel(&d, v, se, 0.0).abs() < 1e-4, "v = {v}");
        }
    }
}
