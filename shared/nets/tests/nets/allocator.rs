//! The heap keeps freed memory for reuse: `init_cpu_runtime` sets mimalloc's purge
//! delay to −1 (never purge), through an option index `libmimalloc-sys` does not name.

use pednav_nets::cpu::MI_OPTION_PURGE_DELAY;
use pednav_nets::init_cpu_runtime;

const CHILD: &str = "PEDNAV_ALLOCATOR_TEST_CHILD";
const THIS_TEST: &str = "allocator::allocator_keeps_freed_memory";

/// The index names the purge delay (its default in mimalloc v3, 1,000 ms, is there before
/// the runtime starts), and after `init_cpu_runtime` it holds −1. Run in a process of
/// its own: the other tests of this binary start the runtime.
#[test]
fn allocator_keeps_freed_memory() {
    if std::env::var_os(CHILD).is_none() {
        let stdout = crate::common::run_self(
            &["--exact", THIS_TEST, "--test-threads", "1"],
            &[(CHILD, "1")],
            &["MIMALLOC_PURGE_DELAY"],
            &format!("in {THIS_TEST}'s own process"),
        );
        assert!(stdout.contains("test result: ok. 1 passed"), "{THIS_TEST} did not run in its own process:\n{stdout}");
        return;
    }
    // SAFETY: mi_option_get only reads an option's value.
    let before = unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) };
    assert_eq!(
        before, 1000,
        "mimalloc option {MI_OPTION_PURGE_DELAY} is not the purge delay (default 1,000 ms): update MI_OPTION_PURGE_DELAY"
    );
    init_cpu_runtime(Some(1));
    // SAFETY: as above.
    let after = unsafe { libmimalloc_sys::mi_option_get(MI_OPTION_PURGE_DELAY) };
    assert_eq!(after, -1, "init_cpu_runtime did not turn mimalloc's purging off");
}
