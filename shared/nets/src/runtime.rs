//! Process-wide CPU settings for fast training, applied from inside the process so
//! no user has to export environment variables.
//!
//! - glibc malloc: by default large buffers are `mmap`ed and returned to the OS on
//!   free, so every training step pays page faults for its activations (measured
//!   2–2.6× slower, DESIGN §7). Raising the mmap and trim thresholds keeps them in the heap.
//! - rayon: one global pool with one worker per available core (the convolution
//!   kernel and candle's gemm both use it).
//!
//! Invariant: [`init_cpu_runtime`] runs its body at most once per process.

use std::sync::OnceLock;

static INIT: OnceLock<usize> = OnceLock::new();

/// Apply the allocator and thread settings; returns the number of worker threads.
/// `threads = None` uses every available core. Later calls return the first result.
pub fn init_cpu_runtime(threads: Option<usize>) -> usize {
    *INIT.get_or_init(|| {
        tune_malloc();
        let n = threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)).max(1);
        // If something already built the global pool, keep it.
        let _ = rayon::ThreadPoolBuilder::new().num_threads(n).build_global();
        rayon::current_num_threads()
    })
}

#[cfg(target_env = "gnu")]
fn tune_malloc() {
    // Keep buffers up to 1 GiB in the heap and never trim it back eagerly.
    const MMAP_THRESHOLD: libc::c_int = 1 << 30;
    // Safety: mallopt only changes allocator tuning parameters.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD);
        libc::mallopt(libc::M_TRIM_THRESHOLD, MMAP_THRESHOLD);
    }
}

#[cfg(not(target_env = "gnu"))]
fn tune_malloc() {}
