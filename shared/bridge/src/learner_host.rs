//! The learner host's bridge: to the learner and the curriculum service it is a set of
//! local actors; to actor hosts it is the run.
//!
//! What it moves:
//! - step records and episode reports ← the link, each remote actor's through its own
//!   local publishers ([`crate::remote`]);
//! - the learner's acknowledgement tables → the link (*Drop*: the next table replaces
//!   a lost one), and the weights → the link (*Block*), the newest kept to answer a
//!   host that asks for it when it joins;
//! - the curriculum service's acknowledgements of the remote actors' episode reports
//!   → the link, every [`REPORT_ACKS_EVERY`] (*Drop*: they are cumulative, the next
//!   replaces a lost one; `pednav_runtime::reports`);
//! - task requests ← the link, asked of the local curriculum service and answered;
//! - heartbeats both ways: the learner's and the curriculum service's out, the remote
//!   actors' in (the progress line counts them, and the learner reads from them what a
//!   remote actor's stream holds);
//! - joins ([`crate::join`]): a host's request is answered with the run's name,
//!   its config and the host's actor ids;
//! - the run's end → the link, once the learner wrote its done marker (repeated, so a
//!   host that reconnects late hears it too).
//!
//! Invariant: nothing the bridge receives waits on anything in a zenoh callback
//! ([`crate::forward`]); a remote record the learner cannot take (gone, stalled) is
//! dropped here and sent again by its actor, whose window still holds it, and so is a
//! report the curriculum service cannot take. The bridge keeps no record of what went
//! through it: the learner and the curriculum service drop what comes twice.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use pednav_runtime::StopFlag;
use pednav_runtime::ipc::{TaskClient, TaskPending};
use pednav_runtime::messages::{EpisodeAckTable, MAX_ACTORS, ProcessKind};
use zenoh::Wait;
use zenoh::bytes::ZBytes;
use zenoh::qos::CongestionControl;
use zenoh::query::Query;
use zenoh::sample::SampleKind;

use crate::error::{BridgeError, Result};
use crate::forward::{BridgeStats, IDLE, LEARNER_HOST, Latest, LocalRun, STATS_EVERY, Tally, link_err, refuse};
use crate::hosts::HOSTS_FILE;
use crate::join::{JOIN_KEY, JoinDesk, JoinRequest, key_safe_name};
use crate::link::{Keys, LinkConfig};
use crate::remote::{Inbound, RemoteActors, WorkerSetup};
use crate::wire;

/// Requests one task client may have open at once (the task service's
/// `max_active_requests_per_client`).
const TASKS_IN_FLIGHT: usize = 8;
/// How long a task request waits for the curriculum service before it is dropped
/// (the remote actor asks again).
const TASK_TIMEOUT: Duration = Duration::from_secs(5);
/// How often the remote actors' episode report acknowledgements are sent.
const REPORT_ACKS_EVERY: Duration = Duration::from_millis(250);
/// How often the learner's done marker is looked for, and the run's end said again
/// once it is over.
const DONE_EVERY: Duration = Duration::from_millis(500);

/// What the learner host's bridge needs.
#[derive(Debug, Clone)]
pub struct LearnerHostOptions {
    /// The run directory.
    pub run_dir: PathBuf,
    /// Where to listen (`--listen`).
    pub link: LinkConfig,
    /// Actors on the learner host itself (ids `0 .. local_actors`).
    pub local_actors: u32,
}

/// The run's name on the link: its directory's name, made key-safe.
pub fn run_name(run_dir: &std::path::Path) -> String {
    let canonical = run_dir.canonicalize().unwrap_or_else(|_| run_dir.to_path_buf());
    key_safe_name(&canonical.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default())
}

/// Run the learner host's bridge until `stop`; returns what it moved.
pub fn run_learner_host(opts: &LearnerHostOptions, stop: &StopFlag) -> Result<BridgeStats> {
    let local = LocalRun::open(&opts.run_dir)?;
    let run = run_name(&opts.run_dir);
    let keys = Keys::new(&run)?;
    let config_path = local.dir.config_path();
    let config_toml = std::fs::read_to_string(&config_path)
        .map_err(|source| BridgeError::Io { path: config_path.clone(), source })?;
    let mut desk = JoinDesk::open(&local.dir.root().join(HOSTS_FILE), &run, config_toml, opts.local_actors)?;
    let session = opts.link.open()?;
    let ipc = local.ipc("bridge", stop)?;
    let acks_in = ipc.ack_subscriber()?;
    let report_acks_in = ipc.episode_ack_subscriber()?;
    let weights_in = ipc.weights_subscriber()?;
    let tasks_out = ipc.task_client()?;
    let beats_in = ipc.heartbeat_subscriber()?;
    let beats_out = ipc.heartbeat_publisher()?;
    let tally = Arc::new(Tally::default());

    let _token = session.liveliness().declare_token(keys.alive(LEARNER_HOST)).wait().map_err(link_err("liveliness"))?;
    let remote = RemoteActors::new(WorkerSetup {
        prefix: local.prefix.clone(),
        step_buffer: local.cfg.runtime.step_buffer,
        give_up: local.give_up,
        record_bytes: local.cfg.observation_bytes(),
        max_points: local.cfg.sim.t_max as usize + 1,
        backlog: 2 * local.cfg.runtime.resend_window(),
        local_actors: opts.local_actors,
        stop: stop.clone(),
        tally: tally.clone(),
    });
    let inbound = |kind: fn(ZBytes) -> Inbound| {
        let remote = remote.clone();
        move |s: zenoh::sample::Sample| {
            remote.deliver(Keys::last_segment(s.key_expr().as_str()), kind(s.payload().clone()))
        }
    };
    let newest_weights = Latest::<ZBytes>::new();
    let (queries_tx, queries_rx) = mpsc::channel::<(Served, Query)>();
    let (beats_tx, beats_rx) = mpsc::channel::<ZBytes>();
    let (hosts_tx, hosts_rx) = mpsc::channel::<(String, SampleKind)>();
    let declared = (
        session
            .declare_subscriber(keys.all_steps())
            .callback(inbound(Inbound::Step))
            .wait()
            .map_err(link_err("steps"))?,
        session
            .declare_subscriber(keys.all_episodes())
            .callback(inbound(Inbound::Episode))
            .wait()
            .map_err(link_err("episodes"))?,
        session
            .declare_subscriber(keys.all_heartbeats())
            .callback(move |s| {
                let _ = beats_tx.send(s.payload().clone());
            })
            .wait()
            .map_err(link_err("heartbeats"))?,
        queryable(&session, keys.weights(), Served::Weights, queries_tx.clone())?,
        queryable(&session, keys.tasks(), Served::Task, queries_tx.clone())?,
        queryable(&session, JOIN_KEY.to_string(), Served::Join, queries_tx)?,
        session
            .liveliness()
            .declare_subscriber(keys.all_alive())
            .history(true)
            .callback(move |s| {
                let _ = hosts_tx.send((Keys::last_segment(s.key_expr().as_str()).to_string(), s.kind()));
            })
            .wait()
            .map_err(link_err("liveliness subscription"))?,
    );
    let acks_link = session
        .declare_publisher(keys.acks())
        .congestion_control(CongestionControl::Drop)
        .wait()
        .map_err(link_err("ack publisher"))?;
    let weights_link = session
        .declare_publisher(keys.weights())
        .congestion_control(CongestionControl::Block)
        .wait()
        .map_err(link_err("weights publisher"))?;
    let report_acks_link = session
        .declare_publisher(keys.report_acks())
        .congestion_control(CongestionControl::Drop)
        .wait()
        .map_err(link_err("episode report acknowledgement publisher"))?;
    let beats_link = session
        .declare_publisher(keys.heartbeats(LEARNER_HOST))
        .congestion_control(CongestionControl::Drop)
        .wait()
        .map_err(link_err("heartbeat publisher"))?;

    let mut tasks = TaskDesk { waiting: VecDeque::new(), in_flight: Vec::new() };
    // The curriculum service's newest acknowledgements of episode reports.
    let mut report_acks = EpisodeAckTable::default();
    let (mut last_stats, mut last_done, mut last_report_acks) = (Instant::now(), Instant::now(), Instant::now());
    tracing::info!(%run, listen = ?opts.link.listen, local_actors = opts.local_actors, "learner-host bridge up");

    while !stop.is_set() {
        let mut busy = false;
        let mut newest_acks = None;
        while let Some(t) = acks_in.receive().map_err(|e| BridgeError::Link(format!("acks: {e:?}")))? {
            newest_acks = Some(*t.payload());
        }
        if let Some(table) = newest_acks {
            busy = true;
            if acks_link.put(wire::encode_acks(&table)).wait().is_ok() {
                Tally::add(&tally.ack_tables, 1);
            }
        }
        let mut newest = None;
        while let Some(w) = weights_in.receive().map_err(|e| BridgeError::Link(format!("weights: {e:?}")))? {
            newest = Some(ZBytes::from(wire::encode_weights(w.user_header(), w.payload())));
        }
        if let Some(bytes) = newest {
            busy = true;
            newest_weights.put(bytes.clone());
            match weights_link.put(bytes).wait() {
                Ok(()) => Tally::add(&tally.weights, 1),
                Err(e) => tracing::warn!("weights not put on the link: {e}"),
            }
        }
        while let Ok((served, query)) = queries_rx.try_recv() {
            busy = true;
            match served {
                Served::Join => answer_join(&mut desk, &query),
                Served::Task => tasks.waiting.push_back((query, Instant::now())),
                Served::Weights => {
                    if let Some(w) = newest_weights.peek()
                        && let Err(e) = query.reply(keys.weights(), w).wait()
                    {
                        tracing::warn!("the newest weights were not sent to a joining host: {e}");
                    }
                }
            }
        }
        busy |= tasks.serve(&tasks_out, &keys, &tally)?;
        while let Some(h) = beats_in.receive().map_err(|e| BridgeError::Link(format!("heartbeats: {e:?}")))? {
            if h.kind != ProcessKind::ACTOR {
                let _ = beats_link.put(wire::encode_heartbeat(&h)).wait();
            }
        }
        while let Ok(bytes) = beats_rx.try_recv() {
            match wire::decode_heartbeat(&bytes.to_bytes()) {
                Ok(h) if h.kind == ProcessKind::ACTOR && h.id >= opts.local_actors => {
                    let _ = beats_out.send_copy(h);
                    Tally::add(&tally.heartbeats, 1);
                }
                Ok(_) => {}
                Err(e) => refuse(&tally, &e),
            }
        }
        while let Ok((host, kind)) = hosts_rx.try_recv() {
            if host == LEARNER_HOST {
                continue;
            }
            let ids = desk.table().host(&host).map(|h| format!("{:?}", h.ids())).unwrap_or_default();
            if kind == SampleKind::Put {
                tracing::info!(%host, actors = %ids, "a host is on the link");
            } else {
                Tally::add(&tally.hosts_gone, 1);
                tracing::warn!(%host, actors = %ids, "a host left the link: its actors are gone until it is back");
            }
        }
        while let Some(t) = report_acks_in.receive().map_err(|e| BridgeError::Link(format!("episode acks: {e:?}")))? {
            report_acks = *t.payload();
        }
        if last_report_acks.elapsed() >= REPORT_ACKS_EVERY {
            last_report_acks = Instant::now();
            // Sent even when empty: a restarted curriculum service that holds nothing of
            // an actor says so by leaving it out, and its actor then sends again.
            let acks = remote_entries(&report_acks, opts.local_actors);
            if report_acks_link.put(wire::encode_report_acks(&acks)).wait().is_ok() {
                Tally::add(&tally.report_acks, 1);
            }
        }
        if last_done.elapsed() >= DONE_EVERY {
            last_done = Instant::now();
            let _ = say_done(&session, &keys, &local);
        }
        if last_stats.elapsed() >= STATS_EVERY {
            last_stats = Instant::now();
            local.write_stats(&tally.snapshot("learner-host", LEARNER_HOST, &run));
        }
        if !busy {
            std::thread::sleep(IDLE);
        }
    }
    // The launcher stops this bridge soon after the learner's done marker appears: say
    // it once more on the way out, so every actor host stops its actors.
    if say_done(&session, &keys, &local) {
        std::thread::sleep(Duration::from_millis(200));
    }
    // No callback may hand a worker anything once the workers are joined.
    drop(declared);
    remote.join();
    // The newest acknowledgements once more, so an actor host still up hears of what
    // was taken last (the curriculum service stops after this bridge: what it saves
    // then, its actors learn of when the run resumes).
    while let Ok(Some(t)) = report_acks_in.receive() {
        report_acks = *t.payload();
    }
    let acks = remote_entries(&report_acks, opts.local_actors);
    if !acks.is_empty() {
        let _ = session
            .put(keys.report_acks(), wire::encode_report_acks(&acks))
            .congestion_control(CongestionControl::Block)
            .wait();
    }
    let stats = tally.snapshot("learner-host", LEARNER_HOST, &run);
    local.write_stats(&stats);
    crate::link::close(session);
    Ok(stats)
}

/// The entries of `table` for remote actors (ids from `local_actors` on) that have
/// reported, as they travel on the link.
fn remote_entries(table: &EpisodeAckTable, local_actors: u32) -> Vec<wire::ReportAck> {
    (local_actors..MAX_ACTORS as u32)
        .filter_map(|actor| {
            let a = table.actors[actor as usize];
            (a.incarnation != 0).then_some(wire::ReportAck {
                actor,
                incarnation: a.incarnation,
                taken: a.taken,
                saved: a.saved,
            })
        })
        .collect()
}

/// Tell the actor hosts that the run is over, if the learner wrote its done marker;
/// whether it did.
fn say_done(session: &zenoh::Session, keys: &Keys, local: &LocalRun) -> bool {
    match std::fs::read_to_string(local.dir.done_marker()) {
        Ok(reason) => session.put(keys.done(), reason).congestion_control(CongestionControl::Block).wait().is_ok(),
        Err(_) => false,
    }
}

/// Which queryable a query came to.
#[derive(Debug, Clone, Copy)]
enum Served {
    Join,
    Task,
    Weights,
}

/// A queryable whose queries go to the bridge's loop.
fn queryable(
    session: &zenoh::Session,
    key: String,
    served: Served,
    tx: mpsc::Sender<(Served, Query)>,
) -> Result<zenoh::query::Queryable<()>> {
    session
        .declare_queryable(key)
        .callback(move |q| {
            let _ = tx.send((served, q));
        })
        .wait()
        .map_err(link_err("queryable"))
}

/// Grant a join or refuse it, saying why (the joining host prints the reason).
fn answer_join(desk: &mut JoinDesk, query: &Query) {
    let request = query.payload().map(|p| serde_json::from_slice::<JoinRequest>(&p.to_bytes()));
    let answer = match request {
        Some(Ok(request)) => desk.answer(&request).inspect(|g| {
            tracing::info!(host = %request.host, first_actor = g.first_actor, actors = g.actors, "a host joined");
        }),
        Some(Err(e)) => Err(format!("the join request is not one ({e}): is the joining host another pednav version?")),
        None => Err("a join request without a body".to_string()),
    };
    let sent = match answer {
        Ok(grant) => query.reply(JOIN_KEY, serde_json::to_vec(&grant).expect("a grant serialises")).wait(),
        Err(why) => {
            tracing::warn!(%why, "a join was refused");
            query.reply_err(why).wait()
        }
    };
    if let Err(e) = sent {
        tracing::warn!("the join answer was not sent: {e}");
    }
}

/// Remote task requests: waiting for a free slot of the task client, or asked of the
/// curriculum service and waiting for its answer.
struct TaskDesk {
    waiting: VecDeque<(Query, Instant)>,
    in_flight: Vec<(Query, TaskPending, Instant)>,
}

impl TaskDesk {
    /// Ask for what waits while slots are free, answer what was answered; whether
    /// anything happened.
    fn serve(&mut self, client: &TaskClient, keys: &Keys, tally: &Tally) -> Result<bool> {
        let mut busy = false;
        while self.in_flight.len() < TASKS_IN_FLIGHT
            && let Some((query, since)) = self.waiting.pop_front()
        {
            busy = true;
            if since.elapsed() > TASK_TIMEOUT {
                // The actor host gave up on it and the actor asked again: asking the
                // curriculum now would only spend a task.
                continue;
            }
            let request = match query.payload().map(|p| wire::decode_task_request(&p.to_bytes())) {
                Some(Ok(r)) => r,
                Some(Err(e)) => {
                    refuse(tally, &e);
                    continue;
                }
                None => continue,
            };
            match client.send_copy(request) {
                Ok(pending) => self.in_flight.push((query, pending, since)),
                Err(e) => tracing::warn!("a remote task request was not passed to the curriculum service: {e:?}"),
            }
        }
        let mut k = 0;
        while k < self.in_flight.len() {
            let (query, pending, since) = &self.in_flight[k];
            let answer = pending
                .receive()
                .map_err(|e| BridgeError::Link(format!("task response: {e:?}")))?
                .map(|r| wire::encode_task_response(r.payload()));
            let answered = answer.is_some();
            if let Some(bytes) = answer {
                busy = true;
                match query.reply(keys.tasks(), bytes).wait() {
                    Ok(()) => Tally::add(&tally.tasks, 1),
                    Err(e) => tracing::warn!("a task answer was not sent: {e}"),
                }
            }
            if answered || since.elapsed() > TASK_TIMEOUT {
                self.in_flight.swap_remove(k);
            } else {
                k += 1;
            }
        }
        Ok(busy)
    }
}
