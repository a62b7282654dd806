//! The saved state of the curriculum service ([`ServiceState`]): JSON followed by a
//! CRC-32 line, written beside its path and renamed into place, keeping the state it
//! replaces as the previous generation (`<name>.prev.json`).
//!
//! A save is the two-generation save of [`pednav_runtime::generations`] (write and
//! sync the new state beside the newest, newest → previous, new → newest, sync the
//! folder); a kill after any of its steps leaves a state that loads at the path or in
//! the previous generation ([`ServiceState::load_or_previous`]), and a failed step (a
//! full disk) leaves both as they were. The crash tests stop a save after each step
//! ([`ServiceState::save_interrupted`]).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use pednav_runtime::generations::{Generations, Halt, SaveFault, SaveReport, SaveSteps, write_synced};
use pednav_runtime::reports::ReportCursors;

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
    /// Which episode reports of every actor the curriculum holds (saved with it, so a
    /// restored service takes again exactly the reports its state lacks; a state
    /// written before reports were acknowledged has none).
    #[serde(default)]
    pub report_cursors: ReportCursors,
}

/// What precedes the checksum of a saved state (after its JSON).
const CRC_TAG: &[u8] = b"\ncrc32 ";

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
    /// damaged (then it is replaced and the previous generation stays) — the
    /// two-generation save of [`pednav_runtime::generations`]. A kill at any point
    /// leaves a loadable state at `path` or in the previous generation; a failed write
    /// (a full disk) returns its error and leaves both as they were.
    pub fn save(&self, path: &Path) -> Result<()> {
        self.save_with_fault(path, SaveFault::None).map(|_| ())
    }

    /// Fault injection for the crash tests: [`ServiceState::save`] stopped after its
    /// first `stop_after` filesystem steps, leaving the files as a kill there would.
    #[doc(hidden)]
    pub fn save_interrupted(&self, path: &Path, stop_after: usize) -> Result<SaveReport> {
        self.save_with_fault(path, SaveFault::KillAfter(stop_after))
    }

    /// [`ServiceState::save`] with a fault put in (tests): a simulated kill ends it
    /// early (`finished: false`), an injected I/O error fails it as a real one would.
    #[doc(hidden)]
    pub fn save_with_fault(&self, path: &Path, fault: SaveFault) -> Result<SaveReport> {
        let mut bytes = serde_json::to_vec(self).expect("state serialises");
        let crc = crc32fast::hash(&bytes);
        bytes.extend_from_slice(CRC_TAG);
        bytes.extend_from_slice(format!("{crc:08x}\n").as_bytes());
        let mut steps = SaveSteps::new(fault);
        let finished = match Generations::file(path).save(
            &mut steps,
            |tmp, steps| steps.run(|| format!("write and sync {}", tmp.display()), || write_synced(tmp, &bytes)),
            |newest| Self::verify(newest).map_err(|e| e.to_string()),
        ) {
            Ok(()) => true,
            Err(Halt::Killed) => false,
            Err(halt @ Halt::Failed { .. }) => {
                return Err(CurriculumError::StateSave { path: path.to_path_buf(), halt });
            }
        };
        Ok(SaveReport { steps: steps.done().to_vec(), finished })
    }

    /// Where the state before the newest one at `path` is kept (`<name>.prev.json`).
    pub fn previous_generation(path: &Path) -> PathBuf {
        Generations::file(path).previous().to_path_buf()
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
