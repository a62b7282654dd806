//! `pednav-learner` — the learner process of a pednav run.
//!
//! Receives every step record (the stream is lossless), rebuilds N_h-frame
//! observations per (actor, env, incarnation) inside the [`DualReplay`] (frames
//! stored once), runs DSAC updates at the configured replay ratio — the
//! [`RateLimiter`] holds back updates until there is data and holds back
//! inserts (so the actors wait on their full send buffers) when updates lag —
//! publishes the acting weights every `runtime.weights_every` updates, writes
//! checkpoints and metrics, and on Ctrl-C/SIGTERM drains what was sent, writes
//! a final checkpoint and exits.
//!
//! Resume: a checkpoint in the run directory restores networks, optimisers, α,
//! RNGs and the limiter's counters. The replay itself is not checkpointed (up to
//! 3e6 frames); a resumed learner refills `dsac.warmup` steps — not counted
//! towards the replay ratio — before it updates again.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Parser;
use pednav_learner::{Dsac, DualReplay, Frame, FrameKind, RateLimiter, Step, load_checkpoint, save_checkpoint};
use pednav_nets::init_cpu_runtime;
use pednav_runtime::ipc::{StepSample, StepSubscriber, receive_step_round};
use pednav_runtime::messages::{Heartbeat, StepHeader, WeightsHeader, process_kind, step_flags};
use pednav_runtime::{Ipc, Metrics, RunDir, StopFlag, run_prefix, weights};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

#[derive(Parser)]
#[command(
    version,
    about = "pednav learner: dual replay + DSAC updates at a fixed replay ratio, weight broadcasts, checkpoints"
)]
struct Cli {
    /// The run directory (created by `pednav-run`).
    #[arg(long)]
    run_dir: PathBuf,
    /// Compute threads (default: all cores).
    #[arg(long)]
    threads: Option<usize>,
    /// Where to train: cpu, cuda or cuda:N (default: the config's `runtime.device`).
    #[arg(long)]
    device: Option<pednav_nets::DeviceSpec>,
}

/// Records received from one actor incarnation (for the integration test's
/// count-and-checksum comparison).
#[derive(Default, Clone, Copy, serde::Serialize)]
struct StreamTally {
    records: u64,
    checksum: u32,
    last_seq: Option<u64>,
    gaps: u64,
}

struct Learner {
    dsac: Dsac,
    limiter: RateLimiter,
    replay: DualReplay,
    sample_rng: ChaCha8Rng,
    received: u64,
    tallies: BTreeMap<(u32, u32), StreamTally>,
    kind: FrameKind,
    refill_until: u64,
    resumed_from: Option<u64>,
}

impl Learner {
    /// Take one step record into the replay. A record of the wrong size (an actor
    /// built from another config) is logged and dropped, never stored.
    fn take(&mut self, h: &StepHeader, bytes: &[u8]) -> Result<()> {
        let expected = match self.kind {
            FrameKind::Pixels { size } => size * size,
            FrameKind::State { dim } => dim * 4,
        };
        if bytes.len() != expected {
            tracing::error!(actor = h.actor, got = bytes.len(), expected, "step record of the wrong size dropped");
            return Ok(());
        }
        let tally = self.tallies.entry((h.actor, h.incarnation)).or_default();
        if let Some(last) = tally.last_seq
            && h.seq != last + 1
        {
            tally.gaps += 1;
            tracing::error!(actor = h.actor, seq = h.seq, last, "gap in the step stream");
        }
        tally.last_seq = Some(h.seq);
        tally.records += 1;
        tally.checksum = tally.checksum.wrapping_add(h.record_crc(bytes));
        self.received += 1;
        let state: Vec<f32>;
        let frame = match self.kind {
            FrameKind::Pixels { .. } => Frame::Pixels(bytes),
            FrameKind::State { .. } => {
                state = bytes.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
                Frame::State(&state)
            }
        };
        self.replay.push(&Step {
            stream: h.stream(),
            first: h.has(step_flags::FIRST),
            frame,
            action: h.action,
            reward: h.reward,
            terminal: h.has(step_flags::TERMINAL),
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

fn main() -> Result<()> {
    pednav_runtime::init_logging();
    let cli = Cli::parse();
    let threads = init_cpu_runtime(cli.threads);
    let stop = StopFlag::install();
    let dir = RunDir::new(&cli.run_dir);
    let cfg = dir.load_config()?;
    let device_spec = cli.device.unwrap_or(cfg.runtime.device);
    let device = device_spec.open()?;
    tracing::info!(device = %device_spec, "learner device");
    let mut dsac = Dsac::new(&cfg.dsac, &cfg.nets, &device, cfg.seed)?;
    let mut limiter = RateLimiter::new(cfg.dsac.warmup, cfg.dsac.train_interval, cfg.dsac.rate_slack);
    let mut sample_rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    sample_rng.set_stream(7);
    let mut resumed_from = None;
    let mut received_total = 0u64;
    let ckpt = dir.learner_checkpoint();
    if ckpt.join("state.json").exists() {
        let meta = load_checkpoint(&ckpt, &mut dsac).with_context(|| format!("resuming from {}", ckpt.display()))?;
        if let Some(l) = meta.limiter {
            limiter = l;
        }
        if let Some(rng) = meta.extra.get("sample_rng").and_then(|v| serde_json::from_value(v.clone()).ok()) {
            sample_rng = rng;
        }
        received_total = meta.extra.get("received_total").and_then(|v| v.as_u64()).unwrap_or(0);
        resumed_from = Some(dsac.updates);
        tracing::info!(updates = dsac.updates, inserted = limiter.inserted, "resumed from checkpoint");
    }
    let kind = cfg.frame_kind();
    let replay = DualReplay::new(&cfg.replay, kind, cfg.nets.history, &device)?;
    let mut l = Learner {
        dsac,
        limiter,
        replay,
        sample_rng,
        received: 0,
        tallies: BTreeMap::new(),
        kind,
        refill_until: if resumed_from.is_some() { cfg.dsac.warmup } else { 0 },
        resumed_from,
    };

    let ipc = Ipc::new(
        &run_prefix(&cli.run_dir),
        "learner",
        cfg.runtime.step_buffer,
        Duration::from_secs_f64(cfg.runtime.give_up_secs),
        stop.clone(),
    )?;
    let steps_in = ipc.step_subscriber()?;
    let n_weights = weights::acting_len(&l.dsac.nets);
    let weights_out = ipc.weights_publisher(n_weights)?;
    let heartbeat = ipc.heartbeat_publisher()?;
    let mut metrics = Metrics::open(&dir.metrics(), &dir.tb(), "learner")?;
    let publish = |dsac: &Dsac| -> Result<()> {
        let flat = weights::flatten(&dsac.nets)?;
        let mut sample =
            weights_out.loan_slice_uninit(flat.len()).map_err(|e| anyhow::anyhow!("loan weights: {e:?}"))?;
        *sample.user_header_mut() =
            WeightsHeader { version: dsac.updates, len: flat.len() as u64, published_ns: pednav_runtime::now_ns() };
        sample.write_from_slice(&flat).send().map_err(|e| anyhow::anyhow!("send weights: {e:?}"))?;
        Ok(())
    };
    publish(&l.dsac)?;
    tracing::info!(
        threads,
        weights = n_weights,
        warmup = cfg.dsac.warmup,
        batch = cfg.dsac.batch_size,
        "learner ready"
    );

    let started = Instant::now();
    let mut last_ckpt = Instant::now();
    let mut last_log = Instant::now();
    let (mut last_received, mut last_updates) = (0u64, l.dsac.updates);
    let mut stats_sum = pednav_learner::UpdateStats::default();
    let mut stats_n = 0u32;
    let (mut t_update, mut t_sample) = (0.0f64, 0.0f64);
    let log_every = Duration::from_secs_f64(cfg.runtime.metrics_every_secs);
    let mut budget_spent: Option<&str> = None;
    let save = |l: &mut Learner, received_total: u64| -> Result<()> {
        let extra = serde_json::json!({
            "sample_rng": l.sample_rng,
            "received_total": received_total,
        });
        save_checkpoint(&ckpt, &mut l.dsac, Some(l.limiter), extra)?;
        Ok(())
    };
    let mut round = Vec::new();
    loop {
        if stop.is_set() {
            break;
        }
        // Inserts, as far as the replay ratio allows (always while refilling).
        // One round takes at most STEP_ROUND_PER_ACTOR records from every actor, so
        // no actor starves while another's queue is always full.
        let mut took = 0;
        while took < 512 && (l.limiter.can_insert() || l.refilling() || budget_spent.is_some()) {
            let n = l.take_round(&steps_in, &mut round)?;
            if n == 0 {
                break;
            }
            received_total += n;
            took += n;
        }
        // One update when the data allows it.
        if budget_spent.is_none() && !l.refilling() && l.limiter.can_update() {
            let t0 = Instant::now();
            let batch = l.replay.sample_shifted(cfg.dsac.batch_size, cfg.dsac.random_shift, &mut l.sample_rng)?;
            t_sample += t0.elapsed().as_secs_f64();
            let t0 = Instant::now();
            let s = l.dsac.update(&batch)?;
            t_update += t0.elapsed().as_secs_f64();
            l.limiter.updated();
            stats_n += 1;
            for (acc, v) in [
                (&mut stats_sum.critic_loss, s.critic_loss),
                (&mut stats_sum.policy_loss, s.policy_loss),
                (&mut stats_sum.fraction_loss, s.fraction_loss),
                (&mut stats_sum.alpha_loss, s.alpha_loss),
                (&mut stats_sum.alpha, s.alpha),
                (&mut stats_sum.entropy, s.entropy),
                (&mut stats_sum.q_mean, s.q_mean),
            ] {
                *acc += v;
            }
            if l.dsac.updates.is_multiple_of(cfg.runtime.weights_every) {
                publish(&l.dsac)?;
            }
            if l.dsac.updates.is_multiple_of(cfg.runtime.checkpoint_every_updates)
                || last_ckpt.elapsed().as_secs_f64() > cfg.runtime.checkpoint_every_secs
            {
                save(&mut l, received_total)?;
                last_ckpt = Instant::now();
            }
        } else if took == 0 {
            std::thread::sleep(Duration::from_micros(200));
        }
        if last_log.elapsed() >= log_every {
            let secs = last_log.elapsed().as_secs_f64();
            last_log = Instant::now();
            let n = stats_n.max(1) as f64;
            let ups = l.dsac.updates - last_updates;
            let steps = l.received - last_received;
            (last_updates, last_received) = (l.dsac.updates, l.received);
            metrics.log(
                received_total,
                &[
                    ("elapsed_s", started.elapsed().as_secs_f64()),
                    ("updates", l.dsac.updates as f64),
                    ("env_steps_per_s", steps as f64 / secs),
                    ("updates_per_s", ups as f64 / secs),
                    ("update_ms", 1e3 * t_update / ups.max(1) as f64),
                    ("sample_ms", 1e3 * t_sample / ups.max(1) as f64),
                    ("replay_terminal", l.replay.terminal_len() as f64),
                    ("replay_nonterminal", l.replay.nonterminal_len() as f64),
                    ("critic_loss", stats_sum.critic_loss / n),
                    ("policy_loss", stats_sum.policy_loss / n),
                    ("fraction_loss", stats_sum.fraction_loss / n),
                    ("alpha_loss", stats_sum.alpha_loss / n),
                    ("alpha", stats_sum.alpha / n),
                    ("entropy", stats_sum.entropy / n),
                    ("q_mean", stats_sum.q_mean / n),
                    ("skipped_updates", l.dsac.skipped as f64),
                ],
            )?;
            tracing::info!(
                received = received_total,
                updates = l.dsac.updates,
                steps_per_s = format!("{:.1}", steps as f64 / secs),
                update_ms = format!("{:.1}", 1e3 * t_update / ups.max(1) as f64),
                refilling = l.refilling(),
                terminal = l.replay.terminal_len(),
                "learner"
            );
            (stats_sum, stats_n, t_update, t_sample) = (Default::default(), 0, 0.0, 0.0);
            let _ = heartbeat.send_copy(Heartbeat {
                kind: process_kind::LEARNER,
                pid: std::process::id(),
                steps: received_total,
                count: l.dsac.updates,
                version: l.dsac.updates - l.dsac.updates % cfg.runtime.weights_every,
                rate: (steps as f64 / secs) as f32,
                ..Heartbeat::default()
            });
            write_stats(&dir, &l, received_total, "running")?;
        }
        if budget_spent.is_none() {
            if cfg.runtime.max_updates > 0 && l.dsac.updates >= cfg.runtime.max_updates {
                budget_spent = Some("max_updates");
            } else if cfg.runtime.max_env_steps > 0 && received_total >= cfg.runtime.max_env_steps {
                budget_spent = Some("max_env_steps");
            }
            if let Some(reason) = budget_spent {
                // Ask the launcher to stop the run; keep receiving (no more updates)
                // until it stops the actors and then this process.
                tracing::info!(
                    reason,
                    updates = l.dsac.updates,
                    "budget spent; waiting for the launcher to stop the run"
                );
                save(&mut l, received_total)?;
                std::fs::write(dir.root().join("DONE"), reason)?;
            }
        }
    }
    // Drain what the actors already sent (they are stopped first by the launcher).
    let drain_until = Instant::now() + Duration::from_millis(500);
    while Instant::now() < drain_until {
        match l.take_round(&steps_in, &mut round)? {
            0 => std::thread::sleep(Duration::from_millis(10)),
            n => received_total += n,
        }
    }
    save(&mut l, received_total)?;
    let status = budget_spent.unwrap_or("stopped");
    write_stats(&dir, &l, received_total, status)?;
    tracing::info!(updates = l.dsac.updates, received = received_total, status, "final checkpoint written");
    Ok(())
}

fn write_stats(dir: &RunDir, l: &Learner, received_total: u64, status: &str) -> Result<()> {
    let tallies: Vec<_> = l
        .tallies
        .iter()
        .map(|(&(actor, incarnation), t)| {
            serde_json::json!({"actor": actor, "incarnation": incarnation, "records": t.records, "checksum": t.checksum, "gaps": t.gaps})
        })
        .collect();
    dir.write_stats(
        "learner",
        &serde_json::json!({
            "status": status,
            "pid": std::process::id(),
            "updates": l.dsac.updates,
            "resumed_from_update": l.resumed_from,
            "received_this_process": l.received,
            "received_total": received_total,
            "limiter": l.limiter,
            "streams": tallies,
        }),
    )?;
    Ok(())
}
