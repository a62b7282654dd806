//! Checkpoints: a bit-exact round trip (continuing after a load gives identical
//! updates; twin critics and the state-prediction head included), clear errors that
//! change nothing for damaged or incompatible checkpoints, and the loads of what a
//! results folder keeps (acting networks, the diagnosed agent).
//!
//! They survive interrupted saves and damaged files (issue 18): a save
//! stopped after each of its filesystem steps, a writer process killed (SIGKILL) at
//! seeded random moments of repeated saves, and every file of a checkpoint damaged in
//! turn. Each time the resume loads one whole generation — the weights are exactly
//! those of one save, never a mixture — names the damaged file, and the next save works.

mod common;
use pednav_tests::damage::Damage;
use pednav_tests::warnings::{self, logged_warnings};

use common::{small, state_batch};

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use candle_core::Device;
use pednav_learner::checkpoint::save_checkpoint_interrupted;
use pednav_learner::{
    CheckpointMeta, Dsac, DsacConfig, acting_files, agent_files, checkpoint_exists, load_acting, load_agent,
    load_checkpoint, load_checkpoint_or_previous, previous_generation, save_checkpoint, warm_start,
};
use pednav_nets::{DsacNets, NetsConfig};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::json;

/// Every parameter of the agent (networks and log α), store by store, as flat vectors:
/// two agents hold the same weights exactly when these are equal.
fn all_values(d: &Dsac) -> Vec<Vec<f32>> {
    let mut out = Vec::new();
    for store in d.nets.stores().into_iter().chain([&d.log_alpha]) {
        for (_, v) in store.vars() {
            out.push(v.flatten_all().unwrap().to_vec1().unwrap());
        }
    }
    out
}

#[test]
fn checkpoints_round_trip_bit_exactly_and_bad_ones_change_nothing() {
    warnings::install();
    let dir = std::env::temp_dir().join(format!("pednav-ckpt-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let (cfg, nets) = small();
    let mut a = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
    for _ in 0..3 {
        a.update(&state_batch(16, &mut rng)).unwrap();
    }
    let ck = dir.join("ckpt");
    save_checkpoint(&ck, &mut a, None, serde_json::json!({"env_steps": 123})).unwrap();
    let mut b = Dsac::new(&cfg, &nets, &Device::Cpu, 2).unwrap();
    let meta = load_checkpoint(&ck, &mut b).unwrap();
    assert_eq!(meta.extra["env_steps"], 123);
    assert_eq!(all_values(&a), all_values(&b));
    assert_eq!((a.updates, a.rng.clone()), (b.updates, b.rng.clone()));
    // Continuing both gives identical results: moments, counters and RNG were restored.
    let batch = state_batch(16, &mut rng);
    let (sa, sb) = (a.update(&batch).unwrap(), b.update(&batch).unwrap());
    assert_eq!(sa, sb);
    assert_eq!(all_values(&a), all_values(&b));

    // Corrupt one byte of a weight file: checksum error naming the file, nothing changed.
    let mut c = Dsac::new(&cfg, &nets, &Device::Cpu, 3).unwrap();
    let untouched = all_values(&c);
    let file = ck.join("quantile.safetensors");
    let mut bytes = std::fs::read(&file).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 0xff;
    std::fs::write(&file, &bytes).unwrap();
    let err = load_checkpoint(&ck, &mut c).unwrap_err().to_string();
    assert!(err.contains("quantile.safetensors") && err.contains("checksum"), "{err}");
    assert_eq!(untouched, all_values(&c));

    // A checkpoint of another architecture: a clear error, nothing changed.
    save_checkpoint(&ck, &mut a, None, serde_json::Value::Null).unwrap();
    let other = NetsConfig { hidden: 16, ..nets.clone() };
    let mut d = Dsac::new(&cfg, &other, &Device::Cpu, 3).unwrap();
    let untouched = all_values(&d);
    let err = load_checkpoint(&ck, &mut d).unwrap_err().to_string();
    assert!(err.contains("written for networks"), "{err}");
    assert_eq!(untouched, all_values(&d));
    let err = load_checkpoint(&dir.join("missing"), &mut d).unwrap_err().to_string();
    assert!(err.contains("is this a checkpoint directory"), "{err}");

    // Twin critics round-trip too (second critic, its target and its moments), and a
    // checkpoint with or without the twin refuses a learner configured the other way.
    let twin_cfg = DsacConfig { twin_critics: true, ..cfg.clone() };
    let mut e = Dsac::new(&twin_cfg, &nets, &Device::Cpu, 4).unwrap();
    e.update(&state_batch(16, &mut rng)).unwrap();
    let twin_ck = dir.join("twin");
    save_checkpoint(&twin_ck, &mut e, None, serde_json::Value::Null).unwrap();
    let mut f = Dsac::new(&twin_cfg, &nets, &Device::Cpu, 5).unwrap();
    load_checkpoint(&twin_ck, &mut f).unwrap();
    assert_eq!(all_values(&e), all_values(&f));
    let batch = state_batch(16, &mut rng);
    assert_eq!(e.update(&batch).unwrap(), f.update(&batch).unwrap());
    assert_eq!(all_values(&e), all_values(&f));
    let mut g = Dsac::new(&cfg, &nets, &Device::Cpu, 6).unwrap();
    let untouched = all_values(&g);
    let err = load_checkpoint(&twin_ck, &mut g).unwrap_err().to_string();
    assert_eq!(untouched, all_values(&g));
    assert!(err.contains("has a twin critic") && err.contains("twin_critics"), "{err}");
    let err = load_checkpoint(&ck, &mut f).unwrap_err().to_string();
    assert!(err.contains("has no twin critic"), "{err}");

    // The state-prediction head and its moments round-trip; a learner configured the
    // other way is refused naming the setting.
    let aux_cfg = DsacConfig { state_aux_weight: 1.0, ..cfg.clone() };
    let mut h = Dsac::new(&aux_cfg, &nets, &Device::Cpu, 4).unwrap();
    h.update(&state_batch(16, &mut rng)).unwrap();
    let aux_ck = dir.join("aux");
    save_checkpoint(&aux_ck, &mut h, None, serde_json::Value::Null).unwrap();
    assert!(aux_ck.join("state_head.safetensors").exists());
    let mut i = Dsac::new(&aux_cfg, &nets, &Device::Cpu, 5).unwrap();
    load_checkpoint(&aux_ck, &mut i).unwrap();
    assert_eq!(all_values(&h), all_values(&i));
    let batch = state_batch(16, &mut rng);
    assert_eq!(h.update(&batch).unwrap(), i.update(&batch).unwrap());
    let mut j = Dsac::new(&cfg, &nets, &Device::Cpu, 6).unwrap();
    let err = load_checkpoint(&aux_ck, &mut j).unwrap_err().to_string();
    assert!(err.contains("state-prediction head") && err.contains("state_aux_weight"), "{err}");
    let err = load_checkpoint(&ck, &mut i).unwrap_err().to_string();
    assert!(err.contains("has no state-prediction head"), "{err}");

    // So do the contrastive head and its moments.
    let contrast_cfg = DsacConfig { contrast_weight: 0.5, ..cfg.clone() };
    let mut k = Dsac::new(&contrast_cfg, &nets, &Device::Cpu, 4).unwrap();
    k.update(&state_batch(16, &mut rng)).unwrap();
    let contrast_ck = dir.join("contrast");
    save_checkpoint(&contrast_ck, &mut k, None, serde_json::Value::Null).unwrap();
    assert!(contrast_ck.join("contrast_head.safetensors").exists());
    let mut l = Dsac::new(&contrast_cfg, &nets, &Device::Cpu, 5).unwrap();
    load_checkpoint(&contrast_ck, &mut l).unwrap();
    assert_eq!(all_values(&k), all_values(&l));
    let batch = state_batch(16, &mut rng);
    assert_eq!(k.update(&batch).unwrap(), l.update(&batch).unwrap());
    let err = load_checkpoint(&contrast_ck, &mut j).unwrap_err().to_string();
    assert!(err.contains("contrastive head") && err.contains("contrast_weight"), "{err}");

    // What a results folder keeps: state.json and the acting networks' files load the
    // policy into fresh networks; a damaged copy is refused and changes nothing.
    let kept = dir.join("results");
    std::fs::create_dir_all(&kept).unwrap();
    let files = acting_files(&a.nets);
    assert_eq!(files, ["state.json", "policy.safetensors"]);
    for file in &files {
        std::fs::copy(ck.join(file), kept.join(file)).unwrap();
    }
    let policy = |n: &DsacNets| -> Vec<Vec<f32>> {
        n.policy.store.vars().iter().map(|(_, v)| v.flatten_all().unwrap().to_vec1().unwrap()).collect()
    };
    let fresh = DsacNets::new(&nets, &Device::Cpu, 9).unwrap();
    let untouched = policy(&fresh);
    let mut bytes = std::fs::read(kept.join("policy.safetensors")).unwrap();
    bytes[100] ^= 1;
    std::fs::write(kept.join("policy.safetensors"), &bytes).unwrap();
    assert!(load_acting(&kept, &fresh).unwrap_err().to_string().contains("checksum"));
    assert_eq!(policy(&fresh), untouched);
    bytes[100] ^= 1;
    std::fs::write(kept.join("policy.safetensors"), &bytes).unwrap();
    load_acting(&kept, &fresh).unwrap();
    assert_eq!(policy(&fresh), policy(&a.nets));

    // What a diagnosed results folder keeps: the online networks and α of the twin
    // checkpoint load them all (Q needs the fraction net and both critics); without
    // one of the files the load names it.
    let diag = dir.join("diagnosed");
    std::fs::create_dir_all(&diag).unwrap();
    let files = agent_files(&e.nets);
    assert_eq!(files.len(), 6, "state, policy, fraction, quantile, quantile2, log α: {files:?}");
    for file in &files {
        std::fs::copy(twin_ck.join(file), diag.join(file)).unwrap();
    }
    let agent = load_agent(&diag, &Device::Cpu).unwrap();
    let mut e = Dsac::new(&twin_cfg, &nets, &Device::Cpu, 7).unwrap();
    load_checkpoint(&twin_ck, &mut e).unwrap();
    let values = |s: &pednav_nets::ParamStore| -> Vec<Vec<f32>> {
        s.vars().iter().map(|(_, v)| v.flatten_all().unwrap().to_vec1().unwrap()).collect()
    };
    assert_eq!(values(&agent.nets.fraction.store), values(&e.nets.fraction.store));
    assert_eq!(values(&agent.nets.quantile.store), values(&e.nets.quantile.store));
    let (twin_a, twin_e) = (agent.nets.twin.as_ref().unwrap(), e.nets.twin.as_ref().unwrap());
    assert_eq!(values(&twin_a.quantile.store), values(&twin_e.quantile.store));
    assert!((agent.alpha - e.alpha().unwrap()).abs() < 1e-6, "α {} vs {}", agent.alpha, e.alpha().unwrap());
    std::fs::remove_file(diag.join("fraction.safetensors")).unwrap();
    let err = load_agent(&diag, &Device::Cpu).err().expect("a missing file is refused").to_string();
    assert!(err.contains("fraction.safetensors"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Flat values of `stores`, store by store (see [`all_values`]).
fn values_of(stores: &[&pednav_nets::ParamStore]) -> Vec<Vec<f32>> {
    stores.iter().flat_map(|s| s.vars()).map(|(_, v)| v.flatten_all().unwrap().to_vec1().unwrap()).collect()
}

#[test]
fn a_warm_start_takes_the_online_networks_and_temperature_and_starts_everything_else_fresh() {
    let dir = scratch("warm");
    let mut rng = ChaCha8Rng::seed_from_u64(8);
    let (cfg, nets) = small();
    let cfg = DsacConfig { twin_critics: true, contrast_weight: 1.0, ..cfg };
    let mut trained = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
    for _ in 0..4 {
        trained.update(&state_batch(16, &mut rng)).unwrap();
    }
    let ck = dir.join("trained");
    save_checkpoint(&ck, &mut trained, None, serde_json::Value::Null).unwrap();
    // What a results folder keeps: the state file and agent_files, nothing else.
    let kept = dir.join("kept");
    std::fs::create_dir_all(&kept).unwrap();
    for f in agent_files(&trained.nets) {
        std::fs::copy(ck.join(&f), kept.join(&f)).unwrap();
    }
    for from in [&ck, &kept] {
        let mut warm = Dsac::new(&cfg, &nets, &Device::Cpu, 2).unwrap();
        let fresh = Dsac::new(&cfg, &nets, &Device::Cpu, 2).unwrap();
        let meta = warm_start(from, &mut warm).unwrap();
        assert_eq!(meta.updates, 4);
        assert_eq!(values_of(&warm.nets.online_stores()), values_of(&trained.nets.online_stores()));
        assert_eq!(values_of(&[&warm.log_alpha]), values_of(&[&trained.log_alpha]));
        // The targets copy the loaded critics (the trained run's targets lag theirs).
        let twin = warm.nets.twin.as_ref().unwrap();
        assert_eq!(values_of(&[&warm.nets.target.store]), values_of(&[&warm.nets.quantile.store]));
        assert_eq!(values_of(&[&twin.target.store]), values_of(&[&twin.quantile.store]));
        assert_ne!(values_of(&[&warm.nets.target.store]), values_of(&[&trained.nets.target.store]));
        // The auxiliary head, counters and RNG are a fresh run's.
        let head = |d: &Dsac| values_of(&[&d.nets.contrast_head.as_ref().unwrap().store]);
        assert_eq!(head(&warm), head(&fresh));
        assert_eq!((warm.updates, warm.rng.clone()), (0, fresh.rng.clone()));
        // The optimisers too: the first update of a warm start equals that of a learner
        // given the same weights by hand (fresh moments, step 1).
        let mut by_hand = Dsac::new(&cfg, &nets, &Device::Cpu, 2).unwrap();
        let mut stores = by_hand.nets.online_stores();
        stores.push(&by_hand.log_alpha);
        for (to, from) in stores.iter().zip(trained.nets.online_stores().into_iter().chain([&trained.log_alpha])) {
            to.copy_from(from).unwrap();
        }
        by_hand.nets.target.store.copy_from(&by_hand.nets.quantile.store).unwrap();
        let t = by_hand.nets.twin.as_ref().unwrap();
        t.target.store.copy_from(&t.quantile.store).unwrap();
        let batch = state_batch(16, &mut rng);
        assert_eq!(warm.update(&batch).unwrap(), by_hand.update(&batch).unwrap());
        assert_eq!(all_values(&warm), all_values(&by_hand));
    }
    // Another architecture, or one critic where the folder has two: refused naming the
    // setting, nothing changed.
    let mut other = Dsac::new(&cfg, &NetsConfig { hidden: 16, ..nets.clone() }, &Device::Cpu, 3).unwrap();
    let untouched = all_values(&other);
    let err = warm_start(&kept, &mut other).unwrap_err().to_string();
    assert!(err.contains("[nets]"), "{err}");
    assert_eq!(untouched, all_values(&other));
    let mut one = Dsac::new(&DsacConfig { twin_critics: false, ..cfg.clone() }, &nets, &Device::Cpu, 3).unwrap();
    let untouched = all_values(&one);
    let err = warm_start(&kept, &mut one).unwrap_err().to_string();
    assert!(err.contains("has a twin critic") && err.contains("dsac.twin_critics"), "{err}");
    assert_eq!(untouched, all_values(&one));
    let _ = std::fs::remove_dir_all(&dir);
}

/// The learner saved as generation `g`: weights from one of four seeds (`g` mod 4),
/// `g` updates; [`save`] labels the checkpoint `g` in its `extra`.
fn generation(g: u64) -> Dsac {
    let (cfg, nets) = small();
    let mut d = Dsac::new(&cfg, &nets, &Device::Cpu, 1000 + g % 4).unwrap();
    d.updates = g;
    d
}

/// A learner that has loaded nothing yet.
fn fresh() -> Dsac {
    let (cfg, nets) = small();
    Dsac::new(&cfg, &nets, &Device::Cpu, 9).unwrap()
}

fn label(g: u64) -> serde_json::Value {
    json!({ "generation": g })
}

fn save(ck: &Path, g: u64) {
    save_checkpoint(ck, &mut generation(g), None, label(g)).unwrap();
}

/// The generation `d` was loaded from (`meta`), after checking that its counters and
/// every weight are exactly that generation's.
fn loaded_generation(d: &Dsac, meta: &CheckpointMeta) -> u64 {
    let g = meta.extra["generation"].as_u64().expect("a labelled generation");
    assert_eq!((meta.updates, d.updates), (g, g), "the counters of generation {g}");
    assert!(all_values(d) == all_values(&generation(g)), "the weights of generation {g}, exactly");
    g
}

/// The generation of the checkpoint folder `dir` on its own (no fallback).
fn generation_in(dir: &Path) -> u64 {
    let mut d = fresh();
    let meta = load_checkpoint(dir, &mut d).unwrap_or_else(|e| panic!("{}: {e}", dir.display()));
    loaded_generation(&d, &meta)
}

fn partial(ck: &Path) -> PathBuf {
    PathBuf::from(format!("{}.tmp", ck.display()))
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("pednav-ckpt-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn files_of(dir: &Path) -> Vec<PathBuf> {
    let mut files: Vec<_> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    files
}

/// The start states of the interrupted save: what is on disk, and which generations
/// a resume may load once a save of generation 3 has been stopped anywhere.
const STARTS: [(&str, &[u64]); 3] =
    [("one generation (1)", &[1, 3]), ("two generations (1, 2)", &[2, 3]), ("the newest (2) damaged", &[1, 3])];

fn set_up(start: usize, ck: &Path) {
    save(ck, 1);
    if start >= 1 {
        save(ck, 2);
    }
    if start == 2 {
        let file = ck.join("quantile.safetensors");
        let mut bytes = std::fs::read(&file).unwrap();
        let mid = bytes.len() / 2;
        bytes[mid] ^= 0x5a;
        std::fs::write(&file, bytes).unwrap();
    }
}

/// A save stopped after each of its filesystem steps in turn (the state a kill there
/// leaves): the resume finds a checkpoint and loads one whole generation — the one
/// that was there or the new one — and the next save (over whatever the stop left,
/// a partial `<dir>.tmp` included) works, keeping what was loaded as the previous
/// generation. From a damaged newest, the good previous generation is never lost.
#[test]
fn a_save_stopped_after_any_step_resumes_from_a_whole_generation() {
    warnings::install();
    let root = scratch("steps");
    for (start, (name, allowed)) in STARTS.iter().enumerate() {
        let mut steps = Vec::new();
        for k in 0.. {
            let ck = root.join(format!("{start}-{k}")).join("learner");
            std::fs::create_dir_all(ck.parent().unwrap()).unwrap();
            set_up(start, &ck);
            let run = save_checkpoint_interrupted(&ck, &mut generation(3), None, label(3), k).unwrap();
            let at = format!("{name}, stopped after {k} steps {:?}", run.steps);
            assert!(run.finished || run.steps.len() == k, "{at}");
            assert!(checkpoint_exists(&ck), "{at}: the resume finds no checkpoint");
            let mut d = fresh();
            let (meta, loaded) =
                load_checkpoint_or_previous(&ck, &mut d).unwrap_or_else(|e| panic!("{at}: cannot resume: {e}"));
            let g = loaded_generation(&d, &meta);
            assert!(allowed.contains(&g), "{at}: loaded generation {g}");
            if run.finished {
                assert_eq!((g, &loaded), (3, &ck), "{at}");
            }
            // A kill in the middle of writing a file leaves it part-written in the
            // partial folder: the next save must clear that too.
            if partial(&ck).is_dir() {
                for file in files_of(&partial(&ck)) {
                    let bytes = std::fs::read(&file).unwrap();
                    std::fs::write(&file, &bytes[..bytes.len() / 2]).unwrap();
                }
            }
            save(&ck, 4);
            let mut d = fresh();
            let (meta, loaded) = load_checkpoint_or_previous(&ck, &mut d).unwrap();
            assert_eq!((loaded_generation(&d, &meta), &loaded), (4, &ck), "{at}: the next save");
            assert_eq!(generation_in(&previous_generation(&ck)), g, "{at}: the next save keeps what was loaded");
            assert!(!partial(&ck).exists(), "{at}: the next save leaves no partial folder");
            std::fs::remove_dir_all(ck.parent().unwrap()).unwrap();
            if run.finished {
                steps = run.steps;
                break;
            }
        }
        eprintln!("{name}: stopped after each of {} steps:\n  {}", steps.len(), steps.join("\n  "));
        assert!(steps.len() >= 10, "{name}: {steps:?}");
        assert!(steps.iter().any(|s| s.starts_with("rename")), "{steps:?}");
    }
    let _ = std::fs::remove_dir_all(&root);
}

/// Every file of the newest checkpoint damaged in turn, each way: the resume falls
/// back to the previous generation with a warning naming the damaged file; the same
/// file damaged in both generations: the error names both. Damage in the previous
/// generation alone changes nothing. A save after a fallback keeps the good previous
/// generation (not the damaged newest), so the next damage still finds it.
#[test]
fn every_damaged_file_falls_back_to_the_previous_generation_and_is_named() {
    warnings::install();
    let root = scratch("damage");
    let ck = root.join("learner");
    let prev = previous_generation(&ck);
    save(&ck, 1);
    save(&ck, 2);
    let files = files_of(&ck);
    let names: Vec<_> = files.iter().map(|f| f.file_name().unwrap().to_str().unwrap()).collect();
    for expected in ["state.json", "optimizer.safetensors", "policy.safetensors", "log_alpha.safetensors"] {
        assert!(names.contains(&expected), "{names:?}");
    }
    assert!(files.len() >= 7, "state, four networks' online and target stores, α, moments: {names:?}");
    for file in &files {
        let kept = std::fs::read(file).unwrap();
        let prev_file = prev.join(file.file_name().unwrap());
        let prev_kept = std::fs::read(&prev_file).unwrap();
        for how in Damage::ALL {
            let at = format!("{} ({how})", file.display());
            how.apply(file).unwrap();
            let mut d = fresh();
            let (resumed, warnings) = logged_warnings(|| load_checkpoint_or_previous(&ck, &mut d));
            let (meta, loaded) = resumed.unwrap_or_else(|e| panic!("{at}: {e}"));
            assert_eq!((loaded_generation(&d, &meta), &loaded), (1, &prev), "{at}");
            assert!(
                warnings.len() == 1 && warnings[0].contains(&file.display().to_string()),
                "{at}: the warning names the file: {warnings:?}"
            );
            how.apply(&prev_file).unwrap();
            let err = load_checkpoint_or_previous(&ck, &mut fresh()).map(|_| ()).unwrap_err().to_string();
            for named in [file, &prev_file] {
                assert!(err.contains(&named.display().to_string()), "{at}: the error names {}: {err}", named.display());
            }
            std::fs::write(file, &kept).unwrap();
            std::fs::write(&prev_file, &prev_kept).unwrap();
        }
        Damage::FlipBytes.apply(&prev_file).unwrap();
        let mut d = fresh();
        let (resumed, warnings) = logged_warnings(|| load_checkpoint_or_previous(&ck, &mut d));
        let (meta, loaded) = resumed.unwrap();
        assert_eq!((loaded_generation(&d, &meta), &loaded, warnings.len()), (2, &ck, 0), "{}", prev_file.display());
        std::fs::write(&prev_file, &prev_kept).unwrap();
    }

    // A resume fell back to generation 1 (2 is damaged); the next save replaces the
    // damaged one, saying so, and keeps 1 as the previous generation.
    let quantile = ck.join("quantile.safetensors");
    Damage::FlipBytes.apply(&quantile).unwrap();
    let ((), warnings) = logged_warnings(|| save(&ck, 3));
    assert!(warnings.len() == 1 && warnings[0].contains(&quantile.display().to_string()), "{warnings:?}");
    assert_eq!((generation_in(&ck), generation_in(&prev)), (3, 1));
    Damage::TruncateToHalf.apply(&ck.join("state.json")).unwrap();
    let mut d = fresh();
    let (meta, loaded) = load_checkpoint_or_previous(&ck, &mut d).unwrap();
    assert_eq!((loaded_generation(&d, &meta), &loaded), (1, &prev));
    let _ = std::fs::remove_dir_all(&root);
}

/// State files written before they carried their own checksum (format 1) still load;
/// a format-2 state file whose checksum field is gone is refused.
#[test]
fn state_files_of_format_1_still_load_and_a_missing_state_checksum_is_refused() {
    warnings::install();
    let root = scratch("format");
    let ck = root.join("learner");
    save(&ck, 1);
    let state = ck.join("state.json");
    let text = std::fs::read_to_string(&state).unwrap();
    let (body, _) = text.rsplit_once(",\n  \"state_crc32\": ").expect("the state file's checksum is its last field");
    std::fs::write(&state, format!("{body}\n}}")).unwrap();
    let err = load_checkpoint(&ck, &mut fresh()).unwrap_err().to_string();
    assert!(err.contains("state.json") && err.contains("checksum field is missing"), "{err}");
    let old = body.replacen("\"format\": 2,", "\"format\": 1,", 1);
    assert_ne!(old, body);
    std::fs::write(&state, format!("{old}\n}}")).unwrap();
    assert_eq!(generation_in(&ck), 1);
    let _ = std::fs::remove_dir_all(&root);
}

const WRITER_DIR: &str = "PEDNAV_TEST_CHECKPOINT_WRITER_DIR";
const WRITER_FROM: &str = "PEDNAV_TEST_CHECKPOINT_WRITER_FROM";

/// Not a test on its own: the writer process of
/// [`a_writer_killed_during_saves_resumes_from_a_whole_generation`] (this test binary
/// run again with [`WRITER_DIR`] set), saving generation after generation until killed.
#[test]
fn checkpoint_writer_process() {
    warnings::install();
    let Ok(dir) = std::env::var(WRITER_DIR) else { return };
    let from: u64 = std::env::var(WRITER_FROM).unwrap().parse().unwrap();
    let mut learners: Vec<Dsac> = (0..4).map(generation).collect();
    for g in from.. {
        let d = &mut learners[(g % 4) as usize];
        d.updates = g;
        save_checkpoint(Path::new(&dir), d, None, label(g)).unwrap();
        println!("saved {g}");
    }
}

/// A process saving checkpoints back to back, killed with SIGKILL at a seeded random
/// moment, 16 times over the same folder (each writer starting over what the last kill
/// left): every time the resume loads a whole generation, the last one reported saved
/// or the one after it — nothing but the save in progress is lost.
#[test]
fn a_writer_killed_during_saves_resumes_from_a_whole_generation() {
    warnings::install();
    let root = scratch("kill");
    let ck = root.join("learner");
    let mut rng = ChaCha8Rng::seed_from_u64(18);
    let (mut from, mut mid_save) = (1u64, 0);
    for round in 0..16 {
        let mut child = Command::new(std::env::current_exe().unwrap())
            .args(["checkpoint_writer_process", "--exact", "--nocapture", "--test-threads=1"])
            .env(WRITER_DIR, &ck)
            .env(WRITER_FROM, from.to_string())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        let out = BufReader::new(child.stdout.take().unwrap());
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in out.lines().map_while(Result::ok) {
                if let Some((_, g)) = line.split_once("saved ") {
                    let _ = tx.send(g.trim().parse::<u64>().unwrap());
                }
            }
        });
        let first = rx.recv_timeout(Duration::from_secs(120)).expect("the writer saves");
        std::thread::sleep(Duration::from_micros(rng.random_range(0..30_000)));
        child.kill().unwrap();
        child.wait().unwrap();
        let last = rx.iter().last().unwrap_or(first);
        let at = format!("kill {round}, after generation {last} was reported saved");
        if partial(&ck).exists() || !ck.exists() {
            mid_save += 1;
        }
        assert!(checkpoint_exists(&ck), "{at}");
        let mut d = fresh();
        let (meta, _) = load_checkpoint_or_previous(&ck, &mut d).unwrap_or_else(|e| panic!("{at}: {e}"));
        let g = loaded_generation(&d, &meta);
        assert!(g == last || g == last + 1, "{at}: loaded generation {g}");
        from = last + 2;
    }
    eprintln!("16 kills, {mid_save} of them with a save's partial folder or rotation on disk");
    let _ = std::fs::remove_dir_all(&root);
}
