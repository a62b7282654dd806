//! Gymnasium-style environments: [`VecEnv`] (M pedestrians, all views rendered in
//! one GPU submission) and [`PedestrianEnv`] (one pedestrian, the [`Env`] trait).
//!
//! Invariant: an environment is stepped only between a `reset` and the end of its
//! episode ([`SimError::NeedsReset`] otherwise). There is no auto-reset: the caller
//! (the actor) asks the curriculum for the next task and calls `reset` itself.
//!
//! Usage loop of a vectorized actor:
//! ```no_run
//! # use std::sync::Arc;
//! # use pednav_sim::{Scene, SimConfig, SimWorld, VecEnv, BackendChoice};
//! # fn main() -> pednav_sim::Result<()> {
//! let world = Arc::new(SimWorld::new(Scene::reference(), SimConfig::default())?);
//! let mut envs = VecEnv::new(world.clone(), 16, BackendChoice::Auto)?;
//! for i in 0..16 { envs.reset(i, world.scene.first_task(), i as u64)?; }
//! let actions = vec![[1.0, 0.0, 0.0]; 16];
//! loop {
//!     let steps = envs.step(&actions)?.to_vec();
//!     let frames = envs.render()?;            // one submission, one readback
//!     let mut buf = vec![0u8; 84 * 84];
//!     frames.copy_frame(0, &mut buf);         // the only copy of the frame
//!     drop(frames);
//!     for (i, t) in steps.iter().enumerate() {
//!         if t.terminated || t.truncated { envs.reset(i, world.scene.first_task(), 1000 + i as u64)?; }
//!     }
//! #   break;
//! }
//! # Ok(()) }
//! ```

use std::sync::Arc;

use crate::config::ObsMode;
use crate::error::{Result, SimError};
use crate::pedestrian::{Action, Pedestrian, Transition};
use crate::render::dynamic::{FAR_DISTANCE, LAMP_DISTANCE};
use crate::render::mesh::part_visible_circle;
use crate::render::{
    BackendChoice, CameraView, DynamicBatch, Frames, Instance, Look, Prototype, Renderer, RendererConfig,
};
use crate::scene::{Pose, RegionKind};
use crate::state_obs::{STATE_OBS_MAX, state_obs_dim, state_observation};
use crate::traffic::{
    HeadKind, PEDESTRIAN_HEAD, PedestrianSignal, SafetyEvents, TrafficStart, TrafficState, VEHICLE_HEAD, VehicleSignal,
    VehicleStyle,
};
use crate::world::SimWorld;

/// M pedestrians sharing one world and one renderer.
pub struct VecEnv {
    world: Arc<SimWorld>,
    peds: Vec<Pedestrian>,
    looks: Vec<Look>,
    renderer: Option<Renderer>,
    transitions: Vec<Transition>,
    cameras: Vec<CameraView>,
    /// Each environment's traffic (all `None` with traffic off).
    traffic: Vec<Option<TrafficState>>,
    /// The reward for entering a zebra outside WALK in episodes reset from now on, when
    /// it differs from the world's ([`VecEnv::set_dont_walk_entry`]).
    dont_walk_entry: Option<f32>,
    batch: DynamicBatch,
}

impl VecEnv {
    /// Create `num_envs` environments; in pixel mode also the renderer (one atlas for all views).
    pub fn new(world: Arc<SimWorld>, num_envs: usize, backend: BackendChoice) -> Result<VecEnv> {
        if num_envs == 0 {
            return Err(SimError::Config {
                field: "num_envs",
                value: "0".into(),
                message: "must be at least 1".into(),
            });
        }
        let renderer = match world.config.obs_mode {
            ObsMode::Pixels => Some(Renderer::new(
                &world.scene,
                &world.map,
                RendererConfig::from_sim(&world.config, num_envs, backend),
            )?),
            ObsMode::State => None,
        };
        Ok(VecEnv {
            peds: vec![Pedestrian::default(); num_envs],
            looks: vec![Look::default(); num_envs],
            renderer,
            transitions: Vec::with_capacity(num_envs),
            cameras: Vec::with_capacity(num_envs),
            traffic: vec![None; num_envs],
            dont_walk_entry: None,
            batch: DynamicBatch::default(),
            world,
        })
    }

    /// Number of environments.
    pub fn num_envs(&self) -> usize {
        self.peds.len()
    }

    /// The shared world.
    pub fn world(&self) -> &Arc<SimWorld> {
        &self.world
    }

    /// The renderer (pixel mode only).
    pub fn renderer(&self) -> Option<&Renderer> {
        self.renderer.as_ref()
    }

    /// Start a new episode in environment `env` at `task`; `seed` drives the
    /// episode's randomness (the rendering look when domain randomisation is on, and
    /// the traffic: arrivals, walkers and the start's position in the signal cycle).
    pub fn reset(&mut self, env: usize, task: Pose, seed: u64) -> Result<()> {
        self.reset_in_cycle(env, task, seed, None)
    }

    /// As [`VecEnv::reset`], with the start's position in the signal cycle set by the
    /// task when `cycle` is given (a fraction of the cycle in [0, 1); the curriculum's
    /// `signal_phase = "task"`) instead of drawn from `seed`; the rest of the traffic
    /// (arrivals, walkers) still comes from `seed`. A `cycle` without traffic, or outside
    /// [0, 1), is an error.
    pub fn reset_in_cycle(&mut self, env: usize, task: Pose, seed: u64, cycle: Option<f32>) -> Result<()> {
        self.world.scene.check_task(task)?;
        if let Some(c) = cycle {
            if self.world.traffic.is_none() || !(0.0..1.0).contains(&c) {
                return Err(SimError::CyclePosition { cycle: c, traffic: self.world.traffic.is_some() });
            }
        }
        self.peds[env].reset(task);
        self.looks[env] = if self.world.config.domain_randomization { Look::randomized(seed) } else { Look::default() };
        if let Some((traffic, settings)) = &self.world.traffic {
            let cfg = &self.world.config;
            let start = TrafficStart { seed, cycle, agent: [task.x, task.y], agent_radius: cfg.agent_radius };
            let mut settings = *settings;
            settings.dont_walk_entry = self.dont_walk_entry.unwrap_or(settings.dont_walk_entry);
            self.traffic[env] = Some(TrafficState::new(traffic, settings, start, cfg.dt));
        }
        Ok(())
    }

    /// The world's reward for entering a zebra outside WALK (`None` with traffic off).
    pub fn world_dont_walk_entry(&self) -> Option<f32> {
        self.world.traffic.as_ref().map(|(_, s)| s.dont_walk_entry)
    }

    /// Pay `reward` instead of the world's for entering a zebra outside WALK in every
    /// episode reset from now on (episodes under way keep theirs: an episode has one
    /// reward). The training actors ramp it in (`curriculum.entry_reward_ramp`). An
    /// error with traffic off or outside the range the config allows ([-1000, 0]).
    pub fn set_dont_walk_entry(&mut self, reward: f32) -> Result<()> {
        let value = reward.to_string();
        if self.world.traffic.is_none() {
            let message = "there is no zebra signal without traffic (sim.traffic is off)".into();
            return Err(SimError::Config { field: "dont_walk_entry", value, message });
        }
        crate::config::check_dont_walk_entry(reward).map_err(|message| SimError::Config {
            field: "dont_walk_entry",
            value,
            message,
        })?;
        self.dont_walk_entry = Some(reward);
        Ok(())
    }

    /// Step every environment with its action. All must be inside an episode.
    pub fn step(&mut self, actions: &[Action]) -> Result<&[Transition]> {
        if actions.len() != self.peds.len() {
            return Err(SimError::ActionCount { expected: self.peds.len(), got: actions.len() });
        }
        for (env, (p, a)) in self.peds.iter().zip(actions).enumerate() {
            if p.done {
                return Err(SimError::NeedsReset { env });
            }
            if !a.iter().all(|v| v.is_finite()) {
                return Err(SimError::NonFiniteAction { env, action: *a });
            }
        }
        self.transitions.clear();
        match &self.world.traffic {
            None => {
                for (p, a) in self.peds.iter_mut().zip(actions) {
                    self.transitions.push(p.step(*a, &self.world));
                }
            }
            Some((traffic, _)) => {
                for ((p, a), state) in self.peds.iter_mut().zip(actions).zip(self.traffic.iter_mut()) {
                    let state = state.as_mut().expect("an environment with traffic is reset before it is stepped");
                    self.transitions.push(p.step_in_traffic(*a, &self.world, traffic, state));
                }
            }
        }
        Ok(&self.transitions)
    }

    /// The pedestrian of environment `env`.
    pub fn pedestrian(&self, env: usize) -> &Pedestrian {
        &self.peds[env]
    }

    /// Camera of environment `env` at its current pose.
    pub fn camera(&self, env: usize) -> CameraView {
        let p = &self.peds[env];
        CameraView {
            x: p.pose.x,
            y: p.pose.y,
            z: self.world.config.eye_height,
            yaw: p.camera_yaw(),
            look: self.looks[env],
        }
    }

    /// The traffic of environment `env` (`None` with traffic off or before its first reset).
    pub fn traffic(&self, env: usize) -> Option<&TrafficState> {
        self.traffic[env].as_ref()
    }

    /// The moving things environment `env`'s camera `c` can see, into the batch's open view.
    fn add_instances(&mut self, env: usize, c: &CameraView, fov: f32) {
        let (Some((traffic, _)), Some(state)) = (&self.world.traffic, &self.traffic[env]) else { return };
        let visible = |p: [f32; 2], r: f32| part_visible_circle(p, r, c.x, c.y, c.yaw, fov);
        // Vehicles wholly beyond the world's edge stand behind its boundary walls
        // (queues form out there): not drawn unless taller than the walls.
        let extent = &self.world.scene.extent;
        let wall = self.world.scene.spec.wall_height;
        let hidden = |p: [f32; 2], r: f32, height: f32| {
            height <= wall
                && (p[0] + r < extent.min[0]
                    || p[0] - r > extent.max[0]
                    || p[1] + r < extent.min[1]
                    || p[1] - r > extent.max[1])
        };
        for (lane, lt) in traffic.lanes.iter().zip(&state.lanes) {
            let yaw = lane.yaw();
            for v in &lt.vehicles {
                let p = v.center(lane);
                let r = 0.5 * v.length.hypot(v.width);
                if hidden(p, r, v.height) || !visible(p, r + 0.5) {
                    continue;
                }
                let far = (p[0] - c.x).hypot(p[1] - c.y) > FAR_DISTANCE;
                let proto = match traffic.kinds[v.kind as usize].style {
                    _ if far => Prototype::Far,
                    VehicleStyle::Car => Prototype::Car,
                    VehicleStyle::Boxy => Prototype::Boxy,
                };
                self.batch.push(
                    proto,
                    Instance { pose: [p[0], p[1], 0.0, yaw], size: [v.length, v.width, v.height, v.tint] },
                );
            }
        }
        let r = traffic.walkers.radius;
        for w in &state.walkers {
            if visible(w.pos, 1.0) {
                let size = [1.2 * r, 1.7 * r, 1.7, w.tint];
                let far = (w.pos[0] - c.x).hypot(w.pos[1] - c.y) > FAR_DISTANCE;
                let proto = if far { Prototype::Far } else { Prototype::Walker };
                self.batch.push(proto, Instance { pose: [w.pos[0], w.pos[1], 0.0, w.yaw(traffic)], size });
            }
        }
        const LIT: f32 = 0.97;
        const DARK: f32 = 0.13;
        for h in &traffic.heads {
            // A lamp shows only to the front of its head, and is under a pixel far off.
            let (dx, dy) = (c.x - h.center[0], c.y - h.center[1]);
            let behind = dx * h.facing[0] + dy * h.facing[1] <= 0.0;
            if behind || dx.hypot(dy) > LAMP_DISTANCE || !visible(h.center, 1.0) {
                continue;
            }
            let yaw = h.facing[1].atan2(h.facing[0]);
            let out = 0.5 * crate::traffic::HEAD_SIZE[1] + 0.01;
            let (x, y) = (h.center[0] + out * h.facing[0], h.center[1] + out * h.facing[1]);
            match h.kind {
                HeadKind::Pedestrian(z) => {
                    let s = traffic.plan.pedestrian(z, state.t);
                    let [stand_z, walk_z] = PEDESTRIAN_HEAD.2;
                    let stand = if s.stand_lit(state.t) { LIT } else { DARK };
                    let walk = if s == PedestrianSignal::Walk { LIT } else { DARK };
                    self.batch.push(
                        Prototype::FigureStand,
                        Instance { pose: [x, y, stand_z, yaw], size: [1.0, 0.3, 0.3, stand] },
                    );
                    self.batch.push(
                        Prototype::FigureWalk,
                        Instance { pose: [x, y, walk_z, yaw], size: [1.0, 0.3, 0.3, walk] },
                    );
                }
                HeadKind::Vehicle(road) => {
                    let s = traffic.plan.vehicle(road, state.t);
                    let lit = [s == VehicleSignal::Red, s == VehicleSignal::Amber, s == VehicleSignal::Green];
                    for (z, on) in VEHICLE_HEAD.2.iter().zip(lit) {
                        let tint = if on { LIT } else { DARK };
                        self.batch
                            .push(Prototype::Lamp, Instance { pose: [x, y, *z, yaw], size: [1.0, 0.22, 0.22, tint] });
                    }
                }
            }
        }
    }

    /// The pedestrian signals in the ground that environment `env`'s camera `c` can
    /// see (`sim.traffic_ground_signals`), into the batch's open view: each band follows
    /// its zebra's heads — bright on WALK, dim while the hand is lit, dark between
    /// its flashes.
    fn add_ground_signals(&mut self, env: usize, c: &CameraView, fov: f32) {
        const WALK: f32 = 0.97;
        const HAND: f32 = 0.35;
        const DARK: f32 = 0.1;
        /// Above the ground, metres: clear of its depth, under a pixel at any distance.
        const LIFT: f32 = 0.02;
        let (Some((traffic, _)), Some(state)) = (&self.world.traffic, &self.traffic[env]) else { return };
        let kind = self.world.config.traffic_ground_signals;
        for (z, zebra) in traffic.zebras.iter().enumerate() {
            let Some(bands) = zebra.ground_signal_bands(kind) else { return };
            let s = traffic.plan.pedestrian(z, state.t);
            let tint = match s {
                PedestrianSignal::Walk => WALK,
                _ if s.stand_lit(state.t) => HAND,
                _ => DARK,
            };
            for band in bands {
                let size = [band.max[0] - band.min[0], band.max[1] - band.min[1]];
                let centre = [0.5 * (band.min[0] + band.max[0]), 0.5 * (band.min[1] + band.max[1])];
                if part_visible_circle(centre, 0.5 * size[0].hypot(size[1]), c.x, c.y, c.yaw, fov) {
                    let pose = [centre[0], centre[1], LIFT, 0.0];
                    self.batch.push(Prototype::GroundLight, Instance { pose, size: [size[0], size[1], 1.0, tint] });
                }
            }
        }
    }

    /// Render the current view of every environment: one submission, one readback.
    /// Errors in state mode, which has no renderer.
    pub fn render(&mut self) -> Result<Frames<'_>> {
        self.cameras.clear();
        self.batch.clear();
        let fov = self.world.config.fov_deg.to_radians();
        let traffic = self.world.traffic.is_some();
        for env in 0..self.peds.len() {
            let c = self.camera(env);
            if traffic {
                self.add_instances(env, &c, fov);
                if self.world.config.traffic_ground_signals.is_on() {
                    self.add_ground_signals(env, &c, fov);
                }
                self.batch.finish_view();
            }
            self.cameras.push(c);
        }
        let renderer = self.renderer.as_mut().ok_or(SimError::Config {
            field: "obs_mode",
            value: "state".into(),
            message: "rendering needs obs_mode = \"pixels\"".into(),
        })?;
        let batch = traffic.then_some(&self.batch);
        Ok(renderer.render_with(&self.cameras, batch)?)
    }

    /// State observation of environment `env` (any mode): its first
    /// [`VecEnv::state_dim`] entries, then zeros.
    pub fn state_obs(&self, env: usize) -> [f32; STATE_OBS_MAX] {
        state_observation(&self.world, &self.peds[env], self.traffic[env].as_ref())
    }

    /// Length of the state observation ([`crate::state_obs::state_obs_dim`]: 22, or
    /// 50 with traffic).
    pub fn state_dim(&self) -> usize {
        state_obs_dim(&self.world.config)
    }
}

/// Extra information of a reset or step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Info {
    /// Pose after the step (or at reset).
    pub pose: Pose,
    /// Region under the agent.
    pub region: RegionKind,
    /// Whether the step collided.
    pub collided: bool,
    /// Steps taken in the episode.
    pub step: u32,
    /// What traffic did to the agent in this step (all false with traffic off or at reset).
    pub safety: SafetyEvents,
}

/// An observation of [`PedestrianEnv`].
#[derive(Debug, Clone, PartialEq)]
pub enum Observation {
    /// `image_size²` greyscale bytes, row-major, top row first.
    Pixels(Vec<u8>),
    /// The state-debug vector ([`VecEnv::state_dim`] entries).
    State(Vec<f32>),
}

/// Result of [`Env::step`].
#[derive(Debug, Clone, PartialEq)]
pub struct StepOutcome<O> {
    /// Observation after the step.
    pub obs: O,
    /// Reward of the step.
    pub reward: f32,
    /// Reached the goal.
    pub terminated: bool,
    /// Hit `t_max`.
    pub truncated: bool,
    /// Extra information.
    pub info: Info,
}

/// The Gymnasium-style single-environment interface.
///
/// ```text
/// let (obs, info) = env.reset(task, seed)?;
/// loop {
///     let out = env.step(policy(&obs))?;
///     if out.terminated || out.truncated { break }
/// }
/// ```
pub trait Env {
    /// Observation type.
    type Obs;
    /// Start an episode at `task`.
    fn reset(&mut self, task: Pose, seed: u64) -> Result<(Self::Obs, Info)>;
    /// Advance one decision step.
    fn step(&mut self, action: Action) -> Result<StepOutcome<Self::Obs>>;
}

/// One pedestrian (a [`VecEnv`] of one).
pub struct PedestrianEnv {
    inner: VecEnv,
}

impl PedestrianEnv {
    /// Create a single environment.
    pub fn new(world: Arc<SimWorld>, backend: BackendChoice) -> Result<PedestrianEnv> {
        Ok(PedestrianEnv { inner: VecEnv::new(world, 1, backend)? })
    }

    /// The underlying vectorized env.
    pub fn inner(&self) -> &VecEnv {
        &self.inner
    }

    fn observe(&mut self) -> Result<Observation> {
        Ok(match self.inner.world.config.obs_mode {
            ObsMode::Pixels => Observation::Pixels(self.inner.render()?.frame(0)),
            ObsMode::State => Observation::State(self.inner.state_obs(0)[..self.inner.state_dim()].to_vec()),
        })
    }
}

impl Env for PedestrianEnv {
    type Obs = Observation;

    fn reset(&mut self, task: Pose, seed: u64) -> Result<(Observation, Info)> {
        self.inner.reset(0, task, seed)?;
        let p = *self.inner.pedestrian(0);
        let info = Info {
            pose: p.pose,
            region: self.inner.world.map.kind_at(p.pose.x, p.pose.y),
            collided: false,
            step: 0,
            safety: SafetyEvents::default(),
        };
        Ok((self.observe()?, info))
    }

    fn step(&mut self, action: Action) -> Result<StepOutcome<Observation>> {
        let t = self.inner.step(&[action])?[0];
        let obs = self.observe()?;
        Ok(StepOutcome {
            obs,
            reward: t.reward,
            terminated: t.terminated,
            truncated: t.truncated,
            info: Info { pose: t.pose, region: t.region, collided: t.collided, step: t.step, safety: t.safety },
        })
    }
}
