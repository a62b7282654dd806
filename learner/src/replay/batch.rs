//! A sampled batch and its assembly: each transition's N_h + n frames and N_h + n − 1
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
    /// The transitions (o_t, o_{t+n}), each transition's N_h + n frames held once:
    /// `transitions.obs()` and `transitions.next_obs()` are views of them, and the
    /// 3D-TCN encodes both in one pass ([`pednav_nets::Encoder::encode_transition`]).
    pub transitions: Transitions,
    /// Actions a_t (B, 3).
    pub action: Tensor,
    /// The n-step returns Σ_{k<n} γᵏ r_{t+k} (B), cut at the goal; r_t when n = 1.
    pub reward: Tensor,
    /// 1 where the goal is reached within the n steps (no bootstrap), else 0 (B).
    pub done: Tensor,
    /// n: the TD target bootstraps from o_{t+n} with γⁿ (1: the paper's one step).
    pub n_step: usize,
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

/// Σ_k γᵏ r_k over `rewards` (r_t first), summed in f64: the n-step return, exactly
/// r_t for one reward.
pub fn n_step_return(rewards: &[f32], gamma: f64) -> f32 {
    let mut discount = 1.0;
    let mut sum = 0.0f64;
    for &r in rewards {
        sum += discount * r as f64;
        discount *= gamma;
    }
    sum as f32
}

/// Collects samples into batch tensors.
pub(super) struct BatchBuilder {
    /// N_h.
    history: usize,
    n_step: usize,
    gamma: f64,
    fl: usize,
    b: usize,
    /// Each transition's N_h + n frames.
    frames: Vec<f32>,
    /// Each transition's N_h + n − 1 actions and rewards (a_t, r_t at N_h − 1).
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
    pub(super) fn new(b: usize, history: usize, n_step: usize, gamma: f64, fl: usize) -> BatchBuilder {
        let span = history + n_step;
        BatchBuilder {
            history,
            n_step,
            gamma,
            fl,
            b,
            frames: Vec::with_capacity(b * span * fl),
            actions: Vec::with_capacity(b * (span - 1) * ACTION_DIM),
            rewards: Vec::with_capacity(b * (span - 1)),
            action: Vec::with_capacity(b * ACTION_DIM),
            reward: Vec::with_capacity(b),
            done: Vec::with_capacity(b),
            weight: Vec::with_capacity(b),
            targets: Vec::new(),
        }
    }

    /// `frames`: N_h + n frames; `acts`/`rews`: the N_h + n − 1 history entries of
    /// the transition (zero after a goal within the n steps).
    pub(super) fn add(&mut self, frames: &[f32], acts: &[[f32; ACTION_DIM]], rews: &[f32], done: f32, weight: f32) {
        let (h, n) = (self.history, self.n_step);
        debug_assert_eq!(frames.len(), (h + n) * self.fl);
        debug_assert_eq!(rews.len(), h + n - 1);
        self.frames.extend_from_slice(frames);
        self.actions.extend(acts.iter().flatten());
        self.rewards.extend_from_slice(rews);
        self.action.extend_from_slice(&acts[h - 1]);
        self.reward.push(n_step_return(&rews[h - 1..], self.gamma));
        self.done.push(done);
        self.weight.push(weight);
    }

    pub(super) fn finish(self, kind: FrameKind, n_terminal: usize, target_dim: usize, dev: &Device) -> Result<Batch> {
        let (b, n_step) = (self.b, self.n_step);
        let span = self.history + n_step;
        let transitions = match kind {
            FrameKind::Pixels { size } => Transitions::Pixels {
                frames: Tensor::from_vec(self.frames, (b, span, size, size), dev)?,
                actions: Tensor::from_vec(self.actions, (b, span - 1, ACTION_DIM), dev)?,
                rewards: Tensor::from_vec(self.rewards, (b, span - 1), dev)?,
                n_step,
            },
            FrameKind::State { dim } => {
                // History 1: each transition is o_t's vector, the n − 1 between, o_{t+n}'s.
                let run = Tensor::from_vec(self.frames, (b, span, dim), dev)?;
                Transitions::State {
                    obs: run.narrow(1, 0, 1)?.reshape((b, dim))?,
                    next: run.narrow(1, n_step, 1)?.reshape((b, dim))?,
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
            n_step,
        })
    }
}
