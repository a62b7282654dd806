//! Episode reports, acknowledged end to end: an actor holds each of its reports until
//! the curriculum service has saved it, and sends it again when no acknowledgement
//! came; the curriculum service takes each report once.
//!
//! A report is named by (actor, incarnation, seq), `seq` counting that actor
//! incarnation's reports from 0. The curriculum service acknowledges cumulatively, per
//! actor, its newest incarnation ([`EpisodeAckTable`], newest wins), at two levels:
//! `taken` — every report numbered below it is in the service's memory, so the actor
//! stops sending it — and `saved` — every report below it is in the service's saved
//! state, so the actor forgets it. A service that restarts from its saved state
//! publishes a `taken` that went back, and the actor sends again what it lacks.
//! Reports can arrive out of order (one lost on a cut link between two hosts is sent
//! again after later ones got through), so the receiving side also remembers which
//! reports above `taken` it has. Every report carries its sender's *low-water mark*
//! ([`EpisodeHeader::low_water`]), the lowest number of its incarnation the sender
//! still holds: a report the sender gave up (its window overflowed while nothing was
//! saved) is never waited for.
//!
//! The path between the two ends does not matter: on one host the reports go straight
//! from the actor to the curriculum service over iceoryx2; across hosts two bridges
//! carry them and the acknowledgements. A bridge that dies, a link that drops or a
//! curriculum service that restarts from its saved state costs a resend, never a
//! report, while the actor runs; an actor that dies takes with it what it held (as it
//! takes its unsent steps and its episode in progress).
//!
//! Invariants (property-tested over links that lose, duplicate, delay and reorder
//! reports and acknowledgements, with a receiver that restarts from its last save):
//! - the receiving side takes a report at most once ([`ReportCursors`] are saved with
//!   the state that consumed the reports, and restored with it);
//! - with a window that never overflows, every report ends up in the saved state;
//! - the sending side holds at most [`HeldReports::capacity`] reports, dropping the
//!   oldest first, and drops a report only once it is saved or to make room.

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use crate::messages::{EpisodeAck, EpisodeAckTable, EpisodeHeader, EpisodePoint};

/// Incarnations of one actor whose records the receiving side keeps (the oldest goes
/// first): an old incarnation's reports still arriving while the new one reports
/// (resent across a link after the actor restarted) is the only reason to keep more
/// than one. A report of an incarnation older than every kept one, with all slots
/// taken, is not taken (it may have been): an actor that restarted this often while
/// its reports were on their way loses those reports rather than have one counted
/// twice.
const INCARNATIONS_KEPT: usize = 64;

/// The receiving side's record of one actor's reports, per incarnation.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ReportCursor {
    incarnations: BTreeMap<u32, Handled>,
}

/// Which reports of one actor incarnation were handled.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
struct Handled {
    /// Every report numbered below this was handled.
    next: u64,
    /// Reports numbered above `next` that were handled (they arrived out of order).
    ahead: BTreeSet<u64>,
}

impl Handled {
    /// Move `next` to `to` if that is further, and over what was handled past it.
    fn advance(&mut self, to: u64) {
        if to > self.next {
            self.next = to;
            self.ahead = self.ahead.split_off(&to);
        }
        while self.ahead.remove(&self.next) {
            self.next += 1;
        }
    }
}

impl ReportCursor {
    /// Whether the report (incarnation, seq), whose sender holds nothing of its
    /// incarnation below `low_water`, is new and should be taken.
    pub fn is_new(&mut self, incarnation: u32, seq: u64, low_water: u64) -> bool {
        if !self.incarnations.contains_key(&incarnation) && self.incarnations.len() >= INCARNATIONS_KEPT {
            if self.incarnations.first_key_value().is_some_and(|(&oldest, _)| incarnation < oldest) {
                return false;
            }
            self.incarnations.pop_first();
        }
        let handled = self.incarnations.entry(incarnation).or_default();
        handled.advance(low_water);
        seq >= handled.next && !handled.ahead.contains(&seq)
    }

    /// Record that the report (incarnation, seq), which [`ReportCursor::is_new`] just
    /// let through, was handled: taken, or refused for good.
    pub fn handled(&mut self, incarnation: u32, seq: u64) {
        if let Some(handled) = self.incarnations.get_mut(&incarnation)
            && seq >= handled.next
        {
            handled.ahead.insert(seq);
            handled.advance(handled.next);
        }
    }

    /// The newest incarnation and its cumulative count (every report below it was
    /// handled).
    pub fn newest(&self) -> Option<(u32, u64)> {
        self.incarnations.last_key_value().map(|(&incarnation, h)| (incarnation, h.next))
    }

    /// Every kept incarnation's cumulative count, oldest first.
    pub fn acks(&self) -> impl Iterator<Item = (u32, u64)> + '_ {
        self.incarnations.iter().map(|(&incarnation, h)| (incarnation, h.next))
    }

    /// The cumulative count of `incarnation` (0 when it has none).
    fn next_of(&self, incarnation: u32) -> u64 {
        self.incarnations.get(&incarnation).map_or(0, |h| h.next)
    }
}

/// The curriculum service's cursors, one per actor id: what it took of every actor's
/// reports. Saved with the curriculum's state, so a restored service takes again
/// exactly the reports its state does not hold.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct ReportCursors {
    actors: BTreeMap<u32, ReportCursor>,
}

impl ReportCursors {
    /// Whether the report under `h` is new and should be taken (then call
    /// [`ReportCursors::handled`] once it is).
    pub fn is_new(&mut self, h: &EpisodeHeader) -> bool {
        self.actors.entry(h.actor).or_default().is_new(h.incarnation, h.seq, h.low_water)
    }

    /// Record that the report under `h` was handled (taken, or refused for good).
    pub fn handled(&mut self, h: &EpisodeHeader) {
        self.actors.entry(h.actor).or_default().handled(h.incarnation, h.seq);
    }

    /// The acknowledgements to publish, these cursors being what was taken and
    /// `saved` what the saved state holds: every actor's newest incarnation.
    pub fn table(&self, saved: &ReportCursors) -> EpisodeAckTable {
        let mut table = EpisodeAckTable::default();
        for (&actor, cursor) in &self.actors {
            if let (Some(entry), Some((incarnation, taken))) = (table.actors.get_mut(actor as usize), cursor.newest()) {
                let saved = saved.actors.get(&actor).map_or(0, |c| c.next_of(incarnation)).min(taken);
                *entry = EpisodeAck { incarnation, reserved: 0, taken, saved };
            }
        }
        table
    }

    /// Every (actor, incarnation, cumulative count) kept, by actor then incarnation.
    pub fn streams(&self) -> impl Iterator<Item = (u32, u32, u64)> + '_ {
        self.actors.iter().flat_map(|(&actor, c)| c.acks().map(move |(incarnation, next)| (actor, incarnation, next)))
    }
}

/// A report the sending side holds.
struct Held {
    header: EpisodeHeader,
    points: Vec<EpisodePoint>,
    /// When it was last sent (`None`: not yet).
    sent: Option<Instant>,
    /// Whether it is to be sent again at once (the receiver said it lacks it).
    lacked: bool,
    /// Whether the receiver said it took it (it is not sent again unless the receiver
    /// later says it lacks it).
    taken: bool,
}

/// One actor incarnation's window of reports not yet saved by the receiver, oldest
/// first.
pub struct HeldReports {
    held: VecDeque<Held>,
    capacity: usize,
}

impl HeldReports {
    /// An empty window of at most `capacity` reports.
    pub fn new(capacity: usize) -> HeldReports {
        HeldReports { held: VecDeque::new(), capacity: capacity.max(1) }
    }

    /// Reports held at most.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Reports held now (taken by the receiver or not).
    pub fn len(&self) -> usize {
        self.held.len()
    }

    /// Whether every report was saved by the receiver.
    pub fn is_empty(&self) -> bool {
        self.held.is_empty()
    }

    /// Reports held that the receiver has not said it took.
    pub fn untaken(&self) -> usize {
        self.held.iter().filter(|h| !h.taken).count()
    }

    /// Hold a new report (its `seq` is the next of its actor incarnation); when the
    /// window is full the oldest is dropped first — whether one was.
    pub fn push(&mut self, header: EpisodeHeader, points: Vec<EpisodePoint>) -> bool {
        let dropped = self.held.len() == self.capacity;
        if dropped {
            self.held.pop_front();
        }
        self.held.push_back(Held { header, points, sent: None, lacked: false, taken: false });
        dropped
    }

    /// Apply the receiver's acknowledgement: forget every report numbered below
    /// `saved`, mark those below `taken` as taken, and make a report marked taken
    /// that is not any more (the receiver restarted without it) due at once. Returns
    /// how many reports were forgotten.
    pub fn acknowledge(&mut self, taken: u64, saved: u64) -> usize {
        let before = self.held.len();
        while self.held.front().is_some_and(|h| h.header.seq < saved) {
            self.held.pop_front();
        }
        for h in &mut self.held {
            if h.header.seq < taken {
                h.taken = true;
            } else if h.taken {
                h.taken = false;
                h.lacked = true;
            }
        }
        before - self.held.len()
    }

    /// Whether a report is due ([`HeldReports::send_due`] would send one).
    pub fn any_due(&self, now: Instant, resend_after: Duration) -> bool {
        self.held.iter().any(|h| is_due(h, now, resend_after))
    }

    /// Send (`send(header, points)`, true when it went) every report not taken that
    /// was not sent yet or was sent `resend_after` ago or longer, oldest first, at most
    /// `max` of them, each stamped with the window's current low-water mark; returns
    /// how many went, and how many of those were sent before.
    pub fn send_due(
        &mut self,
        now: Instant,
        resend_after: Duration,
        max: usize,
        mut send: impl FnMut(&EpisodeHeader, &[EpisodePoint]) -> bool,
    ) -> (usize, usize) {
        // The reports are held in number order, so the first is the lowest.
        let Some(low_water) = self.held.front().map(|h| h.header.seq) else { return (0, 0) };
        let (mut sent, mut again) = (0, 0);
        for h in &mut self.held {
            if sent == max {
                break;
            }
            if !is_due(h, now, resend_after) {
                continue;
            }
            h.header.low_water = low_water;
            if !send(&h.header, &h.points) {
                // Refused (nobody listening, a full queue): the rest waits, in order.
                break;
            }
            again += h.sent.is_some() as usize;
            h.sent = Some(now);
            h.lacked = false;
            sent += 1;
        }
        (sent, again)
    }
}

/// Whether a held report should go out now: not taken, and not sent yet, said lacking
/// by the receiver, or sent `resend_after` ago or longer.
fn is_due(h: &Held, now: Instant, resend_after: Duration) -> bool {
    !h.taken && (h.lacked || h.sent.is_none_or(|t| now.duration_since(t) >= resend_after))
}

/// The entry of `table` for (`actor`, `incarnation`) as (taken, saved): every report
/// numbered below `taken` was taken, every one below `saved` is saved ((0, 0) when the
/// table has nothing of that incarnation: the receiver holds none of its reports).
pub fn acknowledged(table: &EpisodeAckTable, actor: u32, incarnation: u32) -> (u64, u64) {
    match table.actors.get(actor as usize) {
        Some(a) if a.incarnation == incarnation => (a.taken, a.saved),
        _ => (0, 0),
    }
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;

    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};

    use super::*;

    fn header(actor: u32, incarnation: u32, seq: u64) -> EpisodeHeader {
        EpisodeHeader { actor, incarnation, seq, length: 1, ..EpisodeHeader::default() }
    }

    /// What [`exchange`] ended with.
    struct Outcome {
        /// How often each report is in the receiver's state (live at the end).
        taken: BTreeMap<(u32, u32, u64), u32>,
        /// Reports the senders dropped for room.
        dropped: u64,
        /// Reports still held by a sender at the end.
        held: u64,
    }

    /// Senders and a receiver over a link that loses, duplicates, delays and reorders
    /// reports, and loses and delays acknowledgement tables (a queue each way, drawn
    /// from by chance), with cuts that empty both queues, and a receiver that saves its
    /// cursors together with what it took every 5 ticks and, every `restart_every`
    /// ticks, restarts from that save (as the curriculum service saves its cursors with
    /// its state). Two actors, one of which restarts half-way once its first
    /// incarnation holds nothing (a second incarnation, with a fresh window).
    fn exchange(seed: u64, reports: u64, capacity: usize, loss: f64, cut_every: u64, restart_every: u64) -> Outcome {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut senders: BTreeMap<(u32, u32), HeldReports> = BTreeMap::new();
        let mut next_seq: HashMap<(u32, u32), u64> = HashMap::new();
        // The receiver: cursors and what it took, live and as last saved.
        let (mut cursors, mut taken) = (ReportCursors::default(), BTreeMap::<(u32, u32, u64), u32>::new());
        let (mut saved_cursors, mut saved_taken) = (cursors.clone(), taken.clone());
        let (mut to_receiver, mut to_sender): (VecDeque<EpisodeHeader>, VecDeque<EpisodeAckTable>) = Default::default();
        let start = Instant::now();
        let (mut dropped, mut made) = (0u64, 0u64);
        for tick in 0..(reports * 80) {
            let now = start + Duration::from_millis(100 * tick);
            if made < reports && rng.random_bool(0.5) {
                let actor = (made % 2) as u32;
                let mut incarnation = if actor == 1 && made >= reports / 2 { 2 } else { 1 };
                if incarnation == 2 && senders.get(&(1, 1)).is_some_and(|w| !w.is_empty()) {
                    incarnation = 1; // it stops only once its first incarnation holds nothing
                } else if incarnation == 2 {
                    senders.remove(&(1, 1));
                }
                let seq = next_seq.entry((actor, incarnation)).or_default();
                let window = senders.entry((actor, incarnation)).or_insert_with(|| HeldReports::new(capacity));
                dropped += window.push(header(actor, incarnation, *seq), vec![EpisodePoint::default(); 2]) as u64;
                *seq += 1;
                made += 1;
            }
            if cut_every > 0 && tick % cut_every == cut_every - 1 {
                to_receiver.clear();
                to_sender.clear();
            }
            for window in senders.values_mut() {
                window.send_due(now, Duration::from_millis(500), 8, |h, _| {
                    if !rng.random_bool(loss) {
                        to_receiver.push_back(*h);
                        if rng.random_bool(0.1) {
                            to_receiver.push_back(*h); // duplicated on the way
                        }
                    }
                    true
                });
            }
            if to_receiver.len() > 1 && rng.random_bool(0.2) {
                let last = to_receiver.len() - 1;
                to_receiver.swap(0, last);
            }
            for _ in 0..rng.random_range(0..=to_receiver.len()) {
                let h = to_receiver.pop_front().unwrap();
                if cursors.is_new(&h) {
                    *taken.entry((h.actor, h.incarnation, h.seq)).or_default() += 1;
                    cursors.handled(&h);
                }
            }
            if tick % 5 == 4 {
                (saved_cursors, saved_taken) = (cursors.clone(), taken.clone());
            }
            if restart_every > 0 && tick % restart_every == restart_every - 1 {
                (cursors, taken) = (saved_cursors.clone(), saved_taken.clone());
                // A restarted receiver publishes its table at once.
                to_sender.push_back(cursors.table(&saved_cursors));
            }
            if tick.is_multiple_of(3) && !rng.random_bool(loss) {
                to_sender.push_back(cursors.table(&saved_cursors));
            }
            if rng.random_bool(0.5)
                && let Some(table) = to_sender.pop_front()
            {
                for (&(actor, incarnation), window) in &mut senders {
                    let (t, s) = acknowledged(&table, actor, incarnation);
                    window.acknowledge(t, s);
                }
            }
            assert!(senders.values().all(|w| w.len() <= w.capacity()));
            if made == reports && senders.values().all(HeldReports::is_empty) {
                break;
            }
        }
        let held = senders.values().map(|w| w.len() as u64).sum();
        Outcome { taken, dropped, held }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// A window that never overflows: every report taken exactly once and saved,
        /// whatever the link lost, duplicated or reordered and however often the
        /// receiver restarted from its saved state.
        #[test]
        fn every_report_is_taken_once(
            seed in any::<u64>(),
            loss in 0.0f64..0.5,
            cut_every in prop_oneof![Just(0u64), 7u64..40],
            restart_every in prop_oneof![Just(0u64), 11u64..60],
        ) {
            let reports = 60;
            let o = exchange(seed, reports, 1_000, loss, cut_every, restart_every);
            prop_assert_eq!((o.dropped, o.held), (0, 0), "every report saved");
            prop_assert!(o.taken.values().all(|&n| n == 1), "a report taken twice: {:?}", o.taken);
            prop_assert_eq!(o.taken.len() as u64, reports, "reports missing: {:?}", o.taken.keys().collect::<Vec<_>>());
        }

        /// A window too small for the receiver's absences: reports are dropped for
        /// room, but none is taken twice, and every one not dropped arrives
        /// (taken + dropped ≥ made: a dropped one may have gone out first).
        #[test]
        fn an_overflowing_window_takes_nothing_twice(seed in any::<u64>(), loss in 0.0f64..0.9) {
            let reports = 80;
            let o = exchange(seed, reports, 3, loss, 5, 0);
            prop_assert!(o.taken.values().all(|&n| n == 1), "a report taken twice: {:?}", o.taken);
            prop_assert!(
                o.taken.len() as u64 + o.dropped + o.held >= reports,
                "{} taken, {} dropped, {} held", o.taken.len(), o.dropped, o.held
            );
        }
    }

    #[test]
    fn acknowledgements_are_cumulative_with_reports_ahead_remembered() {
        let mut c = ReportCursor::default();
        assert!(c.is_new(1, 0, 0));
        c.handled(1, 0);
        // 1 lost on the way; 2 and 3 arrive.
        for seq in [2, 3] {
            assert!(c.is_new(1, seq, 0));
            c.handled(1, seq);
        }
        assert_eq!(c.newest(), Some((1, 1)));
        assert!(!c.is_new(1, 3, 0), "taken already");
        assert!(c.is_new(1, 1, 0), "the lost one, sent again");
        c.handled(1, 1);
        assert_eq!(c.newest(), Some((1, 4)), "1 closed the gap up to 3");
        // The sender gave up 4 and 5 (its window overflowed): 6 says so.
        assert!(c.is_new(1, 6, 6));
        c.handled(1, 6);
        assert_eq!(c.newest(), Some((1, 7)));
        assert!(!c.is_new(1, 5, 6), "below the low-water mark");
    }

    #[test]
    fn only_the_newest_incarnations_are_kept_and_an_older_one_is_never_taken() {
        let mut c = ReportCursor::default();
        let last = INCARNATIONS_KEPT as u32 + 2;
        for incarnation in 1..=last {
            assert!(c.is_new(incarnation, 0, 0));
            c.handled(incarnation, 0);
        }
        let kept: Vec<u32> = c.acks().map(|(incarnation, _)| incarnation).collect();
        assert_eq!(kept, (3..=last).collect::<Vec<_>>());
        // Incarnation 1's report again (its record was evicted): not taken twice.
        assert!(!c.is_new(1, 0, 0));
        assert_eq!(c.acks().count(), INCARNATIONS_KEPT, "and it takes no slot");
    }

    #[test]
    fn the_table_holds_every_actors_newest_incarnation_taken_and_saved_and_survives_a_save() {
        let mut cursors = ReportCursors::default();
        let take = |cursors: &mut ReportCursors, list: &[(u32, u32, u64)]| {
            for &(actor, incarnation, seq) in list {
                let h = header(actor, incarnation, seq);
                assert!(cursors.is_new(&h));
                cursors.handled(&h);
            }
        };
        take(&mut cursors, &[(0, 1, 0), (0, 1, 1), (0, 2, 0)]);
        let saved = cursors.clone();
        take(&mut cursors, &[(0, 2, 1), (5, 1, 0), (5, 1, 2)]);
        let table = cursors.table(&saved);
        assert_eq!(table.actors[0], EpisodeAck { incarnation: 2, reserved: 0, taken: 2, saved: 1 });
        assert_eq!(
            table.actors[5],
            EpisodeAck { incarnation: 1, reserved: 0, taken: 1, saved: 0 },
            "2 is ahead of a gap"
        );
        assert_eq!(table.actors[1], EpisodeAck::default());
        assert_eq!(acknowledged(&table, 0, 2), (2, 1));
        assert_eq!((acknowledged(&table, 0, 1), acknowledged(&table, 9, 1)), ((0, 0), (0, 0)), "not the newest");
        let back: ReportCursors = serde_json::from_str(&serde_json::to_string(&cursors).unwrap()).unwrap();
        assert_eq!(back, cursors);
        let mut back = back;
        assert!(!back.is_new(&header(5, 1, 2)), "a restored cursor remembers what was ahead");
        assert!(back.is_new(&header(5, 1, 1)));
    }

    #[test]
    fn the_window_forgets_saved_reports_holds_taken_ones_and_drops_the_oldest_for_room() {
        let mut w = HeldReports::new(3);
        for seq in 0..3 {
            assert!(!w.push(header(0, 1, seq), Vec::new()));
        }
        assert!(w.push(header(0, 1, 3), Vec::new()), "full: the oldest goes");
        assert_eq!(w.acknowledge(3, 3), 2);
        assert_eq!(w.acknowledge(2, 2), 0, "an older acknowledgement forgets nothing");
        let mut marks = Vec::new();
        let t = Instant::now();
        let sent = w.send_due(t, Duration::from_secs(1), 8, |h, _| {
            marks.push((h.seq, h.low_water));
            true
        });
        assert_eq!(sent, (1, 0));
        assert_eq!(marks, [(3, 3)], "the report carries the lowest number held");
        assert!(!w.any_due(t, Duration::from_secs(1)));
        assert_eq!(w.send_due(t, Duration::from_secs(1), 8, |_, _| true), (0, 0), "sent, not yet due again");
        assert_eq!(w.send_due(t + Duration::from_secs(1), Duration::from_secs(1), 8, |_, _| true), (1, 1), "due again");
        // A refused send keeps the report due, and what follows it waits.
        w.push(header(0, 1, 4), Vec::new());
        let later = t + Duration::from_secs(2);
        assert_eq!(w.send_due(later, Duration::from_secs(1), 8, |_, _| false), (0, 0));
        assert_eq!(w.send_due(later, Duration::from_secs(1), 1, |_, _| true), (1, 1), "at most max");
        assert_eq!(w.send_due(later, Duration::from_secs(1), 8, |_, _| true), (1, 0));
        // Taken, not saved: held, never due; the receiver restarted without them: due at once.
        assert_eq!((w.acknowledge(5, 3), w.len(), w.untaken()), (0, 2, 0));
        assert!(!w.any_due(later + Duration::from_secs(9), Duration::from_secs(1)));
        assert_eq!((w.acknowledge(4, 3), w.untaken()), (0, 1));
        assert!(w.any_due(later, Duration::from_secs(1)), "4 went back to untaken: due at once");
        assert_eq!(w.send_due(later, Duration::from_secs(1), 8, |_, _| true), (1, 1), "and counted as sent again");
        assert!(!w.any_due(later, Duration::from_secs(1)));
        assert_eq!((w.acknowledge(5, 5), w.len()), (2, 0), "saved: forgotten");
    }
}
