//! Helpers for pednav's tests: the end-to-end tests in `tests/tests/` drive the real
//! binaries as a user would ([`run`]), so they check what the README promises; the
//! fault tests of the learner and the curriculum service capture the warnings they
//! provoke ([`warnings`]) and damage the files they saved ([`damage`]).
//!
//! Invariant: [`binary`] returns an executable of the running test's profile that
//! is newer than every source file of its package.

#![warn(missing_docs)]

pub mod damage;
pub mod run;
pub mod warnings;

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::SystemTime;

/// Root of the workspace.
pub fn workspace_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).parent().expect("tests/ sits in the workspace root").to_path_buf()
}

/// `target/<profile>` of the running test (its executable lives in `target/<profile>/deps`).
fn profile_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test executable path");
    exe.parent().and_then(|d| d.parent()).expect("target/<profile>").to_path_buf()
}

/// Path to binary `bin` of the workspace package `package` living in `package_dir`
/// (relative to the workspace root), built with the profile of the running test.
///
/// `cargo test --workspace` already builds the binaries of packages that have
/// integration tests; that build is used when it is newer than the package's
/// `src/`, `Cargo.toml` and data (`scenes/`). Otherwise the binary is built here
/// (slower: a plain `cargo build` resolves features apart from the test build).
pub fn binary(package: &str, package_dir: &str, bin: &str) -> PathBuf {
    let profile_dir = profile_dir();
    let path = profile_dir.join(bin);
    let pkg = workspace_root().join(package_dir);
    let sources = ["src", "scenes", "Cargo.toml"].iter().map(|p| newest_mtime_of(&pkg.join(p))).max().unwrap();
    let built = std::fs::metadata(&path).and_then(|m| m.modified()).ok();
    if built.is_some_and(|b| b >= sources) {
        return path;
    }
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.args(["build", "-q", "-p", package, "--bin", bin]);
    if profile_dir.file_name().is_some_and(|n| n == "release") {
        cmd.arg("--release");
    }
    let status = cmd.status().expect("running cargo build for the binary under test");
    assert!(status.success(), "cargo build -p {package} --bin {bin} failed");
    assert!(path.exists(), "{} missing after build", path.display());
    path
}

/// Newest modification time of a file, or of any file below a directory.
fn newest_mtime_of(path: &Path) -> SystemTime {
    let own = std::fs::metadata(path).and_then(|m| m.modified()).unwrap_or(SystemTime::UNIX_EPOCH);
    match std::fs::read_dir(path) {
        Ok(entries) => entries.flatten().map(|e| newest_mtime_of(&e.path())).fold(own, SystemTime::max),
        Err(_) => own,
    }
}

/// A fresh, empty scratch directory under the target directory, named after the test.
pub fn scratch_dir(name: &str) -> PathBuf {
    let dir = profile_dir().join("e2e-scratch").join(name);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("create scratch dir");
    dir
}
