//! Finding a victim in `/proc` (a child of this soak's launcher, running the victim's
//! binary on exactly this run directory) and killing it through a pidfd, so that a pid
//! reused in between cannot be hit.

use super::*;

/// Whether `pid` in the /proc-like folder `proc_root` is `victim` of the run in
/// `run_dir`: a live child of `launcher` running the victim's binary with
/// `--run-dir run_dir` exactly (and `--actor K` for actor K, the subcommand `bridge`
/// for a bridge). The link is no process.
pub fn is_victim(proc_root: &Path, pid: u32, launcher: u32, run_dir: &Path, victim: Victim) -> bool {
    if !victim.is_process() {
        return false;
    }
    let dir = proc_root.join(pid.to_string());
    let (Ok(cmdline), Ok(status)) = (std::fs::read(dir.join("cmdline")), std::fs::read_to_string(dir.join("status")))
    else {
        return false;
    };
    let field = |name: &str| status.lines().find_map(|l| l.strip_prefix(name)?.strip_prefix(':').map(str::trim));
    if field("PPid").and_then(|p| p.parse::<u32>().ok()) != Some(launcher)
        || field("State").is_none_or(|s| s.starts_with('Z') || s.starts_with('X'))
    {
        return false;
    }
    let args: Vec<&[u8]> = cmdline.strip_suffix(&[0]).unwrap_or(&cmdline).split(|&b| b == 0).collect();
    let after = |flag: &str| args.iter().position(|a| *a == flag.as_bytes()).and_then(|i| args.get(i + 1).copied());
    let binary = args.first().and_then(|a| Path::new(OsStr::from_bytes(a)).file_name());
    binary == Some(OsStr::new(victim.binary()))
        && after("--run-dir") == Some(run_dir.as_os_str().as_bytes())
        && match victim {
            Victim::Actor(k) => after("--actor") == Some(k.to_string().as_bytes()),
            Victim::LearnerHostBridge | Victim::ActorHostBridge => args.get(1).copied() == Some(b"bridge".as_slice()),
            Victim::Learner | Victim::Curriculum | Victim::Link => true,
        }
}

/// The pid of `victim` in the run at `run_dir` supervised by `launcher`, from the
/// /proc-like folder `proc_root` ([`is_victim`]); `None` when there is none, or more
/// than one (nothing is killed on doubt).
pub fn find_victim(proc_root: &Path, launcher: u32, run_dir: &Path, victim: Victim) -> Option<u32> {
    let mut found = None;
    for entry in std::fs::read_dir(proc_root).ok()?.flatten() {
        let Some(pid) = entry.file_name().to_str().and_then(|s| s.parse::<u32>().ok()) else { continue };
        if is_victim(proc_root, pid, launcher, run_dir, victim) {
            if found.is_some() {
                return None;
            }
            found = Some(pid);
        }
    }
    found
}

/// SIGKILL `pid` through a pidfd, after `still_victim` confirmed (with the pidfd
/// open, so the pid cannot be reused in between) that it is still the victim.
pub(super) fn sigkill_verified(pid: u32, still_victim: impl Fn() -> bool) -> Result<()> {
    // SAFETY: pidfd_open(2) takes a pid and flags and returns a new descriptor or -1.
    let fd = unsafe { libc::syscall(libc::SYS_pidfd_open, pid as libc::pid_t, 0 as libc::c_uint) };
    if fd < 0 {
        bail!("pidfd_open({pid}): {}", std::io::Error::last_os_error());
    }
    // SAFETY: `fd` is a descriptor we own from here on.
    let fd = unsafe { OwnedFd::from_raw_fd(fd as libc::c_int) };
    if !still_victim() {
        bail!("pid {pid} is no longer the victim");
    }
    // SAFETY: pidfd_send_signal(2) on our pidfd, no siginfo, flags 0.
    let r = unsafe {
        libc::syscall(
            libc::SYS_pidfd_send_signal,
            std::os::fd::AsRawFd::as_raw_fd(&fd),
            libc::SIGKILL,
            std::ptr::null::<libc::siginfo_t>(),
            0 as libc::c_uint,
        )
    };
    if r < 0 {
        bail!("pidfd_send_signal({pid}, SIGKILL): {}", std::io::Error::last_os_error());
    }
    Ok(())
}
