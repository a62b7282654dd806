//! Episode reports across the link, acknowledged: the actor host holds each report
//! until the learner host says it was handled, and sends it again after a reconnect or
//! when no acknowledgement came; the learner host publishes each report once.
//!
//! A report is named by (actor, incarnation, seq), `seq` counting that actor
//! incarnation's reports from 0. The learner host acknowledges cumulatively: per
//! (actor, incarnation), `next` — every report numbered below it is handled. Reports
//! can arrive out of order (one lost in a cut link is sent again after later ones got
//! through), so the receiving side also remembers which reports above `next` it has
//! published. Every report carries its sender's *low-water mark*, the lowest number of
//! that actor incarnation the sender still holds: a report the sender gave up (its
//! window overflowed while the learner host was away) is never waited for.
//!
//! Invariants (property-tested over links that lose, duplicate and delay reports and
//! acknowledgements):
//! - the receiving side publishes a report at most once (a cursor that survives:
//!   a learner host that restarts may publish again what it had not yet acknowledged);
//! - with a window that never overflows, every report is eventually published;
//! - the sending side holds at most [`HeldReports::capacity`] reports, dropping the
//!   oldest first, and drops a report only once it is acknowledged or to make room.

use std::collections::{BTreeMap, BTreeSet, HashMap, VecDeque};
use std::time::{Duration, Instant};

use crate::wire::{self, ReportAck};

/// Incarnations of one actor whose cursors the receiving side keeps (the oldest goes
/// first): an actor host still sending an old incarnation's held reports while the new
/// one reports is the only reason to keep more than one. A report of an incarnation
/// older than every kept one, with all slots taken, is not published (it may have
/// been): an actor that restarted this often while its host was cut off loses those
/// reports rather than have one counted twice.
const INCARNATIONS_KEPT: usize = 64;

/// The receiving side's record of one actor's reports, per incarnation.
#[derive(Debug, Default)]
pub(crate) struct ReportCursor {
    incarnations: BTreeMap<u32, Handled>,
}

/// Which reports of one actor incarnation were handled.
#[derive(Debug, Default)]
struct Handled {
    /// Every report numbered below this was handled.
    next: u64,
    /// Reports numbered above `next` that were published (arrived out of order).
    ahead: BTreeSet<u64>,
}

impl Handled {
    /// Move `next` to `to` if that is further, and over what was published past it.
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
    /// incarnation below `low_water`, is new and should be published.
    pub(crate) fn is_new(&mut self, incarnation: u32, seq: u64, low_water: u64) -> bool {
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
    /// let through, was handled: published, or refused for good.
    pub(crate) fn handled(&mut self, incarnation: u32, seq: u64) {
        if let Some(handled) = self.incarnations.get_mut(&incarnation)
            && seq >= handled.next
        {
            handled.ahead.insert(seq);
            handled.advance(handled.next);
        }
    }

    /// The acknowledgements of `actor`'s incarnations.
    pub(crate) fn acks(&self, actor: u32) -> impl Iterator<Item = ReportAck> + '_ {
        self.incarnations.iter().map(move |(&incarnation, h)| ReportAck { actor, incarnation, next: h.next })
    }
}

/// A report the sending side holds.
struct Held {
    actor: u32,
    incarnation: u32,
    seq: u64,
    /// The encoded report ([`wire::encode_episode`]); its low-water mark is restamped
    /// before every send.
    bytes: Vec<u8>,
    /// When it was last put on the link (`None`: not since it arrived or since the
    /// learner host came back).
    sent: Option<Instant>,
}

/// The sending side's window of unacknowledged reports, oldest first.
pub(crate) struct HeldReports {
    held: VecDeque<Held>,
    capacity: usize,
}

impl HeldReports {
    /// An empty window of at most `capacity` reports.
    pub(crate) fn new(capacity: usize) -> HeldReports {
        HeldReports { held: VecDeque::new(), capacity: capacity.max(1) }
    }

    /// Reports held at most.
    #[cfg(test)]
    pub(crate) fn capacity(&self) -> usize {
        self.capacity
    }

    /// Reports held now.
    pub(crate) fn len(&self) -> usize {
        self.held.len()
    }

    /// Whether every report was acknowledged.
    pub(crate) fn is_empty(&self) -> bool {
        self.held.is_empty()
    }

    /// Hold a new report (its number is the next of its actor incarnation); when the
    /// window is full the oldest is dropped first — whether one was.
    pub(crate) fn push(&mut self, actor: u32, incarnation: u32, seq: u64, bytes: Vec<u8>) -> bool {
        let dropped = self.held.len() == self.capacity;
        if dropped {
            self.held.pop_front();
        }
        self.held.push_back(Held { actor, incarnation, seq, bytes, sent: None });
        dropped
    }

    /// Drop what the learner host acknowledged; how many reports that was.
    pub(crate) fn acknowledge(&mut self, acks: &[ReportAck]) -> usize {
        let next: HashMap<(u32, u32), u64> = acks.iter().map(|a| ((a.actor, a.incarnation), a.next)).collect();
        let before = self.held.len();
        self.held.retain(|h| next.get(&(h.actor, h.incarnation)).is_none_or(|&n| h.seq >= n));
        before - self.held.len()
    }

    /// Send everything again at the next [`HeldReports::send_due`] (the learner host
    /// came back: what was on its way may be lost).
    pub(crate) fn resend_all(&mut self) {
        for h in &mut self.held {
            h.sent = None;
        }
    }

    /// Put on the link (`put(actor, bytes)`, true when it went) every report not sent
    /// yet, and every one sent longer than `resend_after` ago without an
    /// acknowledgement, each with its actor incarnation's current low-water mark;
    /// returns how many went.
    pub(crate) fn send_due(
        &mut self,
        now: Instant,
        resend_after: Duration,
        mut put: impl FnMut(u32, &[u8]) -> bool,
    ) -> usize {
        let due = |h: &Held| h.sent.is_none_or(|t| now.duration_since(t) >= resend_after);
        if !self.held.iter().any(due) {
            return 0;
        }
        // An actor incarnation's reports arrive in number order, so its first held one
        // is its lowest.
        let mut low_water: HashMap<(u32, u32), u64> = HashMap::new();
        for h in &self.held {
            low_water.entry((h.actor, h.incarnation)).or_insert(h.seq);
        }
        let mut sent = 0;
        for h in &mut self.held {
            if !due(h) {
                continue;
            }
            wire::restamp_low_water(&mut h.bytes, low_water[&(h.actor, h.incarnation)]);
            if !put(h.actor, &h.bytes) {
                // The link refused it: the rest waits for the next pass, in order.
                break;
            }
            h.sent = Some(now);
            sent += 1;
        }
        sent
    }
}

#[cfg(test)]
mod tests {
    use pednav_runtime::messages::{EpisodeHeader, EpisodePoint};
    use proptest::prelude::*;
    use rand::{Rng, SeedableRng};

    use super::*;

    fn report(actor: u32, incarnation: u32, seq: u64) -> Vec<u8> {
        let h = EpisodeHeader { actor, incarnation, seq, length: 1, ..EpisodeHeader::default() };
        wire::encode_episode(&h, seq, &[EpisodePoint::default()])
    }

    /// Sender and receiver over a link that loses, duplicates, delays and reorders reports
    /// and loses and delays acknowledgements (a queue each way, drawn from by chance),
    /// with cuts that empty both queues; returns how often
    /// each report was published, and how many the sender dropped for room.
    fn exchange(
        seed: u64,
        reports: u64,
        capacity: usize,
        loss: f64,
        cut_every: u64,
    ) -> (BTreeMap<(u32, u64), u32>, u64) {
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let mut sender = HeldReports::new(capacity);
        let mut cursors: HashMap<u32, ReportCursor> = HashMap::new();
        let mut published: BTreeMap<(u32, u64), u32> = BTreeMap::new();
        let (mut to_receiver, mut to_sender): (VecDeque<Vec<u8>>, VecDeque<Vec<ReportAck>>) = Default::default();
        let start = Instant::now();
        let (mut dropped, mut made) = (0u64, 0u64);
        // Two actors, one of which restarts half-way (a second incarnation).
        for tick in 0..(reports * 40) {
            let now = start + Duration::from_millis(100 * tick);
            if made < reports && rng.random_bool(0.5) {
                let actor = (made % 2) as u32;
                let incarnation = if actor == 1 && made >= reports / 2 { 2 } else { 1 };
                let seq = if incarnation == 2 { (made - reports / 2) / 2 } else { made / 2 };
                dropped += sender.push(actor, incarnation, seq, report(actor, incarnation, seq)) as u64;
                made += 1;
            }
            // A cut: everything on its way is lost, and the sender sends all again.
            let cut = cut_every > 0 && tick % cut_every == cut_every - 1;
            if cut {
                to_receiver.clear();
                to_sender.clear();
                sender.resend_all();
            }
            sender.send_due(now, Duration::from_millis(500), |_, bytes| {
                if !rng.random_bool(loss) {
                    to_receiver.push_back(bytes.to_vec());
                    if rng.random_bool(0.1) {
                        to_receiver.push_back(bytes.to_vec()); // duplicated on the way
                    }
                }
                true
            });
            // Deliver part of what is on its way, sometimes out of order.
            if to_receiver.len() > 1 && rng.random_bool(0.2) {
                let last = to_receiver.len() - 1;
                to_receiver.swap(0, last);
            }
            for _ in 0..rng.random_range(0..=to_receiver.len()) {
                let bytes = to_receiver.pop_front().unwrap();
                let (h, low_water, _) = wire::decode_episode(&bytes).unwrap();
                let cursor = cursors.entry(h.actor).or_default();
                if cursor.is_new(h.incarnation, h.seq, low_water) {
                    *published.entry((h.actor * 1000 + h.incarnation, h.seq)).or_default() += 1;
                    cursor.handled(h.incarnation, h.seq);
                }
            }
            if tick.is_multiple_of(3) {
                let acks: Vec<ReportAck> = cursors.iter().flat_map(|(&a, c)| c.acks(a).collect::<Vec<_>>()).collect();
                if !rng.random_bool(loss) {
                    to_sender.push_back(acks);
                }
            }
            // Acknowledgements are delayed too (and lost with the queue on a cut).
            if rng.random_bool(0.5)
                && let Some(acks) = to_sender.pop_front()
            {
                sender.acknowledge(&acks);
            }
            assert!(sender.len() <= sender.capacity());
            if made == reports && sender.is_empty() {
                break;
            }
        }
        (published, dropped)
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(64))]

        /// A window that never overflows: every report published exactly once,
        /// whatever the link lost, duplicated or reordered.
        #[test]
        fn every_report_is_published_once(seed in any::<u64>(), loss in 0.0f64..0.5, cut_every in prop_oneof![Just(0u64), 7u64..40]) {
            let reports = 60;
            let (published, dropped) = exchange(seed, reports, 1_000, loss, cut_every);
            prop_assert_eq!(dropped, 0);
            prop_assert!(published.values().all(|&n| n == 1), "a report published twice: {published:?}");
            prop_assert_eq!(published.len() as u64, reports, "reports missing: {:?}", published.keys().collect::<Vec<_>>());
        }

        /// A window too small for the learner host's absences: reports are dropped for
        /// room, but none is published twice, and every one not dropped arrives
        /// (published + dropped ≥ made: a dropped one may have gone out first).
        #[test]
        fn an_overflowing_window_publishes_nothing_twice(seed in any::<u64>(), loss in 0.0f64..0.9) {
            let reports = 80;
            let (published, dropped) = exchange(seed, reports, 3, loss, 5);
            prop_assert!(published.values().all(|&n| n == 1), "a report published twice: {published:?}");
            prop_assert!(published.len() as u64 + dropped >= reports, "{} published, {dropped} dropped", published.len());
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
        assert_eq!(c.acks(7).collect::<Vec<_>>(), [ReportAck { actor: 7, incarnation: 1, next: 1 }]);
        assert!(!c.is_new(1, 3, 0), "published already");
        assert!(c.is_new(1, 1, 0), "the lost one, sent again");
        c.handled(1, 1);
        assert_eq!(c.acks(7).next().unwrap().next, 4, "1 closed the gap up to 3");
        // The sender gave up 4 and 5 (its window overflowed): 6 says so.
        assert!(c.is_new(1, 6, 6));
        c.handled(1, 6);
        assert_eq!(c.acks(7).next().unwrap().next, 7);
        assert!(!c.is_new(1, 5, 6), "below the low-water mark");
    }

    #[test]
    fn only_the_newest_incarnations_are_kept_and_an_older_one_is_never_published() {
        let mut c = ReportCursor::default();
        let last = INCARNATIONS_KEPT as u32 + 2;
        for incarnation in 1..=last {
            assert!(c.is_new(incarnation, 0, 0));
            c.handled(incarnation, 0);
        }
        let kept: Vec<u32> = c.acks(0).map(|a| a.incarnation).collect();
        assert_eq!(kept, (3..=last).collect::<Vec<_>>());
        // Incarnation 1's report again (its record was evicted): not published twice.
        assert!(!c.is_new(1, 0, 0));
        assert_eq!(c.acks(0).count(), INCARNATIONS_KEPT, "and it takes no slot");
    }

    #[test]
    fn the_window_drops_acknowledged_reports_and_the_oldest_for_room() {
        let mut w = HeldReports::new(3);
        for seq in 0..3 {
            assert!(!w.push(0, 1, seq, report(0, 1, seq)));
        }
        assert!(w.push(0, 1, 3, report(0, 1, 3)), "full: the oldest goes");
        assert_eq!(w.acknowledge(&[ReportAck { actor: 0, incarnation: 1, next: 3 }]), 2);
        assert_eq!(w.acknowledge(&[ReportAck { actor: 0, incarnation: 2, next: 9 }]), 0, "another incarnation's");
        let mut marks = Vec::new();
        let t = Instant::now();
        let sent = w.send_due(t, Duration::from_secs(1), |_, b| {
            marks.push(wire::decode_episode(b).unwrap().1);
            true
        });
        assert_eq!(sent, 1);
        assert_eq!(marks, [3], "the report carries the lowest number held");
        assert_eq!(w.send_due(t, Duration::from_secs(1), |_, _| true), 0, "sent, not yet due again");
        assert_eq!(w.send_due(t + Duration::from_secs(1), Duration::from_secs(1), |_, _| true), 1, "due again");
        w.resend_all();
        assert_eq!(w.send_due(t + Duration::from_secs(1), Duration::from_secs(1), |_, _| true), 1);
    }
}
