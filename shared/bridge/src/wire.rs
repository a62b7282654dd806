//! The bytes that cross hosts: one explicit little-endian encoding per message kind.
//!
//! Invariants (tested, the round trips by property):
//! - `decode(encode(m)) == m` bit for bit, floats included (NaN payloads too: floats
//!   travel as their bits);
//! - every encoding starts with two bytes, the message [`Kind`] and the wire
//!   [`VERSION`], so hosts built from different pednav versions refuse each other's
//!   bytes ([`BridgeError::Version`]) instead of misreading them;
//! - decoding anything else is an error naming the message kind and the field —
//!   never a panic, never a partly filled message, and never an allocation larger
//!   than the bytes received (a length field is checked against what is left before
//!   anything is reserved).
//!
//! Why not the `#[repr(C)]` bytes the iceoryx2 services carry: their layout (padding,
//! field order, endianness) belongs to one build on one machine; a wire format is a
//! contract between builds and machines, so it is written out field by field here,
//! and a change to a message is a change of [`VERSION`].

use pednav_runtime::ipc::MAX_ACTORS;
use pednav_runtime::messages::{
    AckTable, EpisodeHeader, EpisodePoint, Faults, Heartbeat, ProcessKind, StepFlags, StepHeader, StreamAck,
    TaskRequest, TaskResponse, WeightsHeader,
};
use pednav_runtime::reliable::Ack;
use pednav_sim::STATE_OBS_MAX;

use crate::error::{BridgeError, Result};

/// The wire version this build reads and writes (3: episode reports carry their
/// actor's low-water mark and are acknowledged by the curriculum service as taken and
/// as saved, [`Kind::ReportAcks`]; 4: tasks and episode reports carry the start's
/// position in the signal cycle).
pub const VERSION: u8 = 4;

/// What a message is: its first byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Kind {
    /// A step record: [`StepHeader`] and the observation's bytes.
    Step = 1,
    /// An episode report: [`EpisodeHeader`] and its [`EpisodePoint`]s.
    Episode = 2,
    /// The learner's acknowledgements ([`AckTable`], its non-empty entries).
    Acks = 3,
    /// Policy weights: [`WeightsHeader`] and the values.
    Weights = 4,
    /// An actor's [`TaskRequest`].
    TaskRequest = 5,
    /// The curriculum service's [`TaskResponse`].
    TaskResponse = 6,
    /// A process's [`Heartbeat`].
    Heartbeat = 7,
    /// The curriculum service's acknowledgements of episode reports ([`ReportAck`]s).
    ReportAcks = 8,
}

/// One entry of a [`Kind::ReportAcks`] message: every episode report of `actor`'s
/// incarnation `incarnation` numbered below `taken` was taken by the curriculum service
/// (or given up by its actor) and need not be sent again, and every one below `saved`
/// is in the service's saved state (its actor may forget it).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReportAck {
    /// Global actor id.
    pub actor: u32,
    /// The actor process's incarnation.
    pub incarnation: u32,
    /// Reports numbered below this were taken.
    pub taken: u64,
    /// Reports numbered below this are saved.
    pub saved: u64,
}

impl Kind {
    /// Every kind, in code order.
    pub const ALL: [Kind; 8] = [
        Kind::Step,
        Kind::Episode,
        Kind::Acks,
        Kind::Weights,
        Kind::TaskRequest,
        Kind::TaskResponse,
        Kind::Heartbeat,
        Kind::ReportAcks,
    ];

    /// The kind's name in errors and logs.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Step => "step record",
            Kind::Episode => "episode report",
            Kind::Acks => "acknowledgement",
            Kind::Weights => "weights",
            Kind::TaskRequest => "task request",
            Kind::TaskResponse => "task response",
            Kind::Heartbeat => "heartbeat",
            Kind::ReportAcks => "episode report acknowledgement",
        }
    }

    /// The kind of a message's first byte, if it names one.
    pub fn from_code(code: u8) -> Option<Kind> {
        Kind::ALL.into_iter().find(|k| *k as u8 == code)
    }

    /// The kind of an encoded message (its first byte), checking its version.
    pub fn of(bytes: &[u8]) -> Result<Kind> {
        let (code, version) = match bytes {
            [code, version, ..] => (*code, *version),
            _ => {
                return Err(BridgeError::Malformed {
                    kind: "pednav",
                    problem: format!("{} bytes: shorter than the kind and version bytes", bytes.len()),
                });
            }
        };
        // The version first: a newer build's new kind is a version mismatch, not garbage.
        let kind = Kind::from_code(code);
        if version != VERSION {
            let kind = kind.map_or("pednav", Kind::name);
            return Err(BridgeError::Version { kind, found: version, expected: VERSION });
        }
        kind.ok_or_else(|| BridgeError::Malformed { kind: "pednav", problem: format!("unknown message kind {code}") })
    }
}

/// Writes fields in order, little-endian.
struct Enc(Vec<u8>);

impl Enc {
    fn new(kind: Kind, capacity: usize) -> Enc {
        let mut bytes = Vec::with_capacity(capacity + 2);
        bytes.extend_from_slice(&[kind as u8, VERSION]);
        Enc(bytes)
    }

    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }

    fn f32(&mut self, v: f32) {
        self.u32(v.to_bits());
    }

    fn f32s(&mut self, values: &[f32]) {
        for &v in values {
            self.f32(v);
        }
    }

    /// A length-prefixed byte string.
    fn bytes(&mut self, bytes: &[u8]) {
        self.u64(bytes.len() as u64);
        self.0.extend_from_slice(bytes);
    }
}

/// Reads fields in order; every read names its field in the error.
struct Dec<'a> {
    kind: Kind,
    rest: &'a [u8],
}

impl<'a> Dec<'a> {
    /// Check the kind and version bytes.
    fn open(kind: Kind, bytes: &'a [u8]) -> Result<Dec<'a>> {
        let found = Kind::of(bytes).map_err(|e| match e {
            BridgeError::Malformed { problem, .. } => BridgeError::Malformed { kind: kind.name(), problem },
            other => other,
        })?;
        if found != kind {
            return Err(BridgeError::Malformed {
                kind: kind.name(),
                problem: format!("the bytes are a {} message", found.name()),
            });
        }
        Ok(Dec { kind, rest: &bytes[2..] })
    }

    fn malformed(&self, problem: String) -> BridgeError {
        BridgeError::Malformed { kind: self.kind.name(), problem }
    }

    fn take(&mut self, n: usize, field: &str) -> Result<&'a [u8]> {
        if self.rest.len() < n {
            return Err(self.malformed(format!("cut short in `{field}` ({} of {n} bytes left)", self.rest.len())));
        }
        let (head, tail) = self.rest.split_at(n);
        self.rest = tail;
        Ok(head)
    }

    fn u32(&mut self, field: &str) -> Result<u32> {
        let b = self.take(4, field)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn u64(&mut self, field: &str) -> Result<u64> {
        let b = self.take(8, field)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(u64::from_le_bytes(a))
    }

    fn f32(&mut self, field: &str) -> Result<f32> {
        Ok(f32::from_bits(self.u32(field)?))
    }

    fn f32_array<const N: usize>(&mut self, field: &str) -> Result<[f32; N]> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f32(field)?;
        }
        Ok(out)
    }

    /// A count of `elem_bytes`-byte elements, checked against the bytes left (so a
    /// corrupt count never reserves more than was received).
    fn count(&mut self, elem_bytes: usize, field: &str) -> Result<usize> {
        let n = self.u64(field)?;
        let bytes = usize::try_from(n).ok().and_then(|n| n.checked_mul(elem_bytes));
        let fits = bytes.is_some_and(|b| b <= self.rest.len());
        if !fits {
            return Err(self.malformed(format!(
                "`{field}` says {n} elements of {elem_bytes} bytes, but {} bytes are left",
                self.rest.len()
            )));
        }
        Ok(n as usize)
    }

    /// A length-prefixed byte string.
    fn bytes(&mut self, field: &str) -> Result<&'a [u8]> {
        let n = self.count(1, field)?;
        self.take(n, field)
    }

    fn f32s(&mut self, field: &str) -> Result<Vec<f32>> {
        let n = self.count(4, field)?;
        let raw = self.take(4 * n, field)?;
        Ok(raw.chunks_exact(4).map(|c| f32::from_bits(u32::from_le_bytes([c[0], c[1], c[2], c[3]]))).collect())
    }

    /// Nothing may follow the last field.
    fn finish(self) -> Result<()> {
        if self.rest.is_empty() {
            Ok(())
        } else {
            Err(self.malformed(format!("{} bytes after the last field", self.rest.len())))
        }
    }
}

/// A step record: its header, then the observation (a frame or a state vector).
pub fn encode_step(h: &StepHeader, observation: &[u8]) -> Vec<u8> {
    let mut e = Enc::new(Kind::Step, 96 + 4 * STATE_OBS_MAX + observation.len());
    e.u32(h.actor);
    e.u32(h.env);
    e.u32(h.incarnation);
    e.u32(h.flags.0);
    e.u64(h.episode);
    e.u32(h.step);
    e.f32(h.reward);
    e.f32s(&h.action);
    e.u64(h.policy_version);
    e.u64(h.seq);
    e.u64(h.base);
    e.f32s(&h.state);
    e.bytes(observation);
    e.0
}

/// The header and observation of an [`encode_step`] message.
pub fn decode_step(bytes: &[u8]) -> Result<(StepHeader, &[u8])> {
    let mut d = Dec::open(Kind::Step, bytes)?;
    let h = StepHeader {
        actor: d.u32("actor")?,
        env: d.u32("env")?,
        incarnation: d.u32("incarnation")?,
        flags: StepFlags(d.u32("flags")?),
        episode: d.u64("episode")?,
        step: d.u32("step")?,
        reward: d.f32("reward")?,
        action: d.f32_array("action")?,
        policy_version: d.u64("policy_version")?,
        seq: d.u64("seq")?,
        base: d.u64("base")?,
        state: d.f32_array("state")?,
    };
    let observation = d.bytes("observation")?;
    d.finish()?;
    Ok((h, observation))
}

/// An episode report: its actor's low-water mark ([`EpisodeHeader::low_water`]: the
/// lowest report number of this actor incarnation it still holds), the rest of its
/// header, then its points.
pub fn encode_episode(h: &EpisodeHeader, points: &[EpisodePoint]) -> Vec<u8> {
    let mut e = Enc::new(Kind::Episode, 80 + 16 * points.len());
    e.u64(h.low_water);
    e.u32(h.actor);
    e.u32(h.env);
    e.u32(h.incarnation);
    e.u64(h.seq);
    e.u64(h.task_id);
    e.u32(h.category);
    e.u32(h.success);
    e.u32(h.truncated);
    e.u32(h.length);
    e.f32(h.discounted_return);
    e.f32(h.total_reward);
    e.f32(h.start_cycle);
    e.u32(h.has_cycle);
    e.u64(points.len() as u64);
    for p in points {
        e.f32s(&[p.x, p.y, p.yaw, p.reward]);
    }
    e.0
}

/// The header (its low-water mark included) and the points of an [`encode_episode`]
/// message.
pub fn decode_episode(bytes: &[u8]) -> Result<(EpisodeHeader, Vec<EpisodePoint>)> {
    let mut d = Dec::open(Kind::Episode, bytes)?;
    let low_water = d.u64("low_water")?;
    let h = EpisodeHeader {
        actor: d.u32("actor")?,
        env: d.u32("env")?,
        incarnation: d.u32("incarnation")?,
        seq: d.u64("seq")?,
        task_id: d.u64("task_id")?,
        category: d.u32("category")?,
        success: d.u32("success")?,
        truncated: d.u32("truncated")?,
        length: d.u32("length")?,
        discounted_return: d.f32("discounted_return")?,
        total_reward: d.f32("total_reward")?,
        start_cycle: d.f32("start_cycle")?,
        has_cycle: d.u32("has_cycle")?,
        low_water,
    };
    let n = d.count(16, "points")?;
    let mut points = Vec::with_capacity(n);
    for _ in 0..n {
        let [x, y, yaw, reward] = d.f32_array("points")?;
        points.push(EpisodePoint { x, y, yaw, reward });
    }
    d.finish()?;
    Ok((h, points))
}

/// The learner host's episode report acknowledgements.
pub fn encode_report_acks(acks: &[ReportAck]) -> Vec<u8> {
    let mut e = Enc::new(Kind::ReportAcks, 8 + 24 * acks.len());
    e.u64(acks.len() as u64);
    for a in acks {
        e.u32(a.actor);
        e.u32(a.incarnation);
        e.u64(a.taken);
        e.u64(a.saved);
    }
    e.0
}

/// The entries of an [`encode_report_acks`] message.
pub fn decode_report_acks(bytes: &[u8]) -> Result<Vec<ReportAck>> {
    let mut d = Dec::open(Kind::ReportAcks, bytes)?;
    let n = d.count(24, "entries")?;
    let mut acks = Vec::with_capacity(n);
    for _ in 0..n {
        let a = ReportAck {
            actor: d.u32("actor")?,
            incarnation: d.u32("incarnation")?,
            taken: d.u64("taken")?,
            saved: d.u64("saved")?,
        };
        if a.actor as usize >= MAX_ACTORS {
            return Err(d.malformed(format!("actor {}: this build has actor ids below {MAX_ACTORS}", a.actor)));
        }
        acks.push(a);
    }
    d.finish()?;
    Ok(acks)
}

/// The learner's acknowledgements: the entries of actors it has seen (incarnation ≠ 0).
pub fn encode_acks(table: &AckTable) -> Vec<u8> {
    let seen: Vec<(usize, &StreamAck)> = table.streams.iter().enumerate().filter(|(_, s)| s.incarnation != 0).collect();
    let mut e = Enc::new(Kind::Acks, 8 + 24 * seen.len());
    e.u64(seen.len() as u64);
    for (actor, s) in seen {
        e.u32(actor as u32);
        e.u32(s.incarnation);
        e.u32(s.ack.receiver);
        e.u32(s.ack.resend);
        e.u64(s.ack.expected);
    }
    e.0
}

/// The table of an [`encode_acks`] message (actors not named: no entry).
pub fn decode_acks(bytes: &[u8]) -> Result<AckTable> {
    let mut d = Dec::open(Kind::Acks, bytes)?;
    let n = d.count(24, "entries")?;
    let mut table = AckTable::default();
    for _ in 0..n {
        let actor = d.u32("actor")? as usize;
        let incarnation = d.u32("incarnation")?;
        let ack = Ack { receiver: d.u32("receiver")?, resend: d.u32("resend")?, expected: d.u64("expected")? };
        let Some(entry) = table.streams.get_mut(actor) else {
            return Err(d.malformed(format!("actor {actor}: this build has actor ids below {MAX_ACTORS}")));
        };
        if incarnation == 0 || entry.incarnation != 0 {
            return Err(d.malformed(format!(
                "actor {actor}: {}",
                if incarnation == 0 { "an entry of incarnation 0 (no stream)" } else { "named twice" }
            )));
        }
        *entry = StreamAck { incarnation, ack };
    }
    d.finish()?;
    Ok(table)
}

/// Policy weights: the header's version and time, then the values (the header's
/// `len` is the number of values, checked on decoding).
pub fn encode_weights(h: &WeightsHeader, values: &[f32]) -> Vec<u8> {
    let mut e = Enc::new(Kind::Weights, 24 + 4 * values.len());
    e.u64(h.version);
    e.u64(h.published_ns);
    e.u64(values.len() as u64);
    e.f32s(values);
    e.0
}

/// The header and values of an [`encode_weights`] message.
pub fn decode_weights(bytes: &[u8]) -> Result<(WeightsHeader, Vec<f32>)> {
    let mut d = Dec::open(Kind::Weights, bytes)?;
    let version = d.u64("version")?;
    let published_ns = d.u64("published_ns")?;
    let values = d.f32s("values")?;
    d.finish()?;
    Ok((WeightsHeader { version, len: values.len() as u64, published_ns }, values))
}

/// An actor's task request.
pub fn encode_task_request(r: &TaskRequest) -> Vec<u8> {
    let mut e = Enc::new(Kind::TaskRequest, 8);
    e.u32(r.actor);
    e.u32(r.env);
    e.0
}

/// The request of an [`encode_task_request`] message.
pub fn decode_task_request(bytes: &[u8]) -> Result<TaskRequest> {
    let mut d = Dec::open(Kind::TaskRequest, bytes)?;
    let r = TaskRequest { actor: d.u32("actor")?, env: d.u32("env")? };
    d.finish()?;
    Ok(r)
}

/// The curriculum service's answer to a task request.
pub fn encode_task_response(r: &TaskResponse) -> Vec<u8> {
    let mut e = Enc::new(Kind::TaskResponse, 32);
    e.f32s(&[r.x, r.y, r.yaw]);
    e.u32(r.category);
    e.u64(r.task_id);
    e.f32(r.cycle);
    e.u32(r.has_cycle);
    e.0
}

/// The response of an [`encode_task_response`] message.
pub fn decode_task_response(bytes: &[u8]) -> Result<TaskResponse> {
    let mut d = Dec::open(Kind::TaskResponse, bytes)?;
    let r = TaskResponse {
        x: d.f32("x")?,
        y: d.f32("y")?,
        yaw: d.f32("yaw")?,
        category: d.u32("category")?,
        task_id: d.u64("task_id")?,
        cycle: d.f32("cycle")?,
        has_cycle: d.u32("has_cycle")?,
    };
    d.finish()?;
    Ok(r)
}

/// A process's heartbeat.
pub fn encode_heartbeat(h: &Heartbeat) -> Vec<u8> {
    let mut e = Enc::new(Kind::Heartbeat, 96);
    e.u32(h.kind.0);
    e.u32(h.id);
    e.u32(h.pid);
    e.u32(h.phase);
    e.u64(h.env_steps);
    e.u64(h.acl_steps);
    e.u64(h.episodes);
    e.u64(h.updates);
    e.u64(h.version);
    e.u64(h.last_good);
    e.f32(h.recent_return);
    e.f32(h.rate);
    e.u32(h.faults.0);
    e.u32(h.incarnation);
    e.u64(h.stream_base);
    e.0
}

/// The heartbeat of an [`encode_heartbeat`] message.
pub fn decode_heartbeat(bytes: &[u8]) -> Result<Heartbeat> {
    let mut d = Dec::open(Kind::Heartbeat, bytes)?;
    let h = Heartbeat {
        kind: ProcessKind(d.u32("kind")?),
        id: d.u32("id")?,
        pid: d.u32("pid")?,
        phase: d.u32("phase")?,
        env_steps: d.u64("env_steps")?,
        acl_steps: d.u64("acl_steps")?,
        episodes: d.u64("episodes")?,
        updates: d.u64("updates")?,
        version: d.u64("version")?,
        last_good: d.u64("last_good")?,
        recent_return: d.f32("recent_return")?,
        rate: d.f32("rate")?,
        faults: Faults(d.u32("faults")?),
        incarnation: d.u32("incarnation")?,
        stream_base: d.u64("stream_base")?,
    };
    d.finish()?;
    Ok(h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Floats compared by their bits (NaN payloads included).
    fn bits(v: &[f32]) -> Vec<u32> {
        v.iter().map(|f| f.to_bits()).collect()
    }

    fn any_f32() -> impl Strategy<Value = f32> {
        any::<u32>().prop_map(f32::from_bits)
    }

    fn step_header() -> impl Strategy<Value = StepHeader> {
        (
            (any::<u32>(), any::<u32>(), any::<u32>(), any::<u32>(), any::<u64>(), any::<u32>()),
            (any_f32(), proptest::array::uniform3(any_f32()), any::<u64>(), any::<u64>(), any::<u64>()),
            proptest::collection::vec(any_f32(), STATE_OBS_MAX),
        )
            .prop_map(
                |((actor, env, incarnation, flags, episode, step), (reward, action, pv, seq, base), state)| {
                    let mut h = StepHeader {
                        actor,
                        env,
                        incarnation,
                        flags: StepFlags(flags),
                        episode,
                        step,
                        reward,
                        action,
                        policy_version: pv,
                        seq,
                        base,
                        ..StepHeader::default()
                    };
                    h.state.copy_from_slice(&state);
                    h
                },
            )
    }

    /// Field-by-field bit equality of two step headers (`==` fails on NaN).
    fn same_step(a: &StepHeader, b: &StepHeader) -> bool {
        (a.actor, a.env, a.incarnation, a.flags.0, a.episode, a.step, a.policy_version, a.seq, a.base)
            == (b.actor, b.env, b.incarnation, b.flags.0, b.episode, b.step, b.policy_version, b.seq, b.base)
            && a.reward.to_bits() == b.reward.to_bits()
            && bits(&a.action) == bits(&b.action)
            && bits(&a.state) == bits(&b.state)
    }

    proptest! {
        #[test]
        fn a_step_record_round_trips(h in step_header(), obs in proptest::collection::vec(any::<u8>(), 0..300)) {
            let bytes = encode_step(&h, &obs);
            let (back, o) = decode_step(&bytes).unwrap();
            prop_assert!(same_step(&h, &back), "{h:?} came back as {back:?}");
            prop_assert_eq!(o, &obs[..]);
        }

        #[test]
        fn an_episode_report_round_trips(
            ints in (any::<u32>(), any::<u32>(), any::<u32>(), any::<u64>(), any::<u64>(), any::<u32>()),
            flags in (any::<u32>(), any::<u32>(), any::<u32>()),
            rets in (any_f32(), any_f32()),
            points in proptest::collection::vec(proptest::array::uniform4(any_f32()), 0..40),
            low_water in any::<u64>(),
            cycle in (any_f32(), any::<u32>()),
        ) {
            let (actor, env, incarnation, seq, task_id, category) = ints;
            let h = EpisodeHeader {
                actor, env, incarnation, seq, task_id, category,
                success: flags.0, truncated: flags.1, length: flags.2,
                discounted_return: rets.0, total_reward: rets.1, low_water,
                start_cycle: cycle.0, has_cycle: cycle.1,
            };
            let pts: Vec<EpisodePoint> =
                points.iter().map(|&[x, y, yaw, reward]| EpisodePoint { x, y, yaw, reward }).collect();
            let bytes = encode_episode(&h, &pts);
            let (back, back_pts) = decode_episode(&bytes).unwrap();
            prop_assert_eq!(back.low_water, low_water);
            prop_assert_eq!((back.start_cycle.to_bits(), back.has_cycle), (cycle.0.to_bits(), cycle.1));
            prop_assert_eq!(
                (back.actor, back.env, back.incarnation, back.seq, back.task_id, back.category),
                (actor, env, incarnation, seq, task_id, category)
            );
            prop_assert_eq!((back.success, back.truncated, back.length), flags);
            prop_assert_eq!(
                (back.discounted_return.to_bits(), back.total_reward.to_bits()),
                (rets.0.to_bits(), rets.1.to_bits())
            );
            let flat = |p: &[EpisodePoint]| p.iter().flat_map(|q| bits(&[q.x, q.y, q.yaw, q.reward])).collect::<Vec<_>>();
            prop_assert_eq!(flat(&back_pts), flat(&pts));
        }

        #[test]
        fn an_ack_table_round_trips(entries in proptest::collection::btree_map(
            0..MAX_ACTORS, (1u32..=u32::MAX, any::<u32>(), any::<u32>(), any::<u64>()), 0..20)
        ) {
            let mut table = AckTable::default();
            for (&actor, &(incarnation, receiver, resend, expected)) in &entries {
                table.streams[actor] = StreamAck { incarnation, ack: Ack { receiver, resend, expected } };
            }
            let bytes = encode_acks(&table);
            prop_assert_eq!(bytes.len(), 2 + 8 + 24 * entries.len(), "only the entries of actors seen travel");
            prop_assert_eq!(decode_acks(&bytes).unwrap(), table);
        }

        #[test]
        fn report_acks_round_trip(entries in proptest::collection::vec((0..MAX_ACTORS as u32, any::<u32>(), any::<u64>(), any::<u64>()), 0..40)) {
            let acks: Vec<ReportAck> = entries
                .iter()
                .map(|&(actor, incarnation, taken, saved)| ReportAck { actor, incarnation, taken, saved })
                .collect();
            let bytes = encode_report_acks(&acks);
            prop_assert_eq!(bytes.len(), 2 + 8 + 24 * acks.len());
            prop_assert_eq!(decode_report_acks(&bytes).unwrap(), acks);
        }

        #[test]
        fn weights_round_trip(version in any::<u64>(), ns in any::<u64>(), values in proptest::collection::vec(any_f32(), 0..500)) {
            let h = WeightsHeader { version, len: values.len() as u64, published_ns: ns };
            let (back, v) = decode_weights(&encode_weights(&h, &values)).unwrap();
            prop_assert_eq!(back, h);
            prop_assert_eq!(bits(&v), bits(&values));
        }

        #[test]
        fn a_heartbeat_round_trips(
            a in proptest::array::uniform4(any::<u32>()),
            b in proptest::array::uniform6(any::<u64>()),
            c in (any_f32(), any_f32(), any::<u32>(), any::<u32>(), any::<u64>()),
        ) {
            let h = Heartbeat {
                kind: ProcessKind(a[0]), id: a[1], pid: a[2], phase: a[3],
                env_steps: b[0], acl_steps: b[1], episodes: b[2], updates: b[3], version: b[4], last_good: b[5],
                recent_return: c.0, rate: c.1, faults: Faults(c.2), incarnation: c.3, stream_base: c.4,
            };
            let back = decode_heartbeat(&encode_heartbeat(&h)).unwrap();
            prop_assert_eq!(
                [back.kind.0, back.id, back.pid, back.phase, back.faults.0, back.incarnation],
                [a[0], a[1], a[2], a[3], c.2, c.3]
            );
            prop_assert_eq!(
                [back.env_steps, back.acl_steps, back.episodes, back.updates, back.version, back.last_good, back.stream_base],
                [b[0], b[1], b[2], b[3], b[4], b[5], c.4]
            );
            prop_assert_eq!(bits(&[back.recent_return, back.rate]), bits(&[c.0, c.1]));
        }

        #[test]
        fn tasks_round_trip(
            actor in any::<u32>(),
            env in any::<u32>(),
            pose in proptest::array::uniform3(any_f32()),
            category in any::<u32>(),
            task_id in any::<u64>(),
            cycle in (any_f32(), any::<u32>()),
        ) {
            let req = TaskRequest { actor, env };
            prop_assert_eq!(decode_task_request(&encode_task_request(&req)).unwrap(), req);
            let resp = TaskResponse { x: pose[0], y: pose[1], yaw: pose[2], category, task_id, cycle: cycle.0, has_cycle: cycle.1 };
            let back = decode_task_response(&encode_task_response(&resp)).unwrap();
            prop_assert_eq!(bits(&[back.x, back.y, back.yaw, back.cycle]), bits(&[pose[0], pose[1], pose[2], cycle.0]));
            prop_assert_eq!((back.category, back.task_id, back.has_cycle), (category, task_id, cycle.1));
        }

        /// Any bytes at all: an error or a message, never a panic; a cut or extended
        /// message is an error.
        #[test]
        fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..200), cut in 0usize..64) {
            // As they come, and behind each kind's valid first two bytes (so the fields
            // are read, not only the kind).
            for kind in Kind::ALL {
                let mut prefixed = vec![kind as u8, VERSION];
                prefixed.extend_from_slice(&bytes);
                for b in [&bytes[..], &prefixed[..]] {
                    let _ = decode_step(b);
                    let _ = decode_episode(b);
                    let _ = decode_acks(b);
                    let _ = decode_weights(b);
                    let _ = decode_task_request(b);
                    let _ = decode_task_response(b);
                    let _ = decode_heartbeat(b);
                    let _ = decode_report_acks(b);
                }
            }
            let good = encode_episode(&EpisodeHeader::default(), &[EpisodePoint::default(); 3]);
            let short = &good[..good.len().saturating_sub(cut + 1)];
            prop_assert!(decode_episode(short).is_err());
            let mut long = good.clone();
            long.extend_from_slice(&bytes[..bytes.len().min(cut + 1)]);
            prop_assert!(bytes.is_empty() || decode_episode(&long).is_err());
        }
    }

    #[test]
    fn errors_name_the_kind_the_field_and_the_version() {
        let step = encode_step(&StepHeader::default(), &[1, 2, 3]);
        let err = decode_episode(&step).unwrap_err().to_string();
        assert!(err.contains("episode report") && err.contains("step record"), "{err}");
        let err = decode_step(&step[..30]).unwrap_err().to_string();
        assert!(err.contains("step record") && err.contains("cut short in `"), "{err}");
        let mut old = step.clone();
        old[1] = VERSION + 1;
        let err = decode_step(&old).unwrap_err();
        assert!(matches!(err, BridgeError::Version { found, .. } if found == VERSION + 1), "{err}");
        assert!(err.to_string().contains("same pednav version"), "{err}");
        assert!(matches!(Kind::of(&[200, VERSION]), Err(BridgeError::Malformed { .. })));
        assert_eq!(Kind::of(&step).unwrap(), Kind::Step);
    }

    #[test]
    fn a_length_larger_than_the_message_is_refused_before_allocating() {
        let mut bytes = encode_weights(&WeightsHeader::default(), &[]);
        let at = bytes.len() - 8;
        bytes[at..].copy_from_slice(&u64::MAX.to_le_bytes());
        let err = decode_weights(&bytes).unwrap_err().to_string();
        assert!(err.contains("`values` says 18446744073709551615 elements"), "{err}");
    }

    #[test]
    fn an_ack_for_an_actor_beyond_this_build_is_refused() {
        let mut e = Enc::new(Kind::Acks, 32);
        e.u64(1);
        e.u32(MAX_ACTORS as u32);
        e.u32(1);
        e.u32(0);
        e.u32(0);
        e.u64(0);
        let err = decode_acks(&e.0).unwrap_err().to_string();
        assert!(err.contains(&format!("actor {MAX_ACTORS}")), "{err}");
    }

    #[test]
    fn a_report_ack_for_an_actor_beyond_this_build_is_refused() {
        let bytes = encode_report_acks(&[ReportAck { actor: MAX_ACTORS as u32, incarnation: 1, taken: 3, saved: 2 }]);
        let err = decode_report_acks(&bytes).unwrap_err().to_string();
        assert!(
            err.contains("episode report acknowledgement") && err.contains(&format!("actor {MAX_ACTORS}")),
            "{err}"
        );
    }

    #[test]
    fn the_layout_is_little_endian_field_by_field() {
        // By hand: kind 5, version, actor 1, env 0x0203 (little-endian).
        let bytes = encode_task_request(&TaskRequest { actor: 1, env: 0x0203 });
        assert_eq!(bytes, [5, VERSION, 1, 0, 0, 0, 3, 2, 0, 0]);
    }
}
