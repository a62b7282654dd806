//! Per-thread pool of f32 scratch buffers ([`Pooled`]): column matrices, padded
//! inputs and masked gradients are reused between calls instead of allocated and
//! zeroed each time.
//!
//! Invariant: a [`Pooled`] dereferences to exactly the `len` floats it was asked for,
//! starting on a 64-byte boundary (a cache line: the kernels' 64-byte vector and tile
//! rows then never straddle two lines where their offsets are multiples of 64 bytes,
//! whichever buffer the pool hands out), with unspecified contents (every user writes
//! what it reads); on drop its buffer
//! goes back to the pool of the thread that drops it, which keeps at most
//! `POOL_SIZE` buffers (a fuller pool keeps the larger ones).

use rayon::prelude::*;

thread_local! {
    /// Scratch buffers of this thread (column matrices, padded inputs, masked
    /// gradients), kept between calls: allocating and zeroing up to megabytes per
    /// call showed in the actor's profile.
    static POOL: std::cell::RefCell<Vec<Vec<f32>>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Buffers a thread keeps for reuse (a mixed-precision backward on AMX holds seven
/// at once per worker, and the packed weights one more on the calling thread).
const POOL_SIZE: usize = 8;

/// A scratch buffer of `len` floats with unspecified contents (every user writes
/// what it reads), returned to its thread's pool on drop.
pub(super) struct Pooled {
    buf: Vec<f32>,
    /// Index of the first float on a 64-byte boundary.
    start: usize,
    len: usize,
}

/// Floats a buffer needs beyond `len` so that `len` of them can start on a 64-byte boundary.
const ALIGN_SLACK: usize = 64 / std::mem::size_of::<f32>() - 1;

impl Pooled {
    pub(super) fn new(len: usize) -> Pooled {
        if len == 0 {
            // Nothing to hold: leave the pool's buffers to the scratch that needs them.
            return Pooled { buf: Vec::new(), start: 0, len: 0 };
        }
        let need = len + ALIGN_SLACK;
        let mut buf = POOL.with(|p| {
            let mut p = p.borrow_mut();
            // The smallest buffer that is large enough, else the largest (grown).
            let pick = p
                .iter()
                .enumerate()
                .filter(|(_, b)| b.len() >= need)
                .min_by_key(|(_, b)| b.len())
                .or_else(|| p.iter().enumerate().max_by_key(|(_, b)| b.len()))
                .map(|(i, _)| i);
            pick.map(|i| p.swap_remove(i)).unwrap_or_default()
        });
        if buf.len() < need {
            buf.resize(need, 0.0);
        }
        // (`align_offset` may in principle give up; the buffer then stays as it is.)
        let start = Some(buf.as_ptr().align_offset(64)).filter(|&s| s <= ALIGN_SLACK).unwrap_or(0);
        Pooled { buf, start, len }
    }
}

impl Pooled {
    /// A copy of bf16 values `v` (the packed weights) on a 64-byte boundary, read
    /// through [`Pooled::as_bf16`] (a zero pads an odd count).
    pub(super) fn bf16_copy(v: &[u16]) -> Pooled {
        let mut p = Pooled::new(v.len().div_ceil(2));
        let dst = p.as_bf16_mut();
        dst[..v.len()].copy_from_slice(v);
        dst[v.len()..].fill(0);
        p
    }

    /// The buffer's bytes as `2·len` bf16 values (read-only; see [`Pooled::as_bf16_mut`]).
    pub(super) fn as_bf16(&self) -> &[u16] {
        let floats: &[f32] = self;
        // SAFETY: as in `as_bf16_mut`, through a shared borrow.
        unsafe { std::slice::from_raw_parts(floats.as_ptr().cast::<u16>(), 2 * floats.len()) }
    }

    /// The buffer's bytes as `2·len` bf16 values (bit patterns in `u16`), for the
    /// mixed-precision kernels: `Pooled::new(n.div_ceil(2))` holds `n` of them.
    pub(super) fn as_bf16_mut(&mut self) -> &mut [u16] {
        // The same window as `deref_mut`: `len` floats from the aligned start.
        let floats: &mut [f32] = self;
        // SAFETY: the view covers exactly the bytes of the `len` floats it is asked
        // for, `u16` has no invalid bit patterns and an alignment that divides
        // `f32`'s, and the mutable borrow of `self` keeps it the only view.
        unsafe { std::slice::from_raw_parts_mut(floats.as_mut_ptr().cast::<u16>(), 2 * floats.len()) }
    }
}

impl std::ops::Deref for Pooled {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        &self.buf[self.start..self.start + self.len]
    }
}

impl std::ops::DerefMut for Pooled {
    fn deref_mut(&mut self) -> &mut [f32] {
        &mut self.buf[self.start..self.start + self.len]
    }
}

impl Drop for Pooled {
    fn drop(&mut self) {
        let buf = std::mem::take(&mut self.buf);
        if buf.is_empty() {
            return;
        }
        // A thread that is exiting has no pool left; the buffer is simply freed.
        let _ = POOL.try_with(|p| {
            let mut p = p.borrow_mut();
            if p.len() < POOL_SIZE {
                p.push(buf);
            } else if let Some(small) = p.iter_mut().min_by_key(|b| b.len()).filter(|b| b.len() < buf.len()) {
                *small = buf;
            }
        });
    }
}

/// `n` zeros, written in parallel on rayon's pool for a long vector: a layer's
/// output or input gradient (megabytes at a learner's batch) is zeroed by every
/// worker instead of serially by the thread about to call the kernel (that serial
/// fill, `vec![0.0; n]`, was ≈ 3 % each of a learner update's main thread on the Xeon).
pub(super) fn parallel_zeros(n: usize) -> Vec<f32> {
    /// Floats per task (64 KiB); shorter vectors are zeroed in one go.
    const CHUNK: usize = 1 << 14;
    if n < 2 * CHUNK {
        return vec![0.0; n];
    }
    let mut v: Vec<f32> = Vec::with_capacity(n);
    v.spare_capacity_mut()[..n].par_chunks_mut(CHUNK).for_each(|c| c.fill(std::mem::MaybeUninit::new(0.0)));
    // SAFETY: the capacity holds n floats and all n were written just above.
    unsafe { v.set_len(n) };
    v
}
