//! A sampled batch and its assembly: each transition's N_h + 1 frames and N_h
//! action/reward histories collected row by row, then made tensors once; and
//! DrQ's random-shift augmentation of pixel frames.
//!
//! Invariants: row i of every tensor of a [`Batch`] is the same transition, the
//! terminal-pool rows first; a transition's frames are shifted together, so o_t
//! and o_{t+1} stay views of one window.

use candle_core::{Device, Tensor};
use pednav_nets::{ACTION_DIM, Transitions};

use crate::error::Result;

use super::FrameKind;

/// A sampled batch.
#[derive(Debug, Clone)]
pub struct Batch {
    /// The transitions (o_t, o_{t+1}), each transition's N_h + 1 frames held once:
    /// `transitions.obs()` and `transitions.next_obs()` are views of them, and the
    /// 3D-TCN encodes both in one pass ([`pednav_nets::Encoder::encode_transition`]).
    pub transitions: Transitions,
    /// Actions a_t (B, 3).
    pub action: Tensor,
    /// Rewards r_t (B).
    pub reward: Tensor,
    /// 1 where o_{t+1} is terminal (goal reached), else 0 (B).
    pub done: Tensor,
    /// o_t's state targets (B, dim), from a replay built
    /// [`DualReplay::with_state_targets`](super::DualReplay::with_state_targets).
    pub state_target: Option<Tensor>,
    /// Normalised IS ratios η (B): terminal samples first, then non-terminal.
    pub weight: Tensor,
    /// N_T: how many of the B samples came from the terminal pool (the first ones).
    pub n_terminal: usize,
}

/// Square frames of side `size`, concatenated, each shifted by (dx, dy) pixels with
/// the edge replicated (DrQ's "pad by replication, then crop at a random offset"):
/// `out[y][x] = in[clamp(y + dy)][clamp(x + dx)]`.
pub fn shift_frames(frames: &[f32], size: usize, dx: isize, dy: isize) -> Vec<f32> {
    let clamp = |v: isize| v.clamp(0, size as isize - 1) as usize;
    let mut out = Vec::with_capacity(frames.len());
    for frame in frames.chunks_exact(size * size) {
        for y in 0..size {
            let row = &frame[clamp(y as isize + dy) * size..][..size];
            out.extend((0..size).map(|x| row[clamp(x as isize + dx)]));
        }
    }
    out
}

/// Collects samples into batch tensors.
pub(super) struct BatchBuilder {
    n: usize,
    fl: usize,
    b: usize,
    /// Each transition's N_h + 1 frames.
    frames: Vec<f32>,
    /// Each transition's N_h actions and rewards (the newest are a_t, r_t).
    actions: Vec<f32>,
    rewards: Vec<f32>,
    action: Vec<f32>,
    reward: Vec<f32>,
    done: Vec<f32>,
    weight: Vec<f32>,
    /// o_t's state targets, concatenated (empty without state targets).
    pub(super) targets: Vec<f32>,
}

impl BatchBuilder {
    pub(super) fn new(b: usize, n: usize, fl: usize) -> BatchBuilder {
        BatchBuilder {
            n,
            fl,
            b,
            frames: Vec::with_capacity(b * (n + 1) * fl),
            actions: Vec::with_capacity(b * n * ACTION_DIM),
            rewards: Vec::with_capacity(b * n),
            action: Vec::with_capacity(b * ACTION_DIM),
            reward: Vec::with_capacity(b),
            done: Vec::with_capacity(b),
            weight: Vec::with_capacity(b),
            targets: Vec::new(),
        }
    }

    /// `frames`: N_h + 1 frames; `acts`/`rews`: the N_h history entries of the sequence.
    pub(super) fn add(&mut self, frames: &[f32], acts: &[[f32; ACTION_DIM]], rews: &[f32], done: f32, weight: f32) {
        let n = self.n;
        debug_assert_eq!(frames.len(), (n + 1) * self.fl);
        self.frames.extend_from_slice(frames);
        self.actions.extend(acts.iter().flatten());
        self.rewards.extend_from_slice(rews);
        self.action.extend_from_slice(&acts[n - 1]);
        self.reward.push(rews[n - 1]);
        self.done.push(done);
        self.weight.push(weight);
    }

    pub(super) fn finish(self, kind: FrameKind, n_terminal: usize, target_dim: usize, dev: &Device) -> Result<Batch> {
        let (b, n) = (self.b, self.n);
        let transitions = match kind {
            FrameKind::Pixels { size } => Transitions::Pixels {
                frames: Tensor::from_vec(self.frames, (b, n + 1, size, size), dev)?,
                actions: Tensor::from_vec(self.actions, (b, n, ACTION_DIM), dev)?,
                rewards: Tensor::from_vec(self.rewards, (b, n), dev)?,
            },
            FrameKind::State { dim } => {
                // History 1: each transition is o_t's vector then o_{t+1}'s.
                let pairs = Tensor::from_vec(self.frames, (b, 2, dim), dev)?;
                Transitions::State {
                    obs: pairs.narrow(1, 0, 1)?.reshape((b, dim))?,
                    next: pairs.narrow(1, 1, 1)?.reshape((b, dim))?,
                }
            }
        };
        Ok(Batch {
            transitions,
            action: Tensor::from_vec(self.action, (b, ACTION_DIM), dev)?,
            reward: Tensor::from_vec(self.reward, b, dev)?,
            done: Tensor::from_vec(self.done, b, dev)?,
            weight: Tensor::from_vec(self.weight, b, dev)?,
            state_target: match target_dim {
                0 => None,
                d => Some(Tensor::from_vec(self.targets, (b, d), dev)?),
            },
            n_terminal,
        })
    }
}
