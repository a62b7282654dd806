//! Helpers for pednav's end-to-end tests: they drive the real binaries as a user
//! would, so the tests in `tests/tests/` check what the README promises.
//!
//! Invariant: [`binary`] returns an up-to-date executable of the same profile
//! as the running test, building it through cargo if needed.

use std::path::PathBuf;
use std::process::Command;

/// Path to an up-to-date binary `bin` of workspace package `package`, built with the
/// profile of the running test (release or dev).
pub fn binary(package: &str, bin: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    // target/<profile>/deps/<test-exe>
    let profile_dir = exe.parent().and_then(|d| d.parent()).expect("target/<profile>").to_path_buf();
    let release = profile_dir.file_name().is_some_and(|n| n == "release");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.args(["build", "-q", "-p", package, "--bin", bin]);
    if release {
        cmd.arg("--release");
    }
    let status = cmd.status().expect("running cargo build for the binary under test");
    assert!(status.success(), "cargo build -p {package} --bin {bin} failed");
    let path = profile_dir.join(bin);
    assert!(path.exists(), "{} missing after build", path.display());
    path
}

/// A fresh, empty scratch directory under the target directory, named after the test.
pub fn scratch_dir(name: &str) -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    let dir = exe.parent().and_then(|d| d.parent()).expect("target/<profile>").join("e2e-scratch").join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("create scratch dir");
    dir
}
