//! `pednav-run bench bridge`: the two bridges of a run that spans hosts, measured on
//! one machine over loopback, with stand-ins for the learner, the curriculum service
//! and one actor that speak the run's own services and protocol (the actor is a
//! [`StepWriter`], the learner acknowledges with a [`ReceiveCursor`]).
//!
//! Phases: (1) step-record throughput, actor → bridge → link → bridge → learner, with
//! acknowledgements flowing back; (2) weights broadcast latency to the remote host;
//! (3) task request latency; (4) while the actor keeps sending, the link is cut for
//! `--drop-secs` (a TCP relay between the hosts closes every connection and refuses new
//! ones), then the learner stalls for `--stall-secs`; afterwards every record must be in
//! once. For orientation the same run measures plain zenoh pub/sub of records of the
//! same size between two sessions on loopback (congestion control *Block*), over the
//! same transport as the bridges: plain TCP, or mutual TLS with `--tls-dir`.
//!
//! Invariant: every figure is measured in this run; nothing is assumed.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use pednav_bridge::{ActorHostOptions, LearnerHostOptions, LinkConfig, TlsFiles};
use pednav_runtime::channels::{StepPayload, StepWriter, StreamId, TaskRequester};
use pednav_runtime::ipc::receive_step_round;
use pednav_runtime::messages::{AckTable, Heartbeat, ProcessKind, StepHeader, StreamAck, TaskResponse, WeightsHeader};
use pednav_runtime::reliable::{ReceiveCursor, Verdict};
use pednav_runtime::{Ipc, RunConfig, RunDir, StopFlag, now_ns, run_prefix};
use serde::Serialize;

use crate::relay::{Relay, free_port};

/// Arguments of `bench bridge`.
#[derive(Args)]
pub struct BenchBridge {
    /// Step records of the throughput phase.
    #[arg(long, default_value_t = 100_000)]
    records: u64,
    /// Weights broadcasts (and task requests) timed.
    #[arg(long, default_value_t = 200)]
    repeats: usize,
    /// How long the link is cut in the fault phase (seconds; 0: no cut).
    #[arg(long, default_value_t = 15)]
    drop_secs: u64,
    /// How long the learner stalls in the fault phase (seconds; 0: no stall).
    #[arg(long, default_value_t = 60)]
    stall_secs: u64,
    /// Also write the figures as JSON to this file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Run the link (and the plain zenoh reference) over mutual TLS with the
    /// certificates in this folder: `ca.pem`, `learner-host.pem` / `learner-host.key`
    /// and `actor-host.pem` / `actor-host.key`, the learner host's naming 127.0.0.1 —
    /// the layout `shared/bridge/testdata/tls/make.sh` writes. Without it: plain TCP.
    #[arg(long, value_name = "DIR")]
    tls_dir: Option<PathBuf>,
}

/// The figures (`--json`).
#[derive(Debug, Serialize)]
struct Figures {
    /// `tcp` or `tls` (mutual), for the bridges' link and the plain zenoh reference alike.
    transport: &'static str,
    record_bytes: usize,
    records_per_s: f64,
    megabytes_per_s: f64,
    plain_zenoh_records_per_s: f64,
    fraction_of_plain_zenoh: f64,
    weights_floats: usize,
    weights_p50_ms: f64,
    weights_p99_ms: f64,
    task_p50_ms: f64,
    task_p99_ms: f64,
    fault_records_sent: u64,
    lost: u64,
    duplicated: u64,
    corrupted: u64,
    transport_closed: u64,
    drop_secs: u64,
    stall_secs: u64,
}

/// What the learner stand-in saw.
#[derive(Default)]
struct Taken {
    accepted: AtomicU64,
    duplicated: AtomicU64,
    corrupted: AtomicU64,
}

impl BenchBridge {
    /// Whether the link (and the plain zenoh reference) run over mutual TLS.
    pub fn uses_tls(&self) -> bool {
        self.tls_dir.is_some()
    }
}

pub fn run(args: BenchBridge) -> Result<()> {
    let stop = StopFlag::install();
    // The TLS files are checked before anything is made.
    let tls = args.tls_dir.as_deref().map(BenchTls::from_dir).transpose()?;
    let root = std::env::temp_dir().join(format!("pednav-bench-bridge-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let (learner_dir, actor_dir) = (root.join("learner-host"), root.join("actor-host"));
    let cfg = RunConfig::default();
    for d in [&learner_dir, &actor_dir] {
        RunDir::new(d).prepare(&cfg)?;
    }
    let record_bytes = cfg.observation_bytes();
    let transport = if tls.is_some() { "tls" } else { "tcp" };
    let plain = plain_zenoh_rate(record_bytes, 50_000, tls.as_ref())?;
    eprintln!("plain zenoh pub/sub, {record_bytes}-byte records over loopback ({transport}): {plain:.0} records/s");

    let (learner_port, relay_port) = (free_port()?, free_port()?);
    let relay = Relay::start(relay_port, learner_port)?;
    let learner_bridge = {
        let opts = LearnerHostOptions {
            run_dir: learner_dir.clone(),
            link: LinkConfig::listening(&[format!("{transport}/127.0.0.1:{learner_port}")])
                .with_tls(tls.as_ref().map(|t| t.learner_host.clone())),
            local_actors: 0,
        };
        let stop = stop.clone();
        std::thread::spawn(move || pednav_bridge::run_learner_host(&opts, &stop))
    };
    let taken = Arc::new(Taken::default());
    let control = Arc::new(LearnerControl::default());
    let learner = {
        let (prefix, taken, control, stop) = (run_prefix(&learner_dir), taken.clone(), control.clone(), stop.clone());
        let weights_len =
            pednav_runtime::weights::acting_len(&pednav_nets::DsacNets::new(&cfg.nets, &candle_core::Device::Cpu, 0)?);
        std::thread::spawn(move || learner_stand_in(&prefix, weights_len, &taken, &control, &stop))
    };
    std::thread::sleep(Duration::from_millis(500));
    let actor_bridge = {
        let opts = ActorHostOptions {
            run_dir: actor_dir.clone(),
            link: LinkConfig::connecting(&[format!("{transport}/127.0.0.1:{relay_port}")])
                .keep_trying()
                .with_tls(tls.as_ref().map(|t| t.actor_host.clone())),
            run: pednav_bridge::run_name(&learner_dir),
            host: "bench-actors".into(),
        };
        let stop = stop.clone();
        std::thread::spawn(move || pednav_bridge::run_actor_host(&opts, &stop))
    };
    let mut actor = ActorStandIn::open(&actor_dir, &cfg, &stop)?;

    // (1) Throughput.
    let t0 = Instant::now();
    let sent = actor.send_until(&stop, |sent, _| sent >= args.records)?;
    wait_until(&taken.accepted, sent, Duration::from_secs(300), &stop)?;
    let secs = t0.elapsed().as_secs_f64();
    let records_per_s = sent as f64 / secs;
    eprintln!("throughput: {sent} records in {secs:.1} s = {records_per_s:.0} records/s");

    // (2) Weights latency, (3) task latency.
    control.weights_on.store(true, Ordering::Relaxed);
    let weights_ms = actor.weights_latencies(args.repeats, &stop)?;
    control.weights_on.store(false, Ordering::Relaxed);
    let task_ms = actor.task_latencies(args.repeats, &stop)?;

    // (4) Faults: a cut link, then a stalled learner, while the actor keeps sending.
    let fault_start = Instant::now();
    let cut_at = Duration::from_secs(2);
    let stall_at = cut_at + Duration::from_secs(args.drop_secs + 10);
    let end_at = stall_at + Duration::from_secs(args.stall_secs + 10);
    if args.drop_secs > 0 {
        relay.cut_later(cut_at, Duration::from_secs(args.drop_secs));
    }
    if args.stall_secs > 0 {
        *control.stall.lock().unwrap() =
            Some((fault_start + stall_at, fault_start + stall_at + Duration::from_secs(args.stall_secs)));
    }
    let before = actor.sent;
    let total = actor.send_until(&stop, |_, started| started.elapsed() >= end_at)?;
    let fault_records = total - before;
    let drained = wait_until(&taken.accepted, total, Duration::from_secs(300), &stop);
    let accepted = taken.accepted.load(Ordering::Relaxed);
    // One flag stops every thread of the process (the bridges, the stand-ins).
    stop.set();
    let learner_side = learner_bridge.join().map_err(|_| anyhow::anyhow!("the learner-host bridge panicked"))??;
    let _ = actor_bridge.join();
    let _ = learner.join();
    if let Err(e) = drained {
        eprintln!("warning: {e}");
    }
    let figures = Figures {
        transport,
        record_bytes,
        records_per_s,
        megabytes_per_s: records_per_s * record_bytes as f64 / 1e6,
        plain_zenoh_records_per_s: plain,
        fraction_of_plain_zenoh: records_per_s / plain,
        weights_floats: actor.weights_len,
        weights_p50_ms: percentile(&weights_ms, 0.5),
        weights_p99_ms: percentile(&weights_ms, 0.99),
        task_p50_ms: percentile(&task_ms, 0.5),
        task_p99_ms: percentile(&task_ms, 0.99),
        fault_records_sent: fault_records,
        lost: total.saturating_sub(accepted),
        duplicated: taken.duplicated.load(Ordering::Relaxed),
        corrupted: taken.corrupted.load(Ordering::Relaxed),
        // The learner host saw the actor host leave the link once per forced cut; any
        // other departure is a transport zenoh closed (a queue full past wait_before_close).
        transport_closed: learner_side.hosts_gone.saturating_sub(u64::from(args.drop_secs > 0)),
        drop_secs: args.drop_secs,
        stall_secs: args.stall_secs,
    };
    print_table(&figures);
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_string_pretty(&figures)?).with_context(|| path.display().to_string())?;
    }
    let _ = std::fs::remove_dir_all(&root);
    Ok(())
}

fn print_table(f: &Figures) {
    println!("| measure | value | goal |");
    println!("|---|---|---|");
    println!(
        "| step records/s ({} B, through both bridges, {}) | {:.0} ({:.0} MB/s) | ≥ 50,000 |",
        f.record_bytes,
        if f.transport == "tls" { "mutual TLS" } else { "TCP" },
        f.records_per_s,
        f.megabytes_per_s
    );
    println!(
        "| plain zenoh pub/sub, same records | {:.0} (bridge: {:.2} of it) | |",
        f.plain_zenoh_records_per_s, f.fraction_of_plain_zenoh
    );
    println!(
        "| weights ({} floats) p50 / p99 | {:.1} / {:.1} ms | p99 ≤ 50 ms |",
        f.weights_floats, f.weights_p50_ms, f.weights_p99_ms
    );
    println!("| task request p50 / p99 | {:.2} / {:.2} ms | p99 ≤ 10 ms |", f.task_p50_ms, f.task_p99_ms);
    println!(
        "| after a {} s link cut and a {} s learner stall ({} records sent meanwhile): lost / duplicated / corrupted / transports closed | {} / {} / {} / {} | 0 / 0 / 0 / 0 |",
        f.drop_secs, f.stall_secs, f.fault_records_sent, f.lost, f.duplicated, f.corrupted, f.transport_closed
    );
}

fn percentile(values: &[f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Wait until `counter` reaches `target` (or `timeout`, an error naming both).
fn wait_until(counter: &AtomicU64, target: u64, timeout: Duration, stop: &StopFlag) -> Result<()> {
    let start = Instant::now();
    while counter.load(Ordering::Relaxed) < target {
        if start.elapsed() > timeout || stop.is_set() {
            bail!("{} of {target} records arrived within {timeout:?}", counter.load(Ordering::Relaxed));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    Ok(())
}

/// Fill `floats` with record `seq`'s observation: the bits of `seq`, low and high
/// halves alternating, so its bytes are `seq` (little-endian) over and over — cheap to
/// write and to check ([`is_observation_of`]), so the stand-ins leave the cores to the
/// bridges.
fn observation_of(seq: u64, floats: &mut [f32]) {
    let halves = [f32::from_bits(seq as u32), f32::from_bits((seq >> 32) as u32)];
    for (k, v) in floats.iter_mut().enumerate() {
        *v = halves[k % 2];
    }
}

/// Whether `bytes` is record `seq`'s observation (see [`observation_of`]).
fn is_observation_of(seq: u64, bytes: &[u8]) -> bool {
    bytes.len() % 8 == 0 && bytes.chunks_exact(8).all(|c| c == seq.to_le_bytes())
}

/// What the learner stand-in is told: weights broadcasts on or off, a stall window.
#[derive(Default)]
struct LearnerControl {
    weights_on: AtomicBool,
    stall: Mutex<Option<(Instant, Instant)>>,
}

/// The learner and curriculum service of the learner host: takes step records in
/// order (a [`ReceiveCursor`]), checks each, acknowledges, answers task requests and
/// broadcasts weights when told.
fn learner_stand_in(prefix: &str, weights_len: usize, taken: &Taken, control: &LearnerControl, stop: &StopFlag) {
    if let Err(e) = learner_loop(prefix, weights_len, taken, control, stop) {
        eprintln!("learner stand-in: {e}");
    }
}

fn learner_loop(
    prefix: &str,
    weights_len: usize,
    taken: &Taken,
    control: &LearnerControl,
    stop: &StopFlag,
) -> Result<()> {
    let ipc = Ipc::new(prefix, "bench-learner", 2048, Duration::from_secs(600), stop.clone())?;
    let steps = ipc.step_subscriber()?;
    let acks = ipc.ack_publisher()?;
    let beats = ipc.heartbeat_subscriber()?;
    let tasks = ipc.task_server()?;
    let weights = ipc.weights_publisher(weights_len)?;
    let mut cursor = ReceiveCursor::new(std::process::id(), Duration::from_millis(500), Instant::now());
    let mut seen = std::collections::HashSet::new();
    let (mut round, mut last_ack, mut last_weights, mut version) = (Vec::new(), Instant::now(), Instant::now(), 0u64);
    let values = vec![0.5f32; weights_len];
    while !stop.is_set() {
        let now = Instant::now();
        let stalled = control.stall.lock().unwrap().is_some_and(|(a, b)| now >= a && now < b);
        let mut busy = false;
        if !stalled {
            receive_step_round(&steps, &mut round)?;
            busy = !round.is_empty();
            for s in round.drain(..) {
                let h = s.user_header();
                match cursor.offer(h.seq, h.base, now) {
                    Verdict::Accept | Verdict::Resume { .. } => {
                        if !seen.insert(h.seq) {
                            taken.duplicated.fetch_add(1, Ordering::Relaxed);
                        }
                        if !is_observation_of(h.seq, s.payload()) {
                            taken.corrupted.fetch_add(1, Ordering::Relaxed);
                        }
                        taken.accepted.fetch_add(1, Ordering::Relaxed);
                    }
                    Verdict::Duplicate | Verdict::Missing { .. } => {}
                }
            }
            while let Some(b) = beats.receive().map_err(|e| anyhow::anyhow!("heartbeats: {e:?}"))? {
                if b.kind == ProcessKind::ACTOR {
                    cursor.on_announce(b.stream_base, b.env_steps, now);
                }
            }
            if last_ack.elapsed() >= Duration::from_millis(5) {
                last_ack = now;
                let mut table = AckTable::default();
                table.streams[0] = StreamAck { incarnation: 1, ack: cursor.ack() };
                acks.send_copy(table).map_err(|e| anyhow::anyhow!("acks: {e:?}"))?;
            }
        }
        while let Some(request) = tasks.receive().map_err(|e| anyhow::anyhow!("tasks: {e:?}"))? {
            let task_id = request.payload().env as u64;
            let _ = request.send_copy(TaskResponse { task_id, ..TaskResponse::default() });
        }
        if control.weights_on.load(Ordering::Relaxed) && last_weights.elapsed() >= Duration::from_millis(50) {
            last_weights = now;
            version += 1;
            let mut sample = weights.loan_slice_uninit(weights_len).map_err(|e| anyhow::anyhow!("{e:?}"))?;
            *sample.user_header_mut() = WeightsHeader { version, len: weights_len as u64, published_ns: now_ns() };
            sample.write_from_slice(&values).send().map_err(|e| anyhow::anyhow!("{e:?}"))?;
        }
        if !busy {
            std::thread::sleep(Duration::from_micros(100));
        }
    }
    Ok(())
}

/// The actor of the actor host: a [`StepWriter`], a task requester, a weights
/// subscriber and its heartbeat (which announces its stream's tail).
struct ActorStandIn {
    _ipc: Ipc,
    writer: StepWriter,
    tasks: TaskRequester,
    weights: pednav_runtime::ipc::WeightsSubscriber,
    beats: pednav_runtime::ipc::HeartbeatPublisher,
    /// The observation of the record being sent.
    observation: Vec<f32>,
    sent: u64,
    weights_len: usize,
}

impl ActorStandIn {
    fn open(run_dir: &Path, cfg: &RunConfig, stop: &StopFlag) -> Result<ActorStandIn> {
        let ipc = Ipc::new(
            &run_prefix(run_dir),
            "bench-actor",
            cfg.runtime.step_buffer,
            Duration::from_secs(600),
            stop.clone(),
        )?;
        let record_bytes = cfg.observation_bytes();
        if record_bytes % 8 != 0 {
            bail!("records of {record_bytes} bytes: the bench writes its 8-byte pattern whole");
        }
        let writer = StepWriter::open(
            &ipc,
            StreamId { actor: 0, incarnation: 1 },
            record_bytes,
            cfg.runtime.resend_window(),
            stop.clone(),
        )?;
        if !writer.wait_for_learner(Duration::from_secs(60)) {
            bail!("the actor-host bridge did not subscribe to the step records within 60 s");
        }
        Ok(ActorStandIn {
            tasks: TaskRequester::open(&ipc, Duration::from_secs(30), stop.clone())?,
            weights: ipc.weights_subscriber()?,
            beats: ipc.heartbeat_publisher()?,
            writer,
            observation: vec![0.0; record_bytes / 4],
            sent: 0,
            weights_len: 0,
            _ipc: ipc,
        })
    }

    /// Send records until `done(sent, started)`; returns the records sent so far.
    fn send_until(&mut self, stop: &StopFlag, done: impl Fn(u64, Instant) -> bool) -> Result<u64> {
        let (started, mut last_beat) = (Instant::now(), Instant::now());
        while !done(self.sent, started) && !stop.is_set() {
            let seq = self.writer.next_seq();
            let header =
                StepHeader { actor: 0, incarnation: 1, seq, episode: 1, step: seq as u32, ..StepHeader::default() };
            observation_of(seq, &mut self.observation);
            if self.writer.send(header, StepPayload::State(&self.observation))?.is_none() {
                break;
            }
            self.sent += 1;
            if last_beat.elapsed() >= Duration::from_millis(200) {
                last_beat = Instant::now();
                let _ = self.beats.send_copy(Heartbeat {
                    kind: ProcessKind::ACTOR,
                    incarnation: 1,
                    stream_base: self.writer.base(),
                    env_steps: self.writer.next_seq(),
                    ..Heartbeat::default()
                });
            }
        }
        Ok(self.sent)
    }

    /// Publish → receipt latency (ms) of `n` weights broadcasts.
    fn weights_latencies(&mut self, n: usize, stop: &StopFlag) -> Result<Vec<f64>> {
        let (mut out, mut last, deadline) = (Vec::new(), 0u64, Instant::now() + Duration::from_secs(120));
        while out.len() < n && Instant::now() < deadline && !stop.is_set() {
            match self.weights.receive().map_err(|e| anyhow::anyhow!("weights: {e:?}"))? {
                Some(s) if s.user_header().version > last => {
                    last = s.user_header().version;
                    self.weights_len = s.payload().len();
                    out.push(now_ns().saturating_sub(s.user_header().published_ns) as f64 / 1e6);
                }
                _ => std::thread::sleep(Duration::from_micros(50)),
            }
        }
        if out.len() < n {
            bail!("{} of {n} weights broadcasts reached the remote host within 120 s", out.len());
        }
        Ok(out)
    }

    /// Request → response latency (ms) of `n` task requests.
    fn task_latencies(&mut self, n: usize, stop: &StopFlag) -> Result<Vec<f64>> {
        let mut out = Vec::with_capacity(n);
        for k in 0..n {
            let t = Instant::now();
            match self.tasks.request(0, k as u32)? {
                Some(r) if r.task_id == k as u64 => out.push(t.elapsed().as_secs_f64() * 1e3),
                Some(r) => bail!("task request {k} answered with task {}", r.task_id),
                None if stop.is_set() => break,
                None => bail!("task request {k} went unanswered"),
            }
        }
        Ok(out)
    }
}

/// The two hosts' certificates of `--tls-dir`.
struct BenchTls {
    learner_host: TlsFiles,
    actor_host: TlsFiles,
}

impl BenchTls {
    /// The files of `dir`, each checked to exist (an error names the missing one).
    fn from_dir(dir: &Path) -> Result<BenchTls> {
        let file = |name: &str| -> Result<PathBuf> {
            let path = std::path::absolute(dir.join(name)).with_context(|| dir.display().to_string())?;
            if !path.is_file() {
                bail!(
                    "--tls-dir {}: no file {name} (the folder needs ca.pem, learner-host.pem/.key and \
                     actor-host.pem/.key, as shared/bridge/testdata/tls/make.sh writes them)",
                    dir.display()
                );
            }
            Ok(path)
        };
        let host = |name: &str| -> Result<TlsFiles> {
            Ok(TlsFiles {
                ca: file("ca.pem")?,
                certificate: file(&format!("{name}.pem"))?,
                key: file(&format!("{name}.key"))?,
            })
        };
        Ok(BenchTls { learner_host: host("learner-host")?, actor_host: host("actor-host")? })
    }
}

/// Plain zenoh pub/sub of `n` records of `bytes` between two sessions on loopback
/// (Block), over TCP or, with `tls`, mutual TLS; records/s at the subscriber.
fn plain_zenoh_rate(bytes: usize, n: u64, tls: Option<&BenchTls>) -> Result<f64> {
    use zenoh::Wait;
    let port = free_port()?;
    let endpoint = format!("{}/127.0.0.1:{port}", if tls.is_some() { "tls" } else { "tcp" });
    let a =
        LinkConfig::listening(std::slice::from_ref(&endpoint)).with_tls(tls.map(|t| t.learner_host.clone())).open()?;
    let b = LinkConfig::connecting(&[endpoint]).with_tls(tls.map(|t| t.actor_host.clone())).open()?;
    let got = Arc::new(AtomicU64::new(0));
    let counter = got.clone();
    let _sub = a
        .declare_subscriber("pednav/bench/plain")
        .callback(move |_| {
            counter.fetch_add(1, Ordering::Relaxed);
        })
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let publisher = b
        .declare_publisher("pednav/bench/plain")
        .congestion_control(zenoh::qos::CongestionControl::Block)
        .wait()
        .map_err(|e| anyhow::anyhow!("{e}"))?;
    let payload = vec![7u8; bytes];
    // Until the subscription reached the publisher's session.
    let deadline = Instant::now() + Duration::from_secs(20);
    while got.load(Ordering::Relaxed) == 0 {
        publisher.put(payload.clone()).wait().map_err(|e| anyhow::anyhow!("{e}"))?;
        std::thread::sleep(Duration::from_millis(10));
        if Instant::now() > deadline {
            bail!("plain zenoh: nothing arrived within 20 s");
        }
    }
    let start_count = got.load(Ordering::Relaxed);
    let t = Instant::now();
    for _ in 0..n {
        publisher.put(payload.clone()).wait().map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let target = start_count + n;
    while got.load(Ordering::Relaxed) < target && t.elapsed() < Duration::from_secs(120) {
        std::thread::sleep(Duration::from_millis(1));
    }
    let rate = (got.load(Ordering::Relaxed) - start_count) as f64 / t.elapsed().as_secs_f64();
    pednav_bridge::link::close(b);
    pednav_bridge::link::close(a);
    Ok(rate)
}
