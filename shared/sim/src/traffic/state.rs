//! One environment's traffic: its clock, vehicles and walkers, and what they do to
//! the agent.
//!
//! Invariant: a [`TrafficState`] is a pure function of (traffic description,
//! settings, episode seed, start pose) and the agent's positions since — its only
//! randomness is its own ChaCha stream seeded from the episode seed — so the same
//! episode replays bit for bit. The agent never ends a step inside a walker or a
//! vehicle that it walked into ([`TrafficState::block_agent`]); a vehicle that
//! drives into the agent is a hit ([`TrafficState::advance`]).

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::vehicle::{Claim, LaneTraffic};
use super::walker::{self, Walker};
use super::{CONFLICT_HALF_WIDTH, Ground, PedestrianSignal, Traffic, TrafficSettings};
use crate::region_kind::RegionKind;

/// Mixed into the episode seed so the traffic's stream differs from every other
/// stream drawn from the same seed (the look's, the policy's).
const TRAFFIC_STREAM: u64 = 0x7a3f_19c2_5b8e_d041;

/// What the agent ran into while moving (it stops short of it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum AgentContact {
    /// Nothing.
    None,
    /// Another pedestrian.
    Walker,
    /// A vehicle (the agent walked into it; a vehicle driving into the agent is a hit).
    Vehicle,
}

/// Safety events of one decision step (all false with traffic off).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct SafetyEvents {
    /// A moving vehicle hit the agent; the episode ends.
    pub vehicle_hit: bool,
    /// The agent stepped onto a zebra that did not show WALK.
    pub dont_walk_entry: bool,
    /// The agent ends the step on a zebra it entered outside WALK (paid as the road).
    pub against_signal: bool,
    /// The agent bumped into another pedestrian.
    pub pedestrian_bump: bool,
    /// The agent walked into a vehicle (standing or passing beside it).
    pub vehicle_bump: bool,
    /// The agent stood at a kerb (off the road, within 1.5 m of a zebra, moved
    /// under 0.1 m): waiting to cross.
    pub kerb_wait: bool,
}

/// Safety events counted over an episode (what `pednav-eval` writes per episode).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
pub struct SafetyCounts {
    /// Steps in which a vehicle hit the agent (0 or 1: a hit ends the episode).
    pub vehicle_hits: u32,
    /// Zebras entered outside WALK.
    pub dont_walk_entries: u32,
    /// Bumps into other pedestrians.
    pub pedestrian_bumps: u32,
    /// Steps in which the agent walked into a vehicle.
    pub vehicle_bumps: u32,
    /// Steps spent waiting at a kerb.
    pub kerb_wait_steps: u32,
}

impl SafetyCounts {
    /// Count one step's events.
    pub fn add(&mut self, e: &SafetyEvents) {
        self.vehicle_hits += e.vehicle_hit as u32;
        self.dont_walk_entries += e.dont_walk_entry as u32;
        self.pedestrian_bumps += e.pedestrian_bump as u32;
        self.vehicle_bumps += e.vehicle_bump as u32;
        self.kerb_wait_steps += e.kerb_wait as u32;
    }
}

/// The dynamic traffic of one environment.
#[derive(Debug, Clone)]
pub struct TrafficState {
    /// Signal clock, seconds (cycle time = `t` modulo the cycle).
    pub t: f64,
    /// Vehicles of each lane (in [`Traffic::lanes`] order).
    pub lanes: Vec<LaneTraffic>,
    /// Other pedestrians.
    pub walkers: Vec<Walker>,
    /// The level's numbers.
    pub settings: TrafficSettings,
    rng: ChaCha8Rng,
    /// The zebra the agent is on and whether it stepped on under WALK.
    zebra: Option<(usize, bool)>,
    occupied: Vec<bool>,
    /// Scratch of the lanes' claims, kept between sub-steps (no allocation per sub-step).
    claims: Vec<Vec<Claim>>,
}

/// Where and how an episode's traffic starts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrafficStart {
    /// The episode's seed (arrivals, walkers, and the cycle position unless `cycle` sets it).
    pub seed: u64,
    /// The start's position in the signal cycle, a fraction in [0, 1), when the task
    /// sets it; `None` draws it from the seed.
    pub cycle: Option<f32>,
    /// The agent's start (vehicles and walkers keep clear of it).
    pub agent: [f32; 2],
    /// The agent's radius, metres.
    pub agent_radius: f32,
}

impl TrafficState {
    /// The traffic of a new episode: a phase offset drawn uniformly over the cycle
    /// (or `start.cycle` of it: the draw is made either way, so the seed's stream
    /// stays the same), `warmup_s` seconds of vehicles simulated
    /// before it (walkers are placed along the network), vehicles within 1 m of the
    /// agent's start removed, walkers at least 1.5 m from it. `dt` is the decision
    /// step (the warm-up runs the same sub-steps).
    pub fn new(traffic: &Traffic, settings: TrafficSettings, start: TrafficStart, dt: f32) -> TrafficState {
        let TrafficStart { seed, cycle, agent, agent_radius } = start;
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ TRAFFIC_STREAM);
        let drawn = rng.random_range(0.0..traffic.plan.cycle_s);
        let offset = cycle.map_or(drawn, |c| c as f64 * traffic.plan.cycle_s);
        let t0 = offset - traffic.warmup_s as f64;
        let lanes = traffic.lanes.iter().map(|_| LaneTraffic::new(&mut rng, settings.flow, t0)).collect();
        let mut state = TrafficState {
            t: t0,
            lanes,
            walkers: Vec::new(),
            settings,
            rng,
            zebra: None,
            occupied: vec![false; traffic.zebras.len()],
            claims: Vec::new(),
        };
        let h = dt / traffic.substeps as f32;
        while state.t < offset - 1e-9 {
            state.advance_vehicles(traffic, h, &[]);
        }
        state.t = offset;
        for (lane, lt) in traffic.lanes.iter().zip(state.lanes.iter_mut()) {
            lt.vehicles.retain(|v| !v.overlaps_disc(lane, agent, agent_radius + 1.0));
        }
        for _ in 0..settings.walkers {
            let w = Walker::spawn(traffic, &mut state.rng, agent, 1.5);
            state.walkers.push(w);
        }
        state.zebra = traffic
            .zebra_at(agent[0], agent[1])
            .map(|z| (z, traffic.plan.pedestrian(z, offset) == PedestrianSignal::Walk));
        state
    }

    /// Advance the vehicles of every lane by `h`, pedestrians at `peds` (agent first).
    fn advance_vehicles(&mut self, traffic: &Traffic, h: f32, peds: &[[f32; 2]]) {
        for (z, zebra) in traffic.zebras.iter().enumerate() {
            self.occupied[z] = peds.iter().any(|p| zebra.contains(p[0], p[1]));
        }
        // Claims on conflict points: a crossing lane's vehicle that stands across this
        // lane's strip, or is past its own stop line on its way there (committed to
        // the box), with its time to the strip (0 when on it).
        let mut blocked = std::mem::take(&mut self.claims);
        blocked.resize_with(traffic.lanes.len(), Vec::new);
        blocked.iter_mut().for_each(Vec::clear);
        for (i, lane) in traffic.lanes.iter().enumerate() {
            for &(j, s_here, s_there) in &lane.conflicts {
                let other = &traffic.lanes[j];
                let strip = s_there - CONFLICT_HALF_WIDTH;
                let claim = self.lanes[j]
                    .vehicles
                    .iter()
                    .filter(|v| {
                        v.s - v.length <= s_there + CONFLICT_HALF_WIDTH && (v.s >= strip || v.s >= other.stop_s)
                    })
                    .map(|v| ((strip - v.s).max(0.0) / v.v.max(0.5), j))
                    .min_by(|a, b| a.0.total_cmp(&b.0));
                if let Some((time, lane)) = claim {
                    blocked[i].push(Claim { stop: s_here - CONFLICT_HALF_WIDTH, time, lane });
                }
            }
        }
        for (i, ((lane, lt), blocked)) in traffic.lanes.iter().zip(self.lanes.iter_mut()).zip(&blocked).enumerate() {
            let signal = traffic.plan.vehicle(lane.road, self.t);
            lt.advance(
                lane,
                traffic,
                self.settings.flow,
                self.settings.non_yielding,
                signal,
                &self.occupied,
                blocked,
                i,
                self.t,
                h,
                &mut self.rng,
            );
        }
        self.claims = blocked;
        self.t += h as f64;
    }

    /// Advance the traffic by one decision step of `dt` seconds with the agent at
    /// `agent` (walkers once, vehicles in `substeps`); true when a moving vehicle
    /// drove into the agent.
    pub fn advance(
        &mut self,
        traffic: &Traffic,
        ground: &dyn Ground,
        dt: f32,
        agent: [f32; 2],
        agent_radius: f32,
    ) -> bool {
        let n = traffic.substeps;
        let h = dt / n as f32;
        let mut hit = false;
        // Walkers move once per decision step (their social force is stable at
        // 0.25 s: h/τ = 0.5), vehicles every sub-step; the pedestrians the
        // drivers yield to stand where they are for the whole step.
        walker::advance(&mut self.walkers, traffic, ground, agent, agent_radius, self.t, dt, &mut self.rng);
        let mut peds = Vec::with_capacity(self.walkers.len() + 1);
        peds.push(agent);
        peds.extend(self.walkers.iter().map(|w| w.pos));
        for _ in 0..n {
            self.advance_vehicles(traffic, h, &peds);
            hit |= self.vehicle_hits(traffic, agent, agent_radius);
        }
        hit
    }

    fn vehicle_hits(&self, traffic: &Traffic, agent: [f32; 2], r: f32) -> bool {
        traffic.lanes.iter().zip(&self.lanes).any(|(lane, lt)| {
            lt.vehicles.iter().any(|v| (v.v > 0.05 || v.v_prev > 0.05) && v.overlaps_disc(lane, agent, r))
        })
    }

    fn contact_at(&self, traffic: &Traffic, p: [f32; 2], r: f32) -> AgentContact {
        let wr = traffic.walkers.radius;
        if self.walkers.iter().any(|w| (w.pos[0] - p[0]).hypot(w.pos[1] - p[1]) < wr + r) {
            return AgentContact::Walker;
        }
        let vehicle = traffic
            .lanes
            .iter()
            .zip(&self.lanes)
            .any(|(lane, lt)| lt.vehicles.iter().any(|v| v.overlaps_disc(lane, p, r)));
        if vehicle { AgentContact::Vehicle } else { AgentContact::None }
    }

    /// Limit the agent's move from `from` to `to` by the walkers and vehicles where
    /// they stand now: the furthest point along the move (to 1/256 of it) that
    /// touches none, and what it ran into. A start that already touches one (a
    /// vehicle that stopped on the agent's heels) does not hold the agent.
    pub fn block_agent(&self, traffic: &Traffic, from: [f32; 2], to: [f32; 2], r: f32) -> ([f32; 2], AgentContact) {
        let at_end = self.contact_at(traffic, to, r);
        if at_end == AgentContact::None || self.contact_at(traffic, from, r) != AgentContact::None {
            return (to, AgentContact::None);
        }
        let lerp = |f: f32| [from[0] + f * (to[0] - from[0]), from[1] + f * (to[1] - from[1])];
        let (mut lo, mut hi) = (0.0f32, 1.0f32);
        for _ in 0..8 {
            let mid = 0.5 * (lo + hi);
            if self.contact_at(traffic, lerp(mid), r) == AgentContact::None {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        (lerp(lo), at_end)
    }

    /// Track the agent's zebra at `p` after a step that started at signal time `t0`:
    /// (is the agent on a zebra it entered under WALK or off any zebra, did this step
    /// enter a zebra outside WALK).
    pub fn track_zebra(&mut self, traffic: &Traffic, p: [f32; 2], t0: f64) -> (bool, bool) {
        match traffic.zebra_at(p[0], p[1]) {
            None => {
                self.zebra = None;
                (true, false)
            }
            Some(z) => match self.zebra {
                Some((zz, legal)) if zz == z => (legal, false),
                _ => {
                    let legal = traffic.plan.pedestrian(z, t0) == PedestrianSignal::Walk;
                    self.zebra = Some((z, legal));
                    (legal, !legal)
                }
            },
        }
    }

    /// Is the agent at `p` (region `region`) at a kerb: off the road and the zebras,
    /// within 1.5 m of a zebra?
    pub fn at_kerb(traffic: &Traffic, p: [f32; 2], region: RegionKind) -> bool {
        !matches!(region, RegionKind::Road | RegionKind::Zebra)
            && traffic.zebras.iter().any(|z| z.bounds.distance(p[0], p[1]) < 1.5)
    }

    /// Vehicles now on the lanes.
    pub fn num_vehicles(&self) -> usize {
        self.lanes.iter().map(|l| l.vehicles.len()).sum()
    }
}
