//! Traffic validated as traffic engineers would: measured flow per lane against the
//! level's set flow, queue lengths at the stop line, and the saturation flow of a
//! queue discharging at green (the `pednav-sim traffic` command).
//!
//! Invariant: measurement only observes — it runs the same [`TrafficState`] the
//! environments run (with the agent parked far outside the world, so nothing
//! yields to it) and reads its lanes; it changes no rule of the model.

use super::vehicle::Crossings;
use super::{Ground, Traffic, TrafficSettings, TrafficStart, TrafficState, VehicleSignal};

/// What one measurement found.
#[derive(Debug, Clone, PartialEq)]
pub struct FlowReport {
    /// Set arrivals per lane, vehicles/h.
    pub set_flow: f32,
    /// Measured stop-line crossings per lane, vehicles/h, in lane order.
    pub lane_flow: Vec<f64>,
    /// Mean over lanes of the measured flow, vehicles/h.
    pub mean_flow: f64,
    /// Mean number of vehicles queued (slower than 2 m/s, behind their stop line) per lane, sampled each second.
    pub mean_queue: f64,
    /// Largest queue seen on any lane, vehicles.
    pub max_queue: usize,
    /// Arrivals still waiting to enter at the end (a demand above capacity grows this).
    pub backlog: u32,
    /// Saturation headway: mean gap between stop-line crossings from the 5th queued
    /// vehicle of a green on, while the queue discharges without a break (s).
    pub saturation_headway: f64,
    /// 3600 / saturation headway, vehicles/h of green.
    pub saturation_flow: f64,
    /// Headways behind `saturation_headway`.
    pub headways: usize,
    /// Mean time from the start of green to the first queued vehicle's crossing (s).
    pub first_crossing_s: f64,
    /// Simulated seconds measured (after the warm-up).
    pub seconds: f64,
}

/// Where measurements run: the static world the walkers move through, a point far
/// outside the world to park the agent at, the agent's radius and the decision step.
#[derive(Clone, Copy)]
pub struct Bench<'a> {
    /// The static world's colliders.
    pub ground: &'a dyn Ground,
    /// A point far outside the world.
    pub far: [f32; 2],
    /// The agent's radius, metres.
    pub agent_radius: f32,
    /// The decision step, seconds.
    pub dt: f32,
}

/// Run `traffic` for `seconds` after its warm-up at `settings`, seeded with `seed`,
/// and measure it.
pub fn measure(bench: Bench<'_>, traffic: &Traffic, settings: TrafficSettings, seconds: f64, seed: u64) -> FlowReport {
    let Bench { ground, far, agent_radius: r, dt } = bench;
    let mut state =
        TrafficState::new(traffic, settings, TrafficStart { seed, cycle: None, agent: far, agent_radius: r }, dt);
    for lt in state.lanes.iter_mut() {
        lt.crossings = Some(Crossings::new());
    }
    let start = state.t;
    let steps = (seconds / dt as f64).round() as u64;
    let mut queue_sum = 0usize;
    let mut samples = 0usize;
    let mut max_queue = 0;
    // Green onsets per road, for the discharge measurement.
    let mut onsets: Vec<Vec<f64>> = vec![Vec::new(); traffic.roads.len()];
    let mut was_green: Vec<bool> =
        (0..traffic.roads.len()).map(|r| traffic.plan.vehicle(r, state.t) == VehicleSignal::Green).collect();
    let per_second = (1.0 / dt).round().max(1.0) as u64;
    for k in 0..steps {
        state.advance(traffic, ground, dt, far, r);
        for (road, was) in was_green.iter_mut().enumerate() {
            let green = traffic.plan.vehicle(road, state.t) == VehicleSignal::Green;
            if green && !*was {
                onsets[road].push(state.t);
            }
            *was = green;
        }
        if k % per_second == 0 {
            for (lane, lt) in traffic.lanes.iter().zip(&state.lanes) {
                let q = lt
                    .vehicles
                    .iter()
                    .filter(|v| v.s <= lane.stop_s + 0.5 && v.v < 2.0 && lane.stop_s - v.s < 400.0)
                    .count();
                queue_sum += q;
                max_queue = max_queue.max(q);
            }
            samples += traffic.lanes.len();
        }
    }
    let secs = state.t - start;
    let lane_flow: Vec<f64> = state
        .lanes
        .iter()
        .map(|lt| {
            lt.crossings.as_ref().map_or(0, |c| c.iter().filter(|(t, _)| *t > start).count()) as f64 * 3600.0 / secs
        })
        .collect();
    // Discharge: per lane and green, the crossings after its onset while headways stay under 4 s.
    let (mut hw_sum, mut hw_n, mut first_sum, mut first_n) = (0.0, 0usize, 0.0, 0usize);
    for (lane, lt) in traffic.lanes.iter().zip(&state.lanes) {
        let c = lt.crossings.as_ref().expect("recording");
        for &onset in &onsets[lane.road] {
            let run: Vec<f64> = c.iter().map(|(t, _)| *t).filter(|t| *t >= onset).take(64).collect();
            let Some(&first) = run.first() else { continue };
            if first - onset > 6.0 {
                continue; // no queue at this green
            }
            first_sum += first - onset;
            first_n += 1;
            for (i, w) in run.windows(2).enumerate() {
                let gap = w[1] - w[0];
                if gap > 4.0 {
                    break;
                }
                if i + 1 >= 4 {
                    hw_sum += gap;
                    hw_n += 1;
                }
            }
        }
    }
    let saturation_headway = if hw_n > 0 { hw_sum / hw_n as f64 } else { f64::NAN };
    FlowReport {
        set_flow: settings.flow,
        mean_flow: lane_flow.iter().sum::<f64>() / lane_flow.len().max(1) as f64,
        lane_flow,
        mean_queue: queue_sum as f64 / samples.max(1) as f64,
        max_queue,
        backlog: state.lanes.iter().map(|l| l.backlog).sum(),
        saturation_headway,
        saturation_flow: 3600.0 / saturation_headway,
        headways: hw_n,
        first_crossing_s: if first_n > 0 { first_sum / first_n as f64 } else { f64::NAN },
        seconds: secs,
    }
}
