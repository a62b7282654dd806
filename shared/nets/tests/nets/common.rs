//! Run a test binary's tests again in a child process: under every other
//! instruction-set path this CPU supports, so the finite-difference and reference
//! checks cover the baseline, AVX2 and AVX-512 kernels on one machine (the kernels pick
//! their path once per process from `PEDNAV_ISA`, hence one child process per path),
//! or alone where a test needs a process of its own ([`run_self`]).

use std::process::Command;

use pednav_nets::ops::Isa;
use pednav_nets::ops::isa::ISA_ENV;

/// Set in the child processes so they do not start children of their own.
const CHILD: &str = "PEDNAV_ISA_RERUN";

/// Re-run this test binary (every test but `this_test`) with `PEDNAV_ISA` set to each
/// supported path other than the one this process uses; fail with the child's output
/// if any test fails there, or if a child ran no test at all.
pub fn rerun_on_every_other_isa(this_test: &str) {
    if std::env::var_os(CHILD).is_some() {
        return;
    }
    for isa in Isa::supported().into_iter().filter(|&i| i != Isa::active()) {
        let stdout = run_self(
            &["--skip", this_test, "--test-threads", "2"],
            &[(ISA_ENV, isa.name()), (CHILD, "1")],
            &[],
            &format!("with {ISA_ENV}={isa}"),
        );
        let passed = stdout
            .lines()
            .find_map(|l| l.strip_prefix("test result: ok. "))
            .and_then(|r| r.split(' ').next())
            .and_then(|n| n.parse::<usize>().ok())
            .unwrap_or(0);
        assert!(passed > 0, "no test ran with {ISA_ENV}={isa}:\n{stdout}");
        eprintln!("{ISA_ENV}={isa}: {passed} tests passed");
    }
}

/// Run this test binary again with `args`, the variables `set` set and `unset` removed;
/// fail with its output unless it succeeded (`what` says how it ran); its stdout.
pub fn run_self(args: &[&str], set: &[(&str, &str)], unset: &[&str], what: &str) -> String {
    let exe = std::env::current_exe().expect("the test binary's path");
    let mut command = Command::new(exe);
    command.args(args);
    for (name, value) in set {
        command.env(name, value);
    }
    for name in unset {
        command.env_remove(name);
    }
    let out = command.output().expect("start the test binary again");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(out.status.success(), "tests failed {what}:\n{stdout}\n{}", String::from_utf8_lossy(&out.stderr));
    stdout
}
