//! The actor process as a struct: [`ActorProcess::open`] builds the simulators, the
//! local policy and the typed channel ends; [`ActorProcess::run`] loops over
//! [`ActorProcess::step`] — start episodes, pick up newer weights, act, step and
//! render, send the steps and the finished episodes' reports, log.
//!
//! Invariants: nothing is sent while no learner is subscribed (the [`StepWriter`]
//! waits); every finished episode is reported and its report held until the
//! curriculum service has saved it, or given up when the window is full (the
//! [`EpisodeReporter`]; the actor waits at its end, [`REPORTS_FLUSH_WAIT`] at most,
//! for word that the service took the last ones); every record
//! carries the weights version its action came from; the actor's seed is
//! `run seed ⊕ actor id`, mixed with the incarnation so a restarted actor does not
//! replay its predecessor's episodes.

use std::collections::{BTreeSet, VecDeque};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use candle_core::Device;
use pednav_nets::DsacNets;
use pednav_policy::{ActingPolicy, Sampling};
use pednav_runtime::channels::{EpisodeReporter, StepPayload, StepWriter, StreamId, TaskRequester};
use pednav_runtime::columns::actor as col;
use pednav_runtime::ipc::HeartbeatPublisher;
use pednav_runtime::messages::{EpisodeHeader, EpisodePoint, Faults, Heartbeat, ProcessKind, StepFlags, StepHeader};
use pednav_runtime::stats::{self, ActorStats, ProcessStatus};
use pednav_runtime::weights::WeightsClient;
use pednav_runtime::write_health::WriteHealth;
use pednav_runtime::{ActorPolicy, Ipc, Metrics, RunConfig, RunDir, StopFlag};
use pednav_sim::policy::RandomPolicy;
use pednav_sim::{BackendChoice, DiscountedReturn, ObsMode, Policy, Pose, STATE_OBS_MAX, SimWorld, VecEnv};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// How long a stopping actor waits for the acknowledgement of the episode reports it
/// still holds (while their receiver is there).
pub const REPORTS_FLUSH_WAIT: Duration = Duration::from_secs(3);

/// Per-environment episode bookkeeping.
struct Episode {
    id: u64,
    task_id: u64,
    /// The seed the environment and the policy's noise were started with.
    seed: u64,
    category: u32,
    /// The start's position in the signal cycle, when the task set it.
    cycle: Option<f32>,
    step: u32,
    points: Vec<EpisodePoint>,
    ret: DiscountedReturn,
}

/// What this incarnation sent and received (its stats file).
#[derive(Default)]
struct Counters {
    tasks: u64,
    last_task_id: u64,
    steps: u64,
    episodes: u64,
    checksum: u32,
    recent_returns: VecDeque<f32>,
    /// Steps onto a zebra outside WALK sent so far (with traffic).
    dont_walk_entries: u64,
    /// Steps on which a vehicle hit the agent sent so far (with traffic).
    vehicle_hits: u64,
}

impl Counters {
    /// Account for a sent record; the sequence number of the next one is `steps`.
    fn sent(&mut self, header: &StepHeader, observation: &[u8]) {
        self.checksum = self.checksum.wrapping_add(header.record_crc(observation));
        self.steps += 1;
        self.dont_walk_entries += u64::from(header.flags.contains(StepFlags::DONT_WALK_ENTRY));
        self.vehicle_hits += u64::from(header.flags.contains(StepFlags::VEHICLE_HIT));
    }
}

/// Seconds spent per phase over one metrics interval.
struct Timing {
    started: Instant,
    steps: u64,
    infer: f64,
    sim: f64,
    send: f64,
}

impl Timing {
    fn new(steps: u64) -> Timing {
        Timing { started: Instant::now(), steps, infer: 0.0, sim: 0.0, send: 0.0 }
    }
}

/// Which actor this is, and how it was started.
pub struct ActorOptions {
    /// Actor id (0-based).
    pub actor: u32,
    /// Simulator instances (default: the config's `runtime.envs_per_actor`).
    pub envs: Option<usize>,
    /// Where to run policy inference.
    pub device: Device,
}

/// One actor of a run.
pub struct ActorProcess {
    cfg: RunConfig,
    dir: RunDir,
    stop: StopFlag,
    actor: u32,
    incarnation: u32,
    envs: VecEnv,
    pixels: bool,
    /// Whether records carry the state vector (the observation in state mode, the
    /// learner's state-prediction target with `dsac.state_aux_weight` > 0).
    send_state: bool,
    // Kept alive for the ports below.
    _ipc: Ipc,
    steps: StepWriter,
    reports: EpisodeReporter,
    tasks: TaskRequester,
    weights: WeightsClient,
    heartbeat: HeartbeatPublisher,
    metrics: Metrics,
    /// Writes that failed (metrics, stats) and are retried.
    health: WriteHealth,
    /// The learned policy; it receives every newer version of the weights.
    learned: ActingPolicy,
    /// The random walk, when it acts instead (`runtime.policy = "random"`).
    random: Option<RandomPolicy>,
    versions_used: BTreeSet<u64>,
    rng: ChaCha8Rng,
    counters: Counters,
    episodes: Vec<Option<Episode>>,
    next_episode: u64,
    actions: Vec<[f32; 3]>,
    timing: Timing,
    /// With traffic: the world's full zebra-entry reward and the share of it paid in
    /// episodes starting now (`curriculum.entry_reward_ramp`; 1 without a ramp).
    entry_reward: Option<(f32, f32)>,
}

impl ActorProcess {
    /// The simulators, the policy (the seed's initial weights, version 0, as the
    /// learner's) and the channels of actor `opts.actor` of the run in `dir`.
    pub fn open(dir: RunDir, cfg: RunConfig, opts: ActorOptions, stop: StopFlag) -> Result<ActorProcess> {
        let name = format!("actor-{}", opts.actor);
        let incarnation = dir.next_incarnation(&name)?;
        let seed = pednav_config::rng::actor_seed(cfg.seed, opts.actor, incarnation);
        let m = opts.envs.unwrap_or(cfg.runtime.envs_per_actor);
        if m == 0 || m > 4096 {
            bail!("--envs must be 1 … 4096, got {m}");
        }
        let world = Arc::new(SimWorld::new(cfg.scene()?, cfg.sim.clone())?);
        let backend = BackendChoice::from_env().map_err(anyhow::Error::msg)?;
        let envs = VecEnv::new(world, m, backend)?;
        let entry_reward = envs.world_dont_walk_entry().map(|full| (full, 1.0));
        if let Some(r) = envs.renderer() {
            tracing::info!(adapter = %r.adapter_description(), envs = m, "renderer ready");
        }
        let ipc = dir.join_ipc(&cfg, &name, stop.clone())?;
        let steps = StepWriter::open(
            &ipc,
            StreamId { actor: opts.actor, incarnation },
            cfg.observation_bytes(),
            cfg.runtime.resend_window(),
            stop.clone(),
        )?;
        let reports =
            EpisodeReporter::open(&ipc, StreamId { actor: opts.actor, incarnation }, cfg.sim.t_max as usize + 1)?;
        let tasks = TaskRequester::open(&ipc, Duration::from_secs_f64(cfg.runtime.task_timeout_secs), stop.clone())?;
        let weights = WeightsClient::open(&ipc)?;
        let heartbeat = ipc.heartbeat_publisher()?;
        let metrics = Metrics::open(&dir.metrics(), &dir.tb(), &name)?;
        // The learner builds its networks from the run seed too: version 0 is the same here and there.
        let nets = DsacNets::new(&cfg.nets, &opts.device, cfg.seed)?;
        let learned = ActingPolicy::new(nets, &cfg.nets, m, Sampling::Sample);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let random = (cfg.runtime.policy == ActorPolicy::Random)
            .then(|| RandomPolicy::from_rng(ChaCha8Rng::seed_from_u64(rng.random())));
        Ok(ActorProcess {
            pixels: cfg.sim.obs_mode == ObsMode::Pixels,
            send_state: cfg.sim.obs_mode != ObsMode::Pixels || cfg.dsac.builds_state_head(),
            actor: opts.actor,
            incarnation,
            envs,
            _ipc: ipc,
            steps,
            reports,
            tasks,
            weights,
            heartbeat,
            metrics,
            health: WriteHealth::new(Duration::from_secs_f64(cfg.runtime.metrics_every_secs.max(1.0))),
            learned,
            random,
            versions_used: BTreeSet::new(),
            rng,
            counters: Counters::default(),
            episodes: (0..m).map(|_| None).collect(),
            next_episode: 0,
            actions: vec![[0.0; 3]; m],
            timing: Timing::new(0),
            entry_reward,
            cfg,
            dir,
            stop,
        })
    }

    /// Wait for the learner, step until stopped, write the final stats.
    pub fn run(mut self) -> Result<()> {
        tracing::info!(actor = self.actor, incarnation = self.incarnation, envs = self.envs.num_envs(), policy = ?self.cfg.runtime.policy, "actor waiting for the learner and the curriculum service");
        if !self.steps.wait_for_learner(Duration::from_secs(3600)) {
            return self.finish(ProcessStatus::StoppedBeforeLearner);
        }
        self.timing = Timing::new(0);
        while !self.stop.is_set() {
            if !self.step()? {
                break;
            }
        }
        let status = if self.stop.is_set() { ProcessStatus::Stopped } else { ProcessStatus::Ended };
        self.finish(status)
    }

    /// One iteration over all environments; `false` when a send or request saw the
    /// stop request.
    pub fn step(&mut self) -> Result<bool> {
        if !self.start_episodes()? {
            return Ok(false);
        }
        if let Some(new) = self.weights.refresh(&mut self.learned)? {
            tracing::debug!(version = new.version, latency_ms = new.latency_ms, "new weights");
        }
        let t0 = Instant::now();
        self.choose_actions()?;
        self.timing.infer += t0.elapsed().as_secs_f64();
        if !self.step_envs()? {
            return Ok(false);
        }
        // Reports that went without an acknowledgement go out again.
        self.reports.pump()?;
        if self.timing.started.elapsed().as_secs_f64() >= self.cfg.runtime.metrics_every_secs {
            self.log_interval()?;
        }
        Ok(true)
    }

    /// A new task for every environment without an episode, and its first record.
    fn start_episodes(&mut self) -> Result<bool> {
        let starting: Vec<usize> = (0..self.episodes.len()).filter(|&e| self.episodes[e].is_none()).collect();
        if starting.is_empty() {
            return Ok(true);
        }
        self.ramp_entry_reward()?;
        for &e in &starting {
            let Some(task) = self.tasks.request(self.actor, e as u32)? else { return Ok(false) };
            self.counters.tasks += 1;
            self.counters.last_task_id = task.task_id;
            let pose = Pose { x: task.x, y: task.y, yaw: task.yaw };
            let seed = self.rng.random();
            let cycle = task.cycle();
            self.envs.reset_in_cycle(e, pose, seed, cycle).with_context(|| {
                format!(
                    "the curriculum service proposed an invalid task {pose:?} (position in the signal cycle {cycle:?})"
                )
            })?;
            self.next_episode += 1;
            self.episodes[e] = Some(Episode {
                id: self.next_episode,
                task_id: task.task_id,
                seed,
                category: task.category,
                cycle,
                step: 0,
                points: vec![EpisodePoint { x: pose.x, y: pose.y, yaw: pose.yaw, reward: 0.0 }],
                ret: DiscountedReturn::new(self.cfg.dsac.gamma),
            });
        }
        let t0 = Instant::now();
        let states = self.states();
        let state_dim = self.envs.state_dim();
        let frames = if self.pixels { Some(self.envs.render()?) } else { None };
        for &e in &starting {
            let ep = self.episodes[e].as_ref().expect("just started");
            let header = StepHeader {
                actor: self.actor,
                env: e as u32,
                incarnation: self.incarnation,
                flags: StepFlags::FIRST,
                episode: ep.id,
                policy_version: self.weights.version(),
                seq: self.steps.next_seq(),
                state: states[e],
                ..StepHeader::default()
            };
            let Some(bytes) = self.steps.send(header, observation(frames.as_ref(), &states, state_dim, e))? else {
                return Ok(false);
            };
            acting(&mut self.random, &mut self.learned)
                .begin(e, ep.seed, self.pixels.then_some(&bytes[..]))
                .map_err(anyhow::Error::from_boxed)?;
            self.counters.sent(&header, &bytes);
        }
        drop(frames);
        self.timing.send += t0.elapsed().as_secs_f64();
        Ok(true)
    }

    /// Under `curriculum.entry_reward_ramp`: pay the ramp's share of the zebra-entry
    /// reward in the episodes about to start, at the env steps the learner had taken in
    /// when it published the weights acted with (their version is its update count).
    fn ramp_entry_reward(&mut self) -> Result<()> {
        let (Some((full, share)), Some(_)) = (self.entry_reward, self.cfg.curriculum.entry_reward_ramp) else {
            return Ok(());
        };
        let learner_steps = self.cfg.dsac.env_steps_at_update(self.weights.version());
        let now = self.cfg.curriculum.entry_reward_share(learner_steps);
        if now != share {
            self.envs.set_dont_walk_entry(paid(full, now) as f32)?;
            self.entry_reward = Some((full, now));
            tracing::debug!(learner_steps, reward = paid(full, now), "zebra-entry reward ramped");
        }
        Ok(())
    }

    /// Every environment's state vector when records carry it, else zeros (nobody
    /// reads them: pixels without the state-prediction loss).
    fn states(&self) -> Vec<[f32; STATE_OBS_MAX]> {
        let m = self.envs.num_envs();
        if self.send_state { (0..m).map(|e| self.envs.state_obs(e)).collect() } else { vec![[0.0; STATE_OBS_MAX]; m] }
    }

    fn choose_actions(&mut self) -> Result<()> {
        if self.random.is_none() {
            self.versions_used.insert(self.weights.version());
        }
        acting(&mut self.random, &mut self.learned)
            .act(&self.envs, &mut self.actions)
            .map_err(anyhow::Error::from_boxed)
    }

    /// Step and render every environment, send each step, report finished episodes.
    fn step_envs(&mut self) -> Result<bool> {
        let t0 = Instant::now();
        let transitions = self.envs.step(&self.actions)?.to_vec();
        self.timing.sim += t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let states = self.states();
        let state_dim = self.envs.state_dim();
        let frames = if self.pixels { Some(self.envs.render()?) } else { None };
        let mut ended = Vec::new();
        for (e, t) in transitions.iter().enumerate() {
            let ep = self.episodes[e].as_mut().expect("every env is in an episode");
            ep.step = t.step;
            let flags = StepFlags::NONE
                .with_if(StepFlags::TERMINAL, t.terminated)
                .with_if(StepFlags::TRUNCATED, t.truncated)
                .with_if(StepFlags::COLLIDED, t.collided)
                .with_if(StepFlags::VEHICLE_HIT, t.safety.vehicle_hit)
                .with_if(StepFlags::DONT_WALK_ENTRY, t.safety.dont_walk_entry)
                .with_if(StepFlags::PEDESTRIAN_BUMP, t.safety.pedestrian_bump);
            let header = StepHeader {
                actor: self.actor,
                env: e as u32,
                incarnation: self.incarnation,
                flags,
                episode: ep.id,
                step: t.step,
                reward: t.reward,
                action: self.actions[e],
                policy_version: self.weights.version(),
                seq: self.steps.next_seq(),
                base: 0, // the writer fills in its window's base
                state: states[e],
            };
            let Some(bytes) = self.steps.send(header, observation(frames.as_ref(), &states, state_dim, e))? else {
                return Ok(false);
            };
            if !(t.terminated || t.truncated) {
                acting(&mut self.random, &mut self.learned)
                    .observe(e, self.actions[e], t.reward, self.pixels.then_some(&bytes[..]))
                    .map_err(anyhow::Error::from_boxed)?;
            }
            self.counters.sent(&header, &bytes);
            ep.points.push(EpisodePoint { x: t.pose.x, y: t.pose.y, yaw: t.pose.yaw, reward: t.reward });
            ep.ret.add(t.reward);
            if t.terminated || t.truncated {
                ended.push((e, t.reached_goal(), t.truncated));
            }
        }
        drop(frames);
        self.timing.send += t0.elapsed().as_secs_f64();
        for (e, success, truncated) in ended {
            let ep = self.episodes[e].take().expect("ended episode exists");
            let header = EpisodeHeader {
                actor: self.actor,
                env: e as u32,
                task_id: ep.task_id,
                category: ep.category,
                success: success as u32,
                truncated: truncated as u32,
                length: ep.step,
                discounted_return: ep.ret.value() as f32,
                total_reward: ep.ret.undiscounted() as f32,
                // The reporter numbers it (seq, low-water mark).
                ..EpisodeHeader::default()
            }
            .with_start_cycle(ep.cycle);
            self.reports.report(header, &ep.points)?;
            let c = &mut self.counters;
            c.episodes += 1;
            c.recent_returns.push_back(ep.ret.value() as f32);
            if c.recent_returns.len() > 20 {
                c.recent_returns.pop_front();
            }
        }
        Ok(true)
    }

    /// Metrics row, heartbeat and live stats of the interval just ended.
    fn log_interval(&mut self) -> Result<()> {
        let t = std::mem::replace(&mut self.timing, Timing::new(self.counters.steps));
        let secs = t.started.elapsed().as_secs_f64();
        let c = &self.counters;
        let n = (c.steps - t.steps).max(1) as f64;
        let rate = (c.steps - t.steps) as f64 / secs;
        let r = &c.recent_returns;
        // No return before the first episode ends.
        let recent = (!r.is_empty()).then(|| r.iter().sum::<f32>() / r.len() as f32);
        let version = self.weights.version();
        let traffic = self.entry_reward.is_some();
        self.metrics.log_optional(
            c.steps,
            &[
                (col::STEPS_PER_S, Some(rate)),
                (col::EPISODES, Some(c.episodes as f64)),
                (col::POLICY_VERSION, Some(version as f64)),
                (col::RECENT_RETURN, recent.map(f64::from)),
                (col::INFERENCE_MS_PER_STEP, Some(1e3 * t.infer / n)),
                (col::SIM_MS_PER_STEP, Some(1e3 * t.sim / n)),
                (col::RENDER_SEND_MS_PER_STEP, Some(1e3 * t.send / n)),
                (col::ZEBRA_ENTRY_REWARD, self.entry_reward.map(|(full, share)| paid(full, share))),
                (col::DONT_WALK_ENTRIES, traffic.then_some(c.dont_walk_entries as f64)),
                (col::VEHICLE_HITS, traffic.then_some(c.vehicle_hits as f64)),
            ],
        )?;
        self.health.metrics(&self.metrics);
        let _ = self.heartbeat.send_copy(Heartbeat {
            kind: ProcessKind::ACTOR,
            id: self.actor,
            pid: std::process::id(),
            env_steps: c.steps,
            episodes: c.episodes,
            version,
            recent_return: recent.unwrap_or(f32::NAN),
            rate: rate as f32,
            faults: self.health.faults(),
            incarnation: self.incarnation,
            stream_base: self.steps.base(),
            ..Heartbeat::default()
        });
        match self.dir.write_stats(&stats::actor_live(self.actor), &self.stats(ProcessStatus::Running)) {
            Ok(()) => self.health.succeeded("stats"),
            Err(e) => self.health.failed(
                "stats",
                Faults::METRICS,
                e.is_disk_full(),
                &e.to_string(),
                "retried at the next interval",
            ),
        }
        Ok(())
    }

    fn stats(&self, status: ProcessStatus) -> ActorStats {
        let (c, versions) = (&self.counters, &self.versions_used);
        ActorStats {
            actor: self.actor,
            incarnation: self.incarnation,
            pid: std::process::id(),
            status,
            steps_sent: c.steps,
            checksum: c.checksum,
            episodes: c.episodes,
            policy_versions_used: versions.len() as u64,
            first_policy_version: versions.first().copied(),
            last_policy_version: versions.last().copied(),
            tasks_received: c.tasks,
            last_task_id: c.last_task_id,
            records_resent: self.steps.resends().resent,
            resend_requests: self.steps.resends().requests,
            resend_timeouts: self.steps.resends().timeouts,
            reports_resent: self.reports.counts().resent,
            reports_given_up: self.reports.counts().given_up,
            reports_unacknowledged: self.reports.counts().untaken,
        }
    }

    fn finish(&mut self, status: ProcessStatus) -> Result<()> {
        // Word that the last reports were taken, while their receiver is there; a
        // failure here is logged, the final stats are written regardless.
        match self.reports.flush(REPORTS_FLUSH_WAIT) {
            Ok(0) => {}
            Ok(n) => tracing::warn!(
                reports = n,
                "episode reports not acknowledged by the curriculum service when the actor stopped"
            ),
            Err(e) => tracing::warn!("the last episode reports could not be sent: {e}"),
        }
        self.dir.write_stats(&stats::actor_final(self.actor, self.incarnation), &self.stats(status))?;
        tracing::info!(
            steps = self.counters.steps,
            episodes = self.counters.episodes,
            status = status.as_str(),
            "actor finished"
        );
        Ok(())
    }
}

/// The zebra-entry reward paid at `share` of its `full` value (0, not −0, at none of it).
fn paid(full: f32, share: f32) -> f64 {
    f64::from(full * share) + 0.0
}

/// The policy that acts: the random walk when the run asks for it, else the learned one.
fn acting<'a>(random: &'a mut Option<RandomPolicy>, learned: &'a mut ActingPolicy) -> &'a mut dyn Policy {
    match random {
        Some(random) => random,
        None => learned,
    }
}

/// Environment `e`'s observation: its view of the batch render, or the first
/// `state_dim` entries of its state vector.
fn observation<'a>(
    frames: Option<&'a pednav_sim::Frames<'a>>,
    states: &'a [[f32; STATE_OBS_MAX]],
    state_dim: usize,
    e: usize,
) -> StepPayload<'a> {
    match frames {
        Some(frames) => StepPayload::Frame { frames, env: e },
        None => StepPayload::State(&states[e][..state_dim]),
    }
}
