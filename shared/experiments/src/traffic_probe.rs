//! At the kerb with traffic on: can the pedestrian read from its pixels what it must
//! wait for? Examples for two probes ([`crate::probe`]), each a pose at a zebra's
//! kerb and a stretch of traffic seen from it while the pedestrian stands still:
//! - **walk** — does the pedestrian signal of that zebra show WALK (the steady
//!   walking figure) at the last frame? (The flashing clearance and the steady
//!   hand are both "do not start".)
//! - **vehicle soon** — does a vehicle's footprint overlap that zebra at any
//!   decision step within the next `horizon_s` seconds after the last frame (the
//!   pedestrian still standing)?
//!
//! Poses: a zebra and one of its two ends drawn uniformly, the pedestrian 0.4–1.4 m
//! back from the kerb on the sidewalk, anywhere across the zebra's width but
//! 0.3 m from its sides, facing across within ±25° (the view of someone about to
//! cross). The signal phase comes from the episode seed (its offset is uniform over
//! the cycle), the vehicles and walkers from the same seed after the traffic's
//! warm-up — exactly as a training episode starts.
//!
//! Invariant: every example's frames, labels and pose come from the seed alone;
//! two seeds give disjoint draws (the probe's train and test sets use two).

use std::sync::Arc;

use pednav_sim::policy::STAND_STILL;
use pednav_sim::traffic::{PedestrianSignal, Traffic, TrafficState};
use pednav_sim::{BackendChoice, Pose, SimWorld, VecEnv};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::error::{ExperimentError, Result};

/// How kerb examples are drawn.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KerbSetConfig {
    /// Number of examples.
    pub examples: usize,
    /// Frames per example, at successive decision steps (the policy's `N_h`).
    pub history: usize,
    /// The "vehicle soon" label looks this many seconds past the last frame.
    pub horizon_s: f32,
    /// Seed of the poses and the episodes.
    pub seed: u64,
    /// Environments rendered together.
    pub batch_envs: usize,
    /// Render at this many times the frame side and average each `k × k` block of
    /// pixels into one, as a camera's pixel integrates the light over its area (the
    /// renderer samples each pixel at its centre: a lamp smaller than a pixel is hit
    /// or missed whole). 1: the frames exactly as training episodes see them. The
    /// world's `image_size` is the rendered side; frames are `image_size / k`.
    pub supersample: u32,
}

/// The mean of each `k × k` block of a `side²` greyscale frame (rounded to the
/// nearest level): a `(side / k)²` frame. `side` must be a multiple of `k`.
pub fn box_downsample(frame: &[u8], side: usize, k: usize) -> Vec<u8> {
    debug_assert!(k > 0 && side % k == 0 && frame.len() == side * side);
    if k == 1 {
        return frame.to_vec();
    }
    let n = side / k;
    let (area, half) = ((k * k) as u32, (k * k / 2) as u32);
    let mut out = Vec::with_capacity(n * n);
    for by in 0..n {
        for bx in 0..n {
            let sum: u32 = (0..k)
                .map(|dy| {
                    let start = (by * k + dy) * side + bx * k;
                    frame[start..start + k].iter().map(|&p| p as u32).sum::<u32>()
                })
                .sum();
            out.push(((sum + half) / area) as u8);
        }
    }
    out
}

/// Labelled kerb examples; see the module docs.
#[derive(Debug, Clone, Default)]
pub struct KerbExamples {
    /// Frame side, pixels.
    pub size: usize,
    /// Frames per example.
    pub history: usize,
    /// `history × size²` greyscale bytes per example, oldest frame first.
    pub frames: Vec<Vec<u8>>,
    /// 1 where the pedestrian signal shows WALK at the last frame.
    pub walk: Vec<usize>,
    /// 1 where a vehicle is on the zebra within the horizon after the last frame.
    pub vehicle_soon: Vec<usize>,
    /// The zebra each example stands at.
    pub zebra: Vec<usize>,
    /// The pose of each example.
    pub poses: Vec<Pose>,
    /// Time in the signal cycle at the last frame, seconds.
    pub cycle_time: Vec<f64>,
}

impl KerbExamples {
    /// The last frame of every example (`size²` bytes each).
    pub fn last_frames(&self) -> Vec<Vec<u8>> {
        let n = self.size * self.size;
        self.frames.iter().map(|f| f[f.len() - n..].to_vec()).collect()
    }

    /// Share of examples with label 1.
    pub fn positive_share(labels: &[usize]) -> f64 {
        labels.iter().filter(|&&l| l == 1).count() as f64 / labels.len().max(1) as f64
    }
}

/// A pose at the kerb of a random zebra (see the module docs) and that zebra.
pub fn kerb_pose(traffic: &Traffic, rng: &mut impl Rng) -> (Pose, usize) {
    let z = rng.random_range(0..traffic.zebras.len());
    let zebra = &traffic.zebras[z];
    let ends = zebra.ends();
    let j = rng.random_range(0..2usize);
    let (p, q) = (ends[j], ends[1 - j]);
    let len = (p[0] - q[0]).hypot(p[1] - q[1]).max(1e-3);
    let out = [(p[0] - q[0]) / len, (p[1] - q[1]) / len];
    let side = [-out[1], out[0]];
    let width = zebra.bounds.width() * side[0].abs() + zebra.bounds.height() * side[1].abs();
    let lateral = (0.5 * width - 0.3).max(0.0);
    let back = rng.random_range(0.4f32..1.4);
    let across = if lateral > 0.0 { rng.random_range(-lateral..lateral) } else { 0.0 };
    let yaw = (-out[1]).atan2(-out[0]) + rng.random_range(-25f32..25.0).to_radians();
    let pose = Pose {
        x: p[0] + back * out[0] + across * side[0],
        y: p[1] + back * out[1] + across * side[1],
        yaw: pednav_sim::scene::wrap_angle(yaw),
    };
    (pose, z)
}

/// Does a vehicle's footprint overlap zebra `zebra` now?
pub fn vehicle_on_zebra(traffic: &Traffic, state: &TrafficState, zebra: usize) -> bool {
    traffic.lanes.iter().zip(&state.lanes).any(|(lane, lt)| {
        lane.zebras
            .iter()
            .filter(|(z, _, _)| *z == zebra)
            .any(|&(_, s_in, s_out)| lt.vehicles.iter().any(|v| v.s > s_in && v.s - v.length < s_out))
    })
}

/// Draw `cfg.examples` kerb examples in `world` (which must have traffic on),
/// rendering with `backend`; `progress` gets the number of examples done.
pub fn collect(
    world: &Arc<SimWorld>,
    cfg: KerbSetConfig,
    backend: BackendChoice,
    mut progress: impl FnMut(usize),
) -> Result<KerbExamples> {
    let (traffic, _) = world.traffic.as_ref().ok_or_else(|| {
        ExperimentError::Probe("traffic is off: the kerb probes need sim.traffic = light, medium or heavy".into())
    })?;
    if cfg.examples == 0 || cfg.history == 0 || !(cfg.horizon_s > 0.0) {
        return Err(ExperimentError::Probe(format!(
            "examples ({}), history ({}) and horizon_s ({}) must be positive",
            cfg.examples, cfg.history, cfg.horizon_s
        )));
    }
    let (rendered_side, k) = (world.config.image_size as usize, cfg.supersample.max(1) as usize);
    if rendered_side % k != 0 {
        return Err(ExperimentError::Probe(format!(
            "supersample {k} does not divide the rendered side {rendered_side}"
        )));
    }
    let size = rendered_side / k;
    let batch = cfg.batch_envs.clamp(1, cfg.examples);
    let horizon = (cfg.horizon_s / world.config.dt).ceil() as usize;
    let mut env = VecEnv::new(world.clone(), batch, backend)?;
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut out = KerbExamples { size, history: cfg.history, ..KerbExamples::default() };
    while out.frames.len() < cfg.examples {
        let mut zebras = Vec::with_capacity(batch);
        let mut poses = Vec::with_capacity(batch);
        for e in 0..batch {
            let mut tries = 0;
            loop {
                let (pose, z) = kerb_pose(traffic, &mut rng);
                let episode_seed: u64 = rng.random();
                if env.reset(e, pose, episode_seed).is_ok() {
                    zebras.push(z);
                    poses.push(pose);
                    break;
                }
                tries += 1;
                if tries == 1000 {
                    return Err(ExperimentError::Probe("1,000 kerb poses in a row collided with the scene".into()));
                }
            }
        }
        let mut frames = vec![Vec::with_capacity(cfg.history * size * size); batch];
        let mut walk = vec![0usize; batch];
        let mut cycle_time = vec![0.0f64; batch];
        let mut soon = vec![0usize; batch];
        let mut ended = vec![false; batch];
        for step in 1..=cfg.history + horizon {
            for (e, t) in env.step(&vec![STAND_STILL; batch])?.iter().enumerate() {
                ended[e] |= t.terminated || t.truncated;
            }
            if step <= cfg.history {
                let rendered = env.render()?;
                for (e, f) in frames.iter_mut().enumerate() {
                    let frame = rendered.frame(e);
                    if k == 1 {
                        f.extend_from_slice(&frame);
                    } else {
                        f.extend_from_slice(&box_downsample(&frame, rendered_side, k));
                    }
                }
            }
            for e in 0..batch {
                let state = env.traffic(e).expect("traffic is on");
                if step == cfg.history {
                    walk[e] = usize::from(traffic.plan.pedestrian(zebras[e], state.t) == PedestrianSignal::Walk);
                    cycle_time[e] = state.t.rem_euclid(traffic.plan.cycle_s);
                } else if step > cfg.history && vehicle_on_zebra(traffic, state, zebras[e]) {
                    soon[e] = 1;
                }
            }
        }
        for e in (0..batch).filter(|&e| !ended[e]) {
            if out.frames.len() == cfg.examples {
                break;
            }
            out.frames.push(std::mem::take(&mut frames[e]));
            out.walk.push(walk[e]);
            out.vehicle_soon.push(soon[e]);
            out.zebra.push(zebras[e]);
            out.poses.push(poses[e]);
            out.cycle_time.push(cycle_time[e]);
        }
        progress(out.frames.len());
    }
    Ok(out)
}
