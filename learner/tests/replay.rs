//! Dual replay: Algorithm 2's counts and IS ratios by hand, and reconstruction of
//! windows and n-step returns against scripted episodes across episode starts,
//! goals, interleaved streams and ring wrap-around.

use std::collections::HashMap;

use candle_core::Device;
use pednav_learner::{DualReplay, Frame, FrameKind, ReplayConfig, Step, dual_split, n_step_return, shift_frames};
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

/// Check sampled transition `i` against the script. The transition's N_h + n frames
/// are the times t − N_h + 1 … t + n, clamped below to the episode's first frame and
/// above to the goal's time when the goal comes within the n steps (the frames after
/// it repeat it); history entry j is the action and reward taken after the frame at
/// position j, zero before the episode start and after the goal; a_t is the action
/// at t, the reward the discounted sum of the n rewards (γ = `gamma`, cut at the goal).
#[allow(clippy::too_many_arguments)]
fn check_sample(
    t: &Transitions,
    i: usize,
    history: usize,
    n: usize,
    gamma: f64,
    done: f32,
    act: &[f32],
    rew: f32,
    terminal_at: &HashMap<(u8, u8), u32>,
) {
    let Transitions::Pixels { frames, actions, rewards, n_step } = t else { panic!("pixel transitions expected") };
    assert_eq!(*n_step, n);
    let span = history + n;
    let window: Vec<(u8, u8, u32)> = {
        let v: Vec<f32> = frames.get(i).unwrap().flatten_all().unwrap().to_vec1().unwrap();
        v.chunks(4).map(decode).collect()
    };
    assert_eq!(window.len(), span);
    // o_t's newest frame names the stream, the episode and t.
    let (s, e, t) = window[history - 1];
    let goal = terminal_at.get(&(s, e)).copied().filter(|&g| g > t && g <= t + n as u32);
    assert_eq!(done == 1.0, goal.is_some(), "done flag (t {t}, goal {:?})", terminal_at.get(&(s, e)));
    let end = goal.unwrap_or(t + n as u32) as i64;
    let time_at = |p: usize| t as i64 - (history as i64 - 1) + p as i64;
    for (p, &(ws, we, wt)) in window.iter().enumerate() {
        assert_eq!((ws, we), (s, e), "window mixes episodes or streams");
        assert_eq!(wt as i64, time_at(p).clamp(0, end), "frame at position {p} (t {t}, end {end})");
    }
    let av: Vec<f32> = actions.get(i).unwrap().flatten_all().unwrap().to_vec1().unwrap();
    let rv: Vec<f32> = rewards.get(i).unwrap().to_vec1().unwrap();
    assert_eq!((av.len(), rv.len()), (3 * (span - 1), span - 1));
    for j in 0..span - 1 {
        let time = time_at(j);
        let (want_a, want_r) = if (0..end).contains(&time) {
            (action(s as u64, e as u32, time as u32), reward(s as u64, e as u32, time as u32))
        } else {
            ([0.0; 3], 0.0)
        };
        assert_eq!(&av[j * 3..j * 3 + 3], &want_a, "action history at {j} (t {t}, end {end})");
        assert_eq!(rv[j], want_r, "reward history at {j}");
    }
    assert_eq!(act, &action(s as u64, e as u32, t));
    let want: f64 = (0..n as u32)
        .filter(|k| ((t + k) as i64) < end)
        .map(|k| gamma.powi(k as i32) * reward(s as u64, e as u32, t + k) as f64)
        .sum();
    assert!((rew as f64 - want).abs() <= 1e-4 * (1.0 + want.abs()), "return {rew} vs {want} (t {t}, end {end})");
    if n == 1 {
        assert_eq!(rew, reward(s as u64, e as u32, t), "a one-step return is r_t exactly");
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]
    #[test]
    fn sampled_windows_equal_the_scripted_histories(
        seed in 0u64..10_000,
        history in 1usize..6,
        n_step in 1usize..4,
        capacity in 12usize..60,
        streams in 1u64..4,
    ) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let gamma = 0.5;
        let cfg = ReplayConfig { nonterminal_capacity: capacity, terminal_capacity: 5 };
        let mut replay = DualReplay::new(&cfg, FrameKind::Pixels { size: 2 }, history, &Device::Cpu)
            .unwrap()
            .with_n_step(n_step, gamma)
            .unwrap();
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
                prop_assert_eq!(batch.n_step, n_step);
                let act: Vec<Vec<f32>> = batch.action.to_vec2().unwrap();
                let rew: Vec<f32> = batch.reward.to_vec1().unwrap();
                let done: Vec<f32> = batch.done.to_vec1().unwrap();
                for i in 0..8 {
                    check_sample(&batch.transitions, i, history, n_step, gamma, done[i], &act[i], rew[i], &terminal_at);
                    prop_assert_eq!(done[i] == 1.0, i < batch.n_terminal);
                    checked += 1;
                }
            }
        }
        prop_assert!(checked >= 8, "only {} samples were checked", checked);
    }
}

/// At the goal an n-step replay keeps the n transitions that reach it, cut at the
/// goal, and an episode shorter than n keeps as many as it has steps; by hand for one
/// 3-step episode (rewards −1, −2, −4 then the goal) and n = 2, γ = 0.5.
#[test]
fn the_transitions_that_reach_the_goal_are_terminal() {
    let cfg = ReplayConfig { nonterminal_capacity: 40, terminal_capacity: 10 };
    let mut r =
        DualReplay::new(&cfg, FrameKind::State { dim: 1 }, 1, &Device::Cpu).unwrap().with_n_step(2, 0.5).unwrap();
    let rewards = [-1.0, -2.0, -4.0];
    assert_eq!(n_step_return(&rewards, 0.5), -3.0);
    assert_eq!(n_step_return(&[-2.5], 0.9), -2.5);
    for t in 0..4 {
        r.push(&Step {
            stream: 0,
            first: t == 0,
            frame: Frame::State(&[t as f32]),
            action: [t as f32; 3],
            reward: if t == 0 { 0.0 } else { rewards[t - 1] },
            terminal: t == 3,
            state_target: None,
        })
        .unwrap();
    }
    // Terminal: t = 2 (k = 1: −4, goal) and t = 1 (k = 2: −2 + 0.5·(−4) = −4).
    // Non-terminal: only t = 0 → 2 (−1 + 0.5·(−2) = −2); t = 1 → 3 is the goal's.
    assert_eq!((r.terminal_len(), r.nonterminal_len()), (2, 2));
    let batch = r.sample(64, &mut ChaCha8Rng::seed_from_u64(5)).unwrap();
    let Transitions::State { obs, next } = &batch.transitions else { panic!("state batch") };
    let (obs, next): (Vec<Vec<f32>>, Vec<Vec<f32>>) = (obs.to_vec2().unwrap(), next.to_vec2().unwrap());
    let (rew, done): (Vec<f32>, Vec<f32>) = (batch.reward.to_vec1().unwrap(), batch.done.to_vec1().unwrap());
    let act: Vec<Vec<f32>> = batch.action.to_vec2().unwrap();
    let mut seen = std::collections::BTreeSet::new();
    for i in 0..64 {
        let (t, t_next) = (obs[i][0] as i32, next[i][0] as i32);
        let want = match t {
            0 => (2, -2.0, 0.0),
            1 => (3, -4.0, 1.0),
            2 => (3, -4.0, 1.0),
            _ => panic!("o_t at time {t}: the goal is never o_t"),
        };
        assert_eq!((t_next, rew[i], done[i]), want, "sample {i} from t = {t}");
        assert_eq!(act[i], vec![(t + 1) as f32; 3], "a_t is the action stored with step t + 1");
        seen.insert(t);
    }
    assert_eq!(seen.len(), 3, "all three transitions are sampled: {seen:?}");
    // A one-step episode keeps one terminal transition even with n = 2.
    for t in 0..2 {
        r.push(&Step {
            stream: 1,
            first: t == 0,
            frame: Frame::State(&[10.0]),
            action: [0.0; 3],
            reward: -1.0,
            terminal: t == 1,
            state_target: None,
        })
        .unwrap();
    }
    assert_eq!(r.terminal_len(), 3);
    // n-step is chosen before the first push.
    assert!(r.with_n_step(3, 0.5).is_err());
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
