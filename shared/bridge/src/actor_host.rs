//! The actor host's bridge: to its local actors it is the learner and the curriculum
//! service; to the learner host it is a host of actors.
//!
//! What it moves:
//! - step records and episode reports of the local actors → the link, each actor on
//!   its own key, with congestion control *Block*, in the order the actor sent them;
//! - the learner's acknowledgement tables and the weights ← the link, newest wins,
//!   republished on the local services (the newest weights are asked for when the
//!   bridge starts and whenever the learner host comes back on the link, so a host
//!   that joins late or whose link returns acts on the current policy at once);
//! - the curriculum service's acknowledgements of episode reports ← the link, newest
//!   wins, republished on the local service the actors read them from (while the
//!   learner host is away no report is put on the link: each actor holds its reports
//!   until they are acknowledged and sends them again, `pednav_runtime::reports`);
//! - task requests → a query to the learner host, whose answer goes back to the actor;
//! - heartbeats both ways: the local actors' out, the learner's and the curriculum
//!   service's in (the local progress line shows the run's progress);
//! - the run's end ← the link: the learner host's "done" becomes the local run's done
//!   marker, so the local launcher stops its actors.
//!
//! Invariant: the bridge holds no step record and no episode report. A record is in
//! its actor's window until a learner acknowledges it ([`pednav_runtime::reliable`]),
//! a report until the curriculum service acknowledges it
//! ([`pednav_runtime::reports`]), so a bridge that dies, a link that drops and a
//! learner host that restarts lose nothing: the learner asks again for what it lacks,
//! or the actor sends its full window again unasked; a report without an
//! acknowledgement goes out again from its actor.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use pednav_runtime::StopFlag;
use pednav_runtime::ipc::{
    EpisodeAckPublisher, EpisodeSubscriber, StepSample, StepSubscriber, TaskActive, WeightsPublisher,
    receive_step_round,
};
use pednav_runtime::messages::{EpisodeAck, EpisodeAckTable, ProcessKind, TaskResponse};
use zenoh::Wait;
use zenoh::bytes::ZBytes;
use zenoh::handlers::FifoChannelHandler;
use zenoh::qos::CongestionControl;
use zenoh::query::Reply;
use zenoh::sample::SampleKind;

use crate::error::{BridgeError, Result};
use crate::forward::{BridgeStats, IDLE, LEARNER_HOST, Latest, LocalRun, STATS_EVERY, Tally, link_err, refuse};
use crate::link::{Keys, LinkConfig};
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
    let report_acks_out = ipc.episode_ack_publisher()?;
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
    let asked_weights = Latest::<ZBytes>::new();
    ask_for_newest_weights(&session, &keys, &asked_weights);

    let mut out = Outbound {
        session: &session,
        keys: &keys,
        tally: &tally,
        steps: HashMap::new(),
        episodes: HashMap::new(),
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
        busy |= forward_report_acks(&report_acks, &report_acks_out, &tally)?;
        // The answer to an ask, then the broadcast: each is published only if newer
        // than the last weights published.
        for slot in [&asked_weights, &weights] {
            if let Some(bytes) = slot.take() {
                busy = true;
                publish_weights(&ipc, &bytes, &mut weights_out, &tally)?;
            }
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
                ask_for_newest_weights(&session, &keys, &asked_weights);
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
    round: Vec<StepSample>,
}

impl Outbound<'_> {
    /// Put every queued step record and episode report on the link, each on its
    /// actor's key; reports are not put there while the learner host is away
    /// (`learner_alive` false: their actors send them again). Returns whether anything
    /// moved.
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

    /// Every new episode report on the link, while the learner host is there.
    fn forward_reports(&mut self, episodes: &EpisodeSubscriber, learner_alive: bool) -> Result<bool> {
        let mut busy = false;
        while let Some(sample) = episodes.receive().map_err(|e| BridgeError::Link(format!("episodes: {e:?}")))? {
            busy = true;
            let h = sample.user_header();
            if !learner_alive {
                Tally::add(&self.tally.not_delivered, 1);
                continue;
            }
            let put =
                link_for(self.session, &mut self.episodes, h.actor, || self.keys.episodes(h.actor)).and_then(|link| {
                    link.put(wire::encode_episode(h, sample.payload())).wait().map_err(link_err("episode report"))
                });
            match put {
                Ok(()) => Tally::add(&self.tally.episode_reports, 1),
                Err(e) => {
                    Tally::add(&self.tally.not_delivered, 1);
                    tracing::debug!(
                        actor = h.actor,
                        seq = h.seq,
                        "episode report not put on the link (its actor sends it again): {e}"
                    );
                }
            }
        }
        Ok(busy)
    }
}

/// Republish the newest acknowledgements of episode reports from the link on the
/// local service the actors read; whether one came.
fn forward_report_acks(slot: &Latest<ZBytes>, out: &EpisodeAckPublisher, tally: &Tally) -> Result<bool> {
    let Some(bytes) = slot.take() else { return Ok(false) };
    match wire::decode_report_acks(&bytes.to_bytes()) {
        Ok(acks) => {
            let mut table = EpisodeAckTable::default();
            for a in acks {
                // decode_report_acks refuses ids at or above MAX_ACTORS.
                table.actors[a.actor as usize] =
                    EpisodeAck { incarnation: a.incarnation, reserved: 0, taken: a.taken, saved: a.saved };
            }
            out.send_copy(table).map_err(|e| BridgeError::Link(format!("episode ack table: {e:?}")))?;
            Tally::add(&tally.report_acks, 1);
        }
        Err(e) => refuse(tally, &e),
    }
    Ok(true)
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

/// Ask the learner host for the newest weights, without waiting: the answer lands in
/// `slot` (its own, so it cannot displace a broadcast not yet taken). Asked when the
/// bridge starts and whenever the learner host comes (back) on the link, so a late
/// joiner and a host whose link returns act on the current policy at once; no answer
/// is not an error — the next broadcast brings them.
fn ask_for_newest_weights(session: &zenoh::Session, keys: &Keys, slot: &Latest<ZBytes>) {
    let slot = slot.clone();
    let asked = session
        .get(keys.weights())
        .timeout(Duration::from_secs(5))
        .callback(move |reply| {
            if let Ok(sample) = reply.result() {
                slot.put(sample.payload().clone());
            }
        })
        .wait();
    if let Err(e) = asked {
        tracing::debug!("asking the learner host for the newest weights: {e}");
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
