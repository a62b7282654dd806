//! The curriculum service's saved state on disk: a checksum line that catches
//! damage, the previous generation kept by every save, the fallback to it, and a
//! save interrupted after any of its steps (issue 18).

use pednav_tests::damage::Damage;
use pednav_tests::warnings::{self, logged_warnings};

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use pednav_curriculum::{Curriculum, CurriculumConfig, ServiceState};
use pednav_sim::Scene;

fn state(next_task_id: u64) -> ServiceState {
    let c = Curriculum::new(CurriculumConfig::default(), Scene::reference(), 0.25, 3).unwrap();
    ServiceState {
        curriculum: c.state().unwrap(),
        next_task_id,
        proposed: BTreeMap::new(),
        decision_steps: 7,
        report_cursors: Default::default(),
    }
}

#[test]
fn a_damaged_state_is_refused_and_the_previous_generation_loads() {
    warnings::install();
    let dir = std::env::temp_dir().join(format!("pednav-curriculum-state-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("curriculum.json");
    assert!(!ServiceState::exists(&path));
    state(10).save(&path).unwrap();
    state(20).save(&path).unwrap();
    let prev = ServiceState::previous_generation(&path);
    assert_eq!(ServiceState::load(&path).unwrap().next_task_id, 20);
    assert_eq!(ServiceState::load(&prev).unwrap().next_task_id, 10);

    // One changed byte anywhere in the JSON: the checksum refuses it, the previous loads.
    let bytes = std::fs::read(&path).unwrap();
    let mut damaged = bytes.clone();
    let at = damaged.len() / 3;
    damaged[at] = if damaged[at] == b'1' { b'2' } else { b'1' };
    std::fs::write(&path, &damaged).unwrap();
    let err = ServiceState::load(&path).unwrap_err().to_string();
    assert!(err.contains("checksum mismatch") && err.contains("curriculum.json"), "{err}");
    let (s, read) = ServiceState::load_or_previous(&path).unwrap();
    assert_eq!((s.next_task_id, read), (10, prev.clone()));

    // A save interrupted after the newest moved aside leaves only the previous one.
    std::fs::remove_file(&path).unwrap();
    assert!(ServiceState::exists(&path));
    assert_eq!(ServiceState::load_or_previous(&path).unwrap().0.next_task_id, 10);

    // A state written before states carried a checksum (plain JSON) still loads.
    let legacy = dir.join("legacy.json");
    std::fs::write(&legacy, serde_json::to_vec(&state(30)).unwrap()).unwrap();
    assert_eq!(ServiceState::load(&legacy).unwrap().next_task_id, 30);

    // Both generations unreadable: the error names both.
    std::fs::write(&path, b"{").unwrap();
    std::fs::write(&prev, b"").unwrap();
    let err = ServiceState::load_or_previous(&path).unwrap_err().to_string();
    assert!(err.contains("neither") && err.contains("prev.json"), "{err}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// The start states of the interrupted save: what is on disk (states labelled by
/// their next task id), and which states a resume may load once a save of 30 has been
/// stopped anywhere.
const STARTS: [(&str, &[u64]); 3] =
    [("one state (10)", &[10, 30]), ("two generations (10, 20)", &[20, 30]), ("the newest (20) damaged", &[10, 30])];

fn set_up(start: usize, path: &Path) {
    state(10).save(path).unwrap();
    if start >= 1 {
        state(20).save(path).unwrap();
    }
    if start == 2 {
        Damage::FlipBytes.apply(path).unwrap();
    }
}

/// The state a resume loads, and from which file.
fn resume(path: &Path) -> (u64, PathBuf) {
    let (s, read) = ServiceState::load_or_previous(path).unwrap_or_else(|e| panic!("cannot resume: {e}"));
    (s.next_task_id, read)
}

/// A save stopped after each of its filesystem steps in turn (the state a kill there
/// leaves): the resume finds a state and loads the one that was there or the new one;
/// the next save (over a part-written `.json.tmp` too) works and keeps what was loaded
/// as the previous generation. From a damaged newest, the good previous state is
/// never lost.
#[test]
fn a_save_stopped_after_any_step_resumes_from_a_whole_state() {
    warnings::install();
    let root = std::env::temp_dir().join(format!("pednav-curriculum-steps-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    for (start, (name, allowed)) in STARTS.iter().enumerate() {
        let mut steps = Vec::new();
        for k in 0.. {
            let dir = root.join(format!("{start}-{k}"));
            std::fs::create_dir_all(&dir).unwrap();
            let path = dir.join("curriculum.json");
            set_up(start, &path);
            let run = state(30).save_interrupted(&path, k).unwrap();
            let at = format!("{name}, stopped after {k} steps {:?}", run.steps);
            assert!(run.finished || run.steps.len() == k, "{at}");
            assert!(ServiceState::exists(&path), "{at}: the resume finds no state");
            let (loaded, read) = resume(&path);
            assert!(allowed.contains(&loaded), "{at}: loaded {loaded}");
            if run.finished {
                assert_eq!((loaded, &read), (30, &path), "{at}");
            }
            let tmp = path.with_extension("json.tmp");
            if tmp.exists() {
                let bytes = std::fs::read(&tmp).unwrap();
                std::fs::write(&tmp, &bytes[..bytes.len() / 2]).unwrap();
            }
            state(40).save(&path).unwrap();
            assert_eq!(resume(&path), (40, path.clone()), "{at}: the next save");
            let prev = ServiceState::previous_generation(&path);
            assert_eq!(ServiceState::load(&prev).unwrap().next_task_id, loaded, "{at}: the next save keeps it");
            assert!(!tmp.exists(), "{at}");
            std::fs::remove_dir_all(&dir).unwrap();
            if run.finished {
                steps = run.steps;
                break;
            }
        }
        eprintln!("{name}: stopped after each of {} steps:\n  {}", steps.len(), steps.join("\n  "));
        assert!(steps.len() >= 3, "{name}: {steps:?}");
    }
    let _ = std::fs::remove_dir_all(&root);
}

/// Each file of the saved state damaged in turn, each way: the newest damaged falls
/// back to the previous generation with a warning naming the newest file; both
/// damaged, the error names both files; the previous one alone damaged changes
/// nothing. A save after a fallback keeps the good previous state.
#[test]
fn each_damaged_state_file_falls_back_and_is_named() {
    warnings::install();
    let dir = std::env::temp_dir().join(format!("pednav-curriculum-damage-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("curriculum.json");
    let prev = ServiceState::previous_generation(&path);
    state(10).save(&path).unwrap();
    state(20).save(&path).unwrap();
    let (newest_kept, prev_kept) = (std::fs::read(&path).unwrap(), std::fs::read(&prev).unwrap());
    for how in Damage::ALL {
        how.apply(&path).unwrap();
        let (resumed, warnings) = logged_warnings(|| resume(&path));
        assert_eq!(resumed, (10, prev.clone()), "{how}");
        assert!(
            warnings.len() == 1 && warnings[0].contains(&path.display().to_string()),
            "{how}: the warning names the file: {warnings:?}"
        );
        how.apply(&prev).unwrap();
        let err = ServiceState::load_or_previous(&path).unwrap_err().to_string();
        for named in [&path, &prev] {
            assert!(err.contains(&named.display().to_string()), "{how}: the error names {}: {err}", named.display());
        }
        std::fs::write(&path, &newest_kept).unwrap();
        std::fs::write(&prev, &prev_kept).unwrap();
        how.apply(&prev).unwrap();
        let (resumed, warnings) = logged_warnings(|| resume(&path));
        assert_eq!((resumed, warnings.len()), ((20, path.clone()), 0), "{how}: the previous one damaged");
        std::fs::write(&prev, &prev_kept).unwrap();
    }

    // A resume fell back to 10 (20 is damaged); the next save replaces the damaged
    // one, saying so, and keeps 10 as the previous generation.
    Damage::FlipBytes.apply(&path).unwrap();
    let ((), warnings) = logged_warnings(|| state(30).save(&path).unwrap());
    assert!(warnings.len() == 1 && warnings[0].contains(&path.display().to_string()), "{warnings:?}");
    assert_eq!(ServiceState::load(&prev).unwrap().next_task_id, 10);
    Damage::TruncateToHalf.apply(&path).unwrap();
    assert_eq!(resume(&path), (10, prev.clone()));
    let _ = std::fs::remove_dir_all(&dir);
}
