//! Lossless record streams over links that can cut, and receivers that can restart:
//! sequence numbers, cumulative acknowledgements, and resends the receiver asks for.
//!
//! A *stream* is one sender incarnation's records (an actor process's step records,
//! say). [`SendWindow`] numbers them 0, 1, 2, … and keeps every record no receiver has
//! acknowledged; [`ReceiveCursor`] accepts them strictly in order.
//!
//! Invariants (the property test at the end drives both ends over a link that drops
//! everything in flight, delivers duplicates and loses acknowledgements, with
//! receivers that die and are replaced):
//! - **nothing lost**: every record is accepted by a receiver, in order; a receiver
//!   that dies takes with it only what it had acknowledged — everything else is sent
//!   again to its replacement;
//! - **nothing twice** within one receiver: its accepted records increase, one by
//!   one; the one exception is a jump over records a receiver before it took and
//!   acknowledged (a dead receiver's last ack can reach the sender after its
//!   replacement took older records), and such a jump is never silent: the record
//!   after it is a [`Verdict::Resume`], so the caller cuts whatever it was assembling;
//! - **bounded**: the sender holds at most `capacity` records; a full window is the
//!   sender's signal to wait (its credit is spent), so back-pressure reaches the
//!   sender and no queue on the way grows without bound.
//!
//! The protocol, and why it needs nothing from the link but in-order delivery within
//! one connection (TCP, zenoh's reliable channel, iceoryx2's lossless queues):
//! - every record carries `(seq, base)`: its own number and the oldest number the
//!   sender still holds. Records below `base` were acknowledged by some receiver.
//! - A receiver keeps `expected`. It first moves `expected` up to `base` (what lies
//!   below was taken and acknowledged by a receiver before it — a new or restarted
//!   receiver starts there). Then `seq == expected` is accepted, `seq < expected` is a
//!   duplicate (dropped), `seq > expected` means records went missing on the way
//!   (a cut link): dropped, and the receiver asks for a resend from `expected`.
//! - The receiver's [`Ack`] is *state*, not an event: `expected` (everything below it
//!   is in) and a resend counter. The newest ack replaces older ones, so acks may
//!   travel over a lossy newest-wins channel and only the last one matters. A sender
//!   that sees the counter change goes back to `expected` and sends everything it
//!   holds from there (go-back-N).
//! - The tail: a record lost after the last one sent is exposed by no later record,
//!   and a sender whose window is full sends nothing new. The sender therefore
//!   announces `(base, next)` now and then (in its heartbeat); a receiver that is
//!   behind `next` and has made no progress for `retry_after` asks for a resend. The
//!   caller announces only while it reads the stream (after taking what is queued),
//!   or it would ask for records that wait unread in its own queue.
//! - A receiver asks again only after `retry_after` since its last request, so the
//!   stale records still in flight behind a cut do not trigger a rewind each;
//!   `retry_after` should exceed an ack's round trip plus the time to send a window.
//!
//! What the caller keeps: a stream's identity (an ack must reach the sender of the
//! stream it acknowledges — pednav keys both by actor and incarnation), and receiver
//! ids that differ between a receiver and the next one (pednav uses the learner's
//! pid), so a restarted receiver's first request is told from its predecessor's.
//!
//! A receiver's cursor belongs with the state that consumed the records: a receiver
//! restored from a checkpoint restores its cursors with it; one that starts empty
//! starts with empty cursors (and is sent again what its predecessor never
//! acknowledged).

use std::collections::VecDeque;
use std::time::{Duration, Instant};

use iceoryx2::prelude::ZeroCopySend;

/// A receiver's acknowledgement of one stream: everything below `expected` is in, and
/// `resend` counts its requests to send again from `expected`. Newest wins.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend)]
pub struct Ack {
    /// The receiver's incarnation (so a sender can tell a restarted receiver's
    /// counter from its predecessor's).
    pub receiver: u32,
    /// Resend requests made by this receiver so far.
    pub resend: u32,
    /// The next sequence number the receiver will accept.
    pub expected: u64,
}

/// A record leaving the window: its sequence number, the window's base, the record.
#[derive(Debug, PartialEq, Eq)]
pub struct Outgoing<'a, T> {
    /// The record's sequence number.
    pub seq: u64,
    /// The oldest sequence number the sender still holds (travels with the record).
    pub base: u64,
    /// The record.
    pub record: &'a T,
}

impl<T> Clone for Outgoing<'_, T> {
    fn clone(&self) -> Self {
        *self
    }
}

impl<T> Copy for Outgoing<'_, T> {}

/// Why an acknowledgement was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum AckError {
    /// The ack claims records this sender never sent: it belongs to another stream
    /// (another run, another incarnation of the sender).
    #[error("acknowledgement of record {expected} but only {sent} were sent: the ack belongs to another stream")]
    Unsent {
        /// The ack's `expected`.
        expected: u64,
        /// Records this sender has numbered.
        sent: u64,
    },
}

/// What an accepted acknowledgement did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AckEffect {
    /// Records released from the window.
    pub released: usize,
    /// Whether the sender went back to resend (the receiver asked).
    pub rewound: bool,
}

/// The sender's end of a stream: numbers records, keeps the unacknowledged ones,
/// and says which to transmit next (new ones, or resends after a rewind).
#[derive(Debug, Clone)]
pub struct SendWindow<T> {
    records: VecDeque<T>,
    /// Sequence number of `records[0]`.
    base: u64,
    /// Next record to transmit (base ≤ next_transmit ≤ next_seq).
    next_transmit: u64,
    capacity: usize,
    /// The last (receiver, resend) this sender acted on.
    handled: Option<(u32, u32)>,
}

impl<T> SendWindow<T> {
    /// An empty window holding at most `capacity` (≥ 1) unacknowledged records.
    pub fn new(capacity: usize) -> SendWindow<T> {
        assert!(capacity >= 1, "a send window holds at least one record");
        SendWindow { records: VecDeque::with_capacity(capacity), base: 0, next_transmit: 0, capacity, handled: None }
    }

    /// Records held (sent or not, not yet acknowledged).
    pub fn held(&self) -> usize {
        self.records.len()
    }

    /// Most records the window holds.
    pub fn capacity(&self) -> usize {
        self.capacity
    }

    /// Whether another record fits (the sender's credit).
    pub fn has_room(&self) -> bool {
        self.records.len() < self.capacity
    }

    /// The sequence number the next pushed record gets (= records numbered so far).
    pub fn next_seq(&self) -> u64 {
        self.base + self.records.len() as u64
    }

    /// The oldest sequence number still held (everything below is acknowledged).
    pub fn base(&self) -> u64 {
        self.base
    }

    /// Add a record; returns its sequence number, or gives it back when the window
    /// is full (wait for acknowledgements first).
    pub fn push(&mut self, record: T) -> Result<u64, T> {
        if !self.has_room() {
            return Err(record);
        }
        self.records.push_back(record);
        Ok(self.next_seq() - 1)
    }

    /// The next record to transmit — a new one, or a resend after a rewind — and
    /// mark it transmitted. `None` when everything held has been transmitted.
    pub fn take_next(&mut self) -> Option<Outgoing<'_, T>> {
        if self.next_transmit >= self.next_seq() {
            return None;
        }
        let seq = self.next_transmit;
        self.next_transmit += 1;
        Some(Outgoing { seq, base: self.base, record: &self.records[(seq - self.base) as usize] })
    }

    /// Records held but not yet transmitted (since the last rewind).
    pub fn untransmitted(&self) -> usize {
        (self.next_seq() - self.next_transmit) as usize
    }

    /// Go back and transmit everything held again from the oldest record: for a
    /// sender that knows its link was re-established, or whose window stayed full with
    /// no acknowledgement for a while (a retransmission timeout, as in TCP: the
    /// receiver may never have seen those records and cannot ask for what it does not
    /// know of). Otherwise a sender relies on the receiver's requests and its own
    /// announcements.
    pub fn rewind(&mut self) {
        self.next_transmit = self.base;
    }

    /// Apply a receiver's acknowledgement: release what it has, and go back to
    /// `expected` if it asks for a resend it has not asked before.
    pub fn on_ack(&mut self, ack: Ack) -> Result<AckEffect, AckError> {
        if ack.expected > self.next_seq() {
            return Err(AckError::Unsent { expected: ack.expected, sent: self.next_seq() });
        }
        let mut effect = AckEffect::default();
        while self.base < ack.expected {
            self.records.pop_front();
            self.base += 1;
            effect.released += 1;
        }
        self.next_transmit = self.next_transmit.max(self.base);
        // A request is new when it comes from another receiver than the last one
        // acted on, or counts higher; an old ack seen again asks nothing.
        let newer = self.handled.is_none_or(|(r, c)| r != ack.receiver || ack.resend > c);
        if newer {
            if ack.resend > 0 {
                // `base` is `ack.expected` now, or above it for a stale ack.
                self.next_transmit = self.base;
                effect.rewound = true;
            }
            self.handled = Some((ack.receiver, ack.resend));
        }
        Ok(effect)
    }
}

/// What a receiver does with an offered record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Verdict {
    /// The next record in order: take it.
    Accept,
    /// Take it, but it does not follow the last record this receiver took: the
    /// `skipped` records between them were taken and acknowledged by a receiver
    /// before this one. Whatever the caller assembles across records (an episode)
    /// must not continue over the jump.
    Resume {
        /// Records jumped over.
        skipped: u64,
    },
    /// Already accepted (a resend or a duplicate): drop it.
    Duplicate,
    /// Records before it are missing: drop it; the receiver's ack asks for a resend
    /// (unless it asked less than `retry_after` ago).
    Missing {
        /// The sequence number the receiver waits for.
        expected: u64,
    },
}

/// The receiver's end of a stream.
#[derive(Debug, Clone)]
pub struct ReceiveCursor {
    receiver: u32,
    /// Next sequence number to accept; `None` before the first record.
    expected: Option<u64>,
    /// The last record accepted.
    last_accepted: Option<u64>,
    resend: u32,
    retry_after: Duration,
    last_request: Option<Instant>,
    last_progress: Instant,
}

impl ReceiveCursor {
    /// A cursor of the receiver incarnation `receiver` for a stream it has not seen;
    /// it asks for resends at most once per `retry_after`.
    pub fn new(receiver: u32, retry_after: Duration, now: Instant) -> ReceiveCursor {
        ReceiveCursor {
            receiver,
            expected: None,
            last_accepted: None,
            resend: 0,
            retry_after,
            last_request: None,
            last_progress: now,
        }
    }

    /// The next sequence number this receiver accepts (`None` before the first record).
    pub fn expected(&self) -> Option<u64> {
        self.expected
    }

    /// The acknowledgement to publish now.
    pub fn ack(&self) -> Ack {
        Ack { receiver: self.receiver, resend: self.resend, expected: self.expected.unwrap_or(0) }
    }

    /// Requests made so far (the count its acks carry).
    pub fn resend_requests(&self) -> u32 {
        self.resend
    }

    fn request_resend(&mut self, now: Instant) {
        if self.last_request.is_none_or(|t| now.duration_since(t) >= self.retry_after) {
            // At most one request per `retry_after` (≥ milliseconds): 2³² of them
            // take longer than any run.
            self.resend = self.resend.wrapping_add(1);
            self.last_request = Some(now);
        }
    }

    /// Judge a record `(seq, base)` arriving at `now`; on [`Verdict::Accept`] and
    /// [`Verdict::Resume`] the caller must take it (the cursor has moved past it).
    pub fn offer(&mut self, seq: u64, base: u64, now: Instant) -> Verdict {
        // Below `base` everything was acknowledged by a receiver before this one.
        let expected = self.expected.map_or(base, |e| e.max(base));
        self.expected = Some(expected);
        if seq == expected {
            self.expected = Some(expected + 1);
            self.last_progress = now;
            let previous = self.last_accepted.replace(seq);
            match previous {
                Some(last) if last + 1 != seq => Verdict::Resume { skipped: seq - last - 1 },
                _ => Verdict::Accept,
            }
        } else if seq < expected {
            Verdict::Duplicate
        } else {
            self.request_resend(now);
            Verdict::Missing { expected }
        }
    }

    /// The sender says it holds `base ..` and has numbered `next` records (its
    /// heartbeat). A receiver behind `next` that has made no progress for
    /// `retry_after` asks for a resend: the tail of a cut link, or a stream whose
    /// sender waits on a full window and so sends nothing new. As with a record,
    /// everything below `base` counts as taken (a receiver that has seen nothing of
    /// the stream starts there). Call it only while reading the stream. Returns
    /// whether it asked.
    pub fn on_announce(&mut self, base: u64, next: u64, now: Instant) -> bool {
        let expected = self.expected.map_or(base, |e| e.max(base));
        self.expected = Some(expected);
        if expected >= next || now.duration_since(self.last_progress) < self.retry_after {
            return false;
        }
        let before = self.resend;
        self.request_resend(now);
        self.resend != before
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const RETRY: Duration = Duration::from_millis(100);

    #[test]
    fn in_order_records_are_accepted_and_acknowledged() {
        let t0 = Instant::now();
        let mut tx = SendWindow::new(4);
        let mut rx = ReceiveCursor::new(1, RETRY, t0);
        for v in 0..3u32 {
            tx.push(v).unwrap();
        }
        while let Some(o) = tx.take_next() {
            let (seq, base) = (o.seq, o.base);
            assert_eq!(rx.offer(seq, base, t0), Verdict::Accept);
        }
        assert_eq!(rx.ack(), Ack { receiver: 1, resend: 0, expected: 3 });
        assert_eq!(tx.on_ack(rx.ack()), Ok(AckEffect { released: 3, rewound: false }));
        assert_eq!((tx.held(), tx.base(), tx.next_seq()), (0, 3, 3));
    }

    #[test]
    fn a_full_window_refuses_until_acknowledged() {
        let mut tx = SendWindow::new(2);
        assert_eq!(tx.push('a'), Ok(0));
        assert_eq!(tx.push('b'), Ok(1));
        assert_eq!(tx.push('c'), Err('c'));
        tx.on_ack(Ack { receiver: 1, resend: 0, expected: 1 }).unwrap();
        assert_eq!(tx.push('c'), Ok(2));
    }

    #[test]
    fn a_gap_asks_for_a_resend_once_per_interval_and_the_sender_goes_back() {
        let t0 = Instant::now();
        let mut tx = SendWindow::new(8);
        let mut rx = ReceiveCursor::new(7, RETRY, t0);
        for v in 0..5 {
            tx.push(v).unwrap();
        }
        let sent: Vec<(u64, u64)> = std::iter::from_fn(|| tx.take_next().map(|o| (o.seq, o.base))).collect();
        assert_eq!(rx.offer(sent[0].0, sent[0].1, t0), Verdict::Accept);
        // 1 and 2 lost on a cut link; 3 and 4 arrive.
        assert_eq!(rx.offer(3, 0, t0), Verdict::Missing { expected: 1 });
        assert_eq!(rx.offer(4, 0, t0), Verdict::Missing { expected: 1 });
        assert_eq!(rx.ack(), Ack { receiver: 7, resend: 1, expected: 1 }, "one request for one gap");
        let effect = tx.on_ack(rx.ack()).unwrap();
        assert_eq!(effect, AckEffect { released: 1, rewound: true });
        let again: Vec<u64> = std::iter::from_fn(|| tx.take_next().map(|o| o.seq)).collect();
        assert_eq!(again, [1, 2, 3, 4]);
        // The same ack again (newest-wins channels repeat) does not rewind twice.
        assert!(!tx.on_ack(rx.ack()).unwrap().rewound);
        for s in again {
            assert_eq!(rx.offer(s, 1, t0), Verdict::Accept);
        }
        assert_eq!(rx.offer(2, 1, t0), Verdict::Duplicate);
        // Still missing after the interval: asks again.
        assert_eq!(rx.offer(9, 1, t0 + RETRY), Verdict::Missing { expected: 5 });
        assert_eq!(rx.ack().resend, 2);
    }

    #[test]
    fn a_new_receiver_starts_at_the_base_and_gets_what_its_predecessor_never_acknowledged() {
        let t0 = Instant::now();
        let mut tx = SendWindow::new(16);
        let mut old = ReceiveCursor::new(1, RETRY, t0);
        for v in 0..10 {
            tx.push(v).unwrap();
        }
        for _ in 0..6 {
            let (s, b) = tx.take_next().map(|o| (o.seq, o.base)).unwrap();
            assert_eq!(old.offer(s, b, t0), Verdict::Accept);
            if s == 3 {
                tx.on_ack(old.ack()).unwrap(); // acknowledges 0..=3
            }
        }
        // `old` dies having taken 4 and 5 without acknowledging them.
        let mut new = ReceiveCursor::new(2, RETRY, t0);
        let (s, b) = tx.take_next().map(|o| (o.seq, o.base)).unwrap();
        assert_eq!((s, b), (6, 4));
        assert_eq!(new.offer(s, b, t0), Verdict::Missing { expected: 4 });
        assert!(tx.on_ack(new.ack()).unwrap().rewound);
        let resent: Vec<u64> = std::iter::from_fn(|| tx.take_next().map(|o| o.seq)).collect();
        assert_eq!(resent, [4, 5, 6, 7, 8, 9]);
    }

    #[test]
    fn a_lost_tail_is_asked_for_after_an_announcement_and_a_quiet_interval() {
        let t0 = Instant::now();
        let mut tx = SendWindow::new(8);
        let mut rx = ReceiveCursor::new(1, RETRY, t0);
        for v in 0..3 {
            tx.push(v).unwrap();
        }
        let (s, b) = tx.take_next().map(|o| (o.seq, o.base)).unwrap();
        assert_eq!(rx.offer(s, b, t0), Verdict::Accept);
        while tx.take_next().is_some() {} // 1 and 2 lost
        assert!(!rx.on_announce(tx.base(), tx.next_seq(), t0 + RETRY / 2), "progress was recent");
        assert!(rx.on_announce(tx.base(), tx.next_seq(), t0 + RETRY));
        assert!(tx.on_ack(rx.ack()).unwrap().rewound);
        assert_eq!(tx.take_next().map(|o| o.seq), Some(1));
        // A receiver that is up to date never asks.
        let mut done = ReceiveCursor::new(1, RETRY, t0);
        assert_eq!(done.offer(0, 0, t0), Verdict::Accept);
        assert!(!done.on_announce(0, 1, t0 + RETRY * 10));
    }

    #[test]
    fn a_new_receiver_unblocks_a_sender_whose_window_is_full() {
        let t0 = Instant::now();
        let mut tx = SendWindow::new(2);
        tx.push('a').unwrap();
        tx.push('b').unwrap();
        while tx.take_next().is_some() {} // both went to a receiver that died
        let mut rx = ReceiveCursor::new(9, RETRY, t0);
        assert!(!rx.on_announce(tx.base(), tx.next_seq(), t0), "no request before a quiet interval");
        assert!(rx.on_announce(tx.base(), tx.next_seq(), t0 + RETRY));
        assert_eq!(rx.ack(), Ack { receiver: 9, resend: 1, expected: 0 });
        assert!(tx.on_ack(rx.ack()).unwrap().rewound);
        assert_eq!(tx.take_next().map(|o| (o.seq, *o.record)), Some((0, 'a')));
        // A stream whose records were all acknowledged by a predecessor asks nothing.
        let mut fresh = ReceiveCursor::new(10, RETRY, t0);
        assert!(!fresh.on_announce(5, 5, t0 + RETRY * 3));
        assert_eq!(fresh.expected(), Some(5));
    }

    #[test]
    fn a_jump_over_records_a_predecessor_took_is_reported() {
        let t0 = Instant::now();
        let mut rx = ReceiveCursor::new(3, RETRY, t0);
        // A stale record (sent before the dead receiver's last ack reached the sender)...
        assert_eq!(rx.offer(0, 0, t0), Verdict::Accept);
        // ...then the sender's base says 1 and 2 were taken by the receiver before.
        assert!(!rx.on_announce(3, 5, t0));
        assert_eq!(rx.offer(1, 0, t0), Verdict::Duplicate);
        assert_eq!(rx.offer(3, 3, t0), Verdict::Resume { skipped: 2 });
        assert_eq!(rx.offer(4, 3, t0), Verdict::Accept);
    }

    #[test]
    fn an_ack_for_unsent_records_is_refused() {
        let mut tx: SendWindow<u8> = SendWindow::new(4);
        tx.push(1).unwrap();
        assert_eq!(
            tx.on_ack(Ack { receiver: 1, resend: 0, expected: 5 }),
            Err(AckError::Unsent { expected: 5, sent: 1 })
        );
        assert_eq!(tx.held(), 1, "a refused ack releases nothing");
    }

    /// One step of the simulated world.
    #[derive(Debug, Clone)]
    enum Event {
        /// The sender pushes up to this many new records (as its window allows) and
        /// transmits everything pending.
        Send(u8),
        /// The link delivers up to this many records in order.
        Deliver(u8),
        /// The link duplicates the record at its head.
        Duplicate,
        /// The link is cut: everything in flight is lost; the sender may notice (and
        /// rewind) or not (a bridge in between restarted).
        Cut {
            /// Whether the sender learns of it.
            sender_notices: bool,
        },
        /// An old receiver's last ack reaches the sender late.
        StaleAck,
        /// The receiver's newest ack reaches the sender.
        AckArrives,
        /// The sender's announcement reaches the receiver.
        Announce,
        /// The receiver dies; a new incarnation replaces it.
        ReceiverRestarts,
        /// Time passes (in tenths of the retry interval).
        Wait(u8),
    }

    fn event() -> impl Strategy<Value = Event> {
        prop_oneof![
            4 => (1u8..6).prop_map(Event::Send),
            4 => (1u8..8).prop_map(Event::Deliver),
            1 => Just(Event::Duplicate),
            1 => any::<bool>().prop_map(|sender_notices| Event::Cut { sender_notices }),
            1 => Just(Event::StaleAck),
            3 => Just(Event::AckArrives),
            1 => Just(Event::Announce),
            1 => Just(Event::ReceiverRestarts),
            2 => (1u8..15).prop_map(Event::Wait),
        ]
    }

    /// Both ends and the link between them; records are their own sequence numbers
    /// times 3, so a record that arrived under the wrong number would show.
    struct World {
        now: Instant,
        tx: SendWindow<u64>,
        rx: ReceiveCursor,
        link: VecDeque<(u64, u64, u64)>,
        /// What each receiver incarnation accepted, in order (and whether it came as
        /// a [`Verdict::Resume`]).
        accepted: Vec<Vec<(u64, bool)>>,
        /// The last ack of each receiver before the current one.
        old_acks: Vec<Ack>,
        pushed: u64,
        total: u64,
    }

    impl World {
        fn new(total: u64, capacity: usize) -> World {
            let now = Instant::now();
            World {
                now,
                tx: SendWindow::new(capacity),
                rx: ReceiveCursor::new(0, RETRY, now),
                link: VecDeque::new(),
                accepted: vec![Vec::new()],
                old_acks: Vec::new(),
                pushed: 0,
                total,
            }
        }

        fn apply(&mut self, e: &Event) {
            match *e {
                Event::Send(n) => {
                    for _ in 0..n {
                        if self.pushed == self.total || !self.tx.has_room() {
                            break;
                        }
                        let seq = self.tx.push(self.pushed * 3).unwrap();
                        assert_eq!(seq, self.pushed);
                        self.pushed += 1;
                    }
                    while let Some(o) = self.tx.take_next() {
                        self.link.push_back((o.seq, o.base, *o.record));
                    }
                }
                Event::Deliver(n) => {
                    for _ in 0..n {
                        let Some((seq, base, value)) = self.link.pop_front() else { break };
                        assert_eq!(value, seq * 3, "a record travels with its own number");
                        let resumed = match self.rx.offer(seq, base, self.now) {
                            Verdict::Accept => false,
                            Verdict::Resume { skipped } => {
                                let run = self.accepted.last().unwrap();
                                assert_eq!(run.last().map(|&(s, _)| seq - s - 1), Some(skipped), "skipped counted");
                                true
                            }
                            Verdict::Duplicate | Verdict::Missing { .. } => continue,
                        };
                        let run = self.accepted.last_mut().unwrap();
                        // Nothing falls between two receivers: a receiver starts no
                        // later than the sender's base, below which every record was
                        // acknowledged (so accepted) by a receiver before it.
                        assert!(!run.is_empty() || seq <= self.tx.base(), "started at {seq} above the base");
                        run.push((seq, resumed));
                    }
                }
                Event::Duplicate => {
                    if let Some(&head) = self.link.front() {
                        self.link.push_front(head);
                    }
                }
                Event::Cut { sender_notices } => {
                    self.link.clear();
                    if sender_notices {
                        self.tx.rewind();
                    }
                }
                Event::StaleAck => {
                    if let Some(&old) = self.old_acks.last() {
                        self.tx.on_ack(old).expect("an old receiver acknowledged only what was sent");
                    }
                }
                Event::AckArrives => {
                    self.tx.on_ack(self.rx.ack()).expect("acks are of this stream");
                }
                Event::Announce => {
                    self.rx.on_announce(self.tx.base(), self.tx.next_seq(), self.now);
                }
                Event::ReceiverRestarts => {
                    self.old_acks.push(self.rx.ack());
                    let incarnation = self.accepted.len() as u32;
                    self.rx = ReceiveCursor::new(incarnation, RETRY, self.now);
                    self.accepted.push(Vec::new());
                }
                Event::Wait(tenths) => self.now += RETRY * tenths as u32 / 10,
            }
            assert!(self.tx.held() <= self.tx.capacity(), "the window is bounded");
        }

        /// Let the world run without faults until every record is acknowledged: within
        /// a few rounds per record (one record per round with a window of one).
        fn drain(&mut self) {
            for _ in 0..3 * self.total as usize + 10 {
                if self.pushed == self.total && self.tx.held() == 0 {
                    return;
                }
                for e in [Event::Send(8), Event::Deliver(255), Event::Announce, Event::AckArrives, Event::Wait(10)] {
                    self.apply(&e);
                }
            }
            panic!("the stream did not drain: {} of {} pushed, {} held", self.pushed, self.total, self.tx.held());
        }
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(512))]

        /// Nothing lost, nothing twice within a receiver, the window bounded — over a link
        /// that cuts, duplicates and loses acks, with receivers that restart.
        #[test]
        fn every_record_arrives_once_per_receiver_in_order(
            events in proptest::collection::vec(event(), 0..200),
            total in 1u64..60,
            capacity in 1usize..12,
        ) {
            let mut w = World::new(total, capacity);
            for e in &events {
                w.apply(e);
            }
            w.drain();
            let mut covered = vec![false; total as usize];
            for (k, run) in w.accepted.iter().enumerate() {
                prop_assert!(run.first().is_none_or(|&(_, resumed)| !resumed), "receiver {} resumed at its start", k);
                for pair in run.windows(2) {
                    let ((a, _), (b, resumed)) = (pair[0], pair[1]);
                    prop_assert!(b > a, "receiver {} went back: {:?}", k, run);
                    prop_assert_eq!(resumed, b != a + 1, "receiver {} jumped silently (or flagged no jump): {:?}", k, run);
                    // A jump goes only over records an earlier receiver took.
                    for skipped in a + 1..b {
                        let before = w.accepted[..k].iter().flatten().any(|&(s, _)| s == skipped);
                        prop_assert!(before, "receiver {} jumped over {}, which no receiver before it took", k, skipped);
                    }
                }
                for &(s, _) in run {
                    covered[s as usize] = true;
                }
            }
            prop_assert!(covered.iter().all(|&c| c), "every record accepted by some receiver: {:?}", covered);
        }
    }
}
