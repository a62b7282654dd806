//! Dual replay: Algorithm 2's counts and IS ratios by hand, and reconstruction of
//! windows against scripted episodes across episode starts, interleaved streams
//! and ring wrap-around.

use std::collections::HashMap;

use candle_core::Device;
use pednav_learner::{DualReplay, Frame, FrameKind, ReplayConfig, Step, dual_split, shift_frames};
use pednav_nets::{Obs, Transitions};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9 * (1.0 + b.abs())
}

#[test]
fn algorithm_2_counts_and_ratios_by_hand() {
    // p_T = 10/1000 → round(0.64) = 1; P = 0.064; η̃_T = 0.64, η̃_N = 0.064·990/63.
    let (n_t, et, en) = dual_split(10, 990, 64);
    assert_eq!(n_t, 1);
    assert!(close(et, 0.64 / (0.064 * 990.0 / 63.0)) && close(en, 1.0), "{et} {en}");
    assert!(close(et, 63.0 / 99.0));
    // Proportional split: 100/400 of 64 = 16 terminal, both ratios 1.
    let (n_t, et, en) = dual_split(100, 300, 64);
    assert_eq!(n_t, 16);
    assert!(close(et, 1.0) && close(en, 1.0));
    // One terminal among a million: still one sample, heavily down-weighted (63/1e6).
    let (n_t, et, en) = dual_split(1, 1_000_000, 64);
    assert_eq!(n_t, 1);
    assert!(close(et, 63.0 / 1e6) && close(en, 1.0), "{et}");
    // Rounding: 64·3/400 = 0.48 → 0 → raised to 1; 64·30/400 = 4.8 → 5.
    assert_eq!(dual_split(3, 397, 64).0, 1);
    assert_eq!(dual_split(30, 370, 64).0, 5);
    // Empty terminal pool: no terminal samples, uniform weights.
    assert_eq!(dual_split(0, 500, 64), (0, 1.0, 1.0));
}

/// A frame that encodes (stream, episode, t) so sampled windows can be decoded.
fn frame(stream: u64, ep: u32, t: u32) -> [u8; 4] {
    [stream as u8, ep as u8, (t % 256) as u8, (t / 256) as u8]
}

fn decode(px: &[f32]) -> (u8, u8, u32) {
    let b: Vec<u32> = px.iter().map(|v| (v * 255.0).round() as u32).collect();
    (b[0] as u8, b[1] as u8, b[2] + 256 * b[3])
}

fn action(stream: u64, ep: u32, t: u32) -> [f32; 3] {
    [stream as f32, ep as f32, t as f32]
}

fn reward(stream: u64, ep: u32, t: u32) -> f32 {
    -(stream as f32) * 1000.0 - ep as f32 * 10.0 - t as f32 * 0.5
}

/// Check one sampled transition against the script: windows padded with the first
/// frame and zero actions/rewards before the episode start.
#[allow(clippy::too_many_arguments)]
fn check_sample(
    obs: &Obs,
    next: &Obs,
    i: usize,
    n: usize,
    done: f32,
    act: &[f32],
    rew: f32,
    terminal_at: &HashMap<(u8, u8), u32>,
) {
    let (Obs::Pixels { frames: f0, actions: a0, rewards: r0 }, Obs::Pixels { frames: f1, actions: a1, rewards: r1 }) =
        (obs, next)
    else {
        panic!("pixel observations expected")
    };
    let frames = |f: &candle_core::Tensor| -> Vec<(u8, u8, u32)> {
        let v: Vec<f32> = f.get(i).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        v.chunks(4).map(decode).collect()
    };
    let (w0, w1) = (frames(f0), frames(f1));
    let (s, e, t1) = *w1.last().unwrap();
    assert!(t1 >= 1, "a transition ends at t ≥ 1");
    let t = t1 - 1;
    for (win, end) in [(&w0, t), (&w1, t1)] {
        for (k, &(ws, we, wt)) in win.iter().enumerate() {
            let time = end as i64 - (n - 1 - k) as i64;
            assert_eq!((ws, we), (s, e), "window mixes episodes or streams");
            assert_eq!(wt as i64, time.max(0), "frame at window position {k}");
        }
    }
    for (acts, rews, end) in [(a0, r0, t), (a1, r1, t1)] {
        let av: Vec<f32> = acts.get(i).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        let rv: Vec<f32> = rews.get(i).unwrap().to_vec1().unwrap();
        for k in 0..n - 1 {
            let time = end as i64 - (n - 1 - k) as i64;
            let (want_a, want_r) = if time < 0 {
                ([0.0; 3], 0.0)
            } else {
                (action(s as u64, e as u32, time as u32), reward(s as u64, e as u32, time as u32))
            };
            assert_eq!(&av[k * 3..k * 3 + 3], &want_a, "action history at {k} (end {end})");
            assert_eq!(rv[k], want_r, "reward history at {k}");
        }
    }
    assert_eq!(act, &action(s as u64, e as u32, t));
    assert_eq!(rew, reward(s as u64, e as u32, t));
    let is_terminal = terminal_at.get(&(s, e)) == Some(&t1);
    assert_eq!(done == 1.0, is_terminal, "done flag");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(32))]
    #[test]
    fn sampled_windows_equal_the_scripted_histories(
        seed in 0u64..10_000,
        history in 1usize..6,
        capacity in 12usize..60,
        streams in 1u64..4,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let cfg = ReplayConfig { nonterminal_capacity: capacity, terminal_capacity: 5 };
        let mut replay = DualReplay::new(&cfg, FrameKind::Pixels { size: 2 }, history, &Device::Cpu).unwrap();
        // Each stream runs episodes of random length, some ending at the goal.
        let mut state: Vec<(u32, u32, u32, bool)> = (0..streams).map(|_| (0, 0, rng.random_range(1..12), rng.random_bool(0.5))).collect();
        let mut terminal_at = HashMap::new();
        let mut checked = 0;
        // Global index of each stream's last stored step (None: dropped until its next start).
        let mut last_stored: HashMap<u64, Option<u64>> = HashMap::new();
        for _ in 0..capacity * 3 {
            let s = rng.random_range(0..streams);
            let (ep, t, len, goal) = state[s as usize];
            let last = t == len;
            let f = frame(s, ep, t);
            let terminal = last && goal;
            if terminal { terminal_at.insert((s as u8, ep as u8), t); }
            let step = Step {
                stream: s,
                first: t == 0,
                frame: Frame::Pixels(&f),
                action: if t == 0 { [9.0; 3] } else { action(s, ep, t - 1) },
                reward: if t == 0 { 9.0 } else { reward(s, ep, t - 1) },
                terminal,
                state_target: None,
            };
            // A step whose predecessor was overwritten (its stream idled while others
            // filled the ring) is dropped, as is the rest of that episode.
            let head = replay.inserted();
            let expect = t == 0 || last_stored.get(&s).copied().flatten().is_some_and(|g| g + capacity as u64 >= head);
            let stored = replay.push(&step).unwrap();
            prop_assert_eq!(stored, expect);
            last_stored.insert(s, stored.then_some(head));
            state[s as usize] = if last { (ep + 1, 0, rng.random_range(1..12), rng.random_bool(0.5)) } else { (ep, t + 1, len, goal) };
            if replay.nonterminal_len() + replay.terminal_len() > 0 && rng.random_bool(0.3) {
                let Ok(batch) = replay.sample(8, &mut rng) else { continue };
                let act: Vec<Vec<f32>> = batch.action.to_vec2().unwrap();
                let rew: Vec<f32> = batch.reward.to_vec1().unwrap();
                let done: Vec<f32> = batch.done.to_vec1().unwrap();
                // o_t and o_{t+1} are views of the transitions' stored frames.
                let (obs, next) = (batch.transitions.obs().unwrap(), batch.transitions.next_obs().unwrap());
                for i in 0..8 {
                    check_sample(&obs, &next, i, history, done[i], &act[i], rew[i], &terminal_at);
                    prop_assert_eq!(done[i] == 1.0, i < batch.n_terminal);
                    checked += 1;
                }
            }
        }
        prop_assert!(checked >= 8, "only {} samples were checked", checked);
    }
}

#[test]
fn counts_follow_inserts_and_evictions() {
    let cfg = ReplayConfig { nonterminal_capacity: 10, terminal_capacity: 2 };
    let mut r = DualReplay::new(&cfg, FrameKind::State { dim: 1 }, 1, &Device::Cpu).unwrap();
    let push = |r: &mut DualReplay, first, terminal| {
        r.push(&Step {
            stream: 0,
            first,
            frame: Frame::State(&[0.0]),
            action: [0.0; 3],
            reward: 0.0,
            terminal,
            state_target: None,
        })
        .unwrap()
    };
    push(&mut r, true, false);
    assert_eq!((r.nonterminal_len(), r.terminal_len()), (0, 0), "an episode start is not a transition");
    for _ in 0..4 {
        push(&mut r, false, false);
    }
    push(&mut r, false, true);
    assert_eq!((r.nonterminal_len(), r.terminal_len()), (4, 1));
    for ep in 0..3 {
        push(&mut r, true, false);
        push(&mut r, false, false);
        push(&mut r, false, ep < 2);
    }
    // Ring of 10 holds the last 10 of 15 steps; terminal pool keeps its 2 newest.
    assert_eq!(r.terminal_len(), 2);
    assert_eq!(r.inserted(), 15);
    assert_eq!(r.nonterminal_len(), 4, "non-first, non-terminal steps among the last 10");
    assert!(!push(&mut r, false, false) || r.nonterminal_len() == 5);
    let batch = r.sample(6, &mut ChaCha8Rng::seed_from_u64(0)).unwrap();
    assert!(batch.n_terminal >= 1, "at least one terminal sample once one exists");
}

#[test]
fn a_stream_seen_mid_episode_is_ignored_until_its_next_start() {
    let cfg = ReplayConfig { nonterminal_capacity: 10, terminal_capacity: 2 };
    let mut r = DualReplay::new(&cfg, FrameKind::State { dim: 1 }, 1, &Device::Cpu).unwrap();
    let step = |first| Step {
        stream: 7,
        first,
        frame: Frame::State(&[1.0]),
        action: [0.0; 3],
        reward: 0.0,
        terminal: false,
        state_target: None,
    };
    assert!(!r.push(&step(false)).unwrap());
    assert!(r.push(&step(true)).unwrap());
    assert!(r.push(&step(false)).unwrap());
    assert_eq!(r.nonterminal_len(), 1);
}

#[test]
fn random_shift_by_hand() {
    // 3×3 frame 1..9: dx = 1 reads one column to the right (the edge column repeats),
    // dy = −1 one row up (the top row repeats).
    let f: Vec<f32> = (1..=9).map(|v| v as f32).collect();
    assert_eq!(shift_frames(&f, 3, 1, 0), vec![2., 3., 3., 5., 6., 6., 8., 9., 9.]);
    assert_eq!(shift_frames(&f, 3, 0, -1), vec![1., 2., 3., 1., 2., 3., 4., 5., 6.]);
    assert_eq!(shift_frames(&f, 3, 0, 0), f);
    // Frames of one transition shift together.
    let tens: Vec<f32> = f.iter().map(|v| v * 10.0).collect();
    let s = shift_frames(&[f.clone(), tens].concat(), 3, -1, 1);
    assert_eq!(&s[..9], &[4., 4., 5., 7., 7., 8., 7., 7., 8.]);
    assert_eq!(&s[9..], &[40., 40., 50., 70., 70., 80., 70., 70., 80.]);
}

/// With one transition in the replay every sample is that transition: shifted, each
/// window is the stored one moved by one offset in [−1, 1]² (both frames alike), o_t
/// and o_{t+1} are still its views, and several offsets occur.
#[test]
fn sampled_windows_are_shifted_as_a_whole() {
    let cfg = ReplayConfig { nonterminal_capacity: 8, terminal_capacity: 2 };
    let mut r = DualReplay::new(&cfg, FrameKind::Pixels { size: 3 }, 1, &Device::Cpu).unwrap();
    let frames: [[u8; 9]; 2] = [std::array::from_fn(|i| 10 * i as u8), std::array::from_fn(|i| 100 + 10 * i as u8)];
    for (t, px) in frames.iter().enumerate() {
        let step = Step {
            stream: 0,
            first: t == 0,
            frame: Frame::Pixels(px),
            action: [0.0; 3],
            reward: 0.0,
            terminal: false,
            state_target: None,
        };
        r.push(&step).unwrap();
    }
    let plain = r.sample(64, &mut ChaCha8Rng::seed_from_u64(3)).unwrap();
    let window = |b: &pednav_learner::Batch| match &b.transitions {
        Transitions::Pixels { frames, .. } => frames.flatten_from(2).unwrap().to_vec3::<f32>().unwrap(),
        Transitions::State { .. } => panic!("pixel batch"),
    };
    let stored: Vec<f32> = window(&plain)[0].concat();
    let shifted = r.sample_shifted(64, 1, &mut ChaCha8Rng::seed_from_u64(3)).unwrap();
    let (Obs::Pixels { frames: obs, .. }, Obs::Pixels { frames: next, .. }) =
        (shifted.transitions.obs().unwrap(), shifted.transitions.next_obs().unwrap())
    else {
        panic!("pixel batch")
    };
    let (obs, next) = (
        obs.flatten_from(1).unwrap().to_vec2::<f32>().unwrap(),
        next.flatten_from(1).unwrap().to_vec2::<f32>().unwrap(),
    );
    let mut offsets = std::collections::BTreeSet::new();
    for (i, w) in window(&shifted).iter().enumerate() {
        let w = w.concat();
        let offset = (-1..=1)
            .flat_map(|dx| (-1..=1).map(move |dy| (dx, dy)))
            .find(|&(dx, dy)| shift_frames(&stored, 3, dx, dy) == w)
            .unwrap_or_else(|| panic!("sample {i} is no shift of the stored window: {w:?}"));
        offsets.insert(offset);
        assert_eq!((&obs[i][..], &next[i][..]), (&w[..9], &w[9..]), "sample {i}: o_t, o_t+1 are the window's views");
    }
    assert!(offsets.len() >= 5, "64 draws from 9 offsets gave only {offsets:?}");
}

/// With state targets every sample carries its o_t's target — the target pushed with
/// o_t's newest frame — from both pools, across episode starts and ring wrap-around;
/// a step without one is refused, and targets cannot be switched on mid-run.
#[test]
fn state_targets_follow_the_observation_they_were_pushed_with() {
    let cfg = ReplayConfig { nonterminal_capacity: 12, terminal_capacity: 3 };
    let history = 3;
    let mut r = DualReplay::new(&cfg, FrameKind::Pixels { size: 2 }, history, &Device::Cpu)
        .unwrap()
        .with_state_targets(2)
        .unwrap();
    // Step k of the stream: every pixel k, target (10k, 10k + 1); episodes of 5 steps,
    // every other one reaching the goal.
    for k in 0..40u8 {
        let (t, ep) = (k % 5, k / 5);
        let frame = [k; 4];
        let target = [10.0 * k as f32, 10.0 * k as f32 + 1.0];
        let step = Step {
            stream: 0,
            first: t == 0,
            frame: Frame::Pixels(&frame),
            action: [0.0; 3],
            reward: 0.0,
            terminal: t == 4 && ep % 2 == 0,
            state_target: Some(&target),
        };
        assert!(r.push(&step).unwrap());
    }
    assert!(r.terminal_len() > 0);
    let batch = r.sample(64, &mut ChaCha8Rng::seed_from_u64(1)).unwrap();
    assert!(batch.n_terminal >= 1);
    let Obs::Pixels { frames, .. } = batch.transitions.obs().unwrap() else { panic!("pixel batch") };
    let newest = frames.narrow(1, history - 1, 1).unwrap().flatten_from(1).unwrap().to_vec2::<f32>().unwrap();
    let targets = batch.state_target.as_ref().expect("a replay with targets fills them").to_vec2::<f32>().unwrap();
    for (pixels, target) in newest.iter().zip(&targets) {
        let k = (pixels[0] * 255.0).round();
        assert_eq!(target, &vec![10.0 * k, 10.0 * k + 1.0], "o_t's newest frame is step {k}");
    }
    // A step without its target is refused; so is switching targets on after a push.
    let frame = [0u8; 4];
    let bare = Step {
        stream: 1,
        first: true,
        frame: Frame::Pixels(&frame),
        action: [0.0; 3],
        reward: 0.0,
        terminal: false,
        state_target: None,
    };
    assert!(r.push(&bare).unwrap_err().to_string().contains("state targets of 2 values"));
    let mut plain = DualReplay::new(&cfg, FrameKind::Pixels { size: 2 }, history, &Device::Cpu).unwrap();
    plain.push(&bare).unwrap();
    assert!(plain.with_state_targets(2).is_err());
}
