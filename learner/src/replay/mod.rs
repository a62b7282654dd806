//! The dual replay of the paper's Algorithm 2: a terminal pool and a non-terminal
//! pool, a proportional batch split with at least one terminal sample once one
//! exists, and importance-sampling ratios normalised by their maximum.
//!
//! Storage. Steps arrive one at a time, interleaved across (actor, env) streams.
//! The non-terminal pool is a ring of *steps*: each frame is stored once, with a
//! link to the previous step of its episode, the action that led to it and the
//! reward received. A transition (o_t, a_t, r_t, o_{t+1}) is the step holding
//! frame t+1; its two N_h-frame windows and their action/reward histories are
//! rebuilt on sampling by following the links (padding with the episode's first
//! frame and zero actions/rewards before the episode start, as the actors do).
//! Goal-reaching (terminal) transitions are rare and must outlive the ring, so the
//! terminal pool keeps its own copy of the N_h + n frames and N_h + n − 1
//! actions/rewards each one needs.
//!
//! N-step transitions ([`DualReplay::with_n_step`], n = 1 by default as in the
//! paper): a transition then spans N_h + n frames, o_t's window followed by the n
//! newer frames up to o_{t+n}, and carries the discounted sum of its n rewards. A
//! non-terminal sample is drawn by the step holding its *last* frame, so its n steps
//! all exist; one whose window would start before its episode's first step is
//! redrawn (the first n − 1 steps of every episode, which `|B_N|` still counts: the
//! split's error is n − 1 steps per episode). At the goal the terminal pool stores
//! the n transitions that reach it (from t = T − k, k = 1 … n, as far as the episode
//! goes back), each cut at the goal: frames after it repeat the goal's frame and the
//! rewards after it are 0, so the stored window has the common N_h + n layout and
//! the return stops at the goal.
//!
//! Invariants: a sampled window is identical to the window the actor saw (tested
//! against scripted episodes across episode boundaries and ring wrap-around); a
//! transition whose window reaches an overwritten step is never sampled;
//! `|B_N|` counts exactly the steps in the ring that end a transition (non-first,
//! non-terminal).
//!
//! State targets. A replay built [`DualReplay::with_state_targets`] also keeps each
//! step's privileged state vector (the simulator's, for the state-prediction
//! auxiliary loss) beside its frame, and a terminal entry the one of its o_t; a
//! batch then carries o_t's as `state_target`.
//!
//! Memory: the ring holds `nonterminal_capacity` frames (84×84 u8: 7,056 B each,
//! so 1.5e6 frames ≈ 10.6 GB; 42×42: 2.6 GB) plus 25 B per step of links,
//! actions, rewards and flags; a terminal entry holds (N_h + 1) frames and N_h
//! actions/rewards (120 kB at 84×84, N_h 16). Both grow on demand up to their
//! capacities. The per-item sizes are [`ReplayFootprint`] (pednav-config), which
//! `pednav-run check` multiplies out for its memory estimate;
//! [`DualReplay::stored_bytes`] counts what is actually held and is tested equal to it.

mod batch;
mod ring;

use std::collections::HashMap;

use candle_core::Device;
use pednav_nets::ACTION_DIM;
use rand::Rng;
use rand_chacha::ChaCha8Rng;

pub use pednav_config::{FrameKind, ReplayConfig, ReplayFootprint};

// The footprint's action size is the one stored here.
const _: () = assert!(pednav_config::replay::ACTION_VALUES == ACTION_DIM);

use crate::error::{LearnerError, Result, config_error};

use batch::BatchBuilder;
use ring::{Frames, NONE, Sequence, StepRing, Window, write_slot};

pub use batch::{Batch, n_step_return, shift_frames};

/// A frame as handed to the replay.
#[derive(Debug, Clone, Copy)]
pub enum Frame<'a> {
    /// Pixels, row-major.
    Pixels(&'a [u8]),
    /// A state vector.
    State(&'a [f32]),
}

/// One step of one environment, as the learner receives it.
#[derive(Debug, Clone, Copy)]
pub struct Step<'a> {
    /// Identifies the (actor, environment) pair; steps of different streams interleave.
    pub stream: u64,
    /// First step of an episode (its action and reward are ignored).
    pub first: bool,
    /// The observation after the step.
    pub frame: Frame<'a>,
    /// The action that led here.
    pub action: [f32; ACTION_DIM],
    /// The reward received for it.
    pub reward: f32,
    /// The goal was reached here (no bootstrapping from this frame).
    pub terminal: bool,
    /// The simulator's state vector at this observation (a training target only;
    /// required by a replay built [`DualReplay::with_state_targets`], else ignored).
    pub state_target: Option<&'a [f32]>,
}

/// Algorithm 2's split and IS ratios for pool sizes (|B_T|, |B_N|) and batch size N_B:
/// returns (N_T, η_T, η_N). With an empty terminal pool all samples are
/// non-terminal with η = 1 (and vice versa).
pub fn dual_split(terminal: usize, nonterminal: usize, batch: usize) -> (usize, f64, f64) {
    if terminal == 0 {
        return (0, 1.0, 1.0);
    }
    if nonterminal == 0 {
        return (batch, 1.0, 1.0);
    }
    let total = (terminal + nonterminal) as f64;
    let p_t = terminal as f64 / total;
    // At least one terminal sample, and (the paper is silent here) at least one
    // non-terminal sample, so η_N stays defined when terminals dominate.
    let n_t = ((p_t * batch as f64).round() as usize).max(1).min(batch - 1);
    let p = batch as f64 / total;
    let eta_t = p * terminal as f64 / n_t as f64;
    let eta_n = p * nonterminal as f64 / (batch - n_t) as f64;
    let m = eta_t.max(eta_n);
    (n_t, eta_t / m, eta_n / m)
}

/// Terminal and non-terminal pools.
pub struct DualReplay {
    kind: FrameKind,
    frame_len: usize,
    history: usize,
    /// n of the n-step transitions (1: one-step, the paper).
    n_step: usize,
    /// γ of the n-step return.
    gamma: f64,
    ring: StepRing,
    /// Terminal pool: N_h + n frames and N_h + n − 1 actions/rewards per entry.
    term_frames: Frames,
    term_actions: Vec<[f32; ACTION_DIM]>,
    term_rewards: Vec<f32>,
    /// Terminal pool: o_t's state target per entry (`target_dim` floats).
    term_targets: Vec<f32>,
    /// Length of a state target (0: none kept).
    target_dim: usize,
    term_cap: usize,
    term_len: usize,
    term_next: usize,
    /// Last step index of each stream's current episode.
    streams: HashMap<u64, u64>,
    device: Device,
}

impl DualReplay {
    /// Empty pools for frames of `kind` and observation windows of `history` frames.
    pub fn new(cfg: &ReplayConfig, kind: FrameKind, history: usize, device: &Device) -> Result<DualReplay> {
        cfg.validate(kind, history, 1)?;
        Ok(DualReplay {
            kind,
            frame_len: kind.values_per_frame(),
            history,
            n_step: 1,
            gamma: 1.0,
            ring: StepRing {
                cap: cfg.nonterminal_capacity,
                frames: Frames::new(kind),
                prev: Vec::new(),
                action: Vec::new(),
                reward: Vec::new(),
                terminal: Vec::new(),
                targets: Vec::new(),
                head: 0,
                transitions: 0,
            },
            term_frames: Frames::new(kind),
            term_actions: Vec::new(),
            term_rewards: Vec::new(),
            term_targets: Vec::new(),
            target_dim: 0,
            term_cap: cfg.terminal_capacity,
            term_len: 0,
            term_next: 0,
            streams: HashMap::new(),
            device: device.clone(),
        })
    }

    /// Keep a state target of `dim` floats with every step (for the state-prediction
    /// auxiliary loss); batches then carry `state_target`. Call before the first push.
    pub fn with_state_targets(mut self, dim: usize) -> Result<DualReplay> {
        if self.ring.head != 0 {
            return Err(LearnerError::Replay("state targets must be enabled before the first step is stored".into()));
        }
        if dim == 0 {
            return Err(config_error("state_dim", dim, "a state target needs at least one value"));
        }
        self.target_dim = dim;
        Ok(self)
    }

    /// Sample n-step transitions: o_t, a_t, the return Σ_{k<n} γᵏ r_{t+k} and o_{t+n},
    /// cut at the goal (see the module docs). Call before the first push; n = 1 (the
    /// default) is the one-step transition, whatever γ.
    pub fn with_n_step(mut self, n_step: usize, gamma: f64) -> Result<DualReplay> {
        if self.ring.head != 0 {
            return Err(LearnerError::Replay(
                "n-step transitions must be chosen before the first step is stored".into(),
            ));
        }
        // The pools' own capacities, checked by the one rule `pednav-run check` applies.
        let cfg = ReplayConfig { nonterminal_capacity: self.ring.cap, terminal_capacity: self.term_cap };
        cfg.validate(self.kind, self.history, n_step)?;
        if !(0.0..=1.0).contains(&gamma) {
            return Err(config_error("gamma", gamma, "must be in [0, 1]"));
        }
        self.n_step = n_step;
        self.gamma = gamma;
        Ok(self)
    }

    /// n of the transitions this replay samples (1: one-step).
    pub fn n_step(&self) -> usize {
        self.n_step
    }

    /// Length of the state target kept with every step (0: none, the default).
    pub fn state_target_dim(&self) -> usize {
        self.target_dim
    }

    /// |B_T|: terminal transitions stored.
    pub fn terminal_len(&self) -> usize {
        self.term_len
    }

    /// |B_N|: non-terminal transitions stored.
    pub fn nonterminal_len(&self) -> usize {
        self.ring.transitions
    }

    /// Steps inserted since creation.
    pub fn inserted(&self) -> u64 {
        self.ring.head
    }

    /// Bytes per ring step and per terminal entry of this replay (what the run's
    /// memory estimate multiplies by the pools' sizes).
    pub fn footprint(&self) -> ReplayFootprint {
        ReplayFootprint::new(self.kind, self.history, self.n_step, self.target_dim)
    }

    /// Bytes of step and entry data held now (the vectors' lengths times their
    /// element sizes; spare capacity of a vector is not counted — it is never
    /// touched, so not resident). Equals `min(inserted, nonterminal_capacity) ×
    /// ring_step + terminal_len × terminal_entry` of [`DualReplay::footprint`].
    pub fn stored_bytes(&self) -> usize {
        fn bytes<T>(v: &[T]) -> usize {
            std::mem::size_of_val(v)
        }
        fn frames(f: &Frames) -> usize {
            match f {
                Frames::U8(v) => bytes(v),
                Frames::F32(v) => bytes(v),
            }
        }
        let r = &self.ring;
        frames(&r.frames)
            + bytes(&r.prev)
            + bytes(&r.action)
            + bytes(&r.reward)
            + bytes(&r.terminal)
            + bytes(&r.targets)
            + frames(&self.term_frames)
            + bytes(&self.term_actions)
            + bytes(&self.term_rewards)
            + bytes(&self.term_targets)
    }

    /// Store one step. A step of a stream whose episode start was never seen (e.g.
    /// the learner started mid-episode) is dropped until that stream's next first step;
    /// returns whether the step was stored.
    pub fn push(&mut self, step: &Step<'_>) -> Result<bool> {
        let prev = if step.first {
            NONE
        } else {
            match self.streams.get(&step.stream) {
                Some(&p) if self.ring.alive(p) => p,
                _ => return Ok(false),
            }
        };
        let target = match (self.target_dim, step.state_target) {
            (0, _) => None,
            (d, Some(t)) if t.len() == d => Some(t),
            (d, t) => {
                return Err(LearnerError::Replay(format!(
                    "this replay keeps state targets of {d} values; the step has {}",
                    t.map_or("none".to_string(), |t| t.len().to_string())
                )));
            }
        };
        let g = self.ring.head;
        let slot = self.ring.slot(g);
        let r = &mut self.ring;
        if let Some(t) = target {
            write_slot(&mut r.targets, slot, t);
        }
        let fresh = r.prev.len() == slot;
        if !fresh && r.is_transition(slot) {
            r.transitions -= 1;
        }
        r.frames.put(slot, self.frame_len, step.frame)?;
        let (action, reward) = if step.first { ([0.0; ACTION_DIM], 0.0) } else { (step.action, step.reward) };
        if fresh {
            r.prev.push(prev);
            r.action.push(action);
            r.reward.push(reward);
            r.terminal.push(step.terminal);
        } else {
            r.prev[slot] = prev;
            r.action[slot] = action;
            r.reward[slot] = reward;
            r.terminal[slot] = step.terminal;
        }
        r.head += 1;
        if r.is_transition(slot) {
            r.transitions += 1;
        }
        if step.terminal {
            self.streams.remove(&step.stream);
            if prev != NONE {
                self.store_terminals(g);
            }
        } else {
            self.streams.insert(step.stream, g);
        }
        Ok(true)
    }

    /// End the open episodes of the streams `cut` picks: their next steps are dropped
    /// until each stream's next first step, as for a stream whose start was never
    /// seen. For a stream whose records jumped (records taken by another learner
    /// before this one): no transition may link the steps on either side of the jump.
    /// Returns how many open episodes were cut.
    pub fn cut_streams(&mut self, mut cut: impl FnMut(u64) -> bool) -> usize {
        let before = self.streams.len();
        self.streams.retain(|&stream, _| !cut(stream));
        before - self.streams.len()
    }

    /// The `len` steps ending at `g` (times t_g + 1 − len … t_g), `None` before the
    /// episode start; `None` overall if any present step is overwritten.
    fn sequence(&self, g: u64, len: usize) -> Option<Sequence> {
        let mut steps = vec![None; len];
        let mut cur = Some(g);
        for i in (0..len).rev() {
            let c = cur?;
            if !self.ring.alive(c) {
                return None;
            }
            steps[i] = Some(c);
            let p = self.ring.prev[self.ring.slot(c)];
            // Before the episode start the window is padding: stop walking.
            cur = if p == NONE { None } else { Some(p) };
            if cur.is_none() {
                break;
            }
        }
        Some(Sequence { steps })
    }

    /// Frames a transition spans: N_h + n.
    fn span(&self) -> usize {
        self.history + self.n_step
    }

    /// The stored layout of a transition from its present steps `steps` (N_h + k
    /// positions, k ≤ n, the newest last, o_t's newest at position N_h − 1, which
    /// must be present): the ring slot of each of its N_h + n frames — the episode's
    /// first frame before the episode start, the newest frame repeated n − k times
    /// after it (a transition cut at the goal) — and its N_h + n − 1 history entries:
    /// entry i is the action taken after the frame at position i (stored with the
    /// step at i + 1), zero before the episode start and after the newest step.
    fn window(&self, steps: &[Option<u64>]) -> Window {
        let span = self.span();
        debug_assert!(steps.len() <= span && steps[self.history - 1].is_some());
        let first = steps.iter().flatten().copied().next().expect("a transition holds o_t's step");
        let newest = steps.last().copied().flatten().expect("a transition's newest step is present");
        let mut slots: Vec<usize> = steps.iter().map(|s| self.ring.slot(s.unwrap_or(first))).collect();
        slots.resize(span, self.ring.slot(newest));
        let (mut actions, mut rewards) = (Vec::with_capacity(span - 1), Vec::with_capacity(span - 1));
        for i in 0..span - 1 {
            match (steps.get(i).copied().flatten(), steps.get(i + 1).copied().flatten()) {
                (Some(_), Some(next)) => {
                    let slot = self.ring.slot(next);
                    actions.push(self.ring.action[slot]);
                    rewards.push(self.ring.reward[slot]);
                }
                _ => {
                    actions.push([0.0; ACTION_DIM]);
                    rewards.push(0.0);
                }
            }
        }
        let obs_step = steps[self.history - 1].expect("checked above");
        Window { slots, actions, rewards, obs_slot: self.ring.slot(obs_step) }
    }

    /// Store the transitions that reach the goal at step `g`: from t = g − k for
    /// k = 1 … n, as far as the episode and the ring go back, each cut at the goal.
    fn store_terminals(&mut self, g: u64) {
        let span = self.span();
        for k in 1..=self.n_step {
            // The N_h + k steps ending at the goal; o_t = g − k at position N_h − 1.
            let Some(seq) = self.sequence(g, self.history + k) else { break };
            if seq.steps[self.history - 1].is_none() {
                break; // the episode is shorter than k steps
            }
            let w = self.window(&seq.steps);
            let e = self.term_next;
            for (i, &src) in w.slots.iter().enumerate() {
                self.ring.frames.copy_to(src, self.frame_len, &mut self.term_frames, e * span + i);
            }
            if self.target_dim > 0 {
                let d = self.target_dim;
                let target = self.ring.targets[w.obs_slot * d..(w.obs_slot + 1) * d].to_vec();
                write_slot(&mut self.term_targets, e, &target);
            }
            write_slot(&mut self.term_actions, e, &w.actions);
            write_slot(&mut self.term_rewards, e, &w.rewards);
            self.term_next = (e + 1) % self.term_cap;
            self.term_len = (self.term_len + 1).min(self.term_cap);
        }
    }

    /// Draw one sampleable non-terminal transition uniformly (by the step holding
    /// its newest frame; one whose o_t would precede its episode is redrawn).
    fn draw_nonterminal(&self, rng: &mut ChaCha8Rng) -> Result<Window> {
        let r = &self.ring;
        let lo = r.head.saturating_sub(r.cap as u64);
        for _ in 0..10_000 {
            let g = rng.random_range(lo..r.head);
            if !r.is_transition(r.slot(g)) {
                continue;
            }
            if let Some(seq) = self.sequence(g, self.span())
                && seq.steps[self.history - 1].is_some()
            {
                return Ok(self.window(&seq.steps));
            }
        }
        Err(LearnerError::Replay(format!("no sampleable non-terminal transition among {} stored steps", r.head - lo)))
    }

    /// Sample a batch of `batch` transitions by Algorithm 2.
    pub fn sample(&self, batch: usize, rng: &mut ChaCha8Rng) -> Result<Batch> {
        self.sample_shifted(batch, 0, rng)
    }

    /// [`DualReplay::sample`] with DrQ's random-shift augmentation of pixel batches:
    /// each transition's N_h + 1 frames are shifted together by one (dx, dy) drawn
    /// uniformly from [−`max_shift`, `max_shift`]² ([`shift_frames`]), so o_t and
    /// o_{t+1} stay views of one window. `max_shift` 0 draws nothing and equals
    /// [`DualReplay::sample`] bit for bit; state observations are never shifted.
    pub fn sample_shifted(&self, batch: usize, max_shift: usize, rng: &mut ChaCha8Rng) -> Result<Batch> {
        if batch == 0 {
            return Err(config_error("batch_size", batch, "must be positive"));
        }
        if self.term_len + self.ring.transitions == 0 {
            return Err(LearnerError::Replay("sampling from an empty replay".into()));
        }
        let (n_t, eta_t, eta_n) = dual_split(self.term_len, self.ring.transitions, batch);
        let (span, fl) = (self.span(), self.frame_len);
        let entries = span - 1;
        let mut b = BatchBuilder::new(batch, self.history, self.n_step, self.gamma, fl);
        let d = self.target_dim;
        for _ in 0..n_t {
            let e = rng.random_range(0..self.term_len);
            let mut frames = Vec::with_capacity(span * fl);
            for i in 0..span {
                self.term_frames.read(e * span + i, fl, &mut frames);
            }
            self.augment(&mut frames, max_shift, rng);
            b.targets.extend_from_slice(self.term_targets.get(e * d..(e + 1) * d).unwrap_or_default());
            b.add(
                &frames,
                &self.term_actions[e * entries..(e + 1) * entries],
                &self.term_rewards[e * entries..(e + 1) * entries],
                1.0,
                eta_t as f32,
            );
        }
        for _ in n_t..batch {
            let w = self.draw_nonterminal(rng)?;
            let mut frames = Vec::with_capacity(span * fl);
            for &slot in &w.slots {
                self.ring.frames.read(slot, fl, &mut frames);
            }
            self.augment(&mut frames, max_shift, rng);
            if d > 0 {
                b.targets.extend_from_slice(&self.ring.targets[w.obs_slot * d..(w.obs_slot + 1) * d]);
            }
            b.add(&frames, &w.actions, &w.rewards, 0.0, eta_n as f32);
        }
        b.finish(self.kind, n_t, d, &self.device)
    }
}

impl DualReplay {
    /// Shift one transition's frames by a random offset (pixel replays, `max_shift` > 0).
    fn augment(&self, frames: &mut Vec<f32>, max_shift: usize, rng: &mut ChaCha8Rng) {
        let FrameKind::Pixels { size } = self.kind else { return };
        if max_shift == 0 {
            return;
        }
        let m = max_shift as i64;
        let (dx, dy) = (rng.random_range(-m..=m), rng.random_range(-m..=m));
        *frames = shift_frames(frames, size, dx as isize, dy as isize);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What the replay holds is exactly its footprint times its counts, so the memory
    /// estimate of `pednav-run check` (which uses the same footprint) cannot drift
    /// from the storage: pixels and state vectors, with and without state targets,
    /// both pools wrapped around.
    #[test]
    fn stored_bytes_are_the_footprint_times_the_counts() {
        for (kind, history, target_dim) in [
            (FrameKind::Pixels { size: 3 }, 4, 0),
            (FrameKind::Pixels { size: 2 }, 2, 5),
            (FrameKind::State { dim: 6 }, 1, 0),
            (FrameKind::State { dim: 6 }, 1, 3),
        ] {
            let cfg = ReplayConfig { nonterminal_capacity: 40, terminal_capacity: 3 };
            let mut r = DualReplay::new(&cfg, kind, history, &Device::Cpu).unwrap();
            if target_dim > 0 {
                r = r.with_state_targets(target_dim).unwrap();
            }
            let fp = r.footprint();
            assert_eq!(fp, ReplayFootprint::new(kind, history, 1, target_dim));
            assert_eq!(r.stored_bytes(), 0);
            let pixels = vec![7u8; kind.values_per_frame()];
            let state = vec![0.5f32; kind.values_per_frame()];
            let target = vec![1.0f32; target_dim];
            // Episodes of 2 … 6 steps from two interleaved streams, every one reaching the goal.
            let mut terminals = 0;
            for episode in 0..30u64 {
                let len = 2 + (episode % 5) as usize;
                for t in 0..len {
                    for stream in 0..2 {
                        let step = Step {
                            stream,
                            first: t == 0,
                            frame: match kind {
                                FrameKind::Pixels { .. } => Frame::Pixels(&pixels),
                                FrameKind::State { .. } => Frame::State(&state),
                            },
                            action: [0.1; ACTION_DIM],
                            reward: -1.0,
                            terminal: t + 1 == len,
                            state_target: (target_dim > 0).then_some(&target[..]),
                        };
                        assert!(r.push(&step).unwrap());
                        terminals += usize::from(t + 1 == len);
                        let slots = (r.inserted() as usize).min(cfg.nonterminal_capacity);
                        assert_eq!(r.terminal_len(), terminals.min(cfg.terminal_capacity));
                        assert_eq!(
                            r.stored_bytes(),
                            slots * fp.ring_step + r.terminal_len() * fp.terminal_entry,
                            "{kind:?}, N_h {history}, targets {target_dim}"
                        );
                    }
                }
            }
            assert!(r.inserted() as usize > 2 * cfg.nonterminal_capacity);
        }
        // The closed form, by hand: 84×84 pixels, N_h 16, no targets.
        let fp = ReplayFootprint::new(FrameKind::Pixels { size: 84 }, 16, 1, 0);
        assert_eq!(fp.ring_step, 7056 + 8 + 12 + 4 + 1);
        assert_eq!(fp.terminal_entry, 17 * 7056 + 16 * (12 + 4));
    }

    /// A cut stream stores nothing until its next first step; other streams go on.
    #[test]
    fn a_cut_stream_waits_for_its_next_episode() {
        let cfg = ReplayConfig { nonterminal_capacity: 16, terminal_capacity: 4 };
        let mut r = DualReplay::new(&cfg, FrameKind::State { dim: 2 }, 1, &Device::Cpu).unwrap();
        let state = [0.0f32; 2];
        let step = |stream, first| Step {
            stream,
            first,
            frame: Frame::State(&state),
            action: [0.0; ACTION_DIM],
            reward: -1.0,
            terminal: false,
            state_target: None,
        };
        for stream in [1, 2, 3] {
            assert!(r.push(&step(stream, true)).unwrap());
        }
        assert_eq!(r.cut_streams(|s| s >= 2), 2);
        assert!(r.push(&step(1, false)).unwrap(), "an uncut stream goes on");
        assert!(!r.push(&step(2, false)).unwrap(), "no transition spans the cut");
        assert!(r.push(&step(2, true)).unwrap());
        assert!(r.push(&step(2, false)).unwrap(), "the next episode is stored");
    }
}
