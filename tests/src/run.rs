//! Running pednav as a user does, for the end-to-end tests: `deploy/run_local.sh`
//! with the binaries of the running test's profile, the processes' stats files read
//! as the types their writers wrote ([`pednav_runtime::stats`]), and waits bounded by
//! a watchdog that prints the processes' logs when it fires (never a timing assertion).

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use pednav_runtime::RunDir;
use pednav_runtime::stats::{ActorStats, CurriculumStats, LearnerStats};

use crate::{binary, workspace_root};

/// How long a waited-for event may take before a test fails.
pub const WATCHDOG: Duration = Duration::from_secs(600);

/// The folder of the process binaries (built for the running test's profile).
pub fn bin_dir() -> PathBuf {
    let bins = [
        ("pednav-run", "deploy/pednav-run", "pednav-run"),
        ("pednav-actor", "actor", "pednav-actor"),
        ("pednav-learner", "learner", "pednav-learner"),
        ("pednav-curriculum", "curriculum-service", "pednav-curriculum"),
        ("pednav-bench", "deploy/pednav-bench", "pednav-bench"), // what `pednav-run bench` runs
    ];
    let paths: Vec<PathBuf> = bins.iter().map(|(p, d, b)| binary(p, d, b)).collect();
    paths[0].parent().unwrap().to_path_buf()
}

/// `deploy/run_local.sh` with one actor unless `extra` says `--actors`.
pub fn run_local(run_dir: &Path, extra: &[&str]) -> Child {
    let mut args = vec!["--run-dir", run_dir.to_str().unwrap()];
    if !extra.contains(&"--actors") {
        args.extend(["--actors", "1"]);
    }
    args.extend_from_slice(extra);
    Command::new(workspace_root().join("deploy/run_local.sh"))
        .args(&args)
        .env("PEDNAV_SKIP_BUILD", "1")
        .env("PEDNAV_BIN_DIR", bin_dir())
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(run_dir.with_extension(format!("launcher{}.log", extra.len()))).unwrap())
        .spawn()
        .expect("start deploy/run_local.sh")
}

/// A process's stats file, read as the type its writer wrote (`None` until it exists;
/// a file that does not parse as that type fails the test).
pub fn stats<T: serde::de::DeserializeOwned>(run_dir: &Path, name: &str) -> Option<T> {
    RunDir::new(run_dir).read_stats(name).unwrap_or_else(|e| panic!("{e}"))
}

/// The learner's stats.
pub fn learner(run_dir: &Path) -> Option<LearnerStats> {
    stats(run_dir, "learner")
}

/// An actor's stats (`actor-K.live` or `actor-K.I`).
pub fn actor(run_dir: &Path, name: &str) -> Option<ActorStats> {
    stats(run_dir, name)
}

/// The curriculum service's stats.
pub fn curriculum(run_dir: &Path) -> Option<CurriculumStats> {
    stats(run_dir, "curriculum")
}

/// Wait until `cond` holds, failing with `what` and the logs after the watchdog.
pub fn wait_for<T>(run_dir: &Path, what: &str, cond: impl FnMut() -> Option<T>) -> T {
    wait_within(run_dir, what, WATCHDOG, cond)
}

/// [`wait_for`] with its own watchdog.
pub fn wait_within<T>(run_dir: &Path, what: &str, watchdog: Duration, mut cond: impl FnMut() -> Option<T>) -> T {
    let start = Instant::now();
    loop {
        if let Some(v) = cond() {
            return v;
        }
        if start.elapsed() > watchdog {
            let mut logs = String::new();
            for name in ["learner", "curriculum", "actor-0"] {
                let text =
                    std::fs::read_to_string(run_dir.join("logs").join(format!("{name}.log"))).unwrap_or_default();
                let tail: Vec<&str> = text.lines().rev().take(15).collect();
                logs += &format!("\n--- {name}.log (last lines, newest first)\n{}", tail.join("\n"));
            }
            panic!("watchdog: {what} did not happen within {watchdog:?}{logs}");
        }
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// The pid of the running `binary` whose command line names `run_dir`.
pub fn pid_of(binary: &str, run_dir: &Path) -> Option<i32> {
    let dir = run_dir.to_str()?;
    std::fs::read_dir("/proc").ok()?.flatten().find_map(|e| {
        let pid: i32 = e.file_name().to_str()?.parse().ok()?;
        let cmdline = std::fs::read(e.path().join("cmdline")).ok()?;
        let args: Vec<String> = cmdline.split(|&b| b == 0).map(|a| String::from_utf8_lossy(a).into_owned()).collect();
        (args.first()?.ends_with(binary) && args.iter().any(|a| a == dir)).then_some(pid)
    })
}

/// SIGTERM the run (as Ctrl-C would) and wait for a clean exit.
pub fn stop(child: &mut Child, run_dir: &Path) {
    // SAFETY: signalling our own child.
    unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
    let status = wait_for(run_dir, "the run stopping after SIGTERM", || child.try_wait().unwrap());
    assert!(status.success(), "run_local.sh exited with {status} after SIGTERM");
}
