//! The saved state of the curriculum service ([`ServiceState`]): JSON followed by a
//! CRC-32 line, written beside its path and renamed into place, keeping the state it
//! replaces as the previous generation (`<name>.prev.json`).
//!
//! A save is a short list of filesystem steps (write and sync the new state beside
//! the newest, newest → previous, new → newest, sync the folder); a kill after any of
//! them leaves a state that loads at the path or in the previous generation
//! ([`ServiceState::load_or_previous`]). The crash tests stop a save after each step
//! ([`ServiceState::save_interrupted`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::curriculum::CurriculumState;
use crate::error::{CurriculumError, Result};

/// What the curriculum service saves (`checkpoints/curriculum.json` and the snapshots).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ServiceState {
    /// The curriculum itself.
    pub curriculum: CurriculumState,
    /// The next task id to hand out.
    pub next_task_id: u64,
    /// Tasks proposed per category name.
    pub proposed: BTreeMap<String, u64>,
    /// Decision steps of all reported episodes.
    #[serde(default)]
    pub decision_steps: u64,
}

/// What precedes the checksum of a saved state (after its JSON).
const CRC_TAG: &[u8] = b"\ncrc32 ";

/// What [`ServiceState::save_interrupted`] did before it stopped.
#[doc(hidden)]
#[derive(Debug, Clone)]
pub struct InterruptedSave {
    /// The filesystem steps done, in order.
    pub steps: Vec<String>,
    /// Whether the save ran to its end within the steps allowed.
    pub finished: bool,
}

/// Why a save stopped early: at the stop point of a simulated kill, or a failed step.
enum Halt {
    Stopped,
    Failed(CurriculumError),
}

/// The filesystem steps of a save, done in order; with a stop point, the ones after
/// it are not done (a kill there).
struct Steps {
    stop_after: Option<usize>,
    done: Vec<String>,
}

impl Steps {
    /// Do `step` (described by `what`) unless the stop point is reached.
    fn run(&mut self, what: impl FnOnce() -> String, step: impl FnOnce() -> std::io::Result<()>) -> Result<(), Halt> {
        if self.stop_after.is_some_and(|n| self.done.len() >= n) {
            return Err(Halt::Stopped);
        }
        let what = what();
        step().map_err(|e| Halt::Failed(CurriculumError::Report(format!("{what}: {e}"))))?;
        if self.stop_after.is_some() {
            self.done.push(what);
        }
        Ok(())
    }
}

impl ServiceState {
    /// Read a saved state, verifying its checksum line (a state written before states
    /// carried one is read as it is). Errors name the file.
    pub fn load(path: &Path) -> Result<ServiceState> {
        let bytes = Self::read_checked(path)?;
        serde_json::from_slice(json_part(&bytes))
            .map_err(|e| CurriculumError::Report(format!("{}: not a curriculum state: {e}", path.display())))
    }

    /// The bytes of the state at `path` after checking its checksum line, if it has one.
    fn read_checked(path: &Path) -> Result<Vec<u8>> {
        let bad = |m: String| CurriculumError::Report(format!("{}: {m}", path.display()));
        let bytes = std::fs::read(path).map_err(|e| bad(format!("cannot read: {e}")))?;
        if let Some(at) = crc_tag_at(&bytes) {
            let (json, line) = (&bytes[..at], &bytes[at + CRC_TAG.len()..]);
            let want = std::str::from_utf8(line).ok().and_then(|l| u32::from_str_radix(l.trim(), 16).ok());
            let got = crc32fast::hash(json);
            if want != Some(got) {
                return Err(bad(format!(
                    "checksum mismatch (file {got:08x}, recorded {want:08x?}): the file is damaged"
                )));
            }
        }
        Ok(bytes)
    }

    /// Whether the state at `path` is intact: its checksum line matches (a state
    /// without one must parse).
    fn verify(path: &Path) -> Result<()> {
        let bytes = Self::read_checked(path)?;
        if crc_tag_at(&bytes).is_none() {
            Self::load(path)?;
        }
        Ok(())
    }

    /// Write it with a CRC-32 line, atomically; the state that was at `path` becomes
    /// the previous generation ([`ServiceState::previous_generation`]) unless it is
    /// damaged (then it is replaced and the previous generation stays). An
    /// interruption at any point leaves a loadable state at `path` or in the previous
    /// generation.
    pub fn save(&self, path: &Path) -> Result<()> {
        match self.save_steps(path, &mut Steps { stop_after: None, done: Vec::new() }) {
            Ok(()) => Ok(()),
            Err(Halt::Failed(e)) => Err(e),
            Err(Halt::Stopped) => unreachable!("a save without a stop point runs to the end"),
        }
    }

    /// Fault injection for the crash tests: [`ServiceState::save`] stopped after its
    /// first `stop_after` filesystem steps, leaving the files as a kill there would.
    #[doc(hidden)]
    pub fn save_interrupted(&self, path: &Path, stop_after: usize) -> Result<InterruptedSave> {
        let mut steps = Steps { stop_after: Some(stop_after), done: Vec::new() };
        let finished = match self.save_steps(path, &mut steps) {
            Ok(()) => true,
            Err(Halt::Stopped) => false,
            Err(Halt::Failed(e)) => return Err(e),
        };
        Ok(InterruptedSave { steps: steps.done, finished })
    }

    fn save_steps(&self, path: &Path, steps: &mut Steps) -> Result<(), Halt> {
        use std::io::Write;
        let tmp = path.with_extension("json.tmp");
        let mut bytes = serde_json::to_vec(self).expect("state serialises");
        let crc = crc32fast::hash(&bytes);
        bytes.extend_from_slice(CRC_TAG);
        bytes.extend_from_slice(format!("{crc:08x}\n").as_bytes());
        steps.run(
            || format!("write and sync {}", tmp.display()),
            || {
                let mut f = std::fs::File::create(&tmp)?;
                f.write_all(&bytes)?;
                f.sync_all()
            },
        )?;
        if path.exists() {
            match Self::verify(path) {
                Ok(()) => {
                    let prev = Self::previous_generation(path);
                    steps.run(
                        || format!("rename {} to {}", path.display(), prev.display()),
                        || std::fs::rename(path, &prev),
                    )?;
                }
                Err(damaged) => tracing::warn!(
                    damaged = %damaged,
                    kept = %Self::previous_generation(path).display(),
                    "the newest curriculum state is damaged: replacing it, the previous generation stays"
                ),
            }
        }
        steps.run(|| format!("rename {} to {}", tmp.display(), path.display()), || std::fs::rename(&tmp, path))?;
        if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            steps.run(|| format!("sync {}", parent.display()), || std::fs::File::open(parent)?.sync_all())?;
        }
        Ok(())
    }

    /// Where the state before the newest one at `path` is kept (`<name>.prev.json`).
    pub fn previous_generation(path: &Path) -> PathBuf {
        path.with_extension("prev.json")
    }

    /// Whether `path` or its previous generation holds a state.
    pub fn exists(path: &Path) -> bool {
        path.exists() || Self::previous_generation(path).exists()
    }

    /// The newest state at `path`, or — when it is missing or damaged — the previous
    /// generation, with a warning naming the newest file and what is wrong with it;
    /// returns the file read. An error names both files and their problems.
    pub fn load_or_previous(path: &Path) -> Result<(ServiceState, PathBuf)> {
        let newest = match Self::load(path) {
            Ok(s) => return Ok((s, path.to_path_buf())),
            Err(e) => e,
        };
        let prev = Self::previous_generation(path);
        match Self::load(&prev) {
            Ok(s) => {
                tracing::warn!(newest = %newest, loaded = %prev.display(), "the newest curriculum state cannot be read; resuming from the previous one");
                Ok((s, prev))
            }
            Err(previous) => Err(CurriculumError::Report(format!(
                "neither the newest state ({newest}) nor the previous generation ({previous}) loads"
            ))),
        }
    }
}

/// Where the checksum line of a saved state starts, if it has one.
fn crc_tag_at(bytes: &[u8]) -> Option<usize> {
    bytes.windows(CRC_TAG.len()).rposition(|w| w == CRC_TAG)
}

/// The JSON of a saved state (without its checksum line).
fn json_part(bytes: &[u8]) -> &[u8] {
    crc_tag_at(bytes).map_or(bytes, |at| &bytes[..at])
}
