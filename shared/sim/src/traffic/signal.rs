//! The fixed-time signal plan: which lamp every head shows at a time in the cycle.
//!
//! Invariant: a [`SignalPlan`] that exists passed the conflict monitor of
//! [`super::Traffic::resolve`] — no phase gives green to two roads whose lanes
//! cross, no zebra walks while a lane crossing it has green or amber, every walk is
//! at least 7 s, every clearance at least the crossing's length over 1.07 m/s, and
//! walk plus clearance end within their phase's green. The state at a time is a
//! pure function of that time (no memory), so the same time always shows the same
//! lamps.

/// What a vehicle head shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VehicleSignal {
    /// Go.
    Green,
    /// Stop if you can stop comfortably before the line.
    Amber,
    /// Stop.
    Red,
}

/// What a pedestrian head shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PedestrianSignal {
    /// Steady walking figure: start crossing.
    Walk,
    /// Flashing standing figure (hand): do not start; finish if already crossing.
    Clearance,
    /// Steady standing figure: do not cross.
    DontWalk,
}

impl PedestrianSignal {
    /// Is the standing figure lit at `t` seconds? Steady on DON'T WALK, flashing at
    /// 1 Hz (lit the first half of each second) during the clearance.
    pub fn stand_lit(self, t: f64) -> bool {
        match self {
            PedestrianSignal::Walk => false,
            PedestrianSignal::DontWalk => true,
            PedestrianSignal::Clearance => t.rem_euclid(1.0) < 0.5,
        }
    }
}

/// One resolved phase.
#[derive(Debug, Clone, PartialEq)]
pub struct Phase {
    /// Indices of the roads with green.
    pub green: Vec<usize>,
    /// Indices of the zebras that walk.
    pub walk: Vec<usize>,
    /// Green, seconds.
    pub green_s: f64,
    /// Walk, seconds.
    pub walk_s: f64,
    /// Clearance, seconds.
    pub clearance_s: f64,
}

/// The resolved plan.
#[derive(Debug, Clone, PartialEq)]
pub struct SignalPlan {
    /// Phases in order.
    pub phases: Vec<Phase>,
    /// Amber, seconds.
    pub amber_s: f64,
    /// All-red, seconds.
    pub all_red_s: f64,
    /// Cycle length, seconds.
    pub cycle_s: f64,
}

impl SignalPlan {
    /// Build from phases and the intervals between them.
    pub fn new(phases: Vec<Phase>, amber_s: f64, all_red_s: f64) -> SignalPlan {
        let cycle_s = phases.iter().map(|p| p.green_s + amber_s + all_red_s).sum();
        SignalPlan { phases, amber_s, all_red_s, cycle_s }
    }

    /// The phase running at cycle time `t` and the seconds since it started.
    fn phase_at(&self, t: f64) -> (usize, f64) {
        let mut tau = t.rem_euclid(self.cycle_s);
        for (k, p) in self.phases.iter().enumerate() {
            let len = p.green_s + self.amber_s + self.all_red_s;
            if tau < len {
                return (k, tau);
            }
            tau -= len;
        }
        // Rounding at the very end of the cycle.
        (self.phases.len() - 1, self.phases.last().map_or(0.0, |p| p.green_s + self.amber_s + self.all_red_s))
    }

    /// What road `road`'s heads show at time `t`.
    pub fn vehicle(&self, road: usize, t: f64) -> VehicleSignal {
        let (k, tau) = self.phase_at(t);
        let p = &self.phases[k];
        if !p.green.contains(&road) {
            VehicleSignal::Red
        } else if tau < p.green_s {
            VehicleSignal::Green
        } else if tau < p.green_s + self.amber_s {
            VehicleSignal::Amber
        } else {
            VehicleSignal::Red
        }
    }

    /// What zebra `zebra`'s heads show at time `t`.
    pub fn pedestrian(&self, zebra: usize, t: f64) -> PedestrianSignal {
        let (k, tau) = self.phase_at(t);
        let p = &self.phases[k];
        if !p.walk.contains(&zebra) {
            PedestrianSignal::DontWalk
        } else if tau < p.walk_s {
            PedestrianSignal::Walk
        } else if tau < p.walk_s + p.clearance_s {
            PedestrianSignal::Clearance
        } else {
            PedestrianSignal::DontWalk
        }
    }

    /// Seconds from `t` until zebra `zebra` shows the steady DON'T WALK (0 when it
    /// does now): what is left of its WALK and flashing clearance.
    pub fn until_dont_walk(&self, zebra: usize, t: f64) -> f64 {
        let (k, tau) = self.phase_at(t);
        let p = &self.phases[k];
        let end = p.walk_s + p.clearance_s;
        if p.walk.contains(&zebra) && tau < end { end - tau } else { 0.0 }
    }

    /// Seconds from `t` until zebra `zebra` next shows WALK (0 when it does now).
    pub fn until_walk(&self, zebra: usize, t: f64) -> f64 {
        if self.pedestrian(zebra, t) == PedestrianSignal::Walk {
            return 0.0;
        }
        let mut start = 0.0;
        let mut best = f64::INFINITY;
        let tau = t.rem_euclid(self.cycle_s);
        for p in &self.phases {
            if p.walk.contains(&zebra) {
                let wait = (start - tau).rem_euclid(self.cycle_s);
                best = best.min(wait);
            }
            start += p.green_s + self.amber_s + self.all_red_s;
        }
        best
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan() -> SignalPlan {
        SignalPlan::new(
            vec![
                Phase { green: vec![0], walk: vec![0, 1], green_s: 32.0, walk_s: 12.0, clearance_s: 10.0 },
                Phase { green: vec![1], walk: vec![2, 3], green_s: 32.0, walk_s: 12.0, clearance_s: 10.0 },
            ],
            4.0,
            2.0,
        )
    }

    #[test]
    fn a_cycle_runs_green_amber_all_red_for_each_phase_in_turn() {
        let p = plan();
        assert_eq!(p.cycle_s, 76.0);
        let road0: Vec<_> = [0.0, 31.9, 32.0, 35.9, 36.0, 37.9, 38.0, 75.9, 76.0].map(|t| p.vehicle(0, t)).into();
        use VehicleSignal::*;
        assert_eq!(road0, [Green, Green, Amber, Amber, Red, Red, Red, Red, Green]);
        let road1: Vec<_> = [0.0, 37.9, 38.0, 69.9, 70.0, 74.0, 75.9].map(|t| p.vehicle(1, t)).into();
        assert_eq!(road1, [Red, Red, Green, Green, Amber, Red, Red]);
    }

    #[test]
    fn walk_then_flashing_clearance_then_dont_walk() {
        let p = plan();
        use PedestrianSignal::*;
        let z0: Vec<_> = [0.0, 11.9, 12.0, 21.9, 22.0, 40.0].map(|t| p.pedestrian(0, t)).into();
        assert_eq!(z0, [Walk, Walk, Clearance, Clearance, DontWalk, DontWalk]);
        assert_eq!(p.pedestrian(2, 38.0), Walk);
        assert!(Clearance.stand_lit(12.2) && !Clearance.stand_lit(12.7));
        assert!(DontWalk.stand_lit(0.7) && !Walk.stand_lit(0.2));
        assert_eq!(p.until_walk(0, 5.0), 0.0);
        assert_eq!(p.until_walk(0, 12.0), 64.0);
        assert_eq!(p.until_walk(2, 12.0), 26.0);
        assert_eq!([0.0, 12.0, 21.5, 22.0, 40.0].map(|t| p.until_dont_walk(0, t)), [22.0, 10.0, 0.5, 0.0, 0.0]);
        assert_eq!(p.until_dont_walk(2, 40.0), 20.0);
        // Negative times (the warm-up before an episode) wrap into the cycle.
        assert_eq!(p.vehicle(0, -76.0), VehicleSignal::Green);
    }
}
