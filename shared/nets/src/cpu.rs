//! Process-wide CPU settings for fast training, applied from inside the process so
//! no user has to export environment variables.
//!
//! - glibc malloc: by default large buffers are `mmap`ed and returned to the OS on
//!   free, so every training step pays page faults for its activations (measured
//!   2–2.6× slower, DESIGN §7). Raising the mmap and trim thresholds keeps them in the heap.
//! - rayon: one global pool with one worker per available core (the convolution
//!   kernel and candle's gemm both use it).
//! - candle's CPU matmul asks for its thread count on every call, and unless
//!   `RAYON_NUM_THREADS` is set it parses `/proc/cpuinfo` each time (measured: 30 %
//!   of an actor's cached policy step). We set the variable to the pool's size, which
//!   also makes candle split its gemms over exactly the pool's workers. Changing the
//!   environment is only sound while no other thread can read it, so this is done
//!   only when the process has a single thread (call this first thing in `main`).
//!
//! - kernels: the instruction-set path of the custom kernels ([`crate::ops::Isa`],
//!   `PEDNAV_ISA`) is resolved here, so a bad value stops the process at start-up
//!   with the message naming the variable rather than inside the first convolution.
//!
//! Invariant: [`init_cpu_runtime`] runs its body at most once per process.

use std::sync::OnceLock;

static INIT: OnceLock<usize> = OnceLock::new();

/// Apply the allocator and thread settings; returns the number of worker threads.
/// `threads = None` uses every available core. Later calls return the first result.
/// Call it at the start of `main`, before anything spawns a thread (see the module
/// docs for what is skipped otherwise).
pub fn init_cpu_runtime(threads: Option<usize>) -> usize {
    *INIT.get_or_init(|| {
        tune_malloc();
        let n = threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)).max(1);
        if process_threads() == Some(1) {
            // Safety: this is the process's only thread, so nothing reads or writes the
            // environment concurrently.
            unsafe { std::env::set_var("RAYON_NUM_THREADS", n.to_string()) };
        } else {
            tracing::debug!("init_cpu_runtime after other threads started: RAYON_NUM_THREADS left unset");
        }
        let isa = crate::ops::Isa::active();
        tracing::info!(isa = isa.name(), threads = n, "CPU kernels");
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

/// Threads of this process (`/proc/self/status`), if the system says.
fn process_threads() -> Option<usize> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status.lines().find_map(|l| l.strip_prefix("Threads:")).and_then(|v| v.trim().parse().ok())
}
