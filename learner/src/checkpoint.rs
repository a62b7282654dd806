//! Checkpoints: safetensors weights per network, the optimisers' moments, and a
//! JSON state file (architecture, counters, temperature lives in `log_alpha`,
//! RNG state, rate-limiter counters, CRC-32 of every tensor file and, as its last
//! field, of the state file itself).
//!
//! Invariants: a checkpoint directory is written beside the target as
//! `<dir>.tmp`, synced and renamed into place, keeping the checkpoint it replaces as
//! the previous generation (`<dir>.prev`) — the two-generation save of
//! [`pednav_runtime::generations`] — so a crash or a failed write (a full disk) at
//! any point of a save leaves a loadable checkpoint in one of the two (tests stop a
//! save after each of its steps, [`save_checkpoint_interrupted`], and fail each of
//! them, [`save_checkpoint_with_fault`]); loading verifies the format, the architecture,
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
use pednav_nets::{DsacNets, NetParts, NetsConfig, ParamStore};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use pednav_runtime::generations::{Generations, Halt, SaveFault, SaveReport, SaveSteps, sync_path, write_synced};

use crate::dsac::{Dsac, LOG_ALPHA};
use crate::error::{LearnerError, Result};
use crate::rate::RateLimiter;

/// Version of the on-disk layout: 2 adds the state file's own checksum (format 1 is
/// still read).
pub const FORMAT: u32 = 2;
const STATE_FILE: &str = "state.json";
const OPTIM_FILE: &str = "optimizer.safetensors";

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
    /// Whether the checkpoint holds the contrastive head and its optimiser
    /// (`dsac.contrast_weight` > 0; absent in older checkpoints: `false`).
    #[serde(default)]
    pub contrast_head: bool,
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

/// The generations of the checkpoint in `dir`: `dir`, `<dir>.prev` and, while a save
/// runs, `<dir>.tmp` (the rule they follow: [`pednav_runtime::generations`]).
fn generations(dir: &Path) -> Generations {
    Generations::folder(dir, STATE_FILE)
}

/// Where the generation before the newest checkpoint in `dir` is kept: `<dir>.prev`.
pub fn previous_generation(dir: &Path) -> PathBuf {
    generations(dir).previous().to_path_buf()
}

/// Write a checkpoint of `dsac` (plus optional limiter counters and free-form
/// `extra`) to `dir`; the checkpoint that was there becomes the previous generation
/// ([`previous_generation`]), and the one before that is dropped — the two-generation
/// save of [`pednav_runtime::generations`]: the new one is written completely beside
/// the others (`<dir>.tmp`, every file synced), then the previous generation is
/// dropped file by file, the newest becomes the previous, the new one the newest. A
/// kill at any point leaves a loadable checkpoint in `dir` or in the previous
/// generation ([`load_checkpoint_or_previous`] finds it); a failed step (a full disk)
/// returns its error naming the file and leaves both generations as they were, so
/// the caller can keep training and try again later. A newest checkpoint that fails
/// its checksums is not kept as the previous generation: it is replaced and the
/// previous generation stays, so a resume that fell back to the previous one keeps
/// it until a good one replaces it.
pub fn save_checkpoint(
    dir: &Path,
    dsac: &mut Dsac,
    limiter: Option<RateLimiter>,
    extra: serde_json::Value,
) -> Result<()> {
    save_checkpoint_with_fault(dir, dsac, limiter, extra, SaveFault::None).map(|_| ())
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
) -> Result<SaveReport> {
    save_checkpoint_with_fault(dir, dsac, limiter, extra, SaveFault::KillAfter(stop_after))
}

/// [`save_checkpoint`] with a fault put in (tests): a simulated kill ends it early
/// (`finished: false`), an injected I/O error fails it as a real one would.
#[doc(hidden)]
pub fn save_checkpoint_with_fault(
    dir: &Path,
    dsac: &mut Dsac,
    limiter: Option<RateLimiter>,
    extra: serde_json::Value,
    fault: SaveFault,
) -> Result<SaveReport> {
    let mut steps = SaveSteps::new(fault);
    let finished = match generations(dir).save(
        &mut steps,
        |tmp, steps| write_generation(tmp, dsac, limiter, extra, steps),
        |newest| verify_files(newest).map_err(|e| e.to_string()),
    ) {
        Ok(()) => true,
        Err(Halt::Killed) => false,
        Err(halt @ Halt::Failed { .. }) => return Err(LearnerError::CheckpointSave { dir: dir.to_path_buf(), halt }),
    };
    Ok(SaveReport { steps: steps.done().to_vec(), finished })
}

/// The bytes of a safetensors file of `tensors`.
fn safetensors_bytes(tensors: &HashMap<String, Tensor>, path: &Path) -> std::io::Result<Vec<u8>> {
    safetensors::tensor::serialize(tensors.iter().map(|(k, v)| (k.as_str(), v)), None)
        .map_err(|e| std::io::Error::other(format!("{}: cannot serialise: {e}", path.display())))
}

/// Write every file of a checkpoint of `dsac` into the new folder `tmp`, each synced,
/// the state file (with every other file's CRC-32) last, then sync the folder.
fn write_generation(
    tmp: &Path,
    dsac: &mut Dsac,
    limiter: Option<RateLimiter>,
    extra: serde_json::Value,
    steps: &mut SaveSteps,
) -> std::result::Result<(), Halt> {
    steps.run(|| format!("create {}", tmp.display()), || fs::create_dir_all(tmp))?;
    let mut checksums = BTreeMap::new();
    let mut write_tensors = |file: String, tensors: &HashMap<String, Tensor>, steps: &mut SaveSteps| {
        let path = tmp.join(&file);
        let crc = steps.run(
            || format!("write and sync {}", path.display()),
            || {
                let bytes = safetensors_bytes(tensors, &path)?;
                write_synced(&path, &bytes)?;
                Ok(crc32fast::hash(&bytes))
            },
        )?;
        checksums.insert(file, crc);
        Ok::<(), Halt>(())
    };
    for store in &checkpoint_stores(dsac) {
        write_tensors(format!("{}.safetensors", store.name()), &store.tensors(), steps)?;
    }
    let mut moments: HashMap<String, Tensor> = HashMap::new();
    let mut optimizer_steps = BTreeMap::new();
    for (name, opt) in dsac.optimizers() {
        optimizer_steps.insert(name.to_string(), opt.steps());
        for (k, t) in opt.state_tensors() {
            moments.insert(format!("{name}/{k}"), t);
        }
    }
    write_tensors(OPTIM_FILE.to_string(), &moments, steps)?;
    let parts = dsac.nets.parts();
    let meta = CheckpointMeta {
        format: FORMAT,
        nets: dsac.nets.cfg.clone(),
        twin_critics: parts.twin_critic,
        state_head: parts.state_head,
        contrast_head: parts.contrast_head,
        updates: dsac.updates,
        skipped: dsac.skipped,
        optimizer_steps,
        rng: dsac.rng.clone(),
        limiter,
        extra,
        checksums,
    };
    let path = tmp.join(STATE_FILE);
    steps.run(
        || format!("write and sync {}", path.display()),
        || {
            let text = state_file_text(&meta).map_err(std::io::Error::other)?;
            write_synced(&path, text.as_bytes())
        },
    )?;
    steps.run(|| format!("sync {}", tmp.display()), || sync_path(tmp))
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
    if !meta.nets.same_architecture(&nets.cfg) {
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
    // Q(s, a) needs the critics only: the auxiliary heads stay on disk.
    let parts = NetParts { twin_critic: meta.twin_critics, ..NetParts::default() };
    let nets = DsacNets::with_parts(&meta.nets, parts, device, 0)?;
    let mut log_alpha = ParamStore::new(LOG_ALPHA, device);
    log_alpha.insert(LOG_ALPHA, Tensor::zeros(1, candle_core::DType::F32, device)?)?;
    // The online networks only: the Polyak targets play no part in acting or in Q(s, a).
    let mut stores = nets.online_stores();
    stores.push(&log_alpha);
    load_stores(dir, &meta, &stores)?;
    let alpha = f64::from(log_alpha.tensors()["log_alpha"].to_vec1::<f32>()?[0]).exp();
    Ok(TrainedAgent { nets, alpha, meta })
}

/// Start `dsac` from the online networks and temperature of the checkpoint in `dir` —
/// a run's checkpoint or a results folder that keeps [`agent_files`] — for a new run
/// (`dsac.init_from`: a warm start). The architecture, the twin critic and every file
/// read are verified before anything changes; the Polyak targets then become copies of
/// the loaded critics. The optimisers' moments, the counters, the RNG and the auxiliary
/// heads keep their fresh state: a warm start is a new run whose networks begin where
/// another's ended, not a resume. On any error `dsac` is unchanged.
pub fn warm_start(dir: &Path, dsac: &mut Dsac) -> Result<CheckpointMeta> {
    let meta = read_meta(dir)?;
    if !meta.nets.same_architecture(&dsac.nets.cfg) {
        return Err(ck_err(
            dir,
            format!("it holds networks {:?}, this run's are {:?} (`[nets]`)", meta.nets, dsac.nets.cfg),
        ));
    }
    if meta.twin_critics != dsac.nets.parts().twin_critic {
        let (has, wants) = if meta.twin_critics { ("has a", "without") } else { ("has no", "with") };
        return Err(ck_err(
            dir,
            format!("it {has} twin critic and this run is configured {wants} one (`dsac.twin_critics`)"),
        ));
    }
    let mut stores = dsac.nets.online_stores();
    stores.push(&dsac.log_alpha);
    load_stores(dir, &meta, &stores)?;
    dsac.nets.target.store.copy_from(&dsac.nets.quantile.store)?;
    if let Some(twin) = &dsac.nets.twin {
        twin.target.store.copy_from(&twin.quantile.store)?;
    }
    Ok(meta)
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
    if !meta.nets.same_architecture(&dsac.nets.cfg) {
        return Err(ck_err(
            dir,
            format!("it was written for networks {:?}, the learner is configured with {:?}", meta.nets, dsac.nets.cfg),
        ));
    }
    let parts = dsac.nets.parts();
    if meta.twin_critics != parts.twin_critic {
        let (has, wants) = if meta.twin_critics { ("has a", "without") } else { ("has no", "with") };
        return Err(ck_err(
            dir,
            format!("it {has} twin critic and the learner is configured {wants} one (`dsac.twin_critics`)"),
        ));
    }
    if meta.state_head != parts.state_head {
        let (has, wants) = if meta.state_head { ("has a", "0") } else { ("has no", "> 0") };
        return Err(ck_err(
            dir,
            format!(
                "it {has} state-prediction head and the learner is configured with `dsac.state_aux_weight` {wants}: \
                 resume with the setting the run was started with"
            ),
        ));
    }
    if meta.contrast_head != parts.contrast_head {
        let (has, wants) = if meta.contrast_head { ("has a", "0") } else { ("has no", "> 0") };
        return Err(ck_err(
            dir,
            format!(
                "it {has} contrastive head and the learner is configured with `dsac.contrast_weight` {wants}: \
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
