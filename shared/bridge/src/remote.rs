//! The learner host's stand-in for one remote actor: a thread with that actor's own
//! local step and episode publishers, fed from the link.
//!
//! Invariants:
//! - one publisher per remote actor, as a local actor has, so the learner's fair intake
//!   serves remote actors exactly as local ones, and a remote actor whose queue is full
//!   stalls only its own worker;
//! - records reach the local services in the order the link delivered them (one
//!   channel, one thread per actor), and a record that claims another actor id than
//!   its key's, or holds an observation of another size than this run's, is refused;
//! - a worker's backlog is bounded: step records that arrive while it holds
//!   [`WorkerSetup::backlog`] of them (a stalled learner, and an actor that sends its
//!   whole window again every few seconds) are dropped and counted — their actor holds
//!   each until a learner acknowledges it and sends it again when asked; so are
//!   episode reports beyond [`REPORT_BACKLOG`] (a curriculum service that is gone,
//!   while the actor sends its held reports again every two seconds) — their actor
//!   holds each until the curriculum service acknowledges it;
//! - a worker keeps no record of what it published: a report that comes again is
//!   published again, and the curriculum service, which acknowledges what it took,
//!   drops it (`pednav_runtime::reports`).

use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, Sender};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use pednav_runtime::StopFlag;
use pednav_runtime::ipc::{EpisodeSender, StepSender};
use zenoh::bytes::ZBytes;

use crate::error::{BridgeError, Result};
use crate::forward::{Tally, refuse};
use crate::wire;

/// A message from the link for one remote actor.
pub(crate) enum Inbound {
    /// A step record.
    Step(ZBytes),
    /// An episode report.
    Episode(ZBytes),
}

/// What every worker needs to open its publishers.
#[derive(Clone)]
pub(crate) struct WorkerSetup {
    /// The run's iceoryx2 prefix, `runtime.step_buffer` and give-up.
    pub prefix: String,
    pub step_buffer: usize,
    pub give_up: Duration,
    /// Observation bytes of a step record (`RunConfig::observation_bytes`).
    pub record_bytes: usize,
    /// Points of the longest episode report (T_max + 1).
    pub max_points: usize,
    /// Step records a worker may hold unpublished (twice an actor's resend window).
    pub backlog: usize,
    /// Actor ids below this are the learner host's own: no remote record may claim one.
    pub local_actors: u32,
    pub stop: StopFlag,
    pub tally: Arc<Tally>,
}

/// Episode reports a worker may hold unpublished.
const REPORT_BACKLOG: usize = 1024;

/// Messages handed to a worker and not yet published.
#[derive(Default)]
struct Queued {
    steps: AtomicUsize,
    reports: AtomicUsize,
}

/// One remote actor's worker, as the callbacks and the bridge's loop see it.
struct Worker {
    /// Where its messages go.
    tx: Sender<Inbound>,
    /// What it holds unpublished.
    queued: Arc<Queued>,
}

/// The remote actors' workers, started on an actor's first message; shared with the
/// zenoh callbacks (which only send into a channel).
#[derive(Clone)]
pub(crate) struct RemoteActors {
    setup: WorkerSetup,
    workers: Arc<Mutex<HashMap<u32, Worker>>>,
    threads: Arc<Mutex<Vec<std::thread::JoinHandle<()>>>>,
}

impl RemoteActors {
    pub(crate) fn new(setup: WorkerSetup) -> RemoteActors {
        RemoteActors { setup, workers: Arc::default(), threads: Arc::default() }
    }

    /// Hand a message from the key of actor `key_actor` (the text after the last '/')
    /// to that actor's worker. Never blocks.
    pub(crate) fn deliver(&self, key_actor: &str, message: Inbound) {
        let actor = match key_actor.parse::<u32>() {
            Ok(a) if (a as usize) < pednav_runtime::ipc::MAX_ACTORS && a >= self.setup.local_actors => a,
            _ => {
                refuse(
                    &self.setup.tally,
                    &BridgeError::Link(format!(
                        "a message on the key of actor {key_actor:?}: not a remote actor id (the learner host's own \
                         actors hold 0 .. {})",
                        self.setup.local_actors
                    )),
                );
                return;
            }
        };
        let mut workers = self.workers.lock().unwrap_or_else(|p| p.into_inner());
        let worker = workers.entry(actor).or_insert_with(|| {
            let (tx, rx) = mpsc::channel();
            let queued = Arc::new(Queued::default());
            let setup = self.setup.clone();
            let counter = queued.clone();
            let handle = std::thread::Builder::new()
                .name(format!("remote-actor-{actor}"))
                .spawn(move || {
                    if let Err(e) = run_worker(&setup, actor, &rx, &counter) {
                        tracing::error!(actor, "the remote actor's forwarding stopped: {e}");
                    }
                })
                .expect("a thread starts");
            self.threads.lock().unwrap_or_else(|p| p.into_inner()).push(handle);
            tracing::info!(actor, "first message from a remote actor");
            Worker { tx, queued }
        });
        let (count, bound) = match message {
            Inbound::Step(_) => (&worker.queued.steps, self.setup.backlog),
            Inbound::Episode(_) => (&worker.queued.reports, REPORT_BACKLOG),
        };
        if count.load(Ordering::Relaxed) >= bound {
            Tally::add(&self.setup.tally.not_delivered, 1);
            return;
        }
        count.fetch_add(1, Ordering::Relaxed);
        let _ = worker.tx.send(message);
    }

    /// Close every worker's channel and wait for the threads (after `stop`).
    pub(crate) fn join(&self) {
        drop(std::mem::take(&mut *self.workers.lock().unwrap_or_else(|p| p.into_inner())));
        let threads = std::mem::take(&mut *self.threads.lock().unwrap_or_else(|p| p.into_inner()));
        for t in threads {
            let _ = t.join();
        }
    }
}

fn run_worker(setup: &WorkerSetup, actor: u32, rx: &Receiver<Inbound>, queued: &Queued) -> Result<()> {
    let ipc = pednav_runtime::Ipc::new(
        &setup.prefix,
        &format!("bridge-actor-{actor}"),
        setup.step_buffer,
        setup.give_up,
        setup.stop.clone(),
    )?;
    let steps = ipc.step_sender(setup.record_bytes)?;
    let episodes = ipc.episode_sender(setup.max_points)?;
    loop {
        let message = match rx.recv_timeout(Duration::from_millis(200)) {
            Ok(m) => m,
            Err(RecvTimeoutError::Timeout) if !setup.stop.is_set() => continue,
            Err(_) => return Ok(()),
        };
        let result = match message {
            Inbound::Step(bytes) => {
                queued.steps.fetch_sub(1, Ordering::Relaxed);
                publish_step(setup, actor, &steps, &bytes)
            }
            Inbound::Episode(bytes) => {
                queued.reports.fetch_sub(1, Ordering::Relaxed);
                publish_episode(setup, actor, &episodes, &bytes)
            }
        };
        if let Err(e) = result {
            refuse(&setup.tally, &e);
        }
    }
}

/// Publish one step record from the link through the actor's local publisher, waiting
/// for the learner as a local actor does.
fn publish_step(setup: &WorkerSetup, actor: u32, steps: &StepSender, bytes: &ZBytes) -> Result<()> {
    let bytes = bytes.to_bytes();
    let (header, observation) = wire::decode_step(&bytes)?;
    check_sender(actor, header.actor, "step record")?;
    if observation.len() != setup.record_bytes {
        return Err(BridgeError::Malformed {
            kind: "step record",
            problem: format!(
                "an observation of {} bytes from actor {actor}, this run's hold {}: the hosts' configs differ",
                observation.len(),
                setup.record_bytes
            ),
        });
    }
    if steps.publish(header, observation, &setup.stop, setup.give_up)? {
        Tally::add(&setup.tally.step_records, 1);
        Tally::add(&setup.tally.step_bytes, observation.len() as u64);
    } else {
        // The learner stalled past runtime.give_up_secs or is gone: the actor holds the
        // record and sends it again when the learner asks.
        Tally::add(&setup.tally.not_delivered, 1);
    }
    Ok(())
}

/// Publish one episode report from the link through the actor's local publisher (the
/// curriculum service drops one it took before).
fn publish_episode(setup: &WorkerSetup, actor: u32, episodes: &EpisodeSender, bytes: &ZBytes) -> Result<()> {
    let bytes = bytes.to_bytes();
    let (header, points) = wire::decode_episode(&bytes)?;
    check_sender(actor, header.actor, "episode report")?;
    if points.len() > setup.max_points {
        // The hosts' configs differ (the join refuses that): refused, and counted.
        return Err(BridgeError::Malformed {
            kind: "episode report",
            problem: format!(
                "{} points from actor {actor}, this run's episodes have at most {}: the hosts' configs differ",
                points.len(),
                setup.max_points
            ),
        });
    }
    if episodes.publish(header, &points, &setup.stop, setup.give_up)? {
        Tally::add(&setup.tally.episode_reports, 1);
    } else {
        // Not taken, so not acknowledged: its actor sends it again.
        Tally::add(&setup.tally.not_delivered, 1);
    }
    Ok(())
}

/// A message must come from the actor whose key it travels on.
fn check_sender(key_actor: u32, claimed: u32, kind: &'static str) -> Result<()> {
    if key_actor == claimed {
        Ok(())
    } else {
        Err(BridgeError::Malformed {
            kind,
            problem: format!("it names actor {claimed} but travels on the key of actor {key_actor}"),
        })
    }
}
