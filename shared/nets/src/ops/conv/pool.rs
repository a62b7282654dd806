//! Per-thread pool of f32 scratch buffers ([`Pooled`]): column matrices, padded
//! inputs and masked gradients are reused between calls instead of allocated and
//! zeroed each time.
//!
//! Invariant: a [`Pooled`] dereferences to exactly the `len` floats it was asked for,
//! with unspecified contents (every user writes what it reads); on drop its buffer
//! goes back to the pool of the thread that drops it, which keeps at most
//! `POOL_SIZE` buffers (a fuller pool keeps the larger ones).

thread_local! {
    /// Scratch buffers of this thread (column matrices, padded inputs, masked
    /// gradients), kept between calls: allocating and zeroing up to megabytes per
    /// call showed in the actor's profile.
    static POOL: std::cell::RefCell<Vec<Vec<f32>>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Buffers a thread keeps for reuse (a mixed-precision backward holds six at once).
const POOL_SIZE: usize = 8;

/// A scratch buffer of `len` floats with unspecified contents (every user writes
/// what it reads), returned to its thread's pool on drop.
pub(super) struct Pooled {
    buf: Vec<f32>,
    len: usize,
}

impl Pooled {
    pub(super) fn new(len: usize) -> Pooled {
        if len == 0 {
            // Nothing to hold: leave the pool's buffers to the scratch that needs them.
            return Pooled { buf: Vec::new(), len: 0 };
        }
        let mut buf = POOL.with(|p| {
            let mut p = p.borrow_mut();
            // The smallest buffer that is large enough, else the largest (grown).
            let pick = p
                .iter()
                .enumerate()
                .filter(|(_, b)| b.len() >= len)
                .min_by_key(|(_, b)| b.len())
                .or_else(|| p.iter().enumerate().max_by_key(|(_, b)| b.len()))
                .map(|(i, _)| i);
            pick.map(|i| p.swap_remove(i)).unwrap_or_default()
        });
        if buf.len() < len {
            buf.resize(len, 0.0);
        }
        Pooled { buf, len }
    }
}

impl Pooled {
    /// The buffer's bytes as `2·len` bf16 values (bit patterns in `u16`), for the
    /// mixed-precision kernels: `Pooled::new(n.div_ceil(2))` holds `n` of them.
    pub(super) fn as_bf16_mut(&mut self) -> &mut [u16] {
        let len = 2 * self.len;
        // SAFETY: the view covers exactly the bytes of the `len` floats it is asked
        // for, `u16` has no invalid bit patterns and an alignment that divides
        // `f32`'s, and the mutable borrow of `self` keeps it the only view.
        unsafe { std::slice::from_raw_parts_mut(self.buf.as_mut_ptr().cast::<u16>(), len) }
    }
}

impl std::ops::Deref for Pooled {
    type Target = [f32];
    fn deref(&self) -> &[f32] {
        &self.buf[..self.len]
    }
}

impl std::ops::DerefMut for Pooled {
    fn deref_mut(&mut self) -> &mut [f32] {
        &mut self.buf[..self.len]
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
