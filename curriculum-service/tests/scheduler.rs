//! The task scheduler against the reference scene, with synthetic predictors.

use pednav_curriculum::filter::{Fit, category_probabilities};
use pednav_curriculum::returns::TaskFeatures;
use pednav_curriculum::{Category, CurriculumConfig, ReturnPredictor, TaskScheduler, Variant};
use pednav_sim::Scene;
use proptest::prelude::*;

/// Predicts a return that falls with distance to the goal (the features' dx, dy).
struct DistancePredictor;

impl ReturnPredictor for DistancePredictor {
    fn predict(&mut self, features: &[TaskFeatures]) -> Vec<f32> {
        features.iter().map(|f| 5.0 - f.pose[0].hypot(f.pose[1])).collect()
    }
}

fn scheduler(variant: Variant, seed: u64) -> TaskScheduler {
    let cfg = CurriculumConfig { variant, candidates: 512, ..CurriculumConfig::default() };
    TaskScheduler::new(cfg, Scene::reference(), seed).unwrap()
}

fn distance(scene: &Scene, p: pednav_sim::Pose) -> f32 {
    (scene.goal_center[0] - p.x).hypot(scene.goal_center[1] - p.y)
}

#[test]
fn fixed_start_always_proposes_point_3() {
    let mut s = scheduler(Variant::FixedStart, 0);
    let scene = Scene::reference();
    for _ in 0..10 {
        let p = s.propose(&mut DistancePredictor).unwrap();
        assert_eq!((p.pose, p.category), (scene.fixed_start(), Category::Fixed));
        s.record_episode(p.category, 100, -50.0);
    }
    assert_eq!(s.t_c(), 0, "no ACL phase without a curriculum");
}

#[test]
fn navacl_plus_stays_on_the_first_task_until_the_gate_passes() {
    let scene = Scene::reference();
    let mut s = scheduler(Variant::NavAclPlusSlope, 1);
    // 29 good episodes: the 30-episode window is not full yet.
    for _ in 0..29 {
        let p = s.propose(&mut DistancePredictor).unwrap();
        assert_eq!((p.pose, p.category), (scene.first_task(), Category::First));
        s.record_episode(p.category, 20, 0.0);
    }
    // A bad 30th episode: mean = -800/30 ≈ -26.7 below the threshold (0), still closed.
    let p = s.propose(&mut DistancePredictor).unwrap();
    assert_eq!(p.category, Category::First);
    s.record_episode(p.category, 8000, -800.0);
    assert!(!s.in_acl_phase());
    // Good episodes push the bad one out: it is the oldest entry after 29 more and
    // leaves with the 30th, which opens the gate (mean 0 ≥ 0).
    for _ in 0..30 {
        let p = s.propose(&mut DistancePredictor).unwrap();
        assert_eq!(p.category, Category::First);
        s.record_episode(p.category, 20, 0.0);
    }
    assert!(s.in_acl_phase());
    assert_eq!(s.t_c(), 0, "first-task steps are not ACL steps");
    let p = s.propose(&mut DistancePredictor).unwrap();
    assert_ne!(p.category, Category::First);
    assert!(scene.in_curriculum_region(p.pose.x, p.pose.y));
    s.record_episode(p.category, 123, -10.0);
    assert_eq!(s.t_c(), 123);
}

#[test]
fn the_enlarged_region_proposes_beyond_the_curriculum_region() {
    let scene = Scene::reference();
    let enlarged = scene.proposal_region(true);
    let cfg =
        CurriculumConfig { variant: Variant::NavAcl, candidates: 64, enlarged_region: true, ..Default::default() };
    let mut s = TaskScheduler::new(cfg, Scene::reference(), 3).unwrap();
    let mut outside = 0;
    for _ in 0..200 {
        let p = s.propose(&mut DistancePredictor).unwrap();
        assert!(enlarged.iter().any(|a| a.contains(p.pose.x, p.pose.y)), "{:?}", p.pose);
        assert!(scene.check_task(p.pose).is_ok());
        outside += usize::from(!scene.in_curriculum_region(p.pose.x, p.pose.y));
        s.record_episode(p.category, 100, -30.0);
    }
    // The enlarged areas are ≈ 6× the curriculum region: most random-category and
    // many easy/frontier proposals fall outside it.
    assert!(outside > 20, "only {outside} of 200 proposals outside the curriculum region");

    // A scene without enlarged areas cannot honour the setting: refused, naming it.
    let cut = pednav_sim::scene::REFERENCE_SCENE_TOML.split("# Enlarged ACL-proposed region").next().unwrap();
    let plain = Scene::from_toml_str(cut, "plain").unwrap();
    assert!(plain.enlarged_curriculum_region.is_empty());
    let cfg = CurriculumConfig { enlarged_region: true, ..Default::default() };
    let Err(err) = TaskScheduler::new(cfg, plain, 0) else { panic!("enlarged_region without areas accepted") };
    let err = err.to_string();
    assert!(err.contains("enlarged_region") && err.contains("plain"), "{err}");
}

#[test]
fn easy_tasks_lie_closer_to_the_goal_than_frontier_tasks() {
    // NavACL has no gate, so it filters from the first proposal.
    let scene = Scene::reference();
    let mut s = scheduler(Variant::NavAcl, 2);
    let (mut easy, mut frontier) = (Vec::new(), Vec::new());
    for _ in 0..200 {
        let p = s.propose(&mut DistancePredictor).unwrap();
        let fit = p.fit.unwrap();
        let d = distance(&scene, p.pose);
        match p.category {
            Category::Easy => {
                assert!(p.predicted.unwrap() > fit.mu + fit.sigma);
                easy.push(d)
            }
            Category::Frontier => frontier.push(d),
            _ => {}
        }
    }
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len() as f32;
    assert!(easy.len() > 40 && frontier.len() > 40, "{} easy, {} frontier", easy.len(), frontier.len());
    assert!(mean(&easy) + 5.0 < mean(&frontier), "easy {:.1} m vs frontier {:.1} m", mean(&easy), mean(&frontier));
}

#[test]
fn the_same_seed_proposes_the_same_tasks() {
    let run = |seed| {
        let mut s = scheduler(Variant::NavAclPlusHard, seed);
        for _ in 0..30 {
            let p = s.propose(&mut DistancePredictor).unwrap();
            s.record_episode(p.category, 10, 0.0);
        }
        (0..20).map(|_| s.propose(&mut DistancePredictor).unwrap().pose).collect::<Vec<_>>()
    };
    assert_eq!(run(5), run(5));
    assert_ne!(run(5), run(6));
}

#[test]
fn a_non_finite_prediction_is_an_error_naming_the_task() {
    struct Broken;
    impl ReturnPredictor for Broken {
        fn predict(&mut self, features: &[TaskFeatures]) -> Vec<f32> {
            features.iter().map(|_| f32::NAN).collect()
        }
    }
    let mut s = scheduler(Variant::NavAcl, 0);
    let err = s.propose(&mut Broken).unwrap_err().to_string();
    assert!(err.contains("non-finite"), "{err}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 32, ..ProptestConfig::default() })]

    #[test]
    fn proposals_lie_in_the_curriculum_region(seed in 0u64..10_000, variant in 0usize..2) {
        let scene = Scene::reference();
        let variant = [Variant::NavAcl, Variant::NavAclPlusHard][variant];
        let cfg = CurriculumConfig { variant, candidates: 64, pass_window: 1, ..CurriculumConfig::default() };
        let mut s = TaskScheduler::new(cfg, Scene::reference(), seed).unwrap();
        s.record_episode(Category::First, 10, 0.0);
        for _ in 0..5 {
            let p = s.propose(&mut DistancePredictor).unwrap();
            prop_assert!(scene.in_curriculum_region(p.pose.x, p.pose.y));
            prop_assert!(scene.check_task(p.pose).is_ok());
            s.record_episode(p.category, 1000, -30.0);
        }
    }

    #[test]
    fn category_probabilities_sum_to_one(t_c in 0u64..10_000_000, variant in 0usize..4, random_prob in 0.0f32..1.0, hard in 0.0f32..1.0) {
        let variant = [Variant::NavAcl, Variant::NavAclPlusSlope, Variant::NavAclPlusHard, Variant::FixedStart][variant];
        let cfg = CurriculumConfig { variant, random_prob, hard_max_prob: hard, ..CurriculumConfig::default() };
        let probs = category_probabilities(&cfg, t_c);
        prop_assert!(probs.iter().all(|(_, p)| *p >= 0.0));
        prop_assert!((probs.iter().map(|(_, p)| p).sum::<f32>() - 1.0).abs() < 1e-5);
    }

    #[test]
    fn fit_is_finite(preds in proptest::collection::vec(-1e4f32..1e4, 2..500)) {
        let f = Fit::of(&preds).unwrap();
        prop_assert!(f.mu.is_finite() && f.sigma.is_finite() && f.sigma >= 0.0);
    }
}
