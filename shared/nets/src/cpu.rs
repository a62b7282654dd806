//! Process-wide CPU settings for fast training, applied from inside the process so
//! no user has to export environment variables.
//!
//! - the heap: every process that links this crate allocates through mimalloc
//!   ([`ALLOCATOR`]), and [`init_cpu_runtime`] tells it never to return freed memory
//!   to the OS (`mi_option_purge_delay` = −1), so an update's activations reuse the
//!   pages of the last update's instead of being page-faulted in anew. glibc's malloc
//!   could not do that for threads other than the main one: each allocates from its
//!   own arena of 64 MiB heaps, which glibc unmaps as soon as one is empty, and a
//!   larger block is `mmap`ed and unmapped on free (its mmap and trim thresholds and
//!   `M_MMAP_MAX` notwithstanding). With it, `dsac_update` case (a) (84², 100 MB
//!   activations on rayon's workers) took 2.9 M page faults and spent 20 % of its
//!   samples in them; one glibc arena for all threads fixed that but slowed the 42²
//!   cases (lock contention). Measured: docs/results/compute-xeon-amx/allocator/.
//! - rayon: one global pool with one worker per available core (the convolution
//!   kernel and candle's gemm both use it).
//! - candle's CPU matmul asks for its thread count on every call, and unless
//!   `RAYON_NUM_THREADS` is set it parses `/proc/cpuinfo` each time (measured: 30 %
//!   of an actor's cached policy step). We set the variable to the pool's size, which
//!   also makes candle split its gemms over exactly the pool's workers. Changing the
//!   environment is only sound while no other thread can read it, so this is done
//!   only when the process has a single thread (call this first thing in `main`).
//!
//! - candle's barrier pool: its workers spin 25,000 times after every element-wise
//!   operation before they sleep; on two cores that spinning took a core from the
//!   convolution kernels and the actors (≈ 11 % of the learner's samples in a real
//!   run). `CANDLE_BARRIER_POOL_SPIN_LIMIT` is set to [`BARRIER_SPIN_LIMIT`] unless
//!   the user set it; the spinning's share of the profile is gone with it, the update
//!   time of that run did not change measurably (80 ms either way).
//! - candle's barrier pool, its size: by default it has a worker per core beside
//!   rayon's, so on two cores each element-wise op of candle woke a second set of
//!   threads that competed with rayon's for the same cores (≈ 4 % futex wake-ups and
//!   ≈ 3 % barrier waits in the learner's profile). `CANDLE_NUM_THREADS` is set to
//!   [`CANDLE_THREADS`] unless the user set it: candle's element-wise ops then run on
//!   the calling thread (a rayon worker during an update) and the cores stay with the
//!   kernels. Measured in real runs of the default preset, alternating:
//!   docs/results/learner-real-run/README.md.
//! - subnormal floats are *not* flushed to zero: a pixel run's AdamW state holds many
//!   (16 % of its first moments after 120 k env steps), but setting MXCSR's FTZ and
//!   DAZ made no measurable difference to the update time, and changing the
//!   floating-point environment behind the compiler's back is not sound in Rust.
//! - kernels: the instruction-set path of the custom kernels ([`crate::ops::Isa`],
//!   `PEDNAV_ISA`) is resolved here, so a bad value stops the process at start-up
//!   with the message naming the variable rather than inside the first convolution.
//!
//! Invariant: [`init_cpu_runtime`] runs its body at most once per process.

use std::sync::OnceLock;

static INIT: OnceLock<usize> = OnceLock::new();

/// Spins of a candle barrier-pool worker before it sleeps (candle's default: 25,000).
pub const BARRIER_SPIN_LIMIT: u32 = 256;

/// Threads of candle's own element-wise pool (see the module docs).
pub const CANDLE_THREADS: usize = 1;

/// Apply the allocator and thread settings; returns the number of worker threads.
/// `threads = None` uses every available core. Later calls return the first result.
/// Call it at the start of `main`, before anything spawns a thread (see the module
/// docs for what is skipped otherwise).
pub fn init_cpu_runtime(threads: Option<usize>) -> usize {
    *INIT.get_or_init(|| {
        tune_allocator();
        let n = threads.unwrap_or_else(|| std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)).max(1);
        if process_threads() == Some(1) {
            // SAFETY: this is the process's only thread, so nothing reads or writes the
            // environment concurrently.
            unsafe {
                std::env::set_var("RAYON_NUM_THREADS", n.to_string());
                if std::env::var_os("CANDLE_BARRIER_POOL_SPIN_LIMIT").is_none() {
                    std::env::set_var("CANDLE_BARRIER_POOL_SPIN_LIMIT", BARRIER_SPIN_LIMIT.to_string());
                }
                if std::env::var_os("CANDLE_NUM_THREADS").is_none() {
                    std::env::set_var("CANDLE_NUM_THREADS", CANDLE_THREADS.to_string());
                }
            }
        } else {
            tracing::debug!("init_cpu_runtime after other threads started: RAYON_NUM_THREADS left unset");
        }
        let isa = crate::ops::Isa::active();
        // Resolved here so a bad PEDNAV_AMX stops the process before any work.
        let amx = crate::ops::conv::amx_available();
        tracing::info!(isa = isa.name(), amx, threads = n, "CPU kernels");
        // If something already built the global pool, keep it. Its workers get the
        // main thread's stack size: [`on_pool_worker`] runs whole updates there
        // (candle's backward pass walks the graph recursively).
        let _ = rayon::ThreadPoolBuilder::new().num_threads(n).stack_size(WORKER_STACK).build_global();
        rayon::current_num_threads()
    })
}

/// Stack of each worker of the global pool (a Linux main thread's default).
const WORKER_STACK: usize = 8 << 20;

/// Run `f` on a worker of rayon's global pool and wait for it (directly, when the
/// caller is a worker already).
///
/// Why: every parallel kernel called from outside the pool (the convolutions, gemm)
/// is injected into it while the caller sleeps until the job is done — two context
/// switches per call, dozens of calls per update; from a worker, the same kernels
/// split their work with `join` inside the pool and the caller works on its half.
/// Use it around work that calls many parallel kernels in a row (a learner update),
/// on the CPU only (a CUDA context is bound per thread). While `f` waits for its
/// kernels, its worker may run other jobs of the pool, so `f` must not hold a lock
/// that such jobs take (the learner's update holds none; its in-place optimiser ops
/// lock only the parameters no other thread uses).
pub fn on_pool_worker<R: Send>(f: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| f())
}

/// `a` and `b` side by side on rayon's pool where `parallel` (the CPU), one after
/// the other otherwise (a CUDA context is bound per thread); the results as `(a, b)`.
///
/// Why: much of a learner update is serial element-wise work between parallel
/// kernels; two independent parts of it joined this way let one part's serial work
/// run while the other waits, with each part's numbers unchanged (every op is
/// computed as in sequence; only which thread computes it differs). As with
/// [`on_pool_worker`], neither part may hold a lock that the pool's other jobs take:
/// a worker waiting for its half runs other jobs meanwhile.
pub fn join_if<A: Send, B: Send>(parallel: bool, a: impl FnOnce() -> A + Send, b: impl FnOnce() -> B + Send) -> (A, B) {
    if parallel { rayon::join(a, b) } else { (a(), b()) }
}

/// The Rust heap of every process that links this crate (see the module docs).
#[global_allocator]
pub static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// mimalloc's `mi_option_purge_delay` (its `mi_option_t` enum; `libmimalloc-sys`
/// names no constant for it). The test `allocator_keeps_freed_memory` checks that
/// this index holds the purge delay's default (1,000 ms in mimalloc v3) before it is set.
pub const MI_OPTION_PURGE_DELAY: libmimalloc_sys::mi_option_t = 15;

/// Never purge (unless the user set `MIMALLOC_PURGE_DELAY`, which mimalloc reads itself).
fn tune_allocator() {
    if std::env::var_os("MIMALLOC_PURGE_DELAY").is_none() {
        // SAFETY: mi_option_set only stores an option's value; mimalloc reads it on
        // every purge decision.
        unsafe { libmimalloc_sys::mi_option_set(MI_OPTION_PURGE_DELAY, -1) };
    }
}

/// Threads of this process (`/proc/self/status`), if the system says.
fn process_threads() -> Option<usize> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    status.lines().find_map(|l| l.strip_prefix("Threads:")).and_then(|v| v.trim().parse().ok())
}
