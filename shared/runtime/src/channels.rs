//! Typed ends of an actor's channels, over the services of [`crate::ipc`]: a
//! [`StepWriter`] (step records into the lossless stream), an [`EpisodeReporter`]
//! (episode reports) and a [`TaskRequester`] (the curriculum's next task). The
//! weights channel's ends are [`crate::weights::WeightsBroadcaster`] and
//! [`crate::weights::WeightsClient`].
//!
//! Invariants: nothing is sent while nobody is subscribed (records to nobody would be
//! lost: each end waits for its subscriber first); a step record's observation is
//! written straight into the loaned shared-memory sample and always in full (a frame
//! or a state vector of exactly the record's size — checked, never assumed); a stop
//! request ends every wait and makes a failed send a clean `None`/`false`.

use std::mem::MaybeUninit;
use std::time::{Duration, Instant};

use crate::error::{Result, RuntimeError};
use crate::ipc::{EpisodeSender, StepSender, TaskClient};
use crate::messages::{EpisodeHeader, EpisodePoint, StepHeader, TaskRequest, TaskResponse, state_payload};
use crate::{Ipc, StopFlag};

/// How long an actor waits for a learner or curriculum service that is gone
/// (the launcher restarts or stops the run well before).
const WAIT_FOR_SUBSCRIBER: Duration = Duration::from_secs(3600);

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

/// An actor's step stream to the learner.
pub struct StepWriter {
    sender: StepSender,
    record_bytes: usize,
    stop: StopFlag,
}

impl StepWriter {
    /// The writer for records of `record_bytes` observation bytes.
    pub fn open(ipc: &Ipc, record_bytes: usize, stop: StopFlag) -> Result<StepWriter> {
        Ok(StepWriter { sender: ipc.step_sender(record_bytes)?, record_bytes, stop })
    }

    /// Wait until the learner is subscribed (or stop, or `timeout`); returns whether it is.
    pub fn wait_for_learner(&self, timeout: Duration) -> bool {
        self.sender.wait_for_subscriber(&self.stop, timeout)
    }

    /// Send one record: loan a sample, write `observation` into it, send. Returns a
    /// copy of the observation bytes (for the policy cache, whose window keeps its
    /// own), or `None` when stopping.
    pub fn send(&self, header: StepHeader, observation: StepPayload<'_>) -> Result<Option<Vec<u8>>> {
        if observation.bytes() != self.record_bytes {
            return Err(RuntimeError::Message(format!(
                "an observation of {} bytes for step records of {}: the actor's config differs from the run's",
                observation.bytes(),
                self.record_bytes
            )));
        }
        if self.sender.subscribers() == 0 {
            tracing::warn!("the learner is gone; waiting for it before sending more steps");
            if !self.wait_for_learner(WAIT_FOR_SUBSCRIBER) {
                return Ok(None);
            }
        }
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
        match sample.send() {
            Ok(_) => Ok(Some(bytes)),
            Err(_) if self.stop.is_set() => Ok(None),
            Err(e) => Err(RuntimeError::Ipc(format!(
                "step record not delivered (learner stalled beyond runtime.give_up_secs?): {e:?}"
            ))),
        }
    }
}

/// An actor's episode reports to the curriculum service.
pub struct EpisodeReporter {
    sender: EpisodeSender,
    stop: StopFlag,
}

impl EpisodeReporter {
    /// The reporter for episodes of at most `max_points` points (T_max + 1).
    pub fn open(ipc: &Ipc, max_points: usize, stop: StopFlag) -> Result<EpisodeReporter> {
        Ok(EpisodeReporter { sender: ipc.episode_sender(max_points)?, stop })
    }

    /// Send one report; `false` when stopping.
    pub fn send(&self, header: EpisodeHeader, points: &[EpisodePoint]) -> Result<bool> {
        if self.sender.subscribers() == 0 && !self.sender.wait_for_subscriber(&self.stop, WAIT_FOR_SUBSCRIBER) {
            return Ok(false);
        }
        let mut sample = self
            .sender
            .publisher
            .loan_slice_uninit(points.len())
            .map_err(|e| RuntimeError::Ipc(format!("loan episode report: {e:?}")))?;
        *sample.user_header_mut() = header;
        let sample = sample.write_from_slice(points);
        match sample.send() {
            Ok(_) => Ok(true),
            Err(_) if self.stop.is_set() => Ok(false),
            Err(e) => Err(RuntimeError::Ipc(format!("episode report not delivered: {e:?}"))),
        }
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
