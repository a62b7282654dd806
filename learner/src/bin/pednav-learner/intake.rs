//! The learner's side of the actors' step streams: which records it takes, and the
//! acknowledgements and resend requests it publishes (`pednav_runtime::reliable`).
//!
//! Invariant: of each actor incarnation's stream this learner takes one increasing run
//! of records, one by one, except a jump over records a learner before it took, which
//! [`Admit::TakeAfterJump`] reports; its acknowledgement table names, per actor, the
//! newest incarnation it has seen and the next record it will take.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use pednav_runtime::messages::{AckTable, Heartbeat, ProcessKind, StepHeader, StreamAck};
use pednav_runtime::reliable::{ReceiveCursor, Verdict};
use pednav_runtime::stats::{JUMPS_KEPT, StreamTally};

/// How often a learner asks an actor again for records it misses (after a restart,
/// the first out-of-order record asks at once).
const RESEND_RETRY: Duration = Duration::from_secs(1);
/// Least time between two acknowledgement tables.
const ACK_EVERY: Duration = Duration::from_millis(5);
/// Most time between two acknowledgement tables while the learner reads.
const ACK_REPEAT: Duration = Duration::from_millis(200);

/// One actor incarnation's stream at this learner: where it stands
/// ([`ReceiveCursor`]) and what it took (for the integration test's count-and-checksum
/// comparison).
struct Tally {
    cursor: ReceiveCursor,
    first_seq: Option<u64>,
    records: u64,
    checksum: u32,
    out_of_order: u64,
    duplicates: u64,
    resumed: u64,
    /// The ranges jumped over, `[from, to)` (the first [`JUMPS_KEPT`]).
    jumped: Vec<[u64; 2]>,
}

impl Tally {
    fn new(receiver: u32, now: Instant) -> Tally {
        Tally {
            cursor: ReceiveCursor::new(receiver, RESEND_RETRY, now),
            first_seq: None,
            records: 0,
            checksum: 0,
            out_of_order: 0,
            duplicates: 0,
            resumed: 0,
            jumped: Vec::new(),
        }
    }
}

/// What to do with an offered step record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Admit {
    /// Take it: the next record of its stream.
    Take,
    /// Take it, but records before it went to a learner before this one: whatever is
    /// assembled from the stream's earlier records must not continue into it.
    TakeAfterJump,
    /// Drop it (taken already, or records before it are missing and were asked for).
    Drop,
}

/// Every step stream this learner reads.
pub struct StepIntake {
    tallies: BTreeMap<(u32, u32), Tally>,
    /// This learner's incarnation in its acknowledgements (its pid).
    receiver: u32,
    /// Whether an acknowledgement changed since the last table was published.
    changed: bool,
    last_published: Instant,
}

impl StepIntake {
    /// The intake of the learner incarnation `receiver`, which has seen no stream.
    pub fn new(receiver: u32) -> StepIntake {
        StepIntake { tallies: BTreeMap::new(), receiver, changed: false, last_published: Instant::now() }
    }

    /// Judge a record (`observation`: its payload, for the stream's checksum).
    pub fn admit(&mut self, h: &StepHeader, observation: &[u8], now: Instant) -> Admit {
        let receiver = self.receiver;
        let tally = self.tallies.entry((h.actor, h.incarnation)).or_insert_with(|| Tally::new(receiver, now));
        let asked = tally.cursor.resend_requests();
        let admit = match tally.cursor.offer(h.seq, h.base, now) {
            Verdict::Accept => Admit::Take,
            Verdict::Resume { skipped } => {
                tally.resumed += 1;
                if tally.jumped.len() < JUMPS_KEPT {
                    tally.jumped.push([h.seq - skipped, h.seq]);
                }
                tracing::info!(
                    actor = h.actor,
                    incarnation = h.incarnation,
                    skipped,
                    "step stream resumes after records a previous learner took"
                );
                Admit::TakeAfterJump
            }
            Verdict::Duplicate => {
                tally.duplicates += 1;
                return Admit::Drop;
            }
            Verdict::Missing { expected } => {
                tally.out_of_order += 1;
                if tally.cursor.resend_requests() != asked {
                    self.changed = true;
                    tracing::info!(
                        actor = h.actor,
                        incarnation = h.incarnation,
                        expected,
                        got = h.seq,
                        "step records missing (this learner restarted, or records were lost on the way): \
                         asked the actor to send them again"
                    );
                }
                return Admit::Drop;
            }
        };
        self.changed = true;
        tally.first_seq.get_or_insert(h.seq);
        tally.records += 1;
        tally.checksum = tally.checksum.wrapping_add(h.record_crc(observation));
        admit
    }

    /// An actor's heartbeat says how far its stream goes: a stream this learner is
    /// behind on, with no progress for a while, is asked for again (the tail lost
    /// with a killed learner; a stream whose actor waits on a full window). Call it
    /// only while reading the streams ([`ReceiveCursor::on_announce`]).
    pub fn announced(&mut self, h: &Heartbeat, now: Instant) {
        if h.kind != ProcessKind::ACTOR || h.env_steps == 0 {
            return;
        }
        let receiver = self.receiver;
        let tally = self.tallies.entry((h.id, h.incarnation)).or_insert_with(|| Tally::new(receiver, now));
        if tally.cursor.on_announce(h.stream_base, h.env_steps, now) {
            self.changed = true;
            tracing::info!(
                actor = h.id,
                incarnation = h.incarnation,
                announced = h.env_steps,
                expected = tally.cursor.expected(),
                "step records missing at the end of a stream: asked the actor to send them again"
            );
        }
    }

    /// The acknowledgement table to publish now, if one is due: when something changed
    /// (at most every `ACK_EVERY`), and every `ACK_REPEAT` regardless — a table lost on
    /// the lossy service must not leave an actor waiting.
    pub fn due_table(&mut self, now: Instant) -> Option<AckTable> {
        let since = now.saturating_duration_since(self.last_published);
        if !((self.changed && since >= ACK_EVERY) || since >= ACK_REPEAT) {
            return None;
        }
        self.changed = false;
        self.last_published = now;
        Some(self.table())
    }

    /// The acknowledgement table: each actor's newest incarnation's cursor.
    pub fn table(&self) -> AckTable {
        let mut table = AckTable::default();
        for (&(actor, incarnation), t) in &self.tallies {
            if let Some(entry) = table.streams.get_mut(actor as usize)
                && incarnation >= entry.incarnation
            {
                *entry = StreamAck { incarnation, ack: t.cursor.ack() };
            }
        }
        table
    }

    /// What this learner took of each stream, for its stats file.
    pub fn tallies(&self) -> Vec<StreamTally> {
        self.tallies
            .iter()
            .map(|(&(actor, incarnation), t)| StreamTally {
                actor,
                incarnation,
                first_seq: t.first_seq,
                records: t.records,
                checksum: t.checksum,
                out_of_order: t.out_of_order,
                duplicates: t.duplicates,
                resumed: t.resumed,
                jumped: t.jumped.clone(),
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use pednav_runtime::reliable::Ack;

    fn record(actor: u32, incarnation: u32, seq: u64, base: u64) -> StepHeader {
        StepHeader { actor, incarnation, seq, base, ..StepHeader::default() }
    }

    #[test]
    fn the_table_names_each_actors_newest_incarnation_and_is_published_when_due() {
        let mut intake = StepIntake::new(7);
        let t0 = intake.last_published;
        assert_eq!(intake.admit(&record(1, 1, 0, 0), &[], t0), Admit::Take);
        assert_eq!(intake.admit(&record(1, 2, 0, 0), &[], t0), Admit::Take);
        assert_eq!(intake.admit(&record(1, 2, 0, 0), &[], t0), Admit::Drop, "taken already");
        assert_eq!(intake.admit(&record(1, 2, 5, 0), &[], t0), Admit::Drop, "1 … 4 missing: asked for");
        assert_eq!(intake.admit(&record(3, 1, 9, 9), &[], t0), Admit::Take, "a new stream starts at its base");
        let table = intake.table();
        assert_eq!(table.streams[1], StreamAck { incarnation: 2, ack: Ack { receiver: 7, resend: 1, expected: 1 } });
        assert_eq!(table.streams[3].ack.expected, 10);
        assert_eq!(table.streams[0], StreamAck::default(), "an actor not seen has no entry");

        assert!(intake.due_table(t0 + ACK_EVERY / 2).is_none(), "at most one table per ACK_EVERY");
        assert!(intake.due_table(t0 + ACK_EVERY).is_some());
        assert!(intake.due_table(t0 + ACK_EVERY * 2).is_none(), "nothing changed since");
        assert!(intake.due_table(t0 + ACK_EVERY + ACK_REPEAT).is_some(), "repeated regardless");

        let tallies = intake.tallies();
        let newest = tallies.iter().find(|t| (t.actor, t.incarnation) == (1, 2)).unwrap();
        assert_eq!((newest.first_seq, newest.records, newest.duplicates, newest.out_of_order), (Some(0), 1, 1, 1));
    }

    #[test]
    fn a_jump_over_a_predecessors_records_is_taken_and_reported() {
        let mut intake = StepIntake::new(2);
        let t0 = Instant::now();
        assert_eq!(intake.admit(&record(0, 1, 4, 4), &[], t0), Admit::Take);
        // The sender's base moved past 5 … 7: a learner before this one took them.
        assert_eq!(intake.admit(&record(0, 1, 8, 8), &[], t0), Admit::TakeAfterJump);
        let t = &intake.tallies()[0];
        assert_eq!((t.resumed, t.jumped.as_slice(), t.records), (1, &[[5, 8]][..], 2));
    }
}
