//! Message types of the pednav services, defined once for every process.
//!
//! Invariant: every type here is `#[repr(C)]`, holds no pointers and is
//! [`ZeroCopySend`], so it can live in iceoryx2 shared memory and be read by
//! another process built from the same source. Variable-length data (a frame,
//! an episode's steps, the weights) travels as the slice payload of a service
//! whose user header is one of these types.

use iceoryx2::prelude::ZeroCopySend;

use crate::reliable::Ack;

/// Most actor processes a run may have alive at once, on all its hosts together: actor
/// ids are below it (a remote actor has a local publisher on the learner host, so it
/// sizes the services too), and the learner's [`AckTable`] has one entry per id.
pub const MAX_ACTORS: usize = 256;

/// `contains` and `with` of a `u32` bit-set newtype: the one rule of the wire's flag types.
macro_rules! bit_set {
    ($t:ident) => {
        impl $t {
            /// Whether every bit of `other` is set (never for the empty set).
            pub fn contains(self, other: $t) -> bool {
                self.0 & other.0 == other.0 && other.0 != 0
            }

            /// These bits and `other`'s.
            #[must_use]
            pub fn with(self, other: $t) -> $t {
                $t(self.0 | other.0)
            }
        }
    };
}

bit_set!(StepFlags);
bit_set!(Faults);

/// Flag bits of [`StepHeader::flags`]: what happened at a step, as a set. The actor
/// builds it with [`StepFlags::with`] and the learner reads it with
/// [`StepFlags::contains`]; the bit values are the wire format and never change.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
pub struct StepFlags(pub u32);

impl StepFlags {
    /// Nothing happened (a step inside an episode).
    pub const NONE: StepFlags = StepFlags(0);
    /// First step of an episode: the frame is the reset observation; action and reward are unused.
    pub const FIRST: StepFlags = StepFlags(1);
    /// The episode ended with this step without bootstrapping: the goal was reached,
    /// or (with traffic) a vehicle hit the agent ([`StepFlags::VEHICLE_HIT`] then set too).
    pub const TERMINAL: StepFlags = StepFlags(2);
    /// The episode hit T_max with this step (bootstrapping).
    pub const TRUNCATED: StepFlags = StepFlags(4);
    /// The agent collided during this step.
    pub const COLLIDED: StepFlags = StepFlags(8);
    /// Traffic: a vehicle hit the agent in this step (the episode ends, terminal).
    pub const VEHICLE_HIT: StepFlags = StepFlags(16);
    /// Traffic: the agent stepped onto a zebra that did not show WALK.
    pub const DONT_WALK_ENTRY: StepFlags = StepFlags(32);
    /// Traffic: the agent bumped into another pedestrian.
    pub const PEDESTRIAN_BUMP: StepFlags = StepFlags(64);

    /// These flags and `other`'s when `on`, else these.
    #[must_use]
    pub fn with_if(self, other: StepFlags, on: bool) -> StepFlags {
        if on { self.with(other) } else { self }
    }
}

/// The payload of a step record in state mode: the state vector as little-endian
/// f32 bytes. The actor writes it with [`encode_state`], the learner reads it with
/// [`decode_state`]; no other code knows the layout.
pub mod state_payload {
    use std::mem::MaybeUninit;

    /// Bytes of a payload holding `dim` values.
    pub fn bytes(dim: usize) -> usize {
        dim * 4
    }

    /// Write `state` into `dst` (exactly [`bytes`]`(state.len())` long).
    pub fn encode_state(state: &[f32], dst: &mut [MaybeUninit<u8>]) {
        assert_eq!(dst.len(), bytes(state.len()), "a state payload holds exactly its values");
        for (chunk, v) in dst.chunks_exact_mut(4).zip(state) {
            for (d, b) in chunk.iter_mut().zip(v.to_le_bytes()) {
                d.write(b);
            }
        }
    }

    /// The state vector of a payload (its length must be a multiple of 4).
    pub fn decode_state(payload: &[u8]) -> Vec<f32> {
        payload.chunks_exact(4).map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect()
    }

    #[cfg(test)]
    mod tests {
        #[test]
        fn a_state_round_trips_bit_exactly() {
            let state = [1.5f32, -0.0, f32::MIN_POSITIVE, 3.0e7];
            let mut buf = vec![std::mem::MaybeUninit::new(0u8); super::bytes(state.len())];
            super::encode_state(&state, &mut buf);
            // SAFETY: encode_state initialised every byte of `buf` (and it started initialised).
            let bytes: Vec<u8> = buf.iter().map(|b| unsafe { b.assume_init() }).collect();
            let back = super::decode_state(&bytes);
            assert_eq!(back.iter().map(|v| v.to_bits()).collect::<Vec<_>>(), state.map(f32::to_bits).to_vec());
        }
    }
}

/// Header of one step record; the payload is the new observation (an
/// `image_size²` u8 frame, or the f32 state vector as bytes in state mode),
/// written by the actor straight into the loaned shared-memory sample.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
pub struct StepHeader {
    /// Actor id (0 … actors−1).
    pub actor: u32,
    /// Environment index within the actor.
    pub env: u32,
    /// Incarnation of the actor process (its start counter), so a restarted actor's
    /// streams never splice into the dead one's.
    pub incarnation: u32,
    /// What happened at this step.
    pub flags: StepFlags,
    /// Episode id, unique per (actor, env, incarnation).
    pub episode: u64,
    /// Step index within the episode (0 for the reset observation).
    pub step: u32,
    /// Reward of the step that led to this observation.
    pub reward: f32,
    /// Action that led to this observation.
    pub action: [f32; 3],
    /// Weights version the action was computed with (0: the initial weights).
    pub policy_version: u64,
    /// Running sequence number of records sent by this actor incarnation (0, 1, 2, …;
    /// a resent record keeps its number).
    pub seq: u64,
    /// The oldest sequence number the actor still holds to send again: every record
    /// below it was acknowledged by a learner. A learner that has not seen this stream
    /// (a restarted one) starts here ([`crate::reliable`]).
    pub base: u64,
    /// The simulator's state vector at the new observation
    /// ([`pednav_sim::state_obs::state_observation`]: its first
    /// [`pednav_sim::state_obs_dim`] entries, zeros after) when the learner uses it as
    /// the target of the state-prediction auxiliary loss (`dsac.state_aux_weight` > 0)
    /// or in state mode, zeros otherwise. Privileged: it never reaches the policy's
    /// input (in state mode the observation is the payload).
    pub state: [f32; pednav_sim::STATE_OBS_MAX],
}

impl Default for StepHeader {
    /// All zeros (std derives `Default` for arrays of at most 32 only).
    fn default() -> StepHeader {
        StepHeader {
            actor: 0,
            env: 0,
            incarnation: 0,
            flags: StepFlags::default(),
            episode: 0,
            step: 0,
            reward: 0.0,
            action: [0.0; 3],
            policy_version: 0,
            seq: 0,
            base: 0,
            state: [0.0; pednav_sim::STATE_OBS_MAX],
        }
    }
}

impl StepHeader {
    /// Is a flag set?
    pub fn has(&self, flag: StepFlags) -> bool {
        self.flags.contains(flag)
    }

    /// CRC-32 of a record as sender and receiver both compute it (sequence number,
    /// episode, step, then the observation bytes), to check a stream end to end.
    pub fn record_crc(&self, observation: &[u8]) -> u32 {
        let mut c = crc32fast::Hasher::new();
        c.update(&self.seq.to_le_bytes());
        c.update(&self.episode.to_le_bytes());
        c.update(&self.step.to_le_bytes());
        c.update(observation);
        c.finalize()
    }

    /// The replay stream this record belongs to: one per (actor, env, incarnation).
    pub fn stream(&self) -> u64 {
        ((self.actor as u64) << 40) | ((self.incarnation as u64 & 0xFF_FFFF) << 16) | (self.env as u64 & 0xFFFF)
    }

    /// Whether the replay stream `stream` ([`StepHeader::stream`]) is one of this
    /// record's actor incarnation (any of its envs).
    pub fn same_actor_incarnation(&self, stream: u64) -> bool {
        stream >> 16 == self.stream() >> 16
    }
}

/// Header of an episode report; the payload is the episode's T+1 [`EpisodePoint`]s
/// (pose s_t and the reward r_t that led there; r_0 = 0).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
pub struct EpisodeHeader {
    /// Actor id.
    pub actor: u32,
    /// Environment index within the actor.
    pub env: u32,
    /// Task id handed out by the curriculum service.
    pub task_id: u64,
    /// Curriculum category code of the task (`pednav_config::Category::code`).
    pub category: u32,
    /// 1 when the goal was reached.
    pub success: u32,
    /// 1 when the episode hit T_max (returns are bootstrapped).
    pub truncated: u32,
    /// Decision steps T.
    pub length: u32,
    /// Discounted return from the start, Σ γ^k r_{k+1}, as the actor computed it.
    pub discounted_return: f32,
    /// Undiscounted sum of rewards.
    pub total_reward: f32,
    /// Incarnation of the actor process (as in [`StepHeader::incarnation`]).
    pub incarnation: u32,
    /// Running number of this actor incarnation's episode reports (0, 1, 2, …): with
    /// `actor` and `incarnation` it names a report, so a resent one is known as such.
    pub seq: u64,
    /// The sender's low-water mark: the lowest report number of this actor incarnation
    /// it still holds (every one below was acknowledged, or given up for room), so the
    /// receiver never waits for a report that will not come ([`crate::reports`]).
    pub low_water: u64,
    /// The start's position in the signal cycle, [0, 1), as the task gave it (read
    /// only when `has_cycle` is 1).
    pub start_cycle: f32,
    /// 1 when the task set the start's position in the signal cycle
    /// (`curriculum.signal_phase = "task"`), 0 when the episode's seed drew it.
    pub has_cycle: u32,
}

impl EpisodeHeader {
    /// The start's position in the signal cycle, when the task set it.
    pub fn start_cycle(&self) -> Option<f32> {
        (self.has_cycle != 0).then_some(self.start_cycle)
    }

    /// Set (or clear) the start's position in the signal cycle.
    pub fn with_start_cycle(self, cycle: Option<f32>) -> EpisodeHeader {
        EpisodeHeader { start_cycle: cycle.unwrap_or(0.0), has_cycle: cycle.is_some() as u32, ..self }
    }
}

/// One point of an episode: the pose reached and the reward of the step that led there.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
pub struct EpisodePoint {
    /// x, metres.
    pub x: f32,
    /// y, metres.
    pub y: f32,
    /// Body yaw, radians.
    pub yaw: f32,
    /// Reward of the step into this pose (0 for s_0).
    pub reward: f32,
}

/// An actor's request for the next task of one environment.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
pub struct TaskRequest {
    /// Actor id.
    pub actor: u32,
    /// Environment index within the actor.
    pub env: u32,
}

/// The curriculum service's answer: a start pose, its category and an id.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
pub struct TaskResponse {
    /// Start x, metres.
    pub x: f32,
    /// Start y, metres.
    pub y: f32,
    /// Start yaw, radians.
    pub yaw: f32,
    /// Category code (`pednav_config::Category::code`).
    pub category: u32,
    /// Task id, unique within the run.
    pub task_id: u64,
    /// The start's position in the signal cycle, [0, 1) (read only when `has_cycle` is 1).
    pub cycle: f32,
    /// 1 when the curriculum sets the start's position in the signal cycle
    /// (`curriculum.signal_phase = "task"`), 0 when the episode's seed draws it.
    pub has_cycle: u32,
}

impl TaskResponse {
    /// The start's position in the signal cycle, when the task sets it.
    pub fn cycle(&self) -> Option<f32> {
        (self.has_cycle != 0).then_some(self.cycle)
    }

    /// Set (or clear) the start's position in the signal cycle.
    pub fn with_cycle(self, cycle: Option<f32>) -> TaskResponse {
        TaskResponse { cycle: cycle.unwrap_or(0.0), has_cycle: cycle.is_some() as u32, ..self }
    }
}

/// Header of a weights broadcast; the payload is every parameter of the acting
/// networks flattened in [`crate::weights`] order.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
pub struct WeightsHeader {
    /// Monotone version (the learner's update count when published).
    pub version: u64,
    /// Number of f32 values in the payload.
    pub len: u64,
    /// Learner clock when published (ns since the Unix epoch), for latency measurements.
    pub published_ns: u64,
}

/// One actor's entry in the learner's [`AckTable`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
pub struct StreamAck {
    /// The actor incarnation the acknowledgement is for (0: none seen yet; incarnations
    /// start at 1).
    pub incarnation: u32,
    /// The learner's acknowledgement of that incarnation's step stream.
    pub ack: Ack,
}

/// The learner's acknowledgements of every actor's step stream, indexed by actor id
/// (an actor's newest incarnation). Newest wins: each table replaces the last, so it
/// travels on a lossy service ([`crate::reliable`] explains why that is enough).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
pub struct AckTable {
    /// Entry `k` is actor `k`'s.
    pub streams: [StreamAck; MAX_ACTORS],
}

impl Default for AckTable {
    fn default() -> Self {
        AckTable { streams: [StreamAck::default(); MAX_ACTORS] }
    }
}

/// One actor's entry in the curriculum service's [`EpisodeAckTable`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
pub struct EpisodeAck {
    /// The actor incarnation the entry is for (0: none reported yet; incarnations
    /// start at 1).
    pub incarnation: u32,
    /// Unused (keeps the counters aligned on every layout).
    pub reserved: u32,
    /// Every report of that incarnation numbered below this was taken (it is in the
    /// service's memory: not to be sent again unless this number goes back, which
    /// says the service restarted without it).
    pub taken: u64,
    /// Every report of that incarnation numbered below this is in the service's saved
    /// state (its actor may forget it).
    pub saved: u64,
}

/// The curriculum service's acknowledgements of every actor's episode reports,
/// indexed by actor id (an actor's newest incarnation). Newest wins, as the
/// [`AckTable`] of step records: each table replaces the last; an actor stops sending
/// the reports it holds below its entry's `taken` and forgets those below `saved`
/// ([`crate::reports`]).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
pub struct EpisodeAckTable {
    /// Entry `k` is actor `k`'s.
    pub actors: [EpisodeAck; MAX_ACTORS],
}

impl Default for EpisodeAckTable {
    fn default() -> Self {
        EpisodeAckTable { actors: [EpisodeAck::default(); MAX_ACTORS] }
    }
}

/// Kind of process a [`Heartbeat`] comes from (the code is the wire format).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, PartialOrd, Ord, ZeroCopySend)]
pub struct ProcessKind(pub u32);

impl ProcessKind {
    /// An actor.
    pub const ACTOR: ProcessKind = ProcessKind(1);
    /// The learner.
    pub const LEARNER: ProcessKind = ProcessKind(2);
    /// The curriculum service.
    pub const CURRICULUM: ProcessKind = ProcessKind(3);
    /// A bridge between hosts (it sends no heartbeat; the launcher names it so).
    pub const BRIDGE: ProcessKind = ProcessKind(4);
}

/// Periodic liveness and progress of one process (for the launcher's progress line and logs).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
pub struct Heartbeat {
    /// The process that sends it.
    pub kind: ProcessKind,
    /// Actor id (0 for the others).
    pub id: u32,
    /// Process id.
    pub pid: u32,
    /// Curriculum phase: 0 first task, 1 ACL (curriculum only).
    pub phase: u32,
    /// Env steps sent (actor) or received (learner); 0 for the curriculum.
    pub env_steps: u64,
    /// t_c: decision steps of the ACL phase (curriculum only).
    pub acl_steps: u64,
    /// Episodes finished (actor, curriculum).
    pub episodes: u64,
    /// Updates done (learner).
    pub updates: u64,
    /// Weights version in use (actor) or published (learner).
    pub version: u64,
    /// The learner's last checkpoint that reached the disk (its update count), or the
    /// curriculum service's last saved state (episodes reported at that save).
    pub last_good: u64,
    /// Mean discounted return of recent episodes.
    pub recent_return: f32,
    /// Steps per second over the last interval.
    pub rate: f32,
    /// Writes the process could not make at its last attempt.
    pub faults: Faults,
    /// The process's incarnation (an actor's start counter; 0 for the others). With
    /// `stream_base` and `env_steps` it announces what an actor's step stream holds,
    /// so a learner can ask again for records lost at its end ([`crate::reliable`]).
    pub incarnation: u32,
    /// An actor's oldest step record not yet acknowledged by a learner (0 for the others).
    pub stream_base: u64,
}

/// Writes a process could not make (a full disk, a folder made read-only), as bits:
/// it keeps its work in memory, says so in its log once per interval, retries at the
/// next interval, and its heartbeat carries them to the launcher's progress line.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
pub struct Faults(pub u32);

impl Faults {
    /// No fault.
    pub const NONE: Faults = Faults(0);
    /// The last checkpoint (learner) could not be written.
    pub const CHECKPOINT: Faults = Faults(1);
    /// The last saved state (curriculum service) could not be written.
    pub const STATE: Faults = Faults(2);
    /// Metrics rows (CSV, TensorBoard) wait in memory for the disk.
    pub const METRICS: Faults = Faults(4);
    /// The failure is a full disk (or quota).
    pub const DISK_FULL: Faults = Faults(8);
    /// The process's log (`logs/<process>.log`) refuses its lines.
    pub const LOG: Faults = Faults(16);

    /// Whether any fault is set.
    pub fn any(self) -> bool {
        self.0 != 0
    }

    /// What the progress line says, e.g. `checkpoint FAILED: disk full, last good at
    /// update 1200`; `last_good` is the heartbeat's field (0: nothing saved yet), `unit`
    /// what it counts. `None` when there is nothing to show (no fault, or only the
    /// [`Faults::DISK_FULL`] qualifier).
    pub fn describe(self, last_good: u64, unit: &str) -> Option<String> {
        let why = if self.contains(Faults::DISK_FULL) { "disk full" } else { "cannot write" };
        let last = if last_good == 0 { "none yet".to_string() } else { format!("at {unit} {last_good}") };
        let mut parts = Vec::new();
        if self.contains(Faults::CHECKPOINT) {
            parts.push(format!("checkpoint FAILED: {why}, last good {last}"));
        }
        if self.contains(Faults::STATE) {
            parts.push(format!("curriculum state FAILED: {why}, last saved {last}"));
        }
        if self.contains(Faults::METRICS) {
            parts.push(format!("metrics or stats waiting in memory: {why}"));
        }
        if self.contains(Faults::LOG) {
            parts.push(format!("log lines lost: {why}"));
        }
        (!parts.is_empty()).then(|| parts.join("; "))
    }
}

#[cfg(test)]
mod tests {
    use super::{ProcessKind, StepFlags};

    #[test]
    fn step_flags_are_a_set_with_fixed_wire_bits() {
        // The bit values are the wire format: a reader built from other source agrees on them.
        assert_eq!(
            [StepFlags::FIRST, StepFlags::TERMINAL, StepFlags::TRUNCATED, StepFlags::COLLIDED].map(|f| f.0),
            [1, 2, 4, 8]
        );
        let f = StepFlags::NONE
            .with_if(StepFlags::TERMINAL, true)
            .with_if(StepFlags::COLLIDED, true)
            .with_if(StepFlags::TRUNCATED, false);
        assert!(f.contains(StepFlags::TERMINAL) && f.contains(StepFlags::COLLIDED));
        assert!(!f.contains(StepFlags::TRUNCATED) && !f.contains(StepFlags::FIRST));
        assert!(f.contains(StepFlags::TERMINAL.with(StepFlags::COLLIDED)));
        assert!(!f.contains(StepFlags::NONE), "the empty set is never 'set'");
        assert_eq!(f.0, 10);
    }

    #[test]
    fn process_kinds_keep_their_codes() {
        assert_eq!(
            [ProcessKind::ACTOR, ProcessKind::LEARNER, ProcessKind::CURRICULUM, ProcessKind::BRIDGE].map(|k| k.0),
            [1, 2, 3, 4]
        );
    }
}
