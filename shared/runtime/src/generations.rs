//! Two-generation atomic saves: the one rule by which the learner's checkpoint (a
//! folder of files) and the curriculum service's state (one file) reach the disk.
//!
//! A save is a short list of filesystem steps, run through [`SaveSteps`]: remove what
//! an earlier interrupted save left (`partial`); write the new generation completely
//! at `partial`, every file synced; then — when the newest generation verifies —
//! drop the previous generation and turn the newest into the previous one (a newest
//! that does not verify is dropped instead, and the previous one stays); move the new
//! generation into place; sync the parent folder.
//!
//! Invariants:
//! - at every step a loadable generation exists at `newest` or at `previous` (once
//!   one save has finished), so a kill anywhere loses at most the save in progress;
//! - the newest generation is replaced only by a complete, synced one, and becomes
//!   the previous one only when it verified;
//! - a step that fails (a full disk, a folder made read-only) ends the save with the
//!   step and its error and leaves the newest generation as it was before the save —
//!   when the failure came after the newest had become the previous one, that move is
//!   undone — or, when only the final sync of the folder failed, the new generation in
//!   place (it is whole; its durability is what the error reports). The previous
//!   generation may have been dropped already (it goes first). The partial new
//!   generation is removed so that it holds no space; the next save starts afresh.
//!
//! The crash and fault tests drive the same steps: [`SaveFault::KillAfter`] stops a
//! save as a kill would, [`SaveFault::FailAt`] makes one step fail with an I/O error.
//!
//! Files kept as one generation (the run's config, stats files, the host table, the
//! start counters) are replaced with [`write_atomic`], the one temporary-file-and-rename
//! write of the workspace: a reader sees the old file or the new one, never a part.

use std::fs;
use std::io;
use std::path::{Path, PathBuf};

/// The three paths of a two-generation save.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Generations {
    newest: PathBuf,
    previous: PathBuf,
    partial: PathBuf,
    /// A generation that is a folder: the file removed first when the folder is
    /// dropped, so a part-removed folder is never taken for a whole one.
    marker: Option<&'static str>,
}

impl Generations {
    /// Generations of a folder `dir`: `<dir>.prev` and, while a save runs, `<dir>.tmp`;
    /// `marker` is the file whose presence makes the folder a generation (its state file).
    pub fn folder(dir: &Path, marker: &'static str) -> Generations {
        Generations {
            newest: dir.to_path_buf(),
            previous: PathBuf::from(format!("{}.prev", dir.display())),
            partial: PathBuf::from(format!("{}.tmp", dir.display())),
            marker: Some(marker),
        }
    }

    /// Generations of a file `name.ext`: `name.prev.ext` and, while a save runs, `name.ext.tmp`.
    pub fn file(path: &Path) -> Generations {
        let ext = path.extension().map(|e| e.to_string_lossy().into_owned()).unwrap_or_default();
        let prev_ext = if ext.is_empty() { "prev".to_string() } else { format!("prev.{ext}") };
        let tmp_ext = if ext.is_empty() { "tmp".to_string() } else { format!("{ext}.tmp") };
        Generations {
            newest: path.to_path_buf(),
            previous: path.with_extension(prev_ext),
            partial: path.with_extension(tmp_ext),
            marker: None,
        }
    }

    /// Where the newest generation is.
    pub fn newest(&self) -> &Path {
        &self.newest
    }

    /// Where the generation before the newest is kept.
    pub fn previous(&self) -> &Path {
        &self.previous
    }

    /// Where a save writes the new generation before moving it into place.
    pub fn partial(&self) -> &Path {
        &self.partial
    }

    /// Whether either generation exists.
    pub fn exist(&self) -> bool {
        self.newest.exists() || self.previous.exists()
    }

    /// Save a new generation: `write` fills [`Generations::partial`] (a folder it
    /// creates, or the file) through `steps`; `verify` checks an existing newest
    /// generation (its error says what is damaged). See the module docs for the order.
    pub fn save(
        &self,
        steps: &mut SaveSteps,
        write: impl FnOnce(&Path, &mut SaveSteps) -> Result<(), Halt>,
        verify: impl FnOnce(&Path) -> Result<(), String>,
    ) -> Result<(), Halt> {
        let out = self.save_steps(steps, write, verify);
        if let Err(Halt::Failed { .. }) = &out {
            // Best effort. Undo a rotation the failure interrupted (the newest moved to
            // the previous place, the new one not moved in), then drop the partial
            // generation so that a failed save keeps no space.
            if !self.newest.exists() && self.previous.exists() && self.partial.exists() {
                let _ = fs::rename(&self.previous, &self.newest);
            }
            let _ =
                if self.partial.is_dir() { fs::remove_dir_all(&self.partial) } else { fs::remove_file(&self.partial) };
        }
        out
    }

    fn save_steps(
        &self,
        steps: &mut SaveSteps,
        write: impl FnOnce(&Path, &mut SaveSteps) -> Result<(), Halt>,
        verify: impl FnOnce(&Path) -> Result<(), String>,
    ) -> Result<(), Halt> {
        let partial = &self.partial;
        if partial.exists() {
            steps.run(
                || format!("remove the stale {}", partial.display()),
                || if partial.is_dir() { fs::remove_dir_all(partial) } else { fs::remove_file(partial) },
            )?;
        }
        write(partial, steps)?;
        if self.newest.exists() {
            match verify(&self.newest) {
                Ok(()) => {
                    if self.previous.exists() {
                        self.remove(&self.previous, steps)?;
                    }
                    steps.run(
                        || format!("rename {} to {}", self.newest.display(), self.previous.display()),
                        || fs::rename(&self.newest, &self.previous),
                    )?;
                }
                Err(damaged) => {
                    tracing::warn!(
                        damaged = %damaged,
                        kept = %self.previous.display(),
                        "the newest generation is damaged: replacing it, the previous generation stays"
                    );
                    self.remove(&self.newest, steps)?;
                }
            }
        }
        steps.run(
            || format!("rename {} to {}", partial.display(), self.newest.display()),
            || fs::rename(partial, &self.newest),
        )?;
        if let Some(parent) = self.newest.parent().filter(|p| !p.as_os_str().is_empty()) {
            steps.run(|| format!("sync {}", parent.display()), || sync_path(parent))?;
        }
        Ok(())
    }

    /// Remove a generation: a file, or a folder one file at a time (its marker
    /// first), then the folder.
    fn remove(&self, path: &Path, steps: &mut SaveSteps) -> Result<(), Halt> {
        if !path.is_dir() {
            return steps.run(|| format!("remove {}", path.display()), || fs::remove_file(path));
        }
        let mut entries: Vec<PathBuf> = fs::read_dir(path)
            .and_then(|d| d.map(|e| e.map(|e| e.path())).collect::<io::Result<_>>())
            .map_err(|error| Halt::Failed { step: format!("list {}", path.display()), error })?;
        let marker = self.marker.map(std::ffi::OsStr::new);
        entries.sort_by_key(|p| (marker.is_none() || p.file_name() != marker, p.clone()));
        for entry in &entries {
            steps.run(
                || format!("remove {}", entry.display()),
                || if entry.is_dir() { fs::remove_dir_all(entry) } else { fs::remove_file(entry) },
            )?;
        }
        steps.run(|| format!("remove {}", path.display()), || fs::remove_dir(path))
    }
}

/// A fault to put into a save (tests).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SaveFault {
    /// None: the save runs to its end or to a real failure.
    #[default]
    None,
    /// Stop before step `n` (0-based), leaving the files as a kill there would.
    KillAfter(usize),
    /// Step `n` (0-based) fails with an I/O error of this kind instead of running
    /// (e.g. [`io::ErrorKind::StorageFull`], what a full disk returns).
    FailAt(usize, io::ErrorKind),
}

/// Why a save ended early.
#[derive(Debug)]
pub enum Halt {
    /// At a [`SaveFault::KillAfter`] point.
    Killed,
    /// A step failed.
    Failed {
        /// The step, e.g. `write and sync runs/x/checkpoints/learner.tmp/optim.safetensors`.
        step: String,
        /// Its error.
        error: io::Error,
    },
}

impl Halt {
    /// `"<step>: <error>"` for a failed step.
    pub fn describe(&self) -> String {
        match self {
            Halt::Killed => "stopped at a simulated kill".into(),
            Halt::Failed { step, error } => format!("{step}: {error}"),
        }
    }
}

/// The filesystem steps of a save, run in order, with an optional [`SaveFault`].
#[derive(Debug, Default)]
pub struct SaveSteps {
    fault: SaveFault,
    done: Vec<String>,
}

impl SaveSteps {
    /// Steps with `fault` put in (`SaveFault::None` for a real save).
    pub fn new(fault: SaveFault) -> SaveSteps {
        SaveSteps { fault, done: Vec::new() }
    }

    /// Run `step` (described by `what`) unless the fault says otherwise.
    pub fn run<T>(&mut self, what: impl FnOnce() -> String, step: impl FnOnce() -> io::Result<T>) -> Result<T, Halt> {
        let n = self.done.len();
        let out = match self.fault {
            SaveFault::KillAfter(k) if n >= k => return Err(Halt::Killed),
            SaveFault::FailAt(k, kind) if n == k => Err(io::Error::from(kind)),
            _ => step(),
        };
        let what = what();
        match out {
            Ok(v) => {
                self.done.push(what);
                Ok(v)
            }
            Err(error) => Err(Halt::Failed { step: what, error }),
        }
    }

    /// The steps done so far, in order.
    pub fn done(&self) -> &[String] {
        &self.done
    }
}

/// What a save under a [`SaveFault`] did (tests).
#[derive(Debug, Clone)]
pub struct SaveReport {
    /// The filesystem steps done, in order.
    pub steps: Vec<String>,
    /// Whether the save ran to its end.
    pub finished: bool,
}

/// Flush `path` (a file, or a folder's entries) to the disk.
pub fn sync_path(path: &Path) -> io::Result<()> {
    fs::File::open(path)?.sync_all()
}

/// Write `bytes` to a new file at `path` and flush it to the disk.
pub fn write_synced(path: &Path, bytes: &[u8]) -> io::Result<()> {
    use std::io::Write;
    let mut f = fs::File::create(path)?;
    f.write_all(bytes)?;
    f.sync_all()
}

/// Replace the file at `path` with `bytes` in one step: written whole and synced to
/// `<path>.tmp`, renamed over `path`, then the folder synced. A reader sees the old file
/// or the new one, never a part; on failure the temporary file is removed (a full disk
/// is left no fuller) and the old file stays as it was.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    let tmp = PathBuf::from(tmp);
    if let Err(e) = write_synced(&tmp, bytes).and_then(|()| fs::rename(&tmp, path)) {
        let _ = fs::remove_file(&tmp);
        return Err(e);
    }
    match path.parent() {
        Some(folder) if !folder.as_os_str().is_empty() => sync_path(folder),
        _ => Ok(()),
    }
}

/// Attempts of a process's save at stop ([`final_save`]).
pub const FINAL_SAVE_ATTEMPTS: u32 = 3;

/// Pause between two attempts of a save at stop (space may be freed meanwhile).
pub const FINAL_SAVE_PAUSE: std::time::Duration = std::time::Duration::from_secs(2);

/// The one save-at-stop path of the processes (the learner's final checkpoint, the
/// curriculum service's final state): `save` tried [`FINAL_SAVE_ATTEMPTS`] times,
/// [`FINAL_SAVE_PAUSE`] apart, each failure but the last logged as `what`'s; the last
/// error comes back, for the process to end with it (the launcher shows the cause).
pub fn final_save<E: std::fmt::Display>(what: &str, mut save: impl FnMut() -> Result<(), E>) -> Result<(), E> {
    let mut attempt = 1;
    loop {
        match save() {
            Ok(()) => return Ok(()),
            Err(e) if attempt < FINAL_SAVE_ATTEMPTS => {
                tracing::warn!(
                    "{what} FAILED (attempt {attempt} of {FINAL_SAVE_ATTEMPTS}): {e}; trying again in {} s",
                    FINAL_SAVE_PAUSE.as_secs()
                );
                std::thread::sleep(FINAL_SAVE_PAUSE);
                attempt += 1;
            }
            Err(e) => return Err(e),
        }
    }
}

/// Is this the error of a full disk (or a full quota)?
pub fn is_disk_full(error: &io::Error) -> bool {
    matches!(error.kind(), io::ErrorKind::StorageFull | io::ErrorKind::QuotaExceeded)
        || error.raw_os_error().is_some_and(|c| c == libc::ENOSPC || c == libc::EDQUOT)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("pednav-generations-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        fs::create_dir_all(&d).unwrap();
        d
    }

    fn save_text(g: &Generations, text: &str, fault: SaveFault) -> Result<(), Halt> {
        let mut steps = SaveSteps::new(fault);
        g.save(
            &mut steps,
            |p, s| s.run(|| format!("write and sync {}", p.display()), || write_synced(p, text.as_bytes())),
            |p| fs::read_to_string(p).map(|_| ()).map_err(|e| e.to_string()),
        )
    }

    #[test]
    fn a_final_save_tries_three_times_and_returns_the_last_error() {
        let mut calls = 0;
        let ok = final_save("test state", || {
            calls += 1;
            if calls < 2 { Err(format!("failure {calls}")) } else { Ok(()) }
        });
        assert_eq!((ok, calls), (Ok(()), 2), "the second attempt saved");
        let mut calls = 0;
        let err = final_save("test state", || {
            calls += 1;
            Err::<(), _>(format!("failure {calls}"))
        });
        assert_eq!((err, calls), (Err("failure 3".to_string()), 3));
    }

    #[test]
    fn an_atomic_write_replaces_the_file_whole_or_leaves_it_as_it_was() {
        let d = scratch("atomic");
        let path = d.join("stats.json");
        write_atomic(&path, b"first").unwrap();
        write_atomic(&path, b"second, longer").unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), "second, longer");
        assert!(!d.join("stats.json.tmp").exists(), "no temporary file left");
        // The rename fails (a folder stands at the path): the error comes back, nothing is left behind.
        let blocked = d.join("blocked");
        fs::create_dir_all(blocked.join("inside")).unwrap();
        assert!(write_atomic(&blocked, b"x").is_err());
        assert!(blocked.join("inside").is_dir() && !d.join("blocked.tmp").exists());
        // The write fails (no such folder): the error, and no file anywhere.
        assert!(write_atomic(&d.join("missing/stats.json"), b"x").is_err());
        assert_eq!(fs::read_to_string(&path).unwrap(), "second, longer");
        let _ = fs::remove_dir_all(&d);
    }

    #[test]
    fn a_file_keeps_two_generations() {
        let d = scratch("file");
        let g = Generations::file(&d.join("state.json"));
        assert_eq!(g.previous(), d.join("state.prev.json"));
        assert_eq!(g.partial(), d.join("state.json.tmp"));
        for text in ["one", "two", "three"] {
            save_text(&g, text, SaveFault::None).unwrap();
        }
        assert_eq!(fs::read_to_string(g.newest()).unwrap(), "three");
        assert_eq!(fs::read_to_string(g.previous()).unwrap(), "two");
        assert!(!g.partial().exists());
        let _ = fs::remove_dir_all(&d);
    }

    #[test]
    fn a_failed_step_keeps_the_newest_generation_and_no_partial_one() {
        let d = scratch("fail");
        let g = Generations::file(&d.join("state.json"));
        save_text(&g, "one", SaveFault::None).unwrap();
        save_text(&g, "two", SaveFault::None).unwrap();
        // Every step of the next save (write, drop the previous, newest → previous,
        // new → newest, sync the folder), failing in turn with a full disk.
        let read = |p: &Path| fs::read_to_string(p).ok();
        for k in 0..5 {
            let Err(Halt::Failed { step, error }) =
                save_text(&g, "three", SaveFault::FailAt(k, io::ErrorKind::StorageFull))
            else {
                panic!("step {k}: the injected failure must fail the save");
            };
            assert!(is_disk_full(&error), "step {k}: {step}: {error}");
            assert!(!g.partial().exists(), "step {k}: the partial generation is removed");
            // Before the new generation is in place the newest stays what it was; a failed
            // sync of the folder after it leaves the new one in place.
            let want = if k < 4 { "two" } else { "three" };
            assert_eq!(read(g.newest()).as_deref(), Some(want), "step {k}: {step}");
            // The fault cleared, the next save succeeds.
            save_text(&g, "two", SaveFault::None).unwrap();
            assert_eq!(read(g.newest()).as_deref(), Some("two"));
        }
        save_text(&g, "four", SaveFault::None).unwrap();
        assert_eq!(fs::read_to_string(g.newest()).unwrap(), "four");
        let _ = fs::remove_dir_all(&d);
    }

    #[test]
    fn a_kill_at_any_step_leaves_a_loadable_generation() {
        let d = scratch("kill");
        let g = Generations::file(&d.join("state.json"));
        save_text(&g, "one", SaveFault::None).unwrap();
        save_text(&g, "two", SaveFault::None).unwrap();
        for k in 0..6 {
            let _ = save_text(&g, "three", SaveFault::KillAfter(k));
            let loads = |p: &Path| fs::read_to_string(p).ok().filter(|t| t == "two" || t == "three");
            assert!(loads(g.newest()).is_some() || loads(g.previous()).is_some(), "kill after {k} steps");
            save_text(&g, "two", SaveFault::None).unwrap();
        }
        let _ = fs::remove_dir_all(&d);
    }

    #[test]
    fn a_folder_generation_drops_its_marker_first() {
        let d = scratch("folder");
        let g = Generations::folder(&d.join("ck"), "state.json");
        let write = |p: &Path, s: &mut SaveSteps| -> Result<(), Halt> {
            s.run(|| "create".into(), || fs::create_dir_all(p))?;
            for f in ["a.bin", "state.json"] {
                s.run(|| format!("write {f}"), || write_synced(&p.join(f), b"x"))?;
            }
            Ok(())
        };
        for _ in 0..3 {
            g.save(&mut SaveSteps::new(SaveFault::None), write, |_| Ok(())).unwrap();
        }
        // The fourth save's first removal (dropping the previous generation) is its marker.
        let mut steps = SaveSteps::new(SaveFault::KillAfter(4));
        assert!(matches!(g.save(&mut steps, write, |_| Ok(())), Err(Halt::Killed)));
        let prev_marker = g.previous().join("state.json");
        assert_eq!(steps.done().last().unwrap(), &format!("remove {}", prev_marker.display()));
        assert!(!prev_marker.exists() && g.previous().join("a.bin").exists());
        let _ = fs::remove_dir_all(&d);
    }
}
