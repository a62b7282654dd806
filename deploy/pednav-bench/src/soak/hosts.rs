//! One host's launcher as the soak runs it (`pednav-run launch`, or across hosts also
//! `pednav-run join`): started with SIGINT as its death signal, its stderr copied into
//! the soak's log and file, and stopped with SIGINT at the end.

use super::*;

/// One host's launcher as the soak runs it: its run directory, its process, and the
/// thread that copies its stderr into the log (and `<soak>/soak-<host>.log`).
pub(super) struct HostRun {
    pub(super) host: Host,
    /// Its name in the soak's output: `launcher` on one host, else `learner host` or
    /// `actor host` (its stderr lines' prefix too).
    pub(super) name: &'static str,
    pub(super) dir: PathBuf,
    pub(super) launcher: std::process::Child,
    pub(super) pid: u32,
    pub(super) reader: std::thread::JoinHandle<()>,
}

impl HostRun {
    /// Start `pednav-run ARGS` for `host`; it gets SIGINT if the soak dies. Its
    /// stderr goes to `log_file` and, prefixed, to the soak's; on the learner host the
    /// progress line's restart count is kept.
    pub(super) fn start(
        host: Host,
        dir: &Path,
        launcher: &Path,
        args: &[String],
        log_file: &Path,
        prefix: &'static str,
        log: &Arc<Mutex<LauncherLog>>,
    ) -> Result<HostRun> {
        let mut cmd = Command::new(launcher);
        cmd.args(args).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::piped());
        // SAFETY: only async-signal-safe calls between fork and exec. The launcher stops
        // its run when this soak dies.
        unsafe {
            cmd.pre_exec(|| {
                libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGINT);
                Ok(())
            });
        }
        let mut child = cmd.spawn().with_context(|| format!("starting pednav-run {}", args[0]))?;
        let pid = child.id();
        let reader = {
            let (log, stderr) = (log.clone(), child.stderr.take().expect("piped"));
            let mut file = std::fs::File::create(log_file)?;
            std::thread::spawn(move || {
                for line in BufReader::new(stderr).lines().map_while(std::io::Result::ok) {
                    let _ = writeln!(file, "{line}");
                    if line.trim().is_empty() {
                        continue;
                    }
                    eprintln!("  {prefix} | {line}");
                    let mut l = log.lock().unwrap();
                    if host == Host::Learner
                        && line.starts_with('[')
                        && let Some(n) =
                            line.rsplit_once("restarts ").and_then(|(_, n)| n.split_whitespace().next()?.parse().ok())
                    {
                        l.progress_restarts = Some(n);
                    }
                    l.lines.push(line);
                }
            })
        };
        Ok(HostRun { host, name: prefix, dir: dir.to_path_buf(), launcher: child, pid, reader })
    }

    /// SIGINT (Ctrl-C) to the launcher and wait for it ([`STOP_WAIT`], then SIGKILL).
    pub(super) fn stop(&mut self, t: f64) -> Result<ExitStatus> {
        if let Some(s) = self.launcher.try_wait()? {
            return Ok(s);
        }
        eprintln!("soak: [{t:.1} s] stopping the {} (SIGINT, pid {})", self.name, self.pid);
        // SAFETY: signalling our own child.
        unsafe { libc::kill(self.pid as libc::pid_t, libc::SIGINT) };
        let waited = Instant::now();
        loop {
            if let Some(s) = self.launcher.try_wait()? {
                return Ok(s);
            }
            if waited.elapsed() > STOP_WAIT {
                eprintln!("soak: the {} did not stop within {STOP_WAIT:?}; killing it", self.name);
                let _ = self.launcher.kill();
                return Ok(self.launcher.wait()?);
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }
}
