//! The run's iceoryx2 services, opened the same way by every process.
//!
//! Invariants:
//! - every service of a run lives under the run's own prefix ([`run_prefix`]),
//!   derived from the run directory, so two runs side by side never see each
//!   other's services and a run can remove its own stale resources;
//! - the step and episode streams are lossless: safe overflow off and
//!   `RetryUntilDelivered`, with a bounded give-up (the publisher stops retrying
//!   once [`Ipc::give_up`] has passed or the process was asked to stop), so a dead
//!   learner cannot wedge an actor forever — except an actor's own episode reporter,
//!   which never waits (it holds its reports until they are acknowledged and sends
//!   again what a full receiver did not take, [`crate::reports`]);
//! - the learner's intake is fair across actors ([`receive_step_round`]): no
//!   actor waits on its full queue while another's is served;
//! - weights, acknowledgements and heartbeats are lossy by design (newest wins;
//!   history 1 for weights and acknowledgements so a process that starts late still
//!   gets the current ones).
//!
//! Every service is opened with the same settings by every process (an opener
//! with different settings would be refused by iceoryx2), which is why they are
//! built here and nowhere else.

use std::path::Path;
use std::time::Duration;

use iceoryx2::node::Node;
use iceoryx2::port::client::Client;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::server::Server;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::{BackpressureAction, BackpressureInfo};
use iceoryx2::prelude::*;

use crate::error::{Result, RuntimeError};
use crate::messages::{
    AckTable, EpisodeAckTable, EpisodeHeader, EpisodePoint, Heartbeat, StepHeader, TaskRequest, TaskResponse,
    WeightsHeader,
};
use crate::signal::StopFlag;

/// Step-record publisher (actor side).
pub type StepPublisher = Publisher<ipc::Service, [u8], StepHeader>;
/// Step-record subscriber (learner side).
pub type StepSubscriber = Subscriber<ipc::Service, [u8], StepHeader>;
/// Episode-report publisher (actor side).
pub type EpisodePublisher = Publisher<ipc::Service, [EpisodePoint], EpisodeHeader>;
/// Episode-report subscriber (curriculum side).
pub type EpisodeSubscriber = Subscriber<ipc::Service, [EpisodePoint], EpisodeHeader>;
/// Task client (actor side).
pub type TaskClient = Client<ipc::Service, TaskRequest, (), TaskResponse, ()>;
/// Task server (curriculum side).
pub type TaskServer = Server<ipc::Service, TaskRequest, (), TaskResponse, ()>;
/// A task request on its way: the client's side, polled for the response.
pub type TaskPending = iceoryx2::pending_response::PendingResponse<ipc::Service, TaskRequest, (), TaskResponse, ()>;
/// A task request received: the server's side, answered with `send_copy`.
pub type TaskActive = iceoryx2::active_request::ActiveRequest<ipc::Service, TaskRequest, (), TaskResponse, ()>;
/// Weights publisher (learner side).
pub type WeightsPublisher = Publisher<ipc::Service, [f32], WeightsHeader>;
/// Weights subscriber (actor side).
pub type WeightsSubscriber = Subscriber<ipc::Service, [f32], WeightsHeader>;
/// Heartbeat publisher (every process).
pub type HeartbeatPublisher = Publisher<ipc::Service, Heartbeat, ()>;
/// Heartbeat subscriber (the launcher's progress line, tests).
pub type HeartbeatSubscriber = Subscriber<ipc::Service, Heartbeat, ()>;

/// The learner's acknowledgements publisher.
pub type AckPublisher = Publisher<ipc::Service, AckTable, ()>;
/// An actor's view of the learner's acknowledgements.
pub type AckSubscriber = Subscriber<ipc::Service, AckTable, ()>;

/// The curriculum service's episode-report acknowledgements publisher (an actor
/// host's bridge publishes the learner host's there).
pub type EpisodeAckPublisher = Publisher<ipc::Service, EpisodeAckTable, ()>;
/// An actor's view of the episode-report acknowledgements.
pub type EpisodeAckSubscriber = Subscriber<ipc::Service, EpisodeAckTable, ()>;

/// A received step record, borrowed from the sending actor's shared memory until dropped.
pub type StepSample = iceoryx2::sample::Sample<ipc::Service, [u8], StepHeader>;

pub use crate::messages::MAX_ACTORS;
/// Step records the learner may hold from one actor at once, and so one actor's
/// share of a [`receive_step_round`]. 2 is iceoryx2's default, so a step service
/// created by a binary that did not set it explicitly stays compatible.
pub const STEP_ROUND_PER_ACTOR: usize = 2;
/// Episode reports the curriculum service may have queued per actor.
const EPISODE_BUFFER: usize = 256;

/// The iceoryx2 prefix of the run in `run_dir`: `pn` + 8 hex digits of a hash of
/// its canonical path + `_`.
pub fn run_prefix(run_dir: &Path) -> String {
    let canonical = run_dir.canonicalize().unwrap_or_else(|_| run_dir.to_path_buf());
    // FNV-1a: stable across processes and Rust versions (unlike DefaultHasher).
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for b in canonical.to_string_lossy().bytes() {
        h = (h ^ b as u64).wrapping_mul(0x0100_0000_01b3);
    }
    format!("pn{:08x}_", (h ^ (h >> 32)) as u32)
}

fn ipc_err(what: &str, e: impl std::fmt::Debug) -> RuntimeError {
    RuntimeError::Ipc(format!("{what}: {e:?}"))
}

fn service_name(name: &str) -> Result<ServiceName> {
    ServiceName::new(name).map_err(|e| ipc_err(name, e))
}

/// Receive one round of step records, fair across actors: at most
/// [`STEP_ROUND_PER_ACTOR`] from every actor that has records waiting. Returns how
/// many `round` now holds (appended; the caller drops them once consumed).
///
/// Why rounds: iceoryx2's `receive` always serves the first publisher that has
/// data. A learner that takes records more slowly than the actors send them — the
/// normal case, the replay ratio holds inserts back — would drain one actor's
/// always-full queue forever while every other actor blocks on its full queue
/// until it gives up (`runtime.give_up_secs`) and dies. Holding a round's samples
/// until the round ends makes `receive` pass over an actor whose borrow limit is
/// reached, so every actor with data gets its share in every round.
pub fn receive_step_round(sub: &StepSubscriber, round: &mut Vec<StepSample>) -> Result<usize> {
    loop {
        match sub.receive() {
            Ok(Some(sample)) => round.push(sample),
            Ok(None) | Err(iceoryx2::port::ReceiveError::ExceedsMaxBorrows) => return Ok(round.len()),
            Err(e) => return Err(ipc_err("step subscriber", e)),
        }
    }
}

/// A lossless publisher together with its service, so the sender can see whether
/// anyone is listening (records sent to nobody would be lost).
pub struct LosslessSender<
    Payload: std::fmt::Debug + ZeroCopySend + 'static,
    Header: std::fmt::Debug + ZeroCopySend + 'static,
> {
    /// The publisher.
    pub publisher: Publisher<ipc::Service, [Payload], Header>,
    service: iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [Payload], Header>,
}

impl<Payload: std::fmt::Debug + ZeroCopySend + 'static, Header: std::fmt::Debug + ZeroCopySend + 'static>
    LosslessSender<Payload, Header>
{
    /// Subscribers currently attached to the service.
    pub fn subscribers(&self) -> usize {
        self.service.dynamic_config().number_of_subscribers()
    }

    /// Wait until at least one subscriber is attached (or `stop`/`timeout`);
    /// returns whether one is. Call before sending, so nothing goes to nobody.
    pub fn wait_for_subscriber(&self, stop: &StopFlag, timeout: Duration) -> bool {
        let start = std::time::Instant::now();
        while self.subscribers() == 0 {
            if stop.is_set() || start.elapsed() > timeout {
                return false;
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let _ = iceoryx2::port::update_connections::UpdateConnections::update_connections(&self.publisher);
        true
    }

    /// Publish `payload` under `header` once a subscriber is attached (waiting up to
    /// `wait`, as [`LosslessSender::wait_for_subscriber`]); whether it was delivered —
    /// `false` when no subscriber came, the process is stopping, or the receiver stayed
    /// full past the give-up. An error only when no sample can be loaned.
    pub fn publish(&self, header: Header, payload: &[Payload], stop: &StopFlag, wait: Duration) -> Result<bool>
    where
        Payload: Copy,
        Header: Default,
    {
        if self.subscribers() == 0 && !self.wait_for_subscriber(stop, wait) {
            return Ok(false);
        }
        let mut sample = self.publisher.loan_slice_uninit(payload.len()).map_err(|e| ipc_err("loan a sample", e))?;
        *sample.user_header_mut() = header;
        Ok(sample.write_from_slice(payload).send().is_ok())
    }
}

/// Step records: the actor's sender.
pub type StepSender = LosslessSender<u8, StepHeader>;
/// Episode reports: the actor's sender.
pub type EpisodeSender = LosslessSender<EpisodePoint, EpisodeHeader>;

/// One process's connection to the run's services.
pub struct Ipc {
    node: Node<ipc::Service>,
    /// How long a lossless publisher retries a full receiver before giving up.
    pub give_up: Duration,
    stop: StopFlag,
    step_buffer: usize,
}

impl Ipc {
    /// Join the run whose iceoryx2 prefix is `prefix` (see [`run_prefix`]) as the
    /// node `name`; removes resources of dead nodes of this run first.
    pub fn new(prefix: &str, name: &str, step_buffer: usize, give_up: Duration, stop: StopFlag) -> Result<Ipc> {
        let mut config = Config::default();
        config.global.prefix = FileName::new(prefix.as_bytes()).map_err(|e| ipc_err("service prefix", e))?;
        let node_name = NodeName::new(name).map_err(|e| ipc_err("node name", e))?;
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<ipc::Service>()
            .map_err(|e| ipc_err("create node", e))?;
        let ipc = Ipc { node, give_up, stop, step_buffer: step_buffer.max(1) };
        ipc.cleanup_dead_nodes();
        Ok(ipc)
    }

    /// Remove the resources of this run's dead nodes (a SIGKILLed actor, say);
    /// returns how many were cleaned.
    pub fn cleanup_dead_nodes(&self) -> u64 {
        let state = self.node.try_cleanup_dead_nodes();
        if state.cleanups > 0 || state.failed_cleanups > 0 {
            tracing::info!(cleaned = state.cleanups, failed = state.failed_cleanups, "removed dead iceoryx2 nodes");
        }
        state.cleanups
    }

    fn lossless_handler(&self) -> impl Fn(&BackpressureInfo) -> BackpressureAction + Send + 'static {
        let give_up = self.give_up;
        let stop = self.stop.clone();
        move |info: &BackpressureInfo| {
            if stop.is_set() || info.elapsed_time > give_up {
                BackpressureAction::DiscardDataAndFail
            } else {
                if info.retries > 64 {
                    std::thread::sleep(Duration::from_micros(200));
                }
                BackpressureAction::Retry
            }
        }
    }

    /// The step-record publisher of one actor (`max_frame_bytes` per record).
    pub fn step_sender(&self, max_frame_bytes: usize) -> Result<StepSender> {
        let service = self.step_service()?;
        let publisher = service
            .publisher_builder()
            .initial_max_slice_len(max_frame_bytes)
            .max_loaned_samples(4)
            .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
            .set_backpressure_handler(self.lossless_handler())
            .create()
            .map_err(|e| ipc_err("step publisher", e))?;
        Ok(LosslessSender { publisher, service })
    }

    /// The learner's step-record subscriber.
    pub fn step_subscriber(&self) -> Result<StepSubscriber> {
        let service = self.step_service()?;
        service.subscriber_builder().create().map_err(|e| ipc_err("step subscriber", e))
    }

    fn step_service(
        &self,
    ) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [u8], StepHeader>> {
        self.node
            .service_builder(&service_name("pednav/steps")?)
            .publish_subscribe::<[u8]>()
            .user_header::<StepHeader>()
            .enable_safe_overflow(false)
            .subscriber_max_buffer_size(self.step_buffer)
            .subscriber_max_borrowed_samples(STEP_ROUND_PER_ACTOR)
            .history_size(0)
            .max_publishers(MAX_ACTORS)
            .max_subscribers(2)
            .max_nodes(MAX_ACTORS + 4)
            .open_or_create()
            .map_err(|e| ipc_err("step service", e))
    }

    fn episode_service(
        &self,
    ) -> Result<
        iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [EpisodePoint], EpisodeHeader>,
    > {
        self.node
            .service_builder(&service_name("pednav/episodes")?)
            .publish_subscribe::<[EpisodePoint]>()
            .user_header::<EpisodeHeader>()
            .enable_safe_overflow(false)
            .subscriber_max_buffer_size(EPISODE_BUFFER)
            .history_size(0)
            .max_publishers(MAX_ACTORS)
            .max_subscribers(2)
            .max_nodes(MAX_ACTORS + 4)
            .open_or_create()
            .map_err(|e| ipc_err("episode service", e))
    }

    /// An episode-report publisher that waits for room in a full receiver, as a step
    /// sender does (reports of up to `max_points` points): the learner host's stand-in
    /// for a remote actor, which holds nothing itself.
    pub fn episode_sender(&self, max_points: usize) -> Result<EpisodeSender> {
        self.episode_publisher(max_points, true)
    }

    /// An actor's episode-report publisher, which never waits: a report a full
    /// receiver cannot take is not delivered, and its actor, which holds every report
    /// until the curriculum service acknowledges it, sends it again
    /// ([`crate::channels::EpisodeReporter`]).
    pub fn episode_reporter_sender(&self, max_points: usize) -> Result<EpisodeSender> {
        self.episode_publisher(max_points, false)
    }

    /// An episode-report publisher that `waits` for room in a full receiver (up to the
    /// give-up), or drops what a full receiver cannot take.
    fn episode_publisher(&self, max_points: usize, waits: bool) -> Result<EpisodeSender> {
        let service = self.episode_service()?;
        let builder = service.publisher_builder().initial_max_slice_len(max_points).max_loaned_samples(2);
        let builder = if waits {
            builder
                .backpressure_strategy(BackpressureStrategy::RetryUntilDelivered)
                .set_backpressure_handler(self.lossless_handler())
        } else {
            builder.backpressure_strategy(BackpressureStrategy::DiscardData)
        };
        let publisher = builder.create().map_err(|e| ipc_err("episode publisher", e))?;
        Ok(LosslessSender { publisher, service })
    }

    /// The curriculum service's episode-report subscriber.
    pub fn episode_subscriber(&self) -> Result<EpisodeSubscriber> {
        self.episode_service()?.subscriber_builder().create().map_err(|e| ipc_err("episode subscriber", e))
    }

    fn task_service(
        &self,
    ) -> Result<
        iceoryx2::service::port_factory::request_response::PortFactory<ipc::Service, TaskRequest, (), TaskResponse, ()>,
    > {
        self.node
            .service_builder(&service_name("pednav/tasks")?)
            .request_response::<TaskRequest, TaskResponse>()
            .max_clients(MAX_ACTORS)
            .max_servers(1)
            .max_active_requests_per_client(8)
            .max_nodes(MAX_ACTORS + 4)
            .open_or_create()
            .map_err(|e| ipc_err("task service", e))
    }

    /// An actor's task client.
    pub fn task_client(&self) -> Result<TaskClient> {
        self.task_service()?.client_builder().create().map_err(|e| ipc_err("task client", e))
    }

    /// The curriculum service's task server.
    pub fn task_server(&self) -> Result<TaskServer> {
        self.task_service()?.server_builder().create().map_err(|e| ipc_err("task server", e))
    }

    fn weights_service(
        &self,
    ) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, [f32], WeightsHeader>>
    {
        self.node
            .service_builder(&service_name("pednav/weights")?)
            .publish_subscribe::<[f32]>()
            .user_header::<WeightsHeader>()
            .enable_safe_overflow(true)
            .history_size(1)
            .subscriber_max_buffer_size(1)
            .max_publishers(1)
            .max_subscribers(MAX_ACTORS + 2)
            .max_nodes(MAX_ACTORS + 4)
            .open_or_create()
            .map_err(|e| ipc_err("weights service", e))
    }

    /// The learner's weights publisher for `len` floats.
    pub fn weights_publisher(&self, len: usize) -> Result<WeightsPublisher> {
        self.weights_service()?
            .publisher_builder()
            .initial_max_slice_len(len)
            .max_loaned_samples(1)
            .create()
            .map_err(|e| ipc_err("weights publisher", e))
    }

    /// An actor's weights subscriber.
    pub fn weights_subscriber(&self) -> Result<WeightsSubscriber> {
        self.weights_service()?.subscriber_builder().create().map_err(|e| ipc_err("weights subscriber", e))
    }

    /// A service of tables where the newest wins (acknowledgements): safe overflow on,
    /// history 1 so a late subscriber gets the current table, a buffer of 1, one
    /// publisher and a restarting one's successor.
    fn newest_wins_service<T: std::fmt::Debug + ZeroCopySend + 'static>(
        &self,
        name: &str,
    ) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, T, ()>> {
        self.node
            .service_builder(&service_name(name)?)
            .publish_subscribe::<T>()
            .enable_safe_overflow(true)
            .history_size(1)
            .subscriber_max_buffer_size(1)
            .max_publishers(2)
            .max_subscribers(MAX_ACTORS + 2)
            .max_nodes(MAX_ACTORS + 4)
            .open_or_create()
            .map_err(|e| ipc_err(name, e))
    }

    fn ack_service(
        &self,
    ) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, AckTable, ()>> {
        self.newest_wins_service("pednav/acks")
    }

    /// The learner's acknowledgements publisher.
    pub fn ack_publisher(&self) -> Result<AckPublisher> {
        self.ack_service()?.publisher_builder().create().map_err(|e| ipc_err("ack publisher", e))
    }

    /// An actor's subscriber to the learner's acknowledgements.
    pub fn ack_subscriber(&self) -> Result<AckSubscriber> {
        self.ack_service()?.subscriber_builder().create().map_err(|e| ipc_err("ack subscriber", e))
    }

    fn episode_ack_service(
        &self,
    ) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, EpisodeAckTable, ()>>
    {
        self.newest_wins_service("pednav/episode-acks")
    }

    /// The curriculum service's (or an actor host bridge's) episode-report
    /// acknowledgements publisher.
    pub fn episode_ack_publisher(&self) -> Result<EpisodeAckPublisher> {
        self.episode_ack_service()?.publisher_builder().create().map_err(|e| ipc_err("episode ack publisher", e))
    }

    /// A subscriber to the episode-report acknowledgements (an actor; the learner
    /// host's bridge, which forwards the remote actors' entries).
    pub fn episode_ack_subscriber(&self) -> Result<EpisodeAckSubscriber> {
        self.episode_ack_service()?.subscriber_builder().create().map_err(|e| ipc_err("episode ack subscriber", e))
    }

    fn heartbeat_service(
        &self,
    ) -> Result<iceoryx2::service::port_factory::publish_subscribe::PortFactory<ipc::Service, Heartbeat, ()>> {
        self.node
            .service_builder(&service_name("pednav/heartbeats")?)
            .publish_subscribe::<Heartbeat>()
            .enable_safe_overflow(true)
            .subscriber_max_buffer_size(256)
            .history_size(0)
            .max_publishers(MAX_ACTORS + 2)
            .max_subscribers(8)
            .max_nodes(MAX_ACTORS + 4)
            .open_or_create()
            .map_err(|e| ipc_err("heartbeat service", e))
    }

    /// A heartbeat publisher.
    pub fn heartbeat_publisher(&self) -> Result<HeartbeatPublisher> {
        self.heartbeat_service()?.publisher_builder().create().map_err(|e| ipc_err("heartbeat publisher", e))
    }

    /// A heartbeat subscriber.
    pub fn heartbeat_subscriber(&self) -> Result<HeartbeatSubscriber> {
        self.heartbeat_service()?.subscriber_builder().create().map_err(|e| ipc_err("heartbeat subscriber", e))
    }
}
