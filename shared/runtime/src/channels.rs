//! Typed ends of an actor's channels, over the services of [`crate::ipc`]: a
//! [`StepWriter`] (step records into the lossless stream), an [`EpisodeReporter`]
//! (episode reports) and a [`TaskRequester`] (the curriculum's next task). The
//! weights channel's ends are [`crate::weights::WeightsBroadcaster`] and
//! [`crate::weights::WeightsClient`].
//!
//! Invariants: nothing is sent while nobody is subscribed (records to nobody would be
//! lost: the step writer waits for its learner first, the episode reporter holds its
//! reports until someone listens); a step record's observation is written straight
//! into the loaned shared-memory sample and always in full (a frame or a state vector
//! of exactly the record's size — checked, never assumed); a stop request ends every
//! wait and makes a failed send a clean `None`; a step record stays with its writer
//! until a learner acknowledges it, so a learner that restarts is sent again what its
//! predecessor took but never acknowledged, and an episode report stays with its
//! reporter until the curriculum service acknowledges it ([`crate::reports`]).

use std::mem::MaybeUninit;
use std::time::{Duration, Instant};

use crate::error::{Result, RuntimeError};
use crate::ipc::{AckSubscriber, EpisodeAckSubscriber, EpisodeSender, StepSender, TaskClient};
use crate::messages::{EpisodeHeader, EpisodePoint, StepHeader, TaskRequest, TaskResponse, state_payload};
use crate::reliable::SendWindow;
use crate::reports::{self, HeldReports};
use crate::{Ipc, StopFlag};

/// How long an actor waits for a learner that is gone
/// (the launcher restarts or stops the run well before).
const WAIT_FOR_SUBSCRIBER: Duration = Duration::from_secs(3600);
/// A step writer whose window is full and has had no acknowledgement for this long
/// sends everything it holds again (then waits twice as long, up to
/// [`FULL_WINDOW_RESEND_MAX`]): a learner that never saw those records — a replacement
/// behind a link that lost them — learns of them without any message from the actor,
/// which cannot send its heartbeat while it waits here.
const FULL_WINDOW_RESEND: Duration = Duration::from_secs(1);
/// The longest wait between two such resends.
const FULL_WINDOW_RESEND_MAX: Duration = Duration::from_secs(30);

/// The observation of one step record.
#[derive(Clone, Copy)]
pub enum StepPayload<'a> {
    /// View `env` of a batch render.
    Frame {
        /// The batch.
        frames: &'a pednav_sim::Frames<'a>,
        /// Which view.
        env: usize,
    },
    /// A state vector.
    State(&'a [f32]),
}

impl StepPayload<'_> {
    /// Bytes this observation takes in a record.
    pub fn bytes(&self) -> usize {
        match self {
            StepPayload::Frame { frames, .. } => (frames.image_size() as usize).pow(2),
            StepPayload::State(s) => state_payload::bytes(s.len()),
        }
    }

    /// Write all of it into `dst` (which must be exactly [`StepPayload::bytes`] long).
    fn write(&self, dst: &mut [MaybeUninit<u8>]) {
        match self {
            StepPayload::Frame { frames, env } => frames.copy_frame_uninit(*env, dst),
            StepPayload::State(s) => state_payload::encode_state(s, dst),
        }
    }
}

/// Which step stream a [`StepWriter`] writes: one actor incarnation's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StreamId {
    /// Actor id.
    pub actor: u32,
    /// The actor's incarnation (1 for its first start).
    pub incarnation: u32,
}

/// A record the writer holds until the learner acknowledges it.
struct Held {
    header: StepHeader,
    bytes: Vec<u8>,
}

/// What a [`StepWriter`] did beyond sending each record once.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ResendCounts {
    /// Records sent again because a learner asked (a restarted learner, a cut link).
    pub resent: u64,
    /// Times a learner asked.
    pub requests: u64,
    /// Times the window was full with no acknowledgement for a while and everything held
    /// was sent again unasked.
    pub timeouts: u64,
}

/// An actor's step stream to the learner, lossless across a restarted learner: it
/// numbers records, keeps each until the learner acknowledges it, and sends again
/// what a learner asks for ([`crate::reliable`]). A full window makes it wait, as a
/// full learner queue does.
pub struct StepWriter {
    sender: StepSender,
    acks: AckSubscriber,
    window: SendWindow<Held>,
    stream: StreamId,
    record_bytes: usize,
    give_up: Duration,
    stop: StopFlag,
    counts: ResendCounts,
    refused_ack_logged: bool,
}

impl StepWriter {
    /// The writer of `stream`, for records of `record_bytes` observation bytes,
    /// holding at most `window` unacknowledged records.
    pub fn open(ipc: &Ipc, stream: StreamId, record_bytes: usize, window: usize, stop: StopFlag) -> Result<StepWriter> {
        Ok(StepWriter {
            sender: ipc.step_sender(record_bytes)?,
            acks: ipc.ack_subscriber()?,
            window: SendWindow::new(window.max(1)),
            stream,
            record_bytes,
            give_up: ipc.give_up,
            stop,
            counts: ResendCounts::default(),
            refused_ack_logged: false,
        })
    }

    /// Wait until the learner is subscribed (or stop, or `timeout`); returns whether it is.
    pub fn wait_for_learner(&self, timeout: Duration) -> bool {
        self.sender.wait_for_subscriber(&self.stop, timeout)
    }

    /// The sequence number the next record must carry (= records numbered so far).
    pub fn next_seq(&self) -> u64 {
        self.window.next_seq()
    }

    /// The oldest record not yet acknowledged (every one below it was).
    pub fn base(&self) -> u64 {
        self.window.base()
    }

    /// Records held for a resend (sent, not yet acknowledged).
    pub fn held(&self) -> usize {
        self.window.held()
    }

    /// What was sent again so far.
    pub fn resends(&self) -> ResendCounts {
        self.counts
    }

    /// Send one record: wait for room in the window, send what a learner asked for
    /// again, then loan a sample, write `observation` into it and send it. The header's
    /// stream and sequence number must be this writer's ([`StepWriter::next_seq`]);
    /// its `base` is filled in. Returns a copy of the observation bytes (for the policy
    /// cache, whose window keeps its own), or `None` when stopping.
    pub fn send(&mut self, mut header: StepHeader, observation: StepPayload<'_>) -> Result<Option<Vec<u8>>> {
        if observation.bytes() != self.record_bytes {
            return Err(RuntimeError::Message(format!(
                "an observation of {} bytes for step records of {}: the actor's config differs from the run's",
                observation.bytes(),
                self.record_bytes
            )));
        }
        if (header.actor, header.incarnation, header.seq)
            != (self.stream.actor, self.stream.incarnation, self.window.next_seq())
        {
            return Err(RuntimeError::Message(format!(
                "step record (actor {}, incarnation {}, seq {}) on the stream of actor {}, incarnation {}, whose next \
                 record is {}",
                header.actor,
                header.incarnation,
                header.seq,
                self.stream.actor,
                self.stream.incarnation,
                self.window.next_seq()
            )));
        }
        if self.sender.subscribers() == 0 {
            tracing::warn!("the learner is gone; waiting for it before sending more steps");
            if !self.wait_for_learner(WAIT_FOR_SUBSCRIBER) {
                return Ok(None);
            }
        }
        if !self.make_room()? || !self.send_requested()? {
            return Ok(None);
        }
        header.base = self.window.base();
        let mut sample = self
            .sender
            .publisher
            .loan_slice_uninit(self.record_bytes)
            .map_err(|e| RuntimeError::Ipc(format!("loan step record: {e:?}")))?;
        *sample.user_header_mut() = header;
        observation.write(sample.payload_mut());
        // SAFETY: `write` initialised every byte: the payload is `record_bytes` long,
        // which equals `observation.bytes()` (checked above), and both writers fill
        // their whole destination (they assert its length).
        let sample = unsafe { sample.assume_init() };
        let bytes = sample.payload().to_vec();
        let held = Held { header, bytes: bytes.clone() };
        if self.window.push(held).is_err() {
            unreachable!("make_room left room in the window");
        }
        let sent = self.window.take_next().map(|o| o.seq);
        debug_assert_eq!(sent, Some(header.seq), "the new record is the next to transmit");
        match sample.send() {
            Ok(_) => Ok(Some(bytes)),
            Err(_) if self.stop.is_set() => Ok(None),
            Err(e) => Err(RuntimeError::Ipc(format!(
                "step record not delivered (learner stalled beyond runtime.give_up_secs?): {e:?}"
            ))),
        }
    }

    /// Apply the learner's newest acknowledgement of this stream, if there is one.
    fn apply_acks(&mut self) -> Result<()> {
        let mut newest = None;
        loop {
            match self.acks.receive() {
                Ok(Some(table)) => newest = Some(table.payload().streams[self.stream.actor as usize]),
                Ok(None) => break,
                Err(e) => return Err(RuntimeError::Ipc(format!("ack subscriber: {e:?}"))),
            }
        }
        let Some(entry) = newest.filter(|e| e.incarnation == self.stream.incarnation) else { return Ok(()) };
        match self.window.on_ack(entry.ack) {
            Ok(effect) if effect.rewound => {
                self.counts.requests += 1;
                tracing::info!(
                    from = entry.ack.expected.max(self.window.base()),
                    up_to = self.window.next_seq(),
                    "the learner asked for step records again (it restarted, or records were lost on the way)"
                );
            }
            Ok(_) => {}
            Err(e) if !self.refused_ack_logged => {
                self.refused_ack_logged = true;
                tracing::warn!(error = %e, "an acknowledgement was refused (logged once)");
            }
            Err(_) => {}
        }
        Ok(())
    }

    /// Wait until the window has room for one more record, sending again what a
    /// learner asks for meanwhile. `false` when stopping; an error after
    /// `runtime.give_up_secs` without room.
    fn make_room(&mut self) -> Result<bool> {
        let started = Instant::now();
        let (mut quiet_since, mut resend_after) = (started, FULL_WINDOW_RESEND);
        loop {
            let base = self.window.base();
            self.apply_acks()?;
            if self.window.has_room() {
                return Ok(true);
            }
            if self.stop.is_set() {
                return Ok(false);
            }
            if self.window.base() != base {
                (quiet_since, resend_after) = (Instant::now(), FULL_WINDOW_RESEND);
            } else if quiet_since.elapsed() >= resend_after {
                self.window.rewind();
                self.counts.timeouts += 1;
                tracing::info!(
                    held = self.window.held(),
                    from = self.window.base(),
                    waited_s = resend_after.as_secs_f64(),
                    "window full with no acknowledgement: sending the step records it holds again"
                );
                (quiet_since, resend_after) = (Instant::now(), (resend_after * 2).min(FULL_WINDOW_RESEND_MAX));
            }
            if started.elapsed() > self.give_up {
                return Err(RuntimeError::Timeout(format!(
                    "no learner acknowledged any of the last {} step records within runtime.give_up_secs = {:?}",
                    self.window.held(),
                    self.give_up
                )));
            }
            if !self.send_requested()? {
                return Ok(false);
            }
            std::thread::sleep(Duration::from_micros(200));
        }
    }

    /// Send again, in order, every held record a learner asked for. `false` when stopping.
    fn send_requested(&mut self) -> Result<bool> {
        while let Some(o) = self.window.take_next() {
            let mut header = o.record.header;
            header.base = o.base;
            let mut sample = self
                .sender
                .publisher
                .loan_slice_uninit(self.record_bytes)
                .map_err(|e| RuntimeError::Ipc(format!("loan step record: {e:?}")))?;
            *sample.user_header_mut() = header;
            let sample = sample.write_from_slice(&o.record.bytes);
            match sample.send() {
                Ok(_) => self.counts.resent += 1,
                Err(_) if self.stop.is_set() => return Ok(false),
                Err(e) => return Err(RuntimeError::Ipc(format!("step record not sent again: {e:?}"))),
            }
        }
        Ok(true)
    }
}

/// Episode reports an actor holds until the curriculum service saved them, at most
/// (the service saves every `runtime.curriculum_save_every_episodes` episodes of all
/// actors; while nobody acknowledges them — a curriculum service or a learner host
/// that is away — the oldest are given up first, and counted).
pub const HELD_REPORTS: usize = 1024;
/// How long a sent report waits for its acknowledgement before it is sent again (the
/// curriculum service acknowledges within a tenth of a second on one host, the learner
/// host's bridge every quarter of a second across hosts).
pub const REPORT_RESEND_AFTER: Duration = Duration::from_secs(2);
/// Reports sent at most per [`EpisodeReporter::pump`]: a window sent again after a long
/// absence goes out over several steps, not in one burst.
const REPORTS_PER_PUMP: usize = 64;

/// What an [`EpisodeReporter`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReportCounts {
    /// Reports made (numbered, held).
    pub made: u64,
    /// Reports sent again because no acknowledgement came in time.
    pub resent: u64,
    /// Reports dropped unacknowledged to make room in a full window.
    pub given_up: u64,
    /// Reports held now (not yet saved by the curriculum service).
    pub held: u64,
    /// Of those, reports the curriculum service has not said it took.
    pub untaken: u64,
}

/// An actor's episode reports to the curriculum service, lossless end to end: it
/// numbers each report, holds it until the curriculum service has saved it, and sends
/// it again when no acknowledgement that it was taken came in time, or when the
/// service says it lacks it ([`crate::reports`]). It never waits: a report nobody
/// takes now stays held and goes out at a later [`EpisodeReporter::pump`].
pub struct EpisodeReporter {
    sender: EpisodeSender,
    acks: EpisodeAckSubscriber,
    stream: StreamId,
    window: HeldReports,
    counts: ReportCounts,
}

impl EpisodeReporter {
    /// The reporter of `stream`, for episodes of at most `max_points` points (T_max + 1).
    pub fn open(ipc: &Ipc, stream: StreamId, max_points: usize) -> Result<EpisodeReporter> {
        Ok(EpisodeReporter {
            sender: ipc.episode_reporter_sender(max_points)?,
            acks: ipc.episode_ack_subscriber()?,
            stream,
            window: HeldReports::new(HELD_REPORTS),
            counts: ReportCounts::default(),
        })
    }

    /// What it did so far.
    pub fn counts(&self) -> ReportCounts {
        ReportCounts { held: self.window.len() as u64, untaken: self.window.untaken() as u64, ..self.counts }
    }

    /// Hold one report and send what is due: `header`'s stream, number and low-water
    /// mark are filled in here.
    pub fn report(&mut self, mut header: EpisodeHeader, points: &[EpisodePoint]) -> Result<()> {
        (header.actor, header.incarnation, header.seq) = (self.stream.actor, self.stream.incarnation, self.counts.made);
        self.counts.made += 1;
        if self.window.push(header, points.to_vec()) {
            self.counts.given_up += 1;
            if self.counts.given_up.is_power_of_two() {
                tracing::warn!(
                    given_up = self.counts.given_up,
                    held = self.window.len(),
                    "no acknowledgement of episode reports for a long while: the oldest held ones are given up"
                );
            }
        }
        self.pump()
    }

    /// Apply the curriculum service's newest acknowledgement (forget what it saved),
    /// and send every held report that is due (new, sent [`REPORT_RESEND_AFTER`] ago
    /// without word that it was taken, or one the service says it lacks after a
    /// restart). Cheap when there is nothing to do: call it once per step.
    pub fn pump(&mut self) -> Result<()> {
        let mut newest = None;
        loop {
            match self.acks.receive() {
                Ok(Some(table)) => {
                    newest = Some(reports::acknowledged(table.payload(), self.stream.actor, self.stream.incarnation));
                }
                Ok(None) => break,
                Err(e) => return Err(RuntimeError::Ipc(format!("episode ack subscriber: {e:?}"))),
            }
        }
        if let Some((taken, saved)) = newest {
            self.window.acknowledge(taken, saved);
        }
        let now = Instant::now();
        if !self.window.any_due(now, REPORT_RESEND_AFTER) {
            return Ok(());
        }
        if self.sender.subscribers() == 0 {
            // Nobody takes reports now (a curriculum service or a bridge restarting):
            // they stay held (a send connects to a new subscriber by itself).
            return Ok(());
        }
        let publisher = &self.sender.publisher;
        let mut failed = None;
        let (_, again) = self.window.send_due(now, REPORT_RESEND_AFTER, REPORTS_PER_PUMP, |header, points| {
            let mut sample = match publisher.loan_slice_uninit(points.len()) {
                Ok(s) => s,
                Err(e) => {
                    failed = Some(RuntimeError::Ipc(format!("loan episode report: {e:?}")));
                    return false;
                }
            };
            *sample.user_header_mut() = *header;
            // A full receiver does not take it (never waited for): held, sent again later.
            sample.write_from_slice(points).send().is_ok()
        });
        self.counts.resent += again as u64;
        match failed {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// At the actor's end: send what is due and wait up to `wait` for word that the
    /// curriculum service took every held report, while a receiver is there (saving
    /// them is the service's, at its next save or when it stops); returns how many it
    /// has not said it took.
    pub fn flush(&mut self, wait: Duration) -> Result<usize> {
        let started = Instant::now();
        while self.window.untaken() > 0 && started.elapsed() < wait && self.sender.subscribers() > 0 {
            self.pump()?;
            std::thread::sleep(Duration::from_millis(10));
        }
        Ok(self.window.untaken())
    }
}

/// An actor's task requests to the curriculum service.
pub struct TaskRequester {
    client: TaskClient,
    timeout: Duration,
    stop: StopFlag,
}

impl TaskRequester {
    /// The requester; a request unanswered for `timeout` is an error.
    pub fn open(ipc: &Ipc, timeout: Duration, stop: StopFlag) -> Result<TaskRequester> {
        Ok(TaskRequester { client: ipc.task_client()?, timeout, stop })
    }

    /// Ask for the next task of (`actor`, `env`); retries every second while the
    /// service is not (yet) there. `None` when stopping.
    pub fn request(&self, actor: u32, env: u32) -> Result<Option<TaskResponse>> {
        let start = Instant::now();
        while !self.stop.is_set() {
            if start.elapsed() > self.timeout {
                return Err(RuntimeError::Timeout(format!(
                    "no task from the curriculum service within runtime.task_timeout_secs = {:?}",
                    self.timeout
                )));
            }
            let pending = self
                .client
                .send_copy(TaskRequest { actor, env })
                .map_err(|e| RuntimeError::Ipc(format!("task request: {e:?}")))?;
            let asked = Instant::now();
            while asked.elapsed() < Duration::from_secs(1) && !self.stop.is_set() {
                if let Some(response) =
                    pending.receive().map_err(|e| RuntimeError::Ipc(format!("task response: {e:?}")))?
                {
                    return Ok(Some(*response.payload()));
                }
                std::thread::sleep(Duration::from_micros(200));
            }
        }
        Ok(None)
    }
}
