//! The learner's intake is fair across actors: with every actor's queue full, each
//! round of `receive_step_round` takes the same share from every actor, where a
//! plain `receive` serves the first actor's queue until it is empty.

use std::time::Duration;

use pednav_runtime::ipc::{STEP_ROUND_PER_ACTOR, StepSender, receive_step_round};
use pednav_runtime::messages::StepHeader;
use pednav_runtime::{Ipc, StopFlag};

const QUEUE: usize = 64;

fn send(out: &StepSender, actor: u32, seq: u64) {
    let mut s = out.publisher.loan_slice_uninit(4).unwrap();
    *s.user_header_mut() = StepHeader { actor, seq, ..StepHeader::default() };
    s.write_from_slice(&[actor as u8; 4]).send().unwrap();
}

#[test]
fn every_round_takes_an_equal_share_from_every_actor() {
    let prefix = format!("pnfair{:x}_", std::process::id());
    let learner = Ipc::new(&prefix, "learner", QUEUE, Duration::from_secs(5), StopFlag::default()).unwrap();
    let sub = learner.step_subscriber().unwrap();
    let actors: Vec<(Ipc, StepSender)> = (0..3)
        .map(|k| {
            let ipc =
                Ipc::new(&prefix, &format!("actor-{k}"), QUEUE, Duration::from_secs(5), StopFlag::default()).unwrap();
            let out = ipc.step_sender(4).unwrap();
            assert!(out.wait_for_subscriber(&StopFlag::default(), Duration::from_secs(5)));
            (ipc, out)
        })
        .collect();
    // Fill every actor's queue to the brim (sending more would block: lossless).
    for (k, (_, out)) in actors.iter().enumerate() {
        for seq in 0..QUEUE as u64 {
            send(out, k as u32, seq);
        }
    }

    // The premise: a plain receive serves one actor's queue before any other's.
    let first: Vec<u32> = (0..8).map(|_| sub.receive().unwrap().unwrap().user_header().actor).collect();
    assert!(first.iter().all(|&a| a == first[0]), "plain receive interleaved actors: {first:?}");

    // Rounds: each takes STEP_ROUND_PER_ACTOR from every actor with records left,
    // in order within each actor.
    let mut next_seq = [0u64; 3];
    next_seq[first[0] as usize] = 8;
    let mut round = Vec::new();
    let mut rounds = 0;
    while receive_step_round(&sub, &mut round).unwrap() > 0 {
        let mut per_actor = [0usize; 3];
        for s in round.drain(..) {
            let h = *s.user_header();
            assert_eq!(h.seq, next_seq[h.actor as usize], "actor {} out of order", h.actor);
            next_seq[h.actor as usize] += 1;
            per_actor[h.actor as usize] += 1;
        }
        for (k, &n) in per_actor.iter().enumerate() {
            let left_before = QUEUE as u64 - (next_seq[k] - n as u64);
            assert_eq!(n as u64, left_before.min(STEP_ROUND_PER_ACTOR as u64), "round {rounds}: {per_actor:?}");
        }
        rounds += 1;
    }
    assert_eq!(next_seq, [QUEUE as u64; 3], "every record arrived exactly once");
    assert!(rounds >= (QUEUE - 8) / STEP_ROUND_PER_ACTOR);
}
