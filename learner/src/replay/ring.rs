//! The replay's storage: frames of either kind in flat vectors, and the step ring
//! of the non-terminal pool (each step's frame, link to its episode's previous
//! step, action, reward and terminal flag, in slot `global index mod capacity`).
//!
//! Invariants: slot s of every per-step vector (and of the frames, `len` values a
//! slot) belongs to the same step; vectors grow one slot at a time, in order, up to
//! the capacity, then are overwritten in place; a step's link is [`NONE`] exactly
//! when it is the first of its episode.

use pednav_nets::ACTION_DIM;

use crate::error::{LearnerError, Result};

use super::{Frame, FrameKind};

/// The link of an episode's first step (no previous step).
pub(super) const NONE: u64 = u64::MAX;

/// Frames of one pool, `len` values a slot: u8 pixels or f32 state vectors.
pub(super) enum Frames {
    U8(Vec<u8>),
    F32(Vec<f32>),
}

impl Frames {
    pub(super) fn new(kind: FrameKind) -> Frames {
        match kind {
            FrameKind::Pixels { .. } => Frames::U8(Vec::new()),
            FrameKind::State { .. } => Frames::F32(Vec::new()),
        }
    }
    /// Write `frame` at slot `slot` (appending when the slot is new).
    pub(super) fn put(&mut self, slot: usize, len: usize, frame: Frame<'_>) -> Result<()> {
        match (self, frame) {
            (Frames::U8(v), Frame::Pixels(p)) if p.len() == len => write_slot(v, slot, p),
            (Frames::F32(v), Frame::State(s)) if s.len() == len => write_slot(v, slot, s),
            _ => {
                return Err(LearnerError::Replay(format!(
                    "frame does not match the replay's frame kind (length {len})"
                )));
            }
        }
        Ok(())
    }
    /// Append the frame at `slot` to `out` as f32 (pixels scaled to [0, 1]).
    pub(super) fn read(&self, slot: usize, len: usize, out: &mut Vec<f32>) {
        match self {
            Frames::U8(v) => out.extend(v[slot * len..(slot + 1) * len].iter().map(|&p| p as f32 / 255.0)),
            Frames::F32(v) => out.extend_from_slice(&v[slot * len..(slot + 1) * len]),
        }
    }
    pub(super) fn copy_to(&self, slot: usize, len: usize, dst: &mut Frames, dst_slot: usize) {
        match (self, dst) {
            (Frames::U8(s), Frames::U8(d)) => write_slot(d, dst_slot, &s[slot * len..(slot + 1) * len]),
            (Frames::F32(s), Frames::F32(d)) => write_slot(d, dst_slot, &s[slot * len..(slot + 1) * len]),
            _ => unreachable!("pools share a frame kind"),
        }
    }
}

/// Write `data` at slot `slot` of `v` (slots of `data.len()` values), appending
/// when the slot is the next new one.
pub(super) fn write_slot<T: Copy>(v: &mut Vec<T>, slot: usize, data: &[T]) {
    let len = data.len();
    if v.len() == slot * len {
        v.extend_from_slice(data);
    } else {
        v[slot * len..(slot + 1) * len].copy_from_slice(data);
    }
}

/// The step ring of the non-terminal pool.
pub(super) struct StepRing {
    pub(super) cap: usize,
    pub(super) frames: Frames,
    pub(super) prev: Vec<u64>,
    pub(super) action: Vec<[f32; ACTION_DIM]>,
    pub(super) reward: Vec<f32>,
    pub(super) terminal: Vec<bool>,
    /// State targets, `target_dim` per slot (empty when the replay keeps none).
    pub(super) targets: Vec<f32>,
    /// Global index of the next step.
    pub(super) head: u64,
    /// Steps in the ring that are non-terminal transitions (non-first, non-terminal).
    pub(super) transitions: usize,
}

impl StepRing {
    pub(super) fn slot(&self, g: u64) -> usize {
        (g % self.cap as u64) as usize
    }
    pub(super) fn alive(&self, g: u64) -> bool {
        g < self.head && g + self.cap as u64 >= self.head
    }
    pub(super) fn is_transition(&self, slot: usize) -> bool {
        self.prev[slot] != NONE && !self.terminal[slot]
    }
}

/// The N_h + n steps ending at one step, as ring indices or `None` before the
/// episode start.
pub(super) struct Sequence {
    pub(super) steps: Vec<Option<u64>>,
}

/// A transition as stored: the ring slot of each of its N_h + n frames, its
/// N_h + n − 1 history entries, and the slot of o_t's newest step (whose state target
/// is the transition's).
pub(super) struct Window {
    pub(super) slots: Vec<usize>,
    pub(super) actions: Vec<[f32; ACTION_DIM]>,
    pub(super) rewards: Vec<f32>,
    pub(super) obs_slot: usize,
}
