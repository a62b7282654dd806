//! A step stream survives a learner that dies with records it never acknowledged:
//! the actor's `StepWriter` holds them and sends them again to the learner that
//! replaces it — whether that one finds out from the first record it gets, or (when
//! the actor waits on a full window and sends nothing new) because the actor sends its
//! window again after a second without acknowledgement. Real iceoryx2 services, one
//! run prefix per test; loops bounded by a watchdog deadline.

use std::time::{Duration, Instant};

use pednav_runtime::channels::{StepPayload, StepWriter, StreamId};
use pednav_runtime::ipc::{AckPublisher, StepSubscriber};
use pednav_runtime::messages::{AckTable, StepHeader, StreamAck};
use pednav_runtime::reliable::{ReceiveCursor, Verdict};
use pednav_runtime::{Ipc, StopFlag};

const QUEUE: usize = 32;
const STATE: usize = 4;
const STREAM: StreamId = StreamId { actor: 0, incarnation: 1 };
const WATCHDOG: Duration = Duration::from_secs(20);

fn ipc(prefix: &str, name: &str) -> Ipc {
    Ipc::new(prefix, name, QUEUE, Duration::from_secs(10), StopFlag::default()).unwrap()
}

/// Send record `seq` (its state is `seq` four times, so a record sent under the wrong
/// number would show).
fn send(writer: &mut StepWriter, seq: u64) {
    let header = StepHeader { actor: STREAM.actor, incarnation: STREAM.incarnation, seq, ..StepHeader::default() };
    let state = [seq as f32; STATE];
    writer.send(header, StepPayload::State(&state)).unwrap().expect("not stopping");
}

/// A learner's end: its subscriber, its acknowledgements and its cursor on the stream.
struct Learner {
    _ipc: Ipc,
    steps: StepSubscriber,
    acks: AckPublisher,
    cursor: ReceiveCursor,
    taken: Vec<u64>,
}

impl Learner {
    fn new(prefix: &str, id: u32, retry: Duration) -> Learner {
        let ipc = ipc(prefix, &format!("learner-{id}"));
        let steps = ipc.step_subscriber().unwrap();
        let acks = ipc.ack_publisher().unwrap();
        Learner { _ipc: ipc, steps, acks, cursor: ReceiveCursor::new(id, retry, Instant::now()), taken: Vec::new() }
    }

    /// Take up to `n` queued records; returns how many were received (taken or not).
    fn take(&mut self, n: usize) -> usize {
        let mut received = 0;
        while received < n {
            let Some(sample) = self.steps.receive().unwrap() else { break };
            received += 1;
            let h = *sample.user_header();
            let state = pednav_runtime::messages::state_payload::decode_state(sample.payload());
            assert_eq!(state, [h.seq as f32; STATE], "record {} carries its own state", h.seq);
            if self.cursor.offer(h.seq, h.base, Instant::now()) == Verdict::Accept {
                self.taken.push(h.seq);
            }
        }
        received
    }

    fn acknowledge(&self) {
        let mut table = AckTable::default();
        table.streams[STREAM.actor as usize] = StreamAck { incarnation: STREAM.incarnation, ack: self.cursor.ack() };
        self.acks.send_copy(table).unwrap();
    }
}

#[test]
fn records_a_killed_learner_never_acknowledged_reach_its_replacement() {
    let prefix = format!("pnresend{:x}_", std::process::id());
    let actor = ipc(&prefix, "actor-0");
    let mut first = Learner::new(&prefix, 1, Duration::from_secs(1));
    let mut writer = StepWriter::open(&actor, STREAM, STATE * 4, 64, StopFlag::default()).unwrap();
    assert!(writer.wait_for_learner(Duration::from_secs(5)));

    // The first learner takes 20 records but acknowledges only the first 12; 5 more
    // wait in its queue when it dies.
    for seq in 0..20 {
        send(&mut writer, seq);
    }
    assert_eq!(first.take(12), 12);
    first.acknowledge();
    assert_eq!(first.take(8), 8);
    for seq in 20..25 {
        send(&mut writer, seq); // each send also reads the acknowledgement
    }
    assert_eq!(writer.base(), 12, "the writer released what was acknowledged");
    assert_eq!(writer.held(), 13);
    let mut second = Learner::new(&prefix, 2, Duration::from_secs(1));
    let first_taken = std::mem::take(&mut first.taken);
    drop(first);

    // The replacement gets record 25 first: records are missing, it asks again.
    send(&mut writer, 25);
    assert_eq!(second.take(1), 1);
    assert!(second.taken.is_empty(), "25 is out of order for a learner that starts at 12");
    second.acknowledge();
    send(&mut writer, 26); // reads the request: sends 12 ..= 25 again, then 26
    let deadline = Instant::now() + WATCHDOG;
    while second.taken.last() != Some(&26) {
        assert!(Instant::now() < deadline, "watchdog: the resend did not arrive; taken {:?}", second.taken);
        second.take(usize::MAX);
    }
    assert_eq!(second.taken, (12..=26).collect::<Vec<u64>>(), "the replacement has everything from 12");
    assert_eq!(first_taken, (0..20).collect::<Vec<u64>>());
    let counts = writer.resends();
    assert_eq!((counts.requests, counts.resent), (1, 14), "{counts:?}");
}

#[test]
fn an_actor_waiting_on_a_full_window_sends_it_again_to_a_replacement_learner() {
    let prefix = format!("pnresendw{:x}_", std::process::id());
    const WINDOW: usize = 8;
    const TOTAL: u64 = 12;
    let mut first = Learner::new(&prefix, 1, Duration::from_secs(1));
    // The actor on its own thread (iceoryx2 ports stay on the thread that made them):
    // it blocks once its window of 8 unacknowledged records is full.
    let actor_prefix = prefix.clone();
    let actor = std::thread::spawn(move || {
        let ipc = ipc(&actor_prefix, "actor-0");
        let mut writer = StepWriter::open(&ipc, STREAM, STATE * 4, WINDOW, StopFlag::default()).unwrap();
        assert!(writer.wait_for_learner(Duration::from_secs(5)));
        for seq in 0..TOTAL {
            send(&mut writer, seq);
        }
        writer.resends()
    });
    // The first learner takes the window's 8 records, acknowledges nothing, and dies.
    let deadline = Instant::now() + WATCHDOG;
    while first.taken.len() < WINDOW {
        assert!(Instant::now() < deadline, "watchdog: the first learner got {:?}", first.taken);
        first.take(usize::MAX);
        std::thread::sleep(Duration::from_millis(1));
    }
    let retry = Duration::from_millis(50);
    let mut second = Learner::new(&prefix, 2, retry);
    drop(first);
    // Nothing new arrives at first (the actor waits for room, and cannot send its
    // heartbeat meanwhile); after a second with no acknowledgement it sends its whole
    // window again unasked, which the replacement takes from the base on.
    std::thread::sleep(retry);
    assert_eq!(second.take(usize::MAX), 0, "the actor sends nothing while its window is full");
    while second.taken.len() < TOTAL as usize {
        assert!(Instant::now() < deadline, "watchdog: the replacement got {:?}", second.taken);
        second.acknowledge();
        second.take(usize::MAX);
        std::thread::sleep(Duration::from_millis(1));
    }
    let counts = actor.join().expect("the actor thread ends");
    assert_eq!(second.taken, (0..TOTAL).collect::<Vec<u64>>());
    assert_eq!((counts.timeouts, counts.requests, counts.resent), (1, 0, WINDOW as u64), "{counts:?}");
}
