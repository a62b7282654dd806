//! The learner process as a struct: [`LearnerProcess::open`] builds (or resumes)
//! the learner and its channels, [`LearnerProcess::run`] loops over
//! [`LearnerProcess::step`] — take step records, update when the replay ratio
//! allows, publish, checkpoint, log — until stopped, then drains and writes the
//! final checkpoint.
//!
//! Invariant: every checkpoint holds the DSAC state, the limiter's counters and
//! this process's [`ProcessState`] written together, so a resume continues the
//! same batch sequence and step count.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use candle_core::Device;
use pednav_learner::{
    Dsac, DualReplay, Frame, FrameKind, RateLimiter, Step, UpdateStats, checkpoint_exists, load_checkpoint_or_previous,
    save_checkpoint, warm_start,
};
use pednav_runtime::columns::learner as col;
use pednav_runtime::ipc::{
    AckPublisher, HeartbeatPublisher, HeartbeatSubscriber, StepSample, StepSubscriber, receive_step_round,
};
use pednav_runtime::messages::{Faults, Heartbeat, ProcessKind, StepFlags, StepHeader, state_payload};
use pednav_runtime::stats::{LearnerStats, LimiterCounters, ProcessStatus};
use pednav_runtime::weights::WeightsBroadcaster;
use pednav_runtime::write_health::WriteHealth;
use pednav_runtime::{Ipc, Metrics, RunConfig, RunDir, StopFlag};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::intake::{Admit, StepIntake};

/// What the learner process adds to a DSAC checkpoint (`extra` in its state file), so
/// that a resume continues the same batch sequence and step count.
#[derive(serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ProcessState {
    /// The batch sampler's RNG.
    sample_rng: ChaCha8Rng,
    /// Step records received over the whole run (all incarnations).
    received_total: u64,
}

struct Learner {
    dsac: Dsac,
    limiter: RateLimiter,
    replay: DualReplay,
    sample_rng: ChaCha8Rng,
    received: u64,
    intake: StepIntake,
    kind: FrameKind,
    /// Bytes of one record's observation (`RunConfig::observation_bytes`).
    record_bytes: usize,
    refill_until: u64,
    resumed_from: Option<u64>,
}

impl Learner {
    /// Take one step record into the replay. A record of the wrong size (an actor
    /// built from another config) is logged and dropped, never stored.
    fn take(&mut self, h: &StepHeader, bytes: &[u8]) -> Result<()> {
        let expected = self.record_bytes;
        if bytes.len() != expected {
            tracing::error!(actor = h.actor, got = bytes.len(), expected, "step record of the wrong size dropped");
            return Ok(());
        }
        match self.intake.admit(h, bytes, Instant::now()) {
            Admit::Take => {}
            Admit::TakeAfterJump => {
                // No transition may span the jump.
                let cut = self.replay.cut_streams(|s| h.same_actor_incarnation(s));
                tracing::info!(actor = h.actor, open_episodes_cut = cut, "open episodes of the stream cut");
            }
            Admit::Drop => return Ok(()),
        }
        self.received += 1;
        let state: Vec<f32>;
        let frame = match self.kind {
            FrameKind::Pixels { .. } => Frame::Pixels(bytes),
            FrameKind::State { .. } => {
                state = state_payload::decode_state(bytes);
                Frame::State(&state)
            }
        };
        self.replay.push(&Step {
            stream: h.stream(),
            first: h.has(StepFlags::FIRST),
            frame,
            action: h.action,
            reward: h.reward,
            terminal: h.has(StepFlags::TERMINAL),
            state_target: Some(&h.state[..self.replay.state_target_dim().min(h.state.len())]),
        })?;
        if self.received > self.refill_until {
            self.limiter.inserted(1);
        }
        Ok(())
    }

    /// Receive one fair round of step records ([`receive_step_round`]) and take
    /// them all into the replay; returns how many there were (0: nothing waiting).
    fn take_round(&mut self, steps_in: &StepSubscriber, round: &mut Vec<StepSample>) -> Result<u64> {
        receive_step_round(steps_in, round)?;
        let n = round.len() as u64;
        for sample in round.drain(..) {
            self.take(sample.user_header(), sample.payload())?;
        }
        Ok(n)
    }

    fn refilling(&self) -> bool {
        self.received <= self.refill_until
    }
}

/// Sums over one metrics interval.
struct Interval {
    started: Instant,
    received: u64,
    updates: u64,
    stats: UpdateStats,
    n: u32,
    t_update: f64,
    t_sample: f64,
}

impl Interval {
    fn new(received: u64, updates: u64) -> Interval {
        Interval {
            started: Instant::now(),
            received,
            updates,
            stats: UpdateStats::default(),
            n: 0,
            t_update: 0.0,
            t_sample: 0.0,
        }
    }

    fn add(&mut self, s: &UpdateStats) {
        self.n += 1;
        let sum = &mut self.stats;
        for (acc, v) in [
            (&mut sum.critic_loss, s.critic_loss),
            (&mut sum.policy_loss, s.policy_loss),
            (&mut sum.fraction_loss, s.fraction_loss),
            (&mut sum.alpha_loss, s.alpha_loss),
            (&mut sum.alpha, s.alpha),
            (&mut sum.entropy, s.entropy),
            (&mut sum.q_mean, s.q_mean),
            (&mut sum.state_loss, s.state_loss),
            (&mut sum.contrast_loss, s.contrast_loss),
        ] {
            *acc += v;
        }
    }

    /// Mean over the interval's updates; `None` without updates (the CSV cell stays
    /// empty: no placeholder zeros).
    fn mean(&self, sum: f64) -> Option<f64> {
        (self.n > 0).then(|| sum / self.n as f64)
    }
}

/// Where a learner process starts: the run's own checkpoint (a resume: weights,
/// moments, counters, the sampler's RNG), `dsac.init_from` (a warm start: networks
/// only) or a fresh initialisation, in that order.
struct StartingPoint {
    limiter: RateLimiter,
    sample_rng: ChaCha8Rng,
    /// Step records received over the run before this process.
    received_total: u64,
    /// The update count of the checkpoint resumed from.
    resumed_from: Option<u64>,
}

impl StartingPoint {
    /// Load `dsac` from where the run in `dir` starts and return the rest of that state.
    fn of(dir: &RunDir, cfg: &RunConfig, dsac: &mut Dsac) -> Result<StartingPoint> {
        let mut limiter = RateLimiter::new(cfg.dsac.warmup, cfg.dsac.train_interval, cfg.dsac.rate_slack);
        let mut sample_rng = ChaCha8Rng::seed_from_u64(cfg.seed);
        sample_rng.set_stream(pednav_config::rng::stream::BATCH_SAMPLER);
        let mut resumed_from = None;
        let mut received_total = 0u64;
        let ckpt = dir.learner_checkpoint();
        if checkpoint_exists(&ckpt) {
            let (meta, loaded) = load_checkpoint_or_previous(&ckpt, dsac)
                .with_context(|| format!("resuming from {}", ckpt.display()))?;
            if let Some(l) = meta.limiter {
                limiter = l;
            }
            let process: ProcessState = serde_json::from_value(meta.extra.clone()).with_context(|| {
                format!(
                    "{}: the learner process's state (`extra` in state.json: the batch sampler's RNG and the \
                         steps received) is missing or damaged",
                    loaded.display()
                )
            })?;
            sample_rng = process.sample_rng;
            received_total = process.received_total;
            resumed_from = Some(dsac.updates);
            tracing::info!(
                updates = dsac.updates,
                inserted = limiter.inserted,
                from = %loaded.display(),
                "resumed from checkpoint"
            );
        } else if let Some(from) = &cfg.dsac.init_from {
            let meta = warm_start(from, dsac)
                .with_context(|| format!("dsac.init_from: warm start from {}", from.display()))?;
            tracing::info!(
                from = %from.display(),
                updates_there = meta.updates,
                "warm start: online networks and temperature loaded, targets copied from them"
            );
        }
        Ok(StartingPoint { limiter, sample_rng, received_total, resumed_from })
    }
}

/// The learner process: the learner's state, its channels and its bookkeeping.
pub struct LearnerProcess {
    cfg: RunConfig,
    dir: RunDir,
    stop: StopFlag,
    learner: Learner,
    /// Step records received over the whole run (all incarnations of this process).
    received_total: u64,
    // Kept alive for the ports below.
    _ipc: Ipc,
    steps_in: StepSubscriber,
    acks_out: AckPublisher,
    heartbeats_in: HeartbeatSubscriber,
    weights_out: WeightsBroadcaster,
    heartbeat: HeartbeatPublisher,
    metrics: Metrics,
    round: Vec<StepSample>,
    started: Instant,
    last_checkpoint: Instant,
    interval: Interval,
    /// Set once `runtime.max_updates` or `max_env_steps` is reached.
    budget_spent: Option<ProcessStatus>,
    /// Whether the done marker (for the launcher) is written.
    marker_written: bool,
    /// Writes that failed (checkpoint, metrics, stats) and are retried.
    health: WriteHealth,
    /// The update count of the newest checkpoint on disk.
    last_good: Option<u64>,
}

impl LearnerProcess {
    /// Build the learner for the run in `dir` on `device` — resumed from the run's
    /// checkpoint when it has one — open its channels and publish the first weights.
    pub fn open(dir: RunDir, cfg: RunConfig, device: &Device, stop: StopFlag) -> Result<LearnerProcess> {
        let mut dsac = Dsac::new(&cfg.dsac, &cfg.nets, device, cfg.seed)?;
        let StartingPoint { limiter, sample_rng, received_total, resumed_from } =
            StartingPoint::of(&dir, &cfg, &mut dsac)?;
        let kind = cfg.frame_kind();
        let mut replay = DualReplay::new(&cfg.replay, kind, cfg.nets.history, device)?
            .with_n_step(cfg.dsac.n_step, cfg.dsac.gamma)?;
        if cfg.dsac.builds_state_head() {
            replay = replay.with_state_targets(cfg.nets.state_dim)?;
        }
        let l = Learner {
            dsac,
            limiter,
            replay,
            sample_rng,
            received: 0,
            intake: StepIntake::new(std::process::id()),
            kind,
            record_bytes: cfg.observation_bytes(),
            refill_until: if resumed_from.is_some() { cfg.dsac.warmup } else { 0 },
            resumed_from,
        };
        let ipc = dir.join_ipc(&cfg, "learner", stop.clone())?;
        let steps_in = ipc.step_subscriber()?;
        let acks_out = ipc.ack_publisher()?;
        let heartbeats_in = ipc.heartbeat_subscriber()?;
        let weights_out = WeightsBroadcaster::open(&ipc, &l.dsac.nets)?;
        let heartbeat = ipc.heartbeat_publisher()?;
        let metrics = Metrics::open(&dir.metrics(), &dir.tb(), "learner")?;
        weights_out.publish(&l.dsac.nets, l.dsac.updates)?;
        tracing::info!(
            weights = pednav_runtime::weights::acting_len(&l.dsac.nets),
            warmup = cfg.dsac.warmup,
            batch = cfg.dsac.batch_size,
            "learner ready"
        );
        let interval = Interval::new(0, l.dsac.updates);
        let cfg_metrics_secs = cfg.runtime.metrics_every_secs.max(1.0);
        let resumed_from = l.resumed_from;
        Ok(LearnerProcess {
            cfg,
            dir,
            stop,
            learner: l,
            received_total,
            _ipc: ipc,
            steps_in,
            acks_out,
            heartbeats_in,
            weights_out,
            heartbeat,
            metrics,
            round: Vec::new(),
            started: Instant::now(),
            last_checkpoint: Instant::now(),
            interval,
            budget_spent: None,
            marker_written: false,
            health: WriteHealth::new(Duration::from_secs_f64(cfg_metrics_secs)),
            last_good: resumed_from,
        })
    }

    /// Step until stopped, then drain what the actors already sent (the launcher
    /// stops them first) and write the final checkpoint.
    pub fn run(mut self) -> Result<()> {
        while !self.stop.is_set() {
            self.step()?;
        }
        let drain_until = Instant::now() + Duration::from_millis(500);
        while Instant::now() < drain_until {
            if self.take_round()? == 0 {
                std::thread::sleep(Duration::from_millis(10));
            }
        }
        // The last (partial) interval gets its metrics row too: a run shorter than
        // `metrics_every_secs` still leaves a learner log.
        self.log_interval()?;
        self.final_save()?;
        let status = self.budget_spent.unwrap_or(ProcessStatus::Stopped);
        self.write_stats(status);
        tracing::info!(
            updates = self.learner.dsac.updates,
            received = self.received_total,
            status = status.as_str(),
            "final checkpoint written"
        );
        Ok(())
    }

    /// One pass: inserts as far as the replay ratio allows (always while refilling or
    /// once the budget is spent), one update when the data allows it, the metrics
    /// interval, the budget.
    pub fn step(&mut self) -> Result<()> {
        // One round takes at most STEP_ROUND_PER_ACTOR records from every actor, so
        // no actor starves while another's queue is always full.
        let mut took = 0;
        while took < 512
            && (self.learner.limiter.can_insert() || self.learner.refilling() || self.budget_spent.is_some())
        {
            let n = self.take_round()?;
            if n == 0 {
                break;
            }
            took += n;
        }
        if self.budget_spent.is_none() && !self.learner.refilling() && self.learner.limiter.can_update() {
            self.update()?;
        } else if took == 0 {
            std::thread::sleep(Duration::from_micros(200));
        }
        if self.interval.started.elapsed().as_secs_f64() >= self.cfg.runtime.metrics_every_secs {
            self.log_interval()?;
        }
        if self.budget_spent.is_none() {
            self.check_budget();
        } else if !self.marker_written {
            self.write_done_marker();
        }
        Ok(())
    }

    /// One fair round of step records into the replay, then what the actors announced
    /// and the acknowledgements (this learner is reading: see [`StepIntake::announced`]).
    fn take_round(&mut self) -> Result<u64> {
        let n = self.learner.take_round(&self.steps_in, &mut self.round)?;
        self.received_total += n;
        let now = Instant::now();
        loop {
            match self.heartbeats_in.receive() {
                Ok(Some(h)) => self.learner.intake.announced(h.payload(), now),
                Ok(None) => break,
                Err(e) => anyhow::bail!("heartbeat subscriber: {e:?}"),
            }
        }
        if let Some(table) = self.learner.intake.due_table(now) {
            self.acks_out.send_copy(table).map_err(|e| anyhow::anyhow!("ack table: {e:?}"))?;
        }
        Ok(n)
    }

    /// One DSAC update, then the weights broadcast and checkpoint when due.
    fn update(&mut self) -> Result<()> {
        let c = &self.cfg;
        let t0 = Instant::now();
        let batch =
            self.learner.replay.sample_shifted(c.dsac.batch_size, c.dsac.random_shift, &mut self.learner.sample_rng)?;
        self.interval.t_sample += t0.elapsed().as_secs_f64();
        let t0 = Instant::now();
        let stats = self.learner.dsac.update(&batch)?;
        self.interval.t_update += t0.elapsed().as_secs_f64();
        self.learner.limiter.updated();
        self.interval.add(&stats);
        let updates = self.learner.dsac.updates;
        if updates.is_multiple_of(c.runtime.weights_every) {
            self.weights_out.publish(&self.learner.dsac.nets, updates)?;
        }
        if updates.is_multiple_of(c.runtime.checkpoint_every_updates)
            || self.last_checkpoint.elapsed().as_secs_f64() > c.runtime.checkpoint_every_secs
        {
            self.try_save();
            self.last_checkpoint = Instant::now();
        }
        Ok(())
    }

    fn save(&mut self) -> std::result::Result<(), pednav_learner::LearnerError> {
        let l = &mut self.learner;
        let extra = serde_json::to_value(ProcessState {
            sample_rng: l.sample_rng.clone(),
            received_total: self.received_total,
        })
        .expect("the process state serialises");
        save_checkpoint(&self.dir.learner_checkpoint(), &mut l.dsac, Some(l.limiter), extra)?;
        self.last_good = Some(self.learner.dsac.updates);
        Ok(())
    }

    /// A periodic checkpoint: a failure (a full disk) is logged once per interval and
    /// shown on the progress line; training goes on and the next interval retries.
    /// The checkpoint on disk stays the last good one (both of its generations).
    fn try_save(&mut self) {
        match self.save() {
            Ok(()) => self.health.succeeded("checkpoint"),
            Err(e) => {
                let last = self.last_good.map_or("none yet".into(), |u| format!("update {u}"));
                self.health.failed(
                    "checkpoint",
                    Faults::CHECKPOINT,
                    e.is_disk_full(),
                    &e.to_string(),
                    &format!("training goes on; last good checkpoint: {last}; retried at the next interval"),
                );
            }
        }
    }

    /// The checkpoint at stop ([`pednav_runtime::generations::final_save`]); an error
    /// when no attempt succeeds, so the launcher shows the cause.
    fn final_save(&mut self) -> Result<()> {
        pednav_runtime::generations::final_save("final checkpoint", || self.save()).map_err(|e| {
            let last = self.last_good.map_or("none".into(), |u| format!("update {u}"));
            anyhow::Error::new(e)
                .context(format!("the final checkpoint could not be written (last good on disk: {last})"))
        })
    }

    /// Write the learner's live stats; a failure is logged once per interval.
    fn write_stats(&mut self, status: ProcessStatus) {
        match write_stats(&self.dir, &self.learner, self.received_total, status) {
            Ok(()) => self.health.succeeded("stats"),
            Err(e) => self.health.failed(
                "stats",
                Faults::METRICS,
                e.downcast_ref::<pednav_runtime::RuntimeError>().is_some_and(|r| r.is_disk_full()),
                &format!("{e:#}"),
                "written again at the next interval",
            ),
        }
    }

    /// Tell the launcher the budget is spent; retried at every step until it is written.
    fn write_done_marker(&mut self) {
        let reason = self.budget_spent.map_or("budget", ProcessStatus::as_str);
        match std::fs::write(self.dir.done_marker(), reason) {
            Ok(()) => {
                self.marker_written = true;
                self.health.succeeded("done marker");
            }
            Err(e) => self.health.failed(
                "done marker",
                Faults::METRICS,
                pednav_runtime::generations::is_disk_full(&e),
                &format!("{}: {e}", self.dir.done_marker().display()),
                "the run goes on until it is written",
            ),
        }
    }

    /// Metrics row, log line, heartbeat and live stats of the interval just ended.
    fn log_interval(&mut self) -> Result<()> {
        let iv = std::mem::replace(&mut self.interval, Interval::new(self.learner.received, self.learner.dsac.updates));
        let secs = iv.started.elapsed().as_secs_f64();
        let l = &self.learner;
        let ups = l.dsac.updates - iv.updates;
        let steps = l.received - iv.received;
        let per_update = |t: f64| (ups > 0).then(|| 1e3 * t / ups as f64);
        let s = &iv.stats;
        let mut row = vec![
            (col::ELAPSED_S, Some(self.started.elapsed().as_secs_f64())),
            (col::UPDATES, Some(l.dsac.updates as f64)),
            (col::ENV_STEPS_PER_S, Some(steps as f64 / secs)),
            (col::UPDATES_PER_S, Some(ups as f64 / secs)),
            (col::UPDATE_MS, per_update(iv.t_update)),
            (col::SAMPLE_MS, per_update(iv.t_sample)),
            (col::REPLAY_TERMINAL, Some(l.replay.terminal_len() as f64)),
            (col::REPLAY_NONTERMINAL, Some(l.replay.nonterminal_len() as f64)),
            (col::CRITIC_LOSS, iv.mean(s.critic_loss)),
            (col::POLICY_LOSS, iv.mean(s.policy_loss)),
            (col::FRACTION_LOSS, iv.mean(s.fraction_loss)),
            (col::ALPHA_LOSS, iv.mean(s.alpha_loss)),
            (col::ALPHA, iv.mean(s.alpha)),
            (col::ENTROPY, iv.mean(s.entropy)),
            (col::Q_MEAN, iv.mean(s.q_mean)),
            (col::SKIPPED_UPDATES, Some(l.dsac.skipped as f64)),
        ];
        if self.cfg.dsac.builds_state_head() {
            row.push((col::STATE_LOSS, iv.mean(s.state_loss)));
        }
        if self.cfg.dsac.builds_contrast_head() {
            row.push((col::CONTRAST_LOSS, iv.mean(s.contrast_loss)));
        }
        self.metrics.log_optional(self.received_total, &row)?;
        self.health.metrics(&self.metrics);
        tracing::info!(
            received = self.received_total,
            updates = l.dsac.updates,
            steps_per_s = format!("{:.1}", steps as f64 / secs),
            update_ms = format!("{:.1}", per_update(iv.t_update).unwrap_or(0.0)),
            refilling = l.refilling(),
            terminal = l.replay.terminal_len(),
            "learner"
        );
        let _ = self.heartbeat.send_copy(Heartbeat {
            kind: ProcessKind::LEARNER,
            pid: std::process::id(),
            env_steps: self.received_total,
            updates: l.dsac.updates,
            version: l.dsac.updates - l.dsac.updates % self.cfg.runtime.weights_every,
            rate: (steps as f64 / secs) as f32,
            last_good: self.last_good.unwrap_or(0),
            faults: self.health.faults(),
            ..Heartbeat::default()
        });
        self.write_stats(ProcessStatus::Running);
        Ok(())
    }

    /// When `runtime.max_updates` or `max_env_steps` is reached: checkpoint, and ask
    /// the launcher to stop the run (the done marker); keep receiving, without
    /// updates, until it stops the actors and then this process.
    fn check_budget(&mut self) {
        let r = &self.cfg.runtime;
        self.budget_spent = if r.max_updates > 0 && self.learner.dsac.updates >= r.max_updates {
            Some(ProcessStatus::MaxUpdates)
        } else if r.max_env_steps > 0 && self.received_total >= r.max_env_steps {
            Some(ProcessStatus::MaxEnvSteps)
        } else {
            None
        };
        if let Some(reason) = self.budget_spent {
            tracing::info!(
                reason = reason.as_str(),
                updates = self.learner.dsac.updates,
                "budget spent; waiting for the launcher to stop the run"
            );
            self.try_save();
            self.write_done_marker();
        }
    }
}

fn write_stats(dir: &RunDir, l: &Learner, received_total: u64, status: ProcessStatus) -> Result<()> {
    let streams = l.intake.tallies();
    let stats = LearnerStats {
        status,
        pid: std::process::id(),
        updates: l.dsac.updates,
        resumed_from_update: l.resumed_from,
        received_this_process: l.received,
        received_total,
        limiter: LimiterCounters {
            warmup: l.limiter.warmup,
            interval: l.limiter.interval,
            slack: l.limiter.slack,
            inserted: l.limiter.inserted,
            updates: l.limiter.updates,
        },
        streams,
    };
    dir.write_stats("learner", &stats)?;
    Ok(())
}
