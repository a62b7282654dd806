//! Checkpoints: safetensors weights per network, the optimisers' moments, and a
//! JSON state file (architecture, counters, temperature lives in `log_alpha`,
//! RNG state, rate-limiter counters, CRC-32 of every tensor file and, as its last
//! field, of the state file itself).
//!
//! Invariants: a checkpoint directory is written beside the target as
//! `<dir>.tmp`, synced and renamed into place, keeping the checkpoint it replaces as
//! the previous generation (`<dir>.prev`), so a crash at any point of a save leaves a
//! loadable checkpoint in one of the two (tests stop a save after each of its steps,
//! [`save_checkpoint_interrupted`]); loading verifies the format, the architecture,
//! every checksum and every tensor name and shape *before* changing anything, so an
//! incompatible or corrupted checkpoint returns an error and leaves the learner as it
//! was; a save followed by a load restores weights, moments, counters and RNG
//! bit-exactly.
//!
//! The replay contents are not saved (≈ 10 GB at paper scale): a resumed run
//! refills the replay and waits for the warm-up again before updating.

use std::collections::{BTreeMap, HashMap};
use std::fs;
use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use pednav_nets::{DsacNets, NetsConfig, ParamStore};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::dsac::Dsac;
use crate::error::{LearnerError, Result};
use crate::rate::RateLimiter;

/// Version of the on-disk layout: 2 adds the state file's own checksum (format 1 is
/// still read).
pub const FORMAT: u32 = 2;
const STATE_FILE: &str = "state.json";
const OPTIM_FILE: &str = "optimizer.safetensors";
/// Name of the temperature's store (and, with `.safetensors`, its file).
pub(crate) const LOG_ALPHA: &str = "log_alpha";

/// The state file of a checkpoint.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CheckpointMeta {
    /// Layout version ([`FORMAT`]).
    pub format: u32,
    /// The architecture the weights belong to.
    pub nets: NetsConfig,
    /// Whether the checkpoint holds the second critic of twin critics (absent in
    /// checkpoints written before the option existed: `false`).
    #[serde(default)]
    pub twin_critics: bool,
    /// Whether the checkpoint holds the state-prediction head and its optimiser
    /// (`dsac.state_aux_weight` > 0; absent in older checkpoints: `false`).
    #[serde(default)]
    pub state_head: bool,
    /// Updates applied.
    pub updates: u64,
    /// Updates skipped by the non-finite guard.
    pub skipped: u64,
    /// Steps of each optimiser.
    pub optimizer_steps: BTreeMap<String, u64>,
    /// The learner's RNG.
    pub rng: ChaCha8Rng,
    /// Replay-ratio counters, when the caller keeps them.
    pub limiter: Option<RateLimiter>,
    /// Free-form counters of the caller (e.g. the runtime's step counts).
    pub extra: serde_json::Value,
    /// CRC-32 of each tensor file.
    pub checksums: BTreeMap<String, u32>,
}

fn ck_err(path: &Path, message: impl Into<String>) -> LearnerError {
    LearnerError::Checkpoint { path: path.to_path_buf(), message: message.into() }
}

/// Every parameter store a checkpoint holds: the four networks and log α.
fn checkpoint_stores(dsac: &Dsac) -> Vec<ParamStore> {
    dsac.nets.stores().into_iter().chain([&dsac.log_alpha]).cloned().collect()
}

fn crc_of(path: &Path) -> Result<u32> {
    let bytes = fs::read(path).map_err(|e| ck_err(path, format!("cannot read: {e}")))?;
    Ok(crc32fast::hash(&bytes))
}

/// Where the generation before the newest checkpoint in `dir` is kept: `<dir>.prev`.
pub fn previous_generation(dir: &Path) -> PathBuf {
    PathBuf::from(format!("{}.prev", dir.display()))
}

/// Where a checkpoint is written before it is moved into place: `<dir>.tmp`.
fn partial_generation(dir: &Path) -> PathBuf {
    PathBuf::from(format!("{}.tmp", dir.display()))
}

/// Write a checkpoint of `dsac` (plus optional limiter counters and free-form
/// `extra`) to `dir`; the checkpoint that was there becomes the previous generation
/// ([`previous_generation`]), and the one before that is dropped.
///
/// Order: the new one is written completely beside the others (`<dir>.tmp`, every
/// file synced), then the previous generation is dropped file by file, the newest
/// becomes the previous, the new one the newest. An interruption at any point leaves
/// a loadable checkpoint in `dir` or in the previous generation
/// ([`load_checkpoint_or_previous`] finds it), and the next save clears what it left.
/// A newest checkpoint that fails its checksums is not kept as the previous
/// generation: it is replaced and the previous generation stays, so a resume that
/// fell back to the previous one keeps it until a good one replaces it.
pub fn save_checkpoint(
    dir: &Path,
    dsac: &mut Dsac,
    limiter: Option<RateLimiter>,
    extra: serde_json::Value,
) -> Result<()> {
    match save_steps(dir, dsac, limiter, extra, &mut Steps::new(None)) {
        Ok(()) => Ok(()),
        Err(Halt::Failed(e)) => Err(e),
        Err(Halt::Stopped) => unreachable!("a save without a stop point runs to the end"),
    }
}

/// What [`save_checkpoint_interrupted`] did before it stopped.
#[doc(hidden)]
#[derive(Debug, Clone)]
pub struct InterruptedSave {
    /// The filesystem steps done, in order.
    pub steps: Vec<String>,
    /// Whether the save ran to its end within the steps allowed.
    pub finished: bool,
}

/// Fault injection for the crash tests: [`save_checkpoint`] stopped after its first
/// `stop_after` filesystem steps (each a write-and-sync of one file, a removal, a
/// rename or a directory sync), leaving the files as a kill at that point would.
#[doc(hidden)]
pub fn save_checkpoint_interrupted(
    dir: &Path,
    dsac: &mut Dsac,
    limiter: Option<RateLimiter>,
    extra: serde_json::Value,
    stop_after: usize,
) -> Result<InterruptedSave> {
    let mut steps = Steps::new(Some(stop_after));
    let finished = match save_steps(dir, dsac, limiter, extra, &mut steps) {
        Ok(()) => true,
        Err(Halt::Stopped) => false,
        Err(Halt::Failed(e)) => return Err(e),
    };
    Ok(InterruptedSave { steps: steps.done, finished })
}

/// Why a save stopped early.
enum Halt {
    /// At the stop point of a simulated kill.
    Stopped,
    /// A step failed.
    Failed(LearnerError),
}

impl From<LearnerError> for Halt {
    fn from(e: LearnerError) -> Self {
        Halt::Failed(e)
    }
}

/// The filesystem steps of a save, done in order; with a stop point, the ones after
/// it are not done (a kill there).
struct Steps {
    stop_after: Option<usize>,
    done: Vec<String>,
}

impl Steps {
    fn new(stop_after: Option<usize>) -> Steps {
        Steps { stop_after, done: Vec::new() }
    }

    /// Do `step` (described by `what`) unless the stop point is reached.
    fn run<T>(&mut self, what: impl FnOnce() -> String, step: impl FnOnce() -> Result<T>) -> Result<T, Halt> {
        if self.stop_after.is_some_and(|n| self.done.len() >= n) {
            return Err(Halt::Stopped);
        }
        let out = step()?;
        if self.stop_after.is_some() {
            self.done.push(what());
        }
        Ok(out)
    }
}

/// Flush `path` (a file, or a directory's entries) to the disk.
fn sync_path(path: &Path) -> Result<()> {
    fs::File::open(path).and_then(|f| f.sync_all()).map_err(|e| ck_err(path, format!("cannot sync: {e}")))
}

/// Write `bytes` to `path` and flush it to the disk.
fn write_synced(path: &Path, bytes: &[u8]) -> Result<()> {
    use std::io::Write;
    let mut f = fs::File::create(path).map_err(|e| ck_err(path, format!("cannot create: {e}")))?;
    f.write_all(bytes).and_then(|()| f.sync_all()).map_err(|e| ck_err(path, format!("cannot write: {e}")))
}

/// Remove the checkpoint directory `dir` one file at a time, the state file first
/// (so a part-removed one is not taken for a checkpoint), then the directory.
fn remove_generation(dir: &Path, steps: &mut Steps) -> Result<(), Halt> {
    let mut entries: Vec<PathBuf> = fs::read_dir(dir)
        .map_err(|e| ck_err(dir, format!("cannot list: {e}")))?
        .map(|e| e.map(|e| e.path()))
        .collect::<std::io::Result<_>>()
        .map_err(|e| ck_err(dir, format!("cannot list: {e}")))?;
    entries.sort_by_key(|p| (p.file_name() != Some(std::ffi::OsStr::new(STATE_FILE)), p.clone()));
    for path in &entries {
        steps.run(
            || format!("remove {}", path.display()),
            || {
                if path.is_dir() { fs::remove_dir_all(path) } else { fs::remove_file(path) }
                    .map_err(|e| ck_err(path, format!("cannot remove: {e}")))
            },
        )?;
    }
    steps.run(
        || format!("remove {}", dir.display()),
        || fs::remove_dir(dir).map_err(|e| ck_err(dir, format!("cannot remove: {e}"))),
    )
}

fn save_steps(
    dir: &Path,
    dsac: &mut Dsac,
    limiter: Option<RateLimiter>,
    extra: serde_json::Value,
    steps: &mut Steps,
) -> Result<(), Halt> {
    let tmp = partial_generation(dir);
    if tmp.exists() {
        steps.run(
            || format!("remove the stale {}", tmp.display()),
            || {
                fs::remove_dir_all(&tmp)
                    .map_err(|e| ck_err(&tmp, format!("cannot remove a stale partial checkpoint: {e}")))
            },
        )?;
    }
    steps.run(
        || format!("create {}", tmp.display()),
        || fs::create_dir_all(&tmp).map_err(|e| ck_err(&tmp, format!("cannot create: {e}"))),
    )?;
    let mut checksums = BTreeMap::new();
    let stores = checkpoint_stores(dsac);
    for store in &stores {
        let file = format!("{}.safetensors", store.name());
        let path = tmp.join(&file);
        let crc = steps.run(
            || format!("write and sync {}", path.display()),
            || {
                candle_core::safetensors::save(&store.tensors(), &path).map_err(|e| ck_err(&path, e.to_string()))?;
                sync_path(&path)?;
                crc_of(&path)
            },
        )?;
        checksums.insert(file, crc);
    }
    let mut moments: HashMap<String, Tensor> = HashMap::new();
    let mut optimizer_steps = BTreeMap::new();
    for (name, opt) in dsac.optimizers() {
        optimizer_steps.insert(name.to_string(), opt.steps());
        for (k, t) in opt.state_tensors() {
            moments.insert(format!("{name}/{k}"), t);
        }
    }
    let path = tmp.join(OPTIM_FILE);
    let crc = steps.run(
        || format!("write and sync {}", path.display()),
        || {
            candle_core::safetensors::save(&moments, &path).map_err(|e| ck_err(&path, e.to_string()))?;
            sync_path(&path)?;
            crc_of(&path)
        },
    )?;
    checksums.insert(OPTIM_FILE.to_string(), crc);
    let meta = CheckpointMeta {
        format: FORMAT,
        nets: dsac.nets.cfg.clone(),
        twin_critics: dsac.nets.twin.is_some(),
        state_head: dsac.nets.state_head.is_some(),
        updates: dsac.updates,
        skipped: dsac.skipped,
        optimizer_steps,
        rng: dsac.rng.clone(),
        limiter,
        extra,
        checksums,
    };
    let path = tmp.join(STATE_FILE);
    let text = state_file_text(&meta).map_err(|e| ck_err(&path, e.to_string()))?;
    steps.run(|| format!("write and sync {}", path.display()), || write_synced(&path, text.as_bytes()))?;
    steps.run(|| format!("sync {}", tmp.display()), || sync_path(&tmp))?;
    // Rotate: drop the previous generation, newest → previous, new → newest. A newest
    // that is damaged is dropped instead, and the previous generation stays.
    let prev = previous_generation(dir);
    if dir.exists() {
        match verify_files(dir) {
            Ok(()) => {
                if prev.exists() {
                    remove_generation(&prev, steps)?;
                }
                steps.run(
                    || format!("rename {} to {}", dir.display(), prev.display()),
                    || {
                        fs::rename(dir, &prev)
                            .map_err(|e| ck_err(dir, format!("cannot keep the previous checkpoint: {e}")))
                    },
                )?;
            }
            Err(damaged) => {
                tracing::warn!(
                    damaged = %damaged,
                    kept = %prev.display(),
                    "the newest checkpoint is damaged: replacing it, the previous generation stays"
                );
                remove_generation(dir, steps)?;
            }
        }
    }
    steps.run(
        || format!("rename {} to {}", tmp.display(), dir.display()),
        || fs::rename(&tmp, dir).map_err(|e| ck_err(dir, format!("cannot move the new checkpoint into place: {e}"))),
    )?;
    if let Some(parent) = dir.parent().filter(|p| !p.as_os_str().is_empty()) {
        steps.run(|| format!("sync {}", parent.display()), || sync_path(parent))?;
    }
    Ok(())
}

/// Check the checkpoint in `dir` without loading it: its state file (and that
/// file's checksum) and the checksum of every file it lists.
fn verify_files(dir: &Path) -> Result<()> {
    let meta = read_meta(dir)?;
    for (file, want) in &meta.checksums {
        verify_file(&dir.join(file), *want)?;
    }
    Ok(())
}

/// Check that the file at `path` has the CRC-32 `want` the state file recorded for it.
fn verify_file(path: &Path, want: u32) -> Result<()> {
    let got = crc_of(path)?;
    if got != want {
        return Err(ck_err(
            path,
            format!("checksum mismatch (file {got:08x}, state file {want:08x}): the file is corrupted"),
        ));
    }
    Ok(())
}

/// [`load_checkpoint`] of the newest checkpoint in `dir`, or — when it is missing or
/// damaged (a file whose checksum does not match, an interrupted write) — of the
/// previous generation, with a warning naming the damaged file of the newest. Returns
/// the state file and the folder that was loaded; an error names both generations'
/// problems (each naming its file). `dsac` changes only when a load succeeds.
pub fn load_checkpoint_or_previous(dir: &Path, dsac: &mut Dsac) -> Result<(CheckpointMeta, PathBuf)> {
    let newest = match load_checkpoint(dir, dsac) {
        Ok(meta) => return Ok((meta, dir.to_path_buf())),
        Err(e) => e,
    };
    let prev = previous_generation(dir);
    match load_checkpoint(&prev, dsac) {
        Ok(meta) => {
            tracing::warn!(
                newest = %newest,
                loaded = %prev.display(),
                "the newest checkpoint cannot be loaded; resuming from the previous one"
            );
            Ok((meta, prev))
        }
        Err(previous) => Err(ck_err(
            dir,
            format!("neither the newest checkpoint ({newest}) nor the previous generation ({previous}) loads"),
        )),
    }
}

/// Whether `dir` or its previous generation holds a checkpoint (a state file) —
/// what a resume looks for.
pub fn checkpoint_exists(dir: &Path) -> bool {
    dir.join(STATE_FILE).is_file() || previous_generation(dir).join(STATE_FILE).is_file()
}

/// What precedes the state file's own checksum, its last field. The checksum covers
/// the file's bytes before it.
const STATE_CRC_FIELD: &str = ",\n  \"state_crc32\": ";

/// The text of the state file of `meta`: pretty JSON whose last field is the CRC-32
/// of the text before it (still plain JSON; readers ignore the field).
fn state_file_text(meta: &CheckpointMeta) -> serde_json::Result<String> {
    let json = serde_json::to_string_pretty(meta)?;
    let body = json.strip_suffix("\n}").expect("a pretty-printed JSON object ends with `\\n}`");
    let crc = crc32fast::hash(body.as_bytes());
    Ok(format!("{body}{STATE_CRC_FIELD}\"{crc:08x}\"\n}}\n"))
}

/// Read the state file of the checkpoint in `dir` without loading weights, verifying
/// its checksum (format 1, written before state files carried one, is read as it is).
pub fn read_meta(dir: &Path) -> Result<CheckpointMeta> {
    let path = dir.join(STATE_FILE);
    let bytes =
        fs::read(&path).map_err(|e| ck_err(&path, format!("cannot read ({e}); is this a checkpoint directory?")))?;
    let field = STATE_CRC_FIELD.as_bytes();
    let checked = match bytes.windows(field.len()).rposition(|w| w == field) {
        Some(at) => {
            let recorded = bytes[at + field.len()..].get(1..9);
            let want = recorded.and_then(|h| std::str::from_utf8(h).ok()).and_then(|h| u32::from_str_radix(h, 16).ok());
            let got = crc32fast::hash(&bytes[..at]);
            if want != Some(got) {
                return Err(ck_err(
                    &path,
                    format!("checksum mismatch (file {got:08x}, recorded {want:08x?}): the state file is corrupted"),
                ));
            }
            true
        }
        None => false,
    };
    let meta: CheckpointMeta =
        serde_json::from_slice(&bytes).map_err(|e| ck_err(&path, format!("corrupted state file: {e}")))?;
    if !(1..=FORMAT).contains(&meta.format) {
        return Err(ck_err(
            &path,
            format!("format {} is not supported (this build reads formats 1 to {FORMAT})", meta.format),
        ));
    }
    if meta.format >= 2 && !checked {
        return Err(ck_err(&path, "its checksum field is missing: the state file is corrupted"));
    }
    Ok(meta)
}

/// The tensors of `file` in the checkpoint `dir`, after checking its CRC-32 against
/// the state file.
fn read_verified(dir: &Path, meta: &CheckpointMeta, file: &str, dev: &Device) -> Result<HashMap<String, Tensor>> {
    let path = dir.join(file);
    let want = meta.checksums.get(file).ok_or_else(|| ck_err(&path, "not listed in the state file"))?;
    verify_file(&path, *want)?;
    candle_core::safetensors::load(&path, dev).map_err(|e| ck_err(&path, e.to_string()))
}

/// Load only what acting needs ([`DsacNets::acting_stores`]: the policy, plus the
/// quantile net that holds a shared encoder) into `nets` from the checkpoint in
/// `dir`, verifying the architecture and those files' checksums first; on any error
/// `nets` is unchanged. Reads a full checkpoint, or a results folder that keeps only
/// `state.json` and those files ([`acting_files`]).
pub fn load_acting(dir: &Path, nets: &DsacNets) -> Result<CheckpointMeta> {
    let meta = read_meta(dir)?;
    if meta.nets != nets.cfg {
        return Err(ck_err(
            dir,
            format!("it was written for networks {:?}, these networks are {:?}", meta.nets, nets.cfg),
        ));
    }
    load_stores(dir, &meta, &nets.acting_stores())?;
    Ok(meta)
}

/// Load `stores` from the checkpoint `dir` described by `meta`: every file is read
/// and checked (checksum, tensor names and shapes) before any store changes.
fn load_stores(dir: &Path, meta: &CheckpointMeta, stores: &[&ParamStore]) -> Result<()> {
    let Some(first) = stores.first() else { return Ok(()) };
    let dev = first.device().clone();
    let mut weights = Vec::new();
    for store in stores {
        let values = read_verified(dir, meta, &format!("{}.safetensors", store.name()), &dev)?;
        store.check(&values)?;
        weights.push(values);
    }
    for (store, values) in stores.iter().zip(&weights) {
        store.load(values)?;
    }
    Ok(())
}

/// A trained agent for analysis: the online networks of a checkpoint and its temperature.
pub struct TrainedAgent {
    /// Policy, fraction and quantile nets (and the twin critic's when the checkpoint
    /// has one), loaded; the target nets keep their initial weights.
    pub nets: DsacNets,
    /// The entropy temperature α = exp(log α) at the checkpoint.
    pub alpha: f64,
    /// The checkpoint's state file.
    pub meta: CheckpointMeta,
}

/// The online networks of the checkpoint in `dir` and its temperature, on `device`,
/// for analysis of what the critic and the encoders learned (e.g. `pednav-diagnose`):
/// the files [`agent_files`] names, checksums verified. The architecture comes from
/// the checkpoint's state file; a folder without those files (e.g. one that keeps
/// only [`acting_files`]) is refused naming the missing file.
pub fn load_agent(dir: &Path, device: &Device) -> Result<TrainedAgent> {
    let meta = read_meta(dir)?;
    let mut nets = DsacNets::new(&meta.nets, device, 0)?;
    if meta.twin_critics {
        nets = nets.with_twin_critic(0)?;
    }
    let mut log_alpha = ParamStore::new(LOG_ALPHA, device);
    log_alpha.insert(LOG_ALPHA, Tensor::zeros(1, candle_core::DType::F32, device)?)?;
    // The online networks only: the Polyak targets play no part in acting or in Q(s, a).
    let mut stores = nets.online_stores();
    stores.push(&log_alpha);
    load_stores(dir, &meta, &stores)?;
    let alpha = f64::from(log_alpha.tensors()["log_alpha"].to_vec1::<f32>()?[0]).exp();
    Ok(TrainedAgent { nets, alpha, meta })
}

/// The files of a checkpoint that [`load_acting`] reads for `nets`: the state file
/// and the acting networks' weights — what a results folder keeps of a run.
pub fn acting_files(nets: &DsacNets) -> Vec<String> {
    std::iter::once(STATE_FILE.to_string())
        .chain(nets.acting_stores().iter().map(|s| format!("{}.safetensors", s.name())))
        .collect()
}

/// The files of a checkpoint that [`load_agent`] reads: the state file, the online
/// networks' weights and the temperature — what a results folder keeps to be diagnosed.
pub fn agent_files(nets: &DsacNets) -> Vec<String> {
    std::iter::once(STATE_FILE.to_string())
        .chain(nets.online_stores().iter().map(|s| s.name()).chain([LOG_ALPHA]).map(|n| format!("{n}.safetensors")))
        .collect()
}

/// Restore `dsac` from the checkpoint in `dir`. Everything is verified first; on
/// any error `dsac` is unchanged.
pub fn load_checkpoint(dir: &Path, dsac: &mut Dsac) -> Result<CheckpointMeta> {
    let meta = read_meta(dir)?;
    if meta.nets != dsac.nets.cfg {
        return Err(ck_err(
            dir,
            format!("it was written for networks {:?}, the learner is configured with {:?}", meta.nets, dsac.nets.cfg),
        ));
    }
    let twin = dsac.nets.twin.is_some();
    if meta.twin_critics != twin {
        let (has, wants) = if meta.twin_critics { ("has a", "without") } else { ("has no", "with") };
        return Err(ck_err(
            dir,
            format!("it {has} twin critic and the learner is configured {wants} one (`dsac.twin_critics`)"),
        ));
    }
    if meta.state_head != dsac.nets.state_head.is_some() {
        let (has, wants) = if meta.state_head { ("has a", "0") } else { ("has no", "> 0") };
        return Err(ck_err(
            dir,
            format!(
                "it {has} state-prediction head and the learner is configured with `dsac.state_aux_weight` {wants}: \
                 resume with the setting the run was started with"
            ),
        ));
    }
    let dev = dsac.nets.policy.store.device().clone();
    let read = |file: &str| read_verified(dir, &meta, file, &dev);
    let stores = checkpoint_stores(dsac);
    let mut weights = Vec::new();
    for store in &stores {
        let values = read(&format!("{}.safetensors", store.name()))?;
        store.check(&values)?;
        weights.push(values);
    }
    let moments = read(OPTIM_FILE)?;
    // The optimisers this learner has (the twin critic's only with twin critics).
    let known: Vec<&'static str> = dsac.optimizers().iter().map(|(name, _)| *name).collect();
    let mut per_opt: BTreeMap<&str, HashMap<String, Tensor>> = BTreeMap::new();
    for (k, t) in moments {
        let (opt, key) =
            k.split_once('/').ok_or_else(|| ck_err(&dir.join(OPTIM_FILE), format!("bad moment name `{k}`")))?;
        let opt = known
            .iter()
            .copied()
            .find(|o| *o == opt)
            .ok_or_else(|| ck_err(&dir.join(OPTIM_FILE), format!("unknown optimiser `{opt}`")))?;
        per_opt.entry(opt).or_default().insert(key.to_string(), t);
    }
    let empty = HashMap::new();
    for (name, opt) in dsac.optimizers() {
        opt.check_state(per_opt.get(name).unwrap_or(&empty))?;
        if !meta.optimizer_steps.contains_key(name) {
            return Err(ck_err(dir, format!("optimiser `{name}` has no step count in the state file")));
        }
    }
    // Everything verified: apply.
    for (store, values) in stores.iter().zip(&weights) {
        store.load(values)?;
    }
    for (name, opt) in dsac.optimizers() {
        opt.load_state(meta.optimizer_steps[name], per_opt.get(name).unwrap_or(&empty))?;
    }
    dsac.updates = meta.updates;
    dsac.skipped = meta.skipped;
    dsac.rng = meta.rng.clone();
    Ok(meta)
}
