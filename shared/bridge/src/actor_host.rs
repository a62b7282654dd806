//! The actor host's bridge: to its local actors it is the learner and the curriculum
//! service; to the learner host it is a host of actors.
//!
//! What it moves:
//! - step records and episode reports of the local actors → the link, each actor on
//!   its own key, with congestion control *Block*, in the order the actor sent them;
//! - the learner's acknowledgement tables and the weights ← the link, newest wins,
//!   republished on the local services (the newest weights are asked for at once, so a
//!   host that joins late acts on the current policy from its first step);
//! - the learner host's acknowledgements of episode reports ← the link: the bridge
//!   holds each report ([`HeldReports`], at most [`HELD_REPORTS`]) until it is
//!   acknowledged, sends it again [`REPORT_RESEND_AFTER`] after it went without one and
//!   when the learner host comes back, and puts none on the link while the learner
//!   host is away ([`crate::reports`]);
//! - task requests → a query to the learner host, whose answer goes back to the actor;
//! - heartbeats both ways: the local actors' out, the learner's and the curriculum
//!   service's in (the local progress line shows the run's progress);
//! - the run's end ← the link: the learner host's "done" becomes the local run's done
//!   marker, so the local launcher stops its actors.
//!
//! Invariant: the bridge holds no step record. A record is in its actor's window until
//! a learner acknowledges it ([`pednav_runtime::reliable`]), so a bridge that dies, a
//! link that drops and a learner host that restarts lose nothing: the learner asks
//! again for what it lacks, or the actor sends its full window again unasked. Episode
//! reports are held here, not in the actor: a link that drops and a learner host that
//! restarts lose none, but a bridge that dies loses those it held unacknowledged (at
//! most a quarter of a second's, while the learner host is there) and those its actors
//! reported before its replacement was up.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use pednav_runtime::StopFlag;
use pednav_runtime::ipc::{
    EpisodeSubscriber, StepSample, StepSubscriber, TaskActive, WeightsPublisher, receive_step_round,
};
use pednav_runtime::messages::{ProcessKind, TaskResponse};
use zenoh::Wait;
use zenoh::bytes::ZBytes;
use zenoh::handlers::FifoChannelHandler;
use zenoh::qos::CongestionControl;
use zenoh::query::Reply;
use zenoh::sample::SampleKind;

use crate::error::{BridgeError, Result};
use crate::forward::{BridgeStats, IDLE, LEARNER_HOST, Latest, LocalRun, STATS_EVERY, Tally, link_err, refuse};
use crate::link::{Keys, LinkConfig};
use crate::reports::HeldReports;
use crate::wire;

/// How long a task request waits for the learner host's answer (the actor asks again
/// every second while it has none).
const TASK_TIMEOUT: Duration = Duration::from_secs(5);

/// What an actor host's bridge needs.
#[derive(Debug, Clone)]
pub struct ActorHostOptions {
    /// The local run directory (its `config.toml` is the learner host's).
    pub run_dir: PathBuf,
    /// The link to the learner host (`--connect`).
    pub link: LinkConfig,
    /// The run's name on the link (from the join).
    pub run: String,
    /// This host's name on the link.
    pub host: String,
}

/// Rounds of step records one pass of the bridge's loop forwards at most.
const ROUNDS_PER_PASS: usize = 64;

/// Episode reports held unacknowledged, at most (while the learner host is away: the
/// oldest are given up first, and counted).
pub const HELD_REPORTS: usize = 65_536;

/// How long a report that was put on the link waits for its acknowledgement before
/// it is sent again (acknowledgements come every quarter of a second).
pub const REPORT_RESEND_AFTER: Duration = Duration::from_secs(2);

/// How long a stopping bridge waits for the acknowledgement of the reports it holds.
const LAST_ACKS_WAIT: Duration = Duration::from_secs(3);

/// A task request waiting for the learner host's answer.
struct TaskInFlight {
    request: TaskActive,
    replies: FifoChannelHandler<Reply>,
    asked: Instant,
}

/// Run the actor host's bridge until `stop`; returns what it moved.
pub fn run_actor_host(opts: &ActorHostOptions, stop: &StopFlag) -> Result<BridgeStats> {
    let local = LocalRun::open(&opts.run_dir)?;
    let keys = Keys::new(&opts.run)?;
    let session = opts.link.open()?;
    let ipc = local.ipc("bridge", stop)?;
    let steps_in = ipc.step_subscriber()?;
    let episodes_in = ipc.episode_subscriber()?;
    let acks_out = ipc.ack_publisher()?;
    let tasks_in = ipc.task_server()?;
    let beats_in = ipc.heartbeat_subscriber()?;
    let beats_out = ipc.heartbeat_publisher()?;
    let mut weights_out: Option<(WeightsPublisher, Option<u64>)> = None;
    let tally = Arc::new(Tally::default());

    let _token = session.liveliness().declare_token(keys.alive(&opts.host)).wait().map_err(link_err("liveliness"))?;
    let acks = Latest::<ZBytes>::new();
    let report_acks = Latest::<ZBytes>::new();
    let weights = Latest::<ZBytes>::new();
    let done = Latest::<ZBytes>::new();
    let (beats_tx, beats_rx) = mpsc::channel::<ZBytes>();
    let learner_alive = Arc::new(AtomicBool::new(false));
    let _subscriptions = (
        subscribe(&session, keys.acks(), acks.clone())?,
        subscribe(&session, keys.report_acks(), report_acks.clone())?,
        subscribe(&session, keys.weights(), weights.clone())?,
        subscribe(&session, keys.done(), done.clone())?,
        session
            .declare_subscriber(keys.all_heartbeats())
            .callback(move |s| {
                let _ = beats_tx.send(s.payload().clone());
            })
            .wait()
            .map_err(link_err("heartbeat subscription"))?,
        {
            let alive = learner_alive.clone();
            session
                .liveliness()
                .declare_subscriber(keys.alive(LEARNER_HOST))
                .history(true)
                .callback(move |s| alive.store(s.kind() == SampleKind::Put, Ordering::Relaxed))
                .wait()
                .map_err(link_err("liveliness subscription"))?
        },
    );
    ask_for_newest_weights(&session, &keys, &weights);

    let mut out = Outbound {
        session: &session,
        keys: &keys,
        tally: &tally,
        steps: HashMap::new(),
        episodes: HashMap::new(),
        reports: HeldReports::new(HELD_REPORTS),
        round: Vec::new(),
    };
    let beats_link = session
        .declare_publisher(keys.heartbeats(&opts.host))
        .congestion_control(CongestionControl::Drop)
        .wait()
        .map_err(link_err("heartbeat publisher"))?;
    let mut tasks: Vec<TaskInFlight> = Vec::new();
    let (mut learner_seen, mut last_stats) = (false, Instant::now());
    tracing::info!(host = %opts.host, run = %opts.run, "actor-host bridge up");

    while !stop.is_set() {
        let mut busy = false;
        busy |= out.forward(&steps_in, &episodes_in, learner_alive.load(Ordering::Relaxed))?;
        if let Some(bytes) = acks.take() {
            busy = true;
            match wire::decode_acks(&bytes.to_bytes()) {
                Ok(table) => {
                    acks_out.send_copy(table).map_err(|e| BridgeError::Link(format!("ack table: {e:?}")))?;
                    Tally::add(&tally.ack_tables, 1);
                }
                Err(e) => refuse(&tally, &e),
            }
        }
        busy |= out.acknowledge_reports(&report_acks);
        if let Some(bytes) = weights.take() {
            busy = true;
            publish_weights(&ipc, &bytes, &mut weights_out, &tally)?;
        }
        busy |= forward_tasks(&session, &keys, &tasks_in, &mut tasks, &tally)?;
        // Heartbeats: the local actors' out; the learner host's processes' in.
        while let Some(h) = beats_in.receive().map_err(|e| BridgeError::Link(format!("heartbeats: {e:?}")))? {
            if h.kind == ProcessKind::ACTOR {
                let _ = beats_link.put(wire::encode_heartbeat(&h)).wait();
            }
        }
        while let Ok(bytes) = beats_rx.try_recv() {
            match wire::decode_heartbeat(&bytes.to_bytes()) {
                Ok(h) if h.kind != ProcessKind::ACTOR => {
                    let _ = beats_out.send_copy(h);
                    Tally::add(&tally.heartbeats, 1);
                }
                Ok(_) => {}
                Err(e) => refuse(&tally, &e),
            }
        }
        let alive = learner_alive.load(Ordering::Relaxed);
        if alive != learner_seen {
            learner_seen = alive;
            if alive {
                tracing::info!("the learner host is on the link");
                // What was on its way when it left may be lost: send every held report again.
                out.reports.resend_all();
            } else {
                Tally::add(&tally.hosts_gone, 1);
                tracing::warn!(
                    "the learner host left the link: the actors wait (their step records are held) until it is back"
                );
            }
        }
        if let Some(reason) = done.take() {
            out.forward(&steps_in, &episodes_in, true)?;
            let reason = String::from_utf8_lossy(&reason.to_bytes()).into_owned();
            tracing::info!(%reason, "the learner host's run is over");
            if let Err(e) = std::fs::write(local.dir.done_marker(), format!("learner host: {reason}")) {
                tracing::warn!("the done marker could not be written: {e}");
            }
        }
        if last_stats.elapsed() >= STATS_EVERY {
            last_stats = Instant::now();
            local.write_stats(&tally.snapshot("actor-host", &opts.host, &opts.run));
        }
        if !busy {
            std::thread::sleep(IDLE);
        }
    }
    // The actors stopped before the bridge: what they sent last is still queued here,
    // and no actor is left to send it again.
    for _ in 0..10_000 {
        if !out.forward(&steps_in, &episodes_in, true)? {
            break;
        }
    }
    // Wait a little for the acknowledgement of the last reports (sending again what
    // goes without one), so that none is left unconfirmed when the learner host is there.
    let waited = Instant::now();
    while !out.reports.is_empty() && learner_alive.load(Ordering::Relaxed) && waited.elapsed() < LAST_ACKS_WAIT {
        out.acknowledge_reports(&report_acks);
        out.forward(&steps_in, &episodes_in, true)?;
        std::thread::sleep(Duration::from_millis(20));
    }
    if !out.reports.is_empty() {
        tracing::warn!(
            reports = out.reports.len(),
            "episode reports were not acknowledged by the learner host before this bridge stopped"
        );
    }
    drop(out);
    let stats = tally.snapshot("actor-host", &opts.host, &opts.run);
    local.write_stats(&stats);
    crate::link::close(session);
    Ok(stats)
}

/// The local actors' step records and episode reports on their way to the link.
struct Outbound<'a> {
    session: &'a zenoh::Session,
    keys: &'a Keys,
    tally: &'a Tally,
    steps: HashMap<u32, zenoh::pubsub::Publisher<'static>>,
    episodes: HashMap<u32, zenoh::pubsub::Publisher<'static>>,
    /// Episode reports not yet acknowledged by the learner host.
    reports: HeldReports,
    round: Vec<StepSample>,
}

impl Outbound<'_> {
    /// Put every queued step record and episode report on the link, each on its
    /// actor's key; reports wait while the learner host is away (`learner_alive`
    /// false). Returns whether anything moved.
    fn forward(&mut self, steps: &StepSubscriber, episodes: &EpisodeSubscriber, learner_alive: bool) -> Result<bool> {
        let mut busy = false;
        // Rounds until the queues are empty, at most ROUNDS_PER_PASS (the loop's other
        // duties wait no longer than that).
        for _ in 0..ROUNDS_PER_PASS {
            if !self.forward_steps(steps)? {
                break;
            }
            busy = true;
        }
        busy |= self.forward_reports(episodes, learner_alive)?;
        Ok(busy)
    }

    /// One round of step records, fair across the local actors; whether it held any.
    fn forward_steps(&mut self, steps: &StepSubscriber) -> Result<bool> {
        receive_step_round(steps, &mut self.round)?;
        let any = !self.round.is_empty();
        for sample in self.round.drain(..) {
            let h = sample.user_header();
            let link = link_for(self.session, &mut self.steps, h.actor, || self.keys.steps(h.actor))?;
            match link.put(wire::encode_step(h, sample.payload())).wait() {
                Ok(()) => {
                    Tally::add(&self.tally.step_records, 1);
                    Tally::add(&self.tally.step_bytes, sample.payload().len() as u64);
                }
                // The actor holds the record until a learner acknowledges it.
                Err(e) => tracing::debug!(actor = h.actor, seq = h.seq, "step record not put on the link: {e}"),
            }
        }
        Ok(any)
    }

    /// Every new episode report, held; the held ones that are due put on the link
    /// while the learner host is there.
    fn forward_reports(&mut self, episodes: &EpisodeSubscriber, learner_alive: bool) -> Result<bool> {
        let mut busy = false;
        while let Some(sample) = episodes.receive().map_err(|e| BridgeError::Link(format!("episodes: {e:?}")))? {
            busy = true;
            let h = sample.user_header();
            let bytes = wire::encode_episode(h, h.seq, sample.payload());
            if self.reports.push(h.actor, h.incarnation, h.seq, bytes) {
                Tally::add(&self.tally.reports_given_up, 1);
            }
        }
        if !learner_alive {
            return Ok(busy);
        }
        let (session, keys, tally, links) = (self.session, self.keys, self.tally, &mut self.episodes);
        let sent = self.reports.send_due(Instant::now(), REPORT_RESEND_AFTER, |actor, bytes| {
            let put = link_for(session, links, actor, || keys.episodes(actor))
                .and_then(|link| link.put(bytes.to_vec()).wait().map_err(link_err("episode report")));
            match put {
                Ok(()) => true,
                Err(e) => {
                    tracing::warn!(actor, "an episode report was not put on the link (it is sent again): {e}");
                    false
                }
            }
        });
        Tally::add(&tally.episode_reports, sent as u64);
        Ok(busy || sent > 0)
    }

    /// Drop the held reports the learner host acknowledged; whether an
    /// acknowledgement came.
    fn acknowledge_reports(&mut self, slot: &Latest<ZBytes>) -> bool {
        let Some(bytes) = slot.take() else { return false };
        match wire::decode_report_acks(&bytes.to_bytes()) {
            Ok(acks) => {
                self.reports.acknowledge(&acks);
                Tally::add(&self.tally.report_acks, 1);
            }
            Err(e) => refuse(self.tally, &e),
        }
        true
    }
}

/// A subscriber that keeps the newest payload on `key` in `slot`.
fn subscribe(session: &zenoh::Session, key: String, slot: Latest<ZBytes>) -> Result<zenoh::pubsub::Subscriber<()>> {
    session
        .declare_subscriber(key)
        .callback(move |s| slot.put(s.payload().clone()))
        .wait()
        .map_err(link_err("subscription"))
}

/// The link publisher of one actor's records (declared on first use), congestion
/// control *Block*: a record waits for room on the link rather than being dropped.
fn link_for<'a>(
    session: &zenoh::Session,
    links: &'a mut HashMap<u32, zenoh::pubsub::Publisher<'static>>,
    actor: u32,
    key: impl FnOnce() -> String,
) -> Result<&'a zenoh::pubsub::Publisher<'static>> {
    if !links.contains_key(&actor) {
        let publisher = session
            .declare_publisher(key())
            .congestion_control(CongestionControl::Block)
            .wait()
            .map_err(link_err("record publisher"))?;
        links.insert(actor, publisher);
    }
    Ok(&links[&actor])
}

/// Ask the learner host for the newest weights (a late joiner acts on the current
/// policy at once); no answer is not an error — the next broadcast brings them.
fn ask_for_newest_weights(session: &zenoh::Session, keys: &Keys, slot: &Latest<ZBytes>) {
    let Ok(replies) = session.get(keys.weights()).timeout(Duration::from_secs(5)).wait() else { return };
    if let Ok(reply) = replies.recv_timeout(Duration::from_secs(5))
        && let Some(reply) = reply
        && let Ok(sample) = reply.into_result()
    {
        slot.put(sample.payload().clone());
    }
}

/// Republish weights from the link on the local weights service, if newer than the
/// last; the publisher is created for the first message's length, and a message of
/// another length is refused (the hosts' configs differ).
fn publish_weights(
    ipc: &pednav_runtime::Ipc,
    bytes: &ZBytes,
    out: &mut Option<(WeightsPublisher, Option<u64>)>,
    tally: &Tally,
) -> Result<()> {
    let (header, values) = match wire::decode_weights(&bytes.to_bytes()) {
        Ok(w) => w,
        Err(e) => {
            refuse(tally, &e);
            return Ok(());
        }
    };
    if out.is_none() {
        *out = Some((ipc.weights_publisher(values.len())?, None));
    }
    let (publisher, last) = out.as_mut().expect("created above");
    if last.is_some_and(|l| header.version <= l) {
        return Ok(());
    }
    let sample = match publisher.loan_slice_uninit(values.len()) {
        Ok(s) => s,
        Err(e) => {
            refuse(tally, &BridgeError::Link(format!("weights of {} floats: {e:?}", values.len())));
            return Ok(());
        }
    };
    let mut sample = sample;
    *sample.user_header_mut() = header;
    sample.write_from_slice(&values).send().map_err(|e| BridgeError::Link(format!("weights: {e:?}")))?;
    *last = Some(header.version);
    Tally::add(&tally.weights, 1);
    Ok(())
}

/// Ask the learner host for every new local task request, and answer those whose
/// answer arrived; returns whether anything happened.
fn forward_tasks(
    session: &zenoh::Session,
    keys: &Keys,
    server: &pednav_runtime::ipc::TaskServer,
    in_flight: &mut Vec<TaskInFlight>,
    tally: &Tally,
) -> Result<bool> {
    let mut busy = false;
    while let Some(request) = server.receive().map_err(|e| BridgeError::Link(format!("task server: {e:?}")))? {
        busy = true;
        let replies = session
            .get(keys.tasks())
            .payload(wire::encode_task_request(request.payload()))
            .timeout(TASK_TIMEOUT)
            .wait()
            .map_err(link_err("task query"))?;
        in_flight.push(TaskInFlight { request, replies, asked: Instant::now() });
    }
    let mut k = 0;
    while k < in_flight.len() {
        let t = &in_flight[k];
        let answer: Option<std::result::Result<TaskResponse, ()>> = match t.replies.try_recv() {
            Ok(Some(reply)) => Some(match reply.into_result() {
                Ok(sample) => wire::decode_task_response(&sample.payload().to_bytes()).map_err(|e| refuse(tally, &e)),
                Err(_) => Err(()),
            }),
            Ok(None) if t.asked.elapsed() < TASK_TIMEOUT * 2 => None,
            // Finished without an answer, or timed out: the actor asks again.
            _ => Some(Err(())),
        };
        match answer {
            None => k += 1,
            Some(result) => {
                busy = true;
                let t = in_flight.swap_remove(k);
                if let Ok(response) = result {
                    if let Err(e) = t.request.send_copy(response) {
                        tracing::warn!("task response not delivered to the actor: {e:?}");
                    }
                    Tally::add(&tally.tasks, 1);
                }
            }
        }
    }
    Ok(busy)
}
