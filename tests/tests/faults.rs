//! Faults from outside the program, with real processes started as a user starts
//! them: a full disk under a running training (on a small tmpfs this test mounts, as
//! root), and the cause of a process's death found whatever `RUST_BACKTRACE` says.
//! Only watchdogs — no timing assertions.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use pednav_runtime::stats::ProcessStatus;
use pednav_tests::run::{bin_dir, learner, run_local, stop, wait_for, wait_within};
use pednav_tests::{scratch_dir, workspace_root};

/// A tmpfs of `size` mounted at `dir` while it lives (unmounted, lazily, on drop).
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(dir: &Path, size: &str) -> Tmpfs {
        std::fs::create_dir_all(dir).unwrap();
        let out = Command::new("mount").args(["-t", "tmpfs", "-o", &format!("size={size}"), "tmpfs"]).arg(dir).output();
        let ok = out.as_ref().is_ok_and(|o| o.status.success());
        assert!(
            ok,
            "this test mounts a {size} tmpfs at {} to fill a disk for real; mount failed (root is needed): {out:?}",
            dir.display()
        );
        Tmpfs(dir.to_path_buf())
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg("-l").arg(&self.0).status();
    }
}

/// The update count of the checkpoint generation in `dir` (its state file's `updates`);
/// `None` while a save swaps the generations.
fn saved_updates(dir: &Path) -> Option<u64> {
    let text = std::fs::read_to_string(dir.join("state.json")).ok()?;
    let state: serde_json::Value = serde_json::from_str(&text).ok()?;
    state["updates"].as_u64()
}

/// Bytes used by the files under `dir`.
fn bytes_under(dir: &Path) -> u64 {
    std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| {
            let p = e.path();
            if p.is_dir() { bytes_under(&p) } else { e.metadata().map_or(0, |m| m.len()) }
        })
        .sum()
}

/// Free bytes of the filesystem holding `dir`.
fn free_bytes(dir: &Path) -> u64 {
    let out = Command::new("df").args(["-B1", "--output=avail"]).arg(dir).output().unwrap();
    String::from_utf8_lossy(&out.stdout).lines().nth(1).and_then(|l| l.trim().parse().ok()).unwrap()
}

/// Fill the disk of `dir` until `leave` bytes are free: a file of zeros, written in
/// chunks until the next one would not fit.
fn fill_leaving(dir: &Path, leave: u64) -> PathBuf {
    let path = dir.join("filler");
    let mut f = std::fs::File::create(&path).unwrap();
    let chunk = vec![0u8; 64 << 10];
    while free_bytes(dir) > leave + chunk.len() as u64 {
        if f.write_all(&chunk).and_then(|()| f.sync_data()).is_err() {
            break;
        }
    }
    path
}

fn log_of(run_dir: &Path, process: &str) -> String {
    std::fs::read_to_string(run_dir.join("logs").join(format!("{process}.log"))).unwrap_or_default()
}

/// The disk fills under a running training: the learner's checkpoint fails, the
/// learner says so (naming the full disk) and keeps training — no restart — and once
/// space is freed the next checkpoint succeeds; the run then stops with its final
/// checkpoint.
#[test]
fn a_full_disk_stops_the_checkpoints_not_the_training_and_freeing_space_resumes_them() {
    let root = scratch_dir("faults-disk-full");
    let disk = Tmpfs::mount(&root.join("disk"), "48m");
    let run_dir = disk.0.join("run");
    let config = workspace_root().join("deploy/configs/smoke.toml");
    let mut run = run_local(&run_dir, &["--config", config.to_str().unwrap()]);
    let ck = run_dir.join("checkpoints/learner");
    wait_for(&run_dir, "the first checkpoint", || ck.join("state.json").exists().then_some(()));
    let checkpoint = bytes_under(&ck);

    // Leave room for the logs, metrics and stats of a few minutes, not for a checkpoint.
    let filler = fill_leaving(&disk.0, (checkpoint / 3).max(160 << 10));
    let failed_at = wait_for(&run_dir, "the learner reporting a failed checkpoint", || {
        log_of(&run_dir, "learner").contains("checkpoint FAILED (disk full)").then(|| learner(&run_dir))?
    });
    wait_for(&run_dir, "training going on with the disk full", || {
        (learner(&run_dir)?.updates > failed_at.updates + 100).then_some(())
    });
    assert!(!run_dir.join("restarts.jsonl").exists(), "nothing was restarted: a full disk is no reason to");

    // The last good generation is what a restart loads: SIGKILL the learner while the
    // disk is still full; its replacement resumes from the checkpoint on disk (the
    // update count its state file names) and trains on.
    // Not in the middle of a failing save: its partial generation would hold the space
    // the replacement's stats need until its own first save clears it.
    let tmp = run_dir.join("checkpoints/learner.tmp");
    wait_for(&run_dir, "no save in progress", || (!tmp.exists()).then_some(()));
    let on_disk = saved_updates(&ck).expect("the last good checkpoint is on disk");
    let killed = learner(&run_dir).unwrap().pid as i32;
    // SAFETY: the pid is the learner process our run started.
    unsafe { libc::kill(killed, libc::SIGKILL) };
    // The replacement saves every 50 updates (smoke.toml) after the one it resumed from:
    // past 60 it has met the full disk itself.
    wait_for(&run_dir, "the replacement learner resuming from the last good checkpoint and updating", || {
        let l = learner(&run_dir)?;
        (l.pid as i32 != killed && l.resumed_from_update? == on_disk && l.updates > on_disk + 60).then_some(())
    });

    // Space freed: the next checkpoint reaches the disk, and the learner says so.
    std::fs::remove_file(&filler).unwrap();
    wait_for(&run_dir, "a checkpoint newer than the last good one on disk, and the learner saying so", || {
        (saved_updates(&ck)? > on_disk && log_of(&run_dir, "learner").contains("checkpoint written again"))
            .then_some(())
    });
    stop(&mut run, &run_dir);
    let last = learner(&run_dir).unwrap();
    assert_eq!(last.status, ProcessStatus::Stopped);
    let state = std::fs::read_to_string(ck.join("state.json")).unwrap();
    assert!(state.contains(&format!("\"updates\": {}", last.updates)), "the final checkpoint holds the last update");
}

/// A learner that cannot start (both checkpoint generations damaged) dies with the
/// same error again and again: the launcher backs off, gives up within its restart
/// budget, and its message names the cause — with `RUST_BACKTRACE=1`, which appends
/// a backtrace to every error, as without.
#[test]
fn the_cause_of_a_death_is_named_whatever_rust_backtrace_says() {
    let root = scratch_dir("faults-backtrace");
    let run_dir = root.join("run");
    let config = workspace_root().join("deploy/configs/smoke.toml");
    // A run with a checkpoint, then both of its generations damaged.
    let mut run = run_local(&run_dir, &["--config", config.to_str().unwrap()]);
    let ck = run_dir.join("checkpoints/learner");
    let prev = PathBuf::from(format!("{}.prev", ck.display()));
    wait_for(&run_dir, "two checkpoint generations", || prev.join("state.json").exists().then_some(()));
    stop(&mut run, &run_dir);
    for dir in [&ck, &prev] {
        std::fs::write(dir.join("policy.safetensors"), b"damaged").unwrap();
    }
    let stderr = root.join("launcher.log");
    let status = Command::new(workspace_root().join("deploy/run_local.sh"))
        .args(["--run-dir", run_dir.to_str().unwrap(), "--actors", "1"])
        .env("PEDNAV_SKIP_BUILD", "1")
        .env("PEDNAV_BIN_DIR", bin_dir())
        .env("RUST_BACKTRACE", "1")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(&stderr).unwrap())
        .spawn()
        .unwrap();
    let mut child = status;
    let exit = wait_within(&run_dir, "the launcher giving up on the learner", Duration::from_secs(400), || {
        child.try_wait().unwrap()
    });
    assert!(!exit.success(), "the run cannot go on without a loadable checkpoint");
    let text = std::fs::read_to_string(&stderr).unwrap();
    // Every restart line and the final message carry the cause; no backtrace frames.
    let restarts: Vec<&str> = text.lines().filter(|l| l.starts_with("pednav: learner exited")).collect();
    assert!(restarts.len() >= 2, "{text}");
    for line in &restarts {
        assert!(line.contains("policy.safetensors"), "the restart line names the damaged file: {line}");
    }
    assert!(text.contains("the same error 2 times in a row: restarting it from its last checkpoint in 2 s"), "{text}");
    let tail = &text[text.rfind("Error: the run stopped").expect("the launcher's final error")..];
    assert!(tail.contains("learner died 6 times") && tail.contains("policy.safetensors"), "{tail}");
    assert!(!tail.contains("Stack backtrace") && !tail.contains("std::rt::lang_start"), "no backtrace frames: {tail}");
    // The learner's records (an actor restarted meanwhile would add its own).
    let records: Vec<_> =
        pednav_runtime::RunDir::new(&run_dir).read_restarts().into_iter().filter(|r| r.process == "learner").collect();
    assert!(records.len() >= 5 && records.iter().all(|r| r.cause.contains("policy.safetensors")), "{records:?}");
}
