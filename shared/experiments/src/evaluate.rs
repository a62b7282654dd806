//! Running evaluation episodes: a batch of environments stepped together, each
//! taking the next task of the list when its episode ends.
//!
//! Invariant: an episode's result depends only on its task — not on the order or
//! how the list was split across processes — up to floating-point rounding: the
//! simulator is deterministic given the task's seed, the learned policy's streaming
//! cache equals the full recompute per environment, and a sampling policy draws its
//! noise from a generator of its own environment, seeded from the task's seed when
//! the episode starts. (The policy's matrix products are blocked by batch size, so
//! another `--envs` can round differently, and a long episode can amplify that.)

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use candle_core::{Device, Tensor};
use pednav_learner::load_acting;
use pednav_nets::{DsacNets, NetsConfig, Obs};
use pednav_policy::{ActingPolicy, Sampling, action_rows};
use pednav_runtime::RunConfig;
use pednav_sim::draw::Film;
use pednav_sim::oracle::{Oracle, OracleConfig};
use pednav_sim::policy::{OraclePolicy, RandomPolicy, StandStillPolicy};
use pednav_sim::{Action, BackendChoice, DiscountedReturn, ObsMode, Policy, Pose, SimConfig, SimWorld, VecEnv};

use crate::error::{ExperimentError, Result};
use crate::protocol::{EvalTask, YAWS_DEG};
use crate::table::EpisodeResult;

/// Which policy acts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PolicyKind {
    /// The learned policy of a checkpoint: its mode (deterministic) or samples.
    Learned {
        /// Act with tanh(μ) instead of sampling.
        deterministic: bool,
    },
    /// Uniform random actions (the random-walk baseline).
    Random,
    /// Standing still at the start: what never crossing is worth.
    StandStill,
    /// The oracle planner's greedy action (an upper reference); with traffic, gated
    /// by the signals and vehicles ([`pednav_sim::policy::traffic_gate`]).
    Oracle,
    /// The oracle planner's greedy action walked through traffic as if there were
    /// none: what crossing against the signal costs.
    OracleIgnoringTraffic,
}

/// The evaluator's policy: the learned one (which the diagnosis can watch) or a
/// reference policy of the simulator.
// One per evaluator, so the size of the learned variant does not matter.
#[allow(clippy::large_enum_variant)]
enum EvalPolicy {
    Learned(ActingPolicy),
    Reference(Box<dyn Policy>),
}

impl EvalPolicy {
    fn as_policy(&mut self) -> &mut dyn Policy {
        match self {
            EvalPolicy::Learned(p) => p,
            EvalPolicy::Reference(p) => p.as_mut(),
        }
    }
}

/// What an [`EpisodeObserver`] sees when a learned policy acts on every environment.
pub struct ActingStep<'a> {
    /// The observations of all M environments (the full N_h windows for pixels).
    pub obs: &'a Obs,
    /// The actions taken, (M, 3).
    pub actions: &'a Tensor,
    /// log π(a|s) of the sampled actions, (M); `None` when acting with the mode.
    pub log_probs: Option<&'a Tensor>,
    /// Each environment's pose when it decided.
    pub poses: &'a [Pose],
    /// Each environment's task, `None` for an environment only filling the batch
    /// after the task list ran out (its episode is not part of the results).
    pub tasks: &'a [Option<EvalTask>],
}

/// Watches the episodes of [`Evaluator::run_observed`] (e.g. to record features,
/// critic values and returns for diagnosis). The evaluator's results do not depend
/// on whether it is watched.
pub trait EpisodeObserver {
    /// Every environment decided (called once per step, before the step).
    fn decision(&mut self, decision: &ActingStep<'_>) -> Result<()>;
    /// Environment `env` received `reward`; `ended` is `Some(terminated)` when its
    /// episode ended with this step (`false`: truncated at T_max).
    fn transition(&mut self, env: usize, reward: f32, ended: Option<bool>) -> Result<()>;
}

/// Evaluates tasks with one policy on a batch of environments.
pub struct Evaluator {
    world: Arc<SimWorld>,
    envs: VecEnv,
    policy: EvalPolicy,
    gamma: f32,
}

/// Per-environment episode in progress.
struct Running {
    task: EvalTask,
    filler: bool,
    ret: DiscountedReturn,
    steps: u32,
    trajectory: Vec<[f32; 2]>,
    safety: pednav_sim::traffic::SafetyCounts,
}

/// The networks of a run's checkpoint, on `device` (checkpoints load on any device,
/// whichever one wrote them): the run's latest (`<run>/checkpoints/learner`) unless
/// `checkpoint` names another checkpoint directory of the same configuration. Only
/// the acting networks are read ([`load_acting`]), so a results folder that keeps
/// just those files of its final checkpoint evaluates like the run itself.
pub fn load_policy(run_dir: &Path, checkpoint: Option<&Path>, device: &Device) -> Result<(RunConfig, DsacNets)> {
    let cfg = RunConfig::load(&run_dir.join("config.toml"))
        .map_err(|e| ExperimentError::file(&run_dir.join("config.toml"), e))?;
    let ckpt = checkpoint.map_or_else(|| pednav_runtime::RunDir::new(run_dir).learner_checkpoint(), Path::to_path_buf);
    let nets = DsacNets::new(&cfg.nets, device, cfg.seed).map_err(|e| ExperimentError::file(&ckpt, e))?;
    load_acting(&ckpt, &nets).map_err(|e| ExperimentError::file(&ckpt, e))?;
    Ok((cfg, nets))
}

impl Evaluator {
    /// An evaluator with `envs` environments. `sim` is the run's simulator config
    /// (its `t_max` is replaced by `t_max`); `nets` is needed for learned policies.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        scene: pednav_sim::Scene,
        sim: &SimConfig,
        t_max: u32,
        gamma: f32,
        envs: usize,
        kind: PolicyKind,
        nets: Option<(NetsConfig, DsacNets)>,
        seed: u64,
    ) -> Result<Evaluator> {
        let learned = matches!(kind, PolicyKind::Learned { .. });
        // Only a learned pixel policy needs the renderer.
        let obs_mode = if learned { sim.obs_mode } else { ObsMode::State };
        let world = Arc::new(SimWorld::new(scene, SimConfig { t_max, obs_mode, ..sim.clone() })?);
        let envs_ = VecEnv::new(world.clone(), envs, BackendChoice::from_env().map_err(ExperimentError::Plot)?)?;
        let policy = match kind {
            PolicyKind::Learned { deterministic } => {
                let (cfg, nets) =
                    nets.ok_or_else(|| ExperimentError::Plot("a learned policy needs a checkpoint".into()))?;
                let sampling = if deterministic { Sampling::Mode } else { Sampling::Sample };
                EvalPolicy::Learned(ActingPolicy::new(nets, &cfg, envs, sampling))
            }
            PolicyKind::Random => EvalPolicy::Reference(Box::new(RandomPolicy::new(seed))),
            PolicyKind::StandStill => EvalPolicy::Reference(Box::new(StandStillPolicy)),
            PolicyKind::Oracle => EvalPolicy::Reference(Box::new(OraclePolicy::new(Oracle::plan(
                &world,
                OracleConfig { gamma, ..OracleConfig::default() },
            )))),
            PolicyKind::OracleIgnoringTraffic => EvalPolicy::Reference(Box::new(OraclePolicy::ignoring_traffic(
                Oracle::plan(&world, OracleConfig { gamma, ..OracleConfig::default() }),
            ))),
        };
        Ok(Evaluator { world, envs: envs_, policy, gamma })
    }

    fn start(&mut self, e: usize, task: EvalTask, filler: bool, running: &mut [Option<Running>]) -> Result<()> {
        let pose = task.pose();
        self.envs.reset(e, pose, task.seed)?;
        running[e] = Some(Running {
            task,
            filler,
            ret: DiscountedReturn::new(self.gamma as f64),
            steps: 0,
            trajectory: vec![[pose.x, pose.y]],
            safety: Default::default(),
        });
        Ok(())
    }

    /// The policy begins the episodes just started in `started` (with their first
    /// frames when it reads frames); a sampling policy's noise is seeded from the task.
    fn begin(&mut self, started: &[usize], running: &[Option<Running>]) -> Result<()> {
        if started.is_empty() {
            return Ok(());
        }
        let frames = if self.policy.as_policy().needs_frames() {
            let f = self.envs.render()?;
            started.iter().map(|&e| Some(f.frame(e))).collect()
        } else {
            vec![None; started.len()]
        };
        for (&e, frame) in started.iter().zip(frames) {
            let seed = running[e].as_ref().expect("just started").task.seed;
            self.policy.as_policy().begin(e, seed, frame.as_deref()).map_err(ExperimentError::Policy)?;
        }
        Ok(())
    }

    fn actions(&mut self, watch: Option<(&mut dyn EpisodeObserver, &[Option<EvalTask>])>) -> Result<Vec<Action>> {
        let m = self.envs.num_envs();
        match (&mut self.policy, watch) {
            (EvalPolicy::Learned(policy), Some((observer, tasks))) => {
                let poses: Vec<Pose> = (0..m).map(|e| self.envs.pedestrian(e).pose).collect();
                let d = policy.decide(&self.envs, true)?;
                let obs = d.obs.as_ref().expect("asked for the observations");
                observer.decision(&ActingStep {
                    obs,
                    actions: &d.actions,
                    log_probs: d.log_probs.as_ref(),
                    poses: &poses,
                    tasks,
                })?;
                Ok(action_rows(&d.actions)?)
            }
            (policy, _) => {
                let mut actions = vec![[0.0; 3]; m];
                policy.as_policy().act(&self.envs, &mut actions).map_err(ExperimentError::Policy)?;
                Ok(actions)
            }
        }
    }

    /// Run every task; `progress` is called with the number of finished episodes.
    pub fn run(&mut self, tasks: &[EvalTask], progress: impl FnMut(usize)) -> Result<Vec<EpisodeResult>> {
        self.run_observed(tasks, progress, None)
    }

    /// [`Evaluator::run`], with `observer` (if any) shown every decision and
    /// transition of a learned policy.
    pub fn run_observed(
        &mut self,
        tasks: &[EvalTask],
        mut progress: impl FnMut(usize),
        mut observer: Option<&mut dyn EpisodeObserver>,
    ) -> Result<Vec<EpisodeResult>> {
        let m = self.envs.num_envs();
        let mut running: Vec<Option<Running>> = (0..m).map(|_| None).collect();
        let mut results = Vec::with_capacity(tasks.len());
        let mut next = 0;
        let mut started = Vec::new();
        for e in 0..m {
            let (task, filler) = if next < tasks.len() { (tasks[next], false) } else { (tasks[0], true) };
            next += !filler as usize;
            self.start(e, task, filler, &mut running)?;
            started.push(e);
        }
        self.begin(&started, &running)?;
        while running.iter().any(|r| r.as_ref().is_some_and(|r| !r.filler)) {
            let actions = match observer.as_deref_mut() {
                Some(o) => {
                    let counted: Vec<Option<EvalTask>> =
                        running.iter().map(|r| r.as_ref().filter(|r| !r.filler).map(|r| r.task)).collect();
                    self.actions(Some((o, &counted)))?
                }
                None => self.actions(None)?,
            };
            let transitions = self.envs.step(&actions)?.to_vec();
            let pixels = self.policy.as_policy().needs_frames();
            let frames: Vec<Vec<u8>> = if pixels {
                let f = self.envs.render()?;
                (0..m).map(|e| f.frame(e)).collect()
            } else {
                Vec::new()
            };
            started.clear();
            for (e, t) in transitions.iter().enumerate() {
                let r = running[e].as_mut().expect("every env runs an episode");
                r.ret.add(t.reward);
                r.steps += 1;
                r.trajectory.push([t.pose.x, t.pose.y]);
                r.safety.add(&t.safety);
                if let Some(o) = observer.as_deref_mut() {
                    o.transition(e, t.reward, (t.terminated || t.truncated).then_some(t.terminated))?;
                }
                if t.terminated || t.truncated {
                    let done = running[e].take().expect("present");
                    if !done.filler {
                        results.push(EpisodeResult {
                            point: done.task.point,
                            yaw_deg: done.task.yaw_deg,
                            run: done.task.run,
                            discounted_return: done.ret.value() as f32,
                            success: t.reached_goal(),
                            steps: done.steps,
                            trajectory: done.trajectory,
                            safety: self.world.traffic.is_some().then_some(done.safety),
                        });
                        progress(results.len());
                    }
                    let (task, filler) = if next < tasks.len() { (tasks[next], false) } else { (tasks[0], true) };
                    next += !filler as usize;
                    self.start(e, task, filler, &mut running)?;
                    started.push(e);
                } else {
                    let frame = frames.get(e).map(Vec::as_slice);
                    self.policy.as_policy().observe(e, actions[e], t.reward, frame).map_err(ExperimentError::Policy)?;
                }
            }
            self.begin(&started, &running)?;
        }
        Ok(results)
    }

    /// Record one task as a GIF: the ×4 first-person view beside the map with the
    /// trajectory ([`Film`]; a black view for state observations).
    pub fn record_gif(&mut self, task: EvalTask, out: &Path) -> Result<EpisodeResult> {
        if self.envs.num_envs() != 1 {
            return Err(ExperimentError::Plot("record_gif needs an evaluator with one environment".into()));
        }
        let mut running = vec![None];
        self.start(0, task, false, &mut running)?;
        self.begin(&[0], &running)?;
        let pixels = self.world.config.obs_mode == ObsMode::Pixels;
        let mut film = Film::new(&self.world);
        let mut view = if pixels { Some(self.envs.render()?.frame(0)) } else { None };
        loop {
            let r = running[0].as_ref().expect("running");
            let trail: Vec<(f32, f32)> = r.trajectory.iter().map(|p| (p[0], p[1])).collect();
            let p = self.envs.pedestrian(0);
            film.add(view.as_deref(), &trail, Pose { yaw: p.camera_yaw(), ..p.pose });
            let a = self.actions(None)?;
            let t = self.envs.step(&a)?[0];
            let r = running[0].as_mut().expect("running");
            r.ret.add(t.reward);
            r.steps += 1;
            r.trajectory.push([t.pose.x, t.pose.y]);
            r.safety.add(&t.safety);
            if t.terminated || t.truncated {
                let done = running[0].take().expect("running");
                film.save(out)?;
                return Ok(EpisodeResult {
                    point: task.point,
                    yaw_deg: task.yaw_deg,
                    run: task.run,
                    discounted_return: done.ret.value() as f32,
                    success: t.reached_goal(),
                    steps: done.steps,
                    trajectory: done.trajectory,
                    safety: self.world.traffic.is_some().then_some(done.safety),
                });
            }
            view = if pixels { Some(self.envs.render()?.frame(0)) } else { None };
            self.policy.as_policy().observe(0, a[0], t.reward, view.as_deref()).map_err(ExperimentError::Policy)?;
        }
    }
}

/// The oracle's optimal discounted return per start point, averaged over the
/// protocol's yaws (greedy rollouts on the planned values, `t_max` steps).
pub fn oracle_per_point(
    scene: &pednav_sim::Scene,
    sim: &SimConfig,
    gamma: f32,
    t_max: u32,
    starts: &[(u32, f32, f32)],
) -> Result<BTreeMap<u32, f64>> {
    let world = SimWorld::new(scene.clone(), SimConfig { t_max, obs_mode: ObsMode::State, ..sim.clone() })?;
    let oracle = Oracle::plan(&world, OracleConfig { gamma, ..OracleConfig::default() });
    Ok(starts
        .iter()
        .map(|&(point, x, y)| {
            let mean = YAWS_DEG
                .iter()
                .map(|&yaw| oracle.rollout(&world, Pose::from_degrees(x, y, yaw), t_max).discounted_return as f64)
                .sum::<f64>()
                / YAWS_DEG.len() as f64;
            (point, mean)
        })
        .collect())
}
