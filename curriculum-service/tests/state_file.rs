//! The curriculum service's saved state on disk: a checksum line that catches
//! damage, the previous generation kept by every save, and the fallback to it.

use std::collections::BTreeMap;

use pednav_curriculum::{Curriculum, CurriculumConfig, ServiceState};
use pednav_sim::Scene;

fn state(next_task_id: u64) -> ServiceState {
    let c = Curriculum::new(CurriculumConfig::default(), Scene::reference(), 3).unwrap();
    ServiceState { curriculum: c.state().unwrap(), next_task_id, proposed: BTreeMap::new(), decision_steps: 7 }
}

#[test]
fn a_damaged_state_is_refused_and_the_previous_generation_loads() {
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
