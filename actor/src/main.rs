//! `pednav-actor` — one actor process of a pednav run.
//!
//! Owns `runtime.envs_per_actor` simulator instances ([`VecEnv`]: one renderer,
//! all views in one submission and one readback) and a local copy of the policy.
//! Each iteration:
//! 1. pick up the newest weights, if the learner published any (never blocks);
//! 2. choose actions for all envs — through the [`PolicyStream`] cache, so a step
//!    costs one new frame of spatial convolution plus the temporal layers, not a
//!    recompute of all N_h frames;
//! 3. step all envs, render all views once;
//! 4. per env, loan a step record from shared memory, copy the frame straight
//!    from the renderer's mapped readback into it (the only copy between the
//!    rasteriser and the learner's replay), push the same bytes into the policy
//!    cache, send;
//! 5. at an episode's end, publish its report and ask the curriculum service for
//!    the next task.
//!
//! Invariants: nothing is sent while no learner is subscribed (records to nobody
//! would be lost); every record carries the weights version its action came
//! from; the actor's seed is `run seed ⊕ actor id`, mixed with the incarnation
//! so a restarted actor does not replay its predecessor's episodes.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use candle_core::Tensor;
use clap::Parser;
use pednav_nets::{DsacNets, Obs, PolicyStream, init_cpu_runtime};
use pednav_runtime::messages::{
    EpisodeHeader, EpisodePoint, Heartbeat, StepHeader, TaskRequest, process_kind, step_flags,
};
use pednav_runtime::{ActorPolicy, Ipc, Metrics, RunDir, StopFlag, run_prefix, weights};
use pednav_sim::{BackendChoice, ObsMode, Pose, SimWorld, VecEnv};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

#[derive(Parser)]
#[command(version, about = "pednav actor: steps simulators, streams steps to the learner, acts with its newest policy")]
struct Cli {
    /// The run directory (created by `pednav-run`).
    #[arg(long)]
    run_dir: PathBuf,
    /// This actor's id (0-based; seeds and stream ids derive from it).
    #[arg(long)]
    actor: u32,
    /// Simulator instances in this actor (default: the config's `runtime.envs_per_actor`).
    #[arg(long)]
    envs: Option<usize>,
    /// Where to run policy inference: cpu, cuda or cuda:N (default: the config's
    /// `runtime.actor_device`).
    #[arg(long)]
    device: Option<pednav_nets::DeviceSpec>,
}

/// Per-environment episode bookkeeping.
struct Episode {
    id: u64,
    task_id: u64,
    category: u32,
    step: u32,
    points: Vec<EpisodePoint>,
    discounted: f64,
    discount: f64,
    total: f64,
}

#[derive(Default)]
struct Counters {
    tasks: u64,
    last_task_id: u64,
    steps: u64,
    episodes: u64,
    checksum: u32,
    recent_returns: VecDeque<f32>,
}

fn main() -> Result<()> {
    pednav_sim::prepare_headless_env();
    pednav_runtime::init_logging();
    let cli = Cli::parse();
    init_cpu_runtime(Some(1));
    let stop = StopFlag::install();
    let dir = RunDir::new(&cli.run_dir);
    let cfg = dir.load_config()?;
    let name = format!("actor-{}", cli.actor);
    let incarnation = dir.next_incarnation(&name)?;
    let seed = cfg.seed ^ (cli.actor as u64 + 1).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ ((incarnation as u64) << 48);
    let m = cli.envs.unwrap_or(cfg.runtime.envs_per_actor);
    if m == 0 || m > 4096 {
        bail!("--envs must be 1 … 4096, got {m}");
    }
    let world = Arc::new(SimWorld::new(cfg.scene()?, cfg.sim.clone())?);
    let backend = BackendChoice::from_env().map_err(anyhow::Error::msg)?;
    let mut envs = VecEnv::new(world.clone(), m, backend)?;
    if let Some(r) = envs.renderer() {
        tracing::info!(adapter = %r.adapter_description(), envs = m, "renderer ready");
    }
    let pixels = cfg.sim.obs_mode == ObsMode::Pixels;
    let obs_bytes = cfg.observation_bytes();

    let ipc = Ipc::new(
        &run_prefix(&cli.run_dir),
        &name,
        cfg.runtime.step_buffer,
        Duration::from_secs_f64(cfg.runtime.give_up_secs),
        stop.clone(),
    )?;
    let steps_out = ipc.step_sender(obs_bytes)?;
    let reports_out = ipc.episode_sender(cfg.sim.t_max as usize + 1)?;
    let tasks = ipc.task_client()?;
    let weights_in = ipc.weights_subscriber()?;
    let heartbeat = ipc.heartbeat_publisher()?;
    let mut metrics = Metrics::open(&dir.metrics(), &dir.tb(), &name)?;

    let device = cli.device.unwrap_or(cfg.runtime.actor_device).open()?;
    // The learner builds its networks from the run seed too: version 0 is the same here and there.
    let nets = DsacNets::new(&cfg.nets, &device, cfg.seed)?;
    let mut stream = PolicyStream::new(&cfg.nets, m, &device);
    let mut version = 0u64;
    let mut versions_used = std::collections::BTreeSet::new();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let wait = Duration::from_secs_f64(cfg.runtime.task_timeout_secs);

    tracing::info!(actor = cli.actor, incarnation, envs = m, policy = ?cfg.runtime.policy, "actor waiting for the learner and the curriculum service");
    if !steps_out.wait_for_subscriber(&stop, Duration::from_secs(3600)) {
        return finish(
            &dir,
            &name,
            cli.actor,
            incarnation,
            &Counters::default(),
            &versions_used,
            "stopped before the learner came up",
        );
    }
    let mut counters = Counters::default();
    let mut episodes: Vec<Option<Episode>> = (0..m).map(|_| None).collect();
    let mut next_episode = 0u64;
    let all: Vec<usize> = (0..m).collect();
    let mut actions = vec![[0.0f32; 3]; m];
    let (mut t_infer, mut t_sim, mut t_send, mut last_steps) = (0.0f64, 0.0f64, 0.0f64, 0u64);
    let mut last_log = Instant::now();
    let log_every = Duration::from_secs_f64(cfg.runtime.metrics_every_secs);

    'run: while !stop.is_set() {
        // 5. Start episodes where needed (at the beginning and after each end).
        let starting: Vec<usize> = (0..m).filter(|&e| episodes[e].is_none()).collect();
        if !starting.is_empty() {
            for &e in &starting {
                let Some(task) = request_task(&tasks, cli.actor, e as u32, wait, &stop)? else { break 'run };
                counters.tasks += 1;
                counters.last_task_id = task.task_id;
                let pose = Pose { x: task.x, y: task.y, yaw: task.yaw };
                envs.reset(e, pose, rng.random())
                    .with_context(|| format!("the curriculum service proposed an invalid task {pose:?}"))?;
                next_episode += 1;
                episodes[e] = Some(Episode {
                    id: next_episode,
                    task_id: task.task_id,
                    category: task.category,
                    step: 0,
                    points: vec![EpisodePoint { x: pose.x, y: pose.y, yaw: pose.yaw, reward: 0.0 }],
                    discounted: 0.0,
                    discount: 1.0,
                    total: 0.0,
                });
            }
            let t0 = Instant::now();
            let states: Vec<_> = if pixels { Vec::new() } else { (0..m).map(|e| envs.state_obs(e)).collect() };
            let frames = if pixels { Some(envs.render()?) } else { None };
            for &e in &starting {
                let ep = episodes[e].as_ref().expect("just started");
                let header = StepHeader {
                    actor: cli.actor,
                    env: e as u32,
                    incarnation,
                    flags: step_flags::FIRST,
                    episode: ep.id,
                    policy_version: version,
                    seq: counters.steps,
                    ..StepHeader::default()
                };
                let sent = send_step(
                    &steps_out,
                    header,
                    obs_bytes,
                    |dst| write_observation(frames.as_ref(), &states, e, dst),
                    &stop,
                )?;
                let Some(bytes) = sent else { break 'run };
                if pixels {
                    stream.reset(e, &bytes)?;
                }
                counters.sent(&header, &bytes);
            }
            drop(frames);
            t_send += t0.elapsed().as_secs_f64();
        }

        // 1. Newest weights, without blocking.
        let mut newest = None;
        while let Some(sample) = weights_in.receive().map_err(|e| anyhow::anyhow!("weights: {e:?}"))? {
            newest = Some(sample);
        }
        if let Some(sample) = newest {
            let h = *sample.user_header();
            if h.version > version {
                weights::load(&nets, sample.payload())?;
                stream.invalidate();
                version = h.version;
                let latency_ms = (pednav_runtime::now_ns().saturating_sub(h.published_ns)) as f64 / 1e6;
                tracing::debug!(version, latency_ms, "new weights");
            }
        }

        // 2. Actions.
        let t0 = Instant::now();
        match cfg.runtime.policy {
            ActorPolicy::Random => {
                for a in actions.iter_mut() {
                    *a = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
                }
            }
            ActorPolicy::Learned => {
                let features = if pixels {
                    stream.features(nets.acting_encoder(), &all)?
                } else {
                    let s: Vec<f32> = (0..m).flat_map(|e| envs.state_obs(e)).collect();
                    nets.acting_encoder().encode(&Obs::State(Tensor::from_vec(s, (m, cfg.nets.state_dim), &device)?))?
                };
                let dist = nets.policy.head(&features)?;
                let eps = pednav_nets::heads::standard_normal(&mut rng, m, &device)?;
                let a = dist.sample(&eps)?.action.to_vec2::<f32>()?;
                for (dst, src) in actions.iter_mut().zip(a) {
                    *dst = [src[0], src[1], src[2]];
                }
                versions_used.insert(version);
            }
        }
        t_infer += t0.elapsed().as_secs_f64();

        // 3. Step and render.
        let t0 = Instant::now();
        let transitions = envs.step(&actions)?.to_vec();
        t_sim += t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let states: Vec<_> = if pixels { Vec::new() } else { (0..m).map(|e| envs.state_obs(e)).collect() };
        let frames = if pixels { Some(envs.render()?) } else { None };
        let mut ended = Vec::new();
        for (e, t) in transitions.iter().enumerate() {
            let ep = episodes[e].as_mut().expect("every env is in an episode");
            ep.step = t.step;
            let mut flags = 0;
            if t.terminated {
                flags |= step_flags::TERMINAL;
            }
            if t.truncated {
                flags |= step_flags::TRUNCATED;
            }
            if t.collided {
                flags |= step_flags::COLLIDED;
            }
            let header = StepHeader {
                actor: cli.actor,
                env: e as u32,
                incarnation,
                flags,
                episode: ep.id,
                step: t.step,
                reward: t.reward,
                action: actions[e],
                policy_version: version,
                seq: counters.steps,
            };
            let sent = send_step(
                &steps_out,
                header,
                obs_bytes,
                |dst| write_observation(frames.as_ref(), &states, e, dst),
                &stop,
            )?;
            let Some(bytes) = sent else { break 'run };
            if pixels && !(t.terminated || t.truncated) {
                stream.push(e, actions[e], t.reward, &bytes)?;
            }
            counters.sent(&header, &bytes);
            ep.points.push(EpisodePoint { x: t.pose.x, y: t.pose.y, yaw: t.pose.yaw, reward: t.reward });
            ep.discounted += ep.discount * t.reward as f64;
            ep.discount *= cfg.dsac.gamma;
            ep.total += t.reward as f64;
            if t.terminated || t.truncated {
                ended.push((e, t.terminated, t.truncated));
            }
        }
        drop(frames);
        t_send += t0.elapsed().as_secs_f64();
        for (e, success, truncated) in ended {
            let ep = episodes[e].take().expect("ended episode exists");
            let header = EpisodeHeader {
                actor: cli.actor,
                env: e as u32,
                task_id: ep.task_id,
                category: ep.category,
                success: success as u32,
                truncated: truncated as u32,
                length: ep.step,
                discounted_return: ep.discounted as f32,
                total_reward: ep.total as f32,
            };
            if !send_report(&reports_out, header, &ep.points, &stop)? {
                break 'run;
            }
            counters.episodes += 1;
            counters.recent_returns.push_back(ep.discounted as f32);
            if counters.recent_returns.len() > 20 {
                counters.recent_returns.pop_front();
            }
        }

        if last_log.elapsed() >= log_every {
            let secs = last_log.elapsed().as_secs_f64();
            last_log = Instant::now();
            let n = (counters.steps - last_steps).max(1) as f64;
            let rate = (counters.steps - last_steps) as f64 / secs;
            last_steps = counters.steps;
            let recent = mean(&counters.recent_returns);
            metrics.log_optional(
                counters.steps,
                &[
                    ("steps_per_s", Some(rate)),
                    ("episodes", Some(counters.episodes as f64)),
                    ("policy_version", Some(version as f64)),
                    // No return before the first episode ends.
                    ("recent_return", Some(recent as f64).filter(|r| r.is_finite())),
                    ("inference_ms_per_step", Some(1e3 * t_infer / n)),
                    ("sim_ms_per_step", Some(1e3 * t_sim / n)),
                    ("render_send_ms_per_step", Some(1e3 * t_send / n)),
                ],
            )?;
            (t_infer, t_sim, t_send) = (0.0, 0.0, 0.0);
            let _ = heartbeat.send_copy(Heartbeat {
                kind: process_kind::ACTOR,
                id: cli.actor,
                pid: std::process::id(),
                steps: counters.steps,
                count: counters.episodes,
                version,
                recent_return: recent,
                rate: rate as f32,
                ..Heartbeat::default()
            });
            dir.write_stats(
                &format!("{name}.live"),
                &stats_json(cli.actor, incarnation, &counters, &versions_used, "running"),
            )?;
        }
    }
    finish(
        &dir,
        &name,
        cli.actor,
        incarnation,
        &counters,
        &versions_used,
        if stop.is_set() { "stopped" } else { "ended" },
    )
}

impl Counters {
    /// Account for a sent record; the sequence number of the next one is `steps`.
    fn sent(&mut self, header: &StepHeader, observation: &[u8]) {
        self.checksum = self.checksum.wrapping_add(header.record_crc(observation));
        self.steps += 1;
    }
}

/// Write environment `e`'s observation: its frame from the batch render, or its state vector.
fn write_observation(
    frames: Option<&pednav_sim::Frames<'_>>,
    states: &[[f32; pednav_sim::STATE_OBS_DIM]],
    e: usize,
    dst: &mut [std::mem::MaybeUninit<u8>],
) {
    match frames {
        Some(f) => f.copy_frame_uninit(e, dst),
        None => write_state(&states[e], dst),
    }
}

fn mean(v: &VecDeque<f32>) -> f32 {
    if v.is_empty() { f32::NAN } else { v.iter().sum::<f32>() / v.len() as f32 }
}

fn write_state(state: &[f32], dst: &mut [std::mem::MaybeUninit<u8>]) {
    for (chunk, v) in dst.chunks_exact_mut(4).zip(state) {
        for (d, b) in chunk.iter_mut().zip(v.to_le_bytes()) {
            d.write(b);
        }
    }
}

/// Loan a record, let `fill` write the observation in place, send it; returns a
/// copy of the bytes for the policy cache (its window keeps its own), or `None` when stopping.
fn send_step(
    out: &pednav_runtime::ipc::StepSender,
    header: StepHeader,
    len: usize,
    fill: impl FnOnce(&mut [std::mem::MaybeUninit<u8>]),
    stop: &StopFlag,
) -> Result<Option<Vec<u8>>> {
    if out.subscribers() == 0 {
        tracing::warn!("the learner is gone; waiting for it before sending more steps");
        if !out.wait_for_subscriber(stop, Duration::from_secs(3600)) {
            return Ok(None);
        }
    }
    let mut sample = out.publisher.loan_slice_uninit(len).map_err(|e| anyhow::anyhow!("loan step record: {e:?}"))?;
    *sample.user_header_mut() = header;
    fill(sample.payload_mut());
    // SAFETY: `fill` initialised every byte (copy_frame_uninit / write_state write all `len`).
    let sample = unsafe { sample.assume_init() };
    let bytes = sample.payload().to_vec();
    match sample.send() {
        Ok(_) => Ok(Some(bytes)),
        Err(_) if stop.is_set() => Ok(None),
        Err(e) => bail!("step record not delivered (learner stalled beyond runtime.give_up_secs?): {e:?}"),
    }
}

fn send_report(
    out: &pednav_runtime::ipc::EpisodeSender,
    header: EpisodeHeader,
    points: &[EpisodePoint],
    stop: &StopFlag,
) -> Result<bool> {
    if out.subscribers() == 0 && !out.wait_for_subscriber(stop, Duration::from_secs(3600)) {
        return Ok(false);
    }
    let mut sample =
        out.publisher.loan_slice_uninit(points.len()).map_err(|e| anyhow::anyhow!("loan episode report: {e:?}"))?;
    *sample.user_header_mut() = header;
    let sample = sample.write_from_slice(points);
    match sample.send() {
        Ok(_) => Ok(true),
        Err(_) if stop.is_set() => Ok(false),
        Err(e) => bail!("episode report not delivered: {e:?}"),
    }
}

/// Ask the curriculum service for a task; retries while it is not (yet) there.
fn request_task(
    client: &pednav_runtime::ipc::TaskClient,
    actor: u32,
    env: u32,
    timeout: Duration,
    stop: &StopFlag,
) -> Result<Option<pednav_runtime::messages::TaskResponse>> {
    let start = Instant::now();
    while !stop.is_set() {
        if start.elapsed() > timeout {
            bail!("no task from the curriculum service within runtime.task_timeout_secs = {timeout:?}");
        }
        let pending =
            client.send_copy(TaskRequest { actor, env }).map_err(|e| anyhow::anyhow!("task request: {e:?}"))?;
        let asked = Instant::now();
        while asked.elapsed() < Duration::from_secs(1) && !stop.is_set() {
            if let Some(response) = pending.receive().map_err(|e| anyhow::anyhow!("task response: {e:?}"))? {
                return Ok(Some(*response.payload()));
            }
            std::thread::sleep(Duration::from_micros(200));
        }
    }
    Ok(None)
}

fn stats_json(
    actor: u32,
    incarnation: u32,
    c: &Counters,
    versions: &std::collections::BTreeSet<u64>,
    status: &str,
) -> serde_json::Value {
    serde_json::json!({
        "actor": actor,
        "incarnation": incarnation,
        "pid": std::process::id(),
        "status": status,
        "steps_sent": c.steps,
        "checksum": c.checksum,
        "episodes": c.episodes,
        "policy_versions_used": versions.len(),
        "first_policy_version": versions.first(),
        "last_policy_version": versions.last(),
        "tasks_received": c.tasks,
        "last_task_id": c.last_task_id,
    })
}

fn finish(
    dir: &RunDir,
    name: &str,
    actor: u32,
    incarnation: u32,
    c: &Counters,
    versions: &std::collections::BTreeSet<u64>,
    status: &str,
) -> Result<()> {
    dir.write_stats(&format!("{name}.{incarnation}"), &stats_json(actor, incarnation, c, versions, status))?;
    tracing::info!(steps = c.steps, episodes = c.episodes, status, "actor finished");
    Ok(())
}
