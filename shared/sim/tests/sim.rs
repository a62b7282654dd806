//! Behaviour of the simulator against independently known facts of the scene:
//! the rewards written in the scene file, the building and pole positions, the goal
//! area, the paper's calibration targets for the oracle.

use std::sync::{Arc, OnceLock};

use pednav_sim::oracle::{Oracle, OracleConfig};
use pednav_sim::scene::{Footprint, ObstacleKind};
use pednav_sim::{
    BackendChoice, Env, ObsMode, Observation, Pedestrian, PedestrianEnv, Pose, RegionKind, Scene, SimConfig, SimError,
    SimWorld, VecEnv,
};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn world(cfg: SimConfig) -> Arc<SimWorld> {
    Arc::new(SimWorld::new(Scene::reference(), cfg).expect("reference world"))
}

fn backend() -> BackendChoice {
    BackendChoice::from_env().expect("PEDNAV_BACKEND")
}

/// Walk `n` steps with a fixed action, returning the transitions.
fn walk(w: &SimWorld, start: Pose, action: [f32; 3], n: usize) -> Vec<pednav_sim::Transition> {
    let mut p = Pedestrian::default();
    p.reset(start);
    (0..n).map(|_| p.step(action, w)).collect()
}

#[test]
fn action_mapping_matches_the_paper_ranges() {
    let cfg = SimConfig::default();
    let lo = pednav_sim::command_of([-1.0, -1.0, -1.0], &cfg);
    let hi = pednav_sim::command_of([1.0, 1.0, 1.0], &cfg);
    let out = pednav_sim::command_of([5.0, -7.0, 0.0], &cfg);
    assert_eq!((lo.speed, hi.speed), (0.0, 2.0));
    assert!((hi.yaw_rate - 80f32.to_radians()).abs() < 1e-6 && (lo.yaw_rate + 80f32.to_radians()).abs() < 1e-6);
    assert!((hi.head_yaw - 60f32.to_radians()).abs() < 1e-6);
    assert_eq!(out.speed, 2.0, "actions are clipped");
    assert!((out.yaw_rate + 80f32.to_radians()).abs() < 1e-6);
}

#[test]
fn rewards_per_region_are_the_scene_values_plus_speed() {
    let w = world(SimConfig::default());
    let r = w.scene.rewards().clone();
    // Full speed (2 m/s) along open ground in each region: reward = region + 0.125·2.
    let cases = [
        (Pose::from_degrees(25.0, -7.0, 180.0), RegionKind::Sidewalk, r.sidewalk),
        (Pose::from_degrees(8.0, 7.0, 180.0), RegionKind::GoalSidewalk, r.goal_sidewalk),
        (Pose::from_degrees(13.0, -3.0, 90.0), RegionKind::Zebra, r.zebra),
        (Pose::from_degrees(30.0, -2.5, 0.0), RegionKind::Road, r.road),
    ];
    for (start, kind, map_reward) in cases {
        let t = walk(&w, start, [1.0, 0.0, 0.0], 1)[0];
        assert_eq!(t.region, kind, "start {start:?}");
        assert!(!t.collided);
        assert!((t.reward - (map_reward + r.speed * 2.0)).abs() < 1e-6, "{kind:?}: {}", t.reward);
        assert!((t.pose.x - start.x - 0.5 * start.yaw.cos()).abs() < 1e-3, "walked 0.5 m");
    }
    // Standing still: the map reward alone (−1.0 on the start sidewalk).
    let t = walk(&w, Pose::from_degrees(25.0, -7.0, 180.0), [-1.0, 0.0, 0.0], 1)[0];
    assert_eq!(t.reward, -1.0);
}

#[test]
fn buildings_cannot_be_walked_through_and_collisions_cost_three() {
    let w = world(SimConfig::default());
    let r = w.scene.rewards().clone();
    // The south-east block starts at y = −9 for x in [9, 20]; walk south into it for 20 steps.
    let steps = walk(&w, Pose::from_degrees(15.0, -7.0, -90.0), [1.0, 0.0, 0.0], 20);
    let last = steps.last().unwrap();
    assert!(last.pose.y > -9.0 + 0.29, "stopped at the wall, y = {}", last.pose.y);
    let hits: Vec<_> = steps.iter().filter(|t| t.collided).collect();
    assert!(hits.len() >= 15, "pressing against a wall collides every step, got {}", hits.len());
    for t in hits {
        assert!((t.reward - (r.sidewalk + r.speed * 2.0 + r.collision)).abs() < 1e-5, "{}", t.reward);
    }
    // A pole: the traffic-light pole at (10.4, −5.6); walk at it from the east.
    let pole = w.scene.obstacles.iter().find(|o| o.kind == ObstacleKind::Pole).unwrap();
    let Footprint::Cylinder { center, radius } = pole.footprint else { panic!("pole is a cylinder") };
    let steps = walk(&w, Pose::from_degrees(center[0] + 2.0, center[1], 180.0), [1.0, 0.0, 0.0], 10);
    assert!(steps.iter().any(|t| t.collided), "the pole is solid");
    for t in &steps {
        let d = ((t.pose.x - center[0]).powi(2) + (t.pose.y - center[1]).powi(2)).sqrt();
        assert!(d >= radius + 0.29, "agent centre {d} m from the pole axis");
    }
}

#[test]
fn reaching_the_goal_terminates_and_t_max_truncates() {
    let w = world(SimConfig { t_max: 30, ..SimConfig::default() });
    // 6 m west of the goal (x ≥ 18), facing east: 12 steps of 0.5 m.
    let facing_goal = Pose::from_degrees(12.0, 7.0, 0.0);
    let steps = walk(&w, facing_goal, [1.0, 0.0, 0.0], 30);
    let end = steps.iter().position(|t| t.terminated).expect("reaches the goal");
    assert_eq!(steps[end].region, RegionKind::Goal);
    assert!(steps[..end].iter().all(|t| !t.terminated && !t.truncated));
    let r = w.scene.rewards();
    assert!((steps[end].reward - (r.goal + r.speed * 2.0)).abs() < 1e-5);
    assert!(!steps[end].truncated, "a goal step is never also truncated");

    // Standing still: truncated exactly at step t_max, never terminated.
    let steps = walk(&w, w.scene.first_task(), [-1.0, 0.0, 0.0], 30);
    assert!(steps[..29].iter().all(|t| !t.truncated && !t.terminated));
    assert!(steps[29].truncated && !steps[29].terminated && steps[29].step == 30);

    // The vectorized env refuses to step a finished episode.
    let mut env = VecEnv::new(w.clone(), 1, backend()).unwrap();
    env.reset(0, w.scene.first_task(), 0).unwrap();
    for _ in 0..30 {
        if env.step(&[[-1.0, 0.0, 0.0]]).unwrap()[0].truncated {
            break;
        }
    }
    assert!(matches!(env.step(&[[0.0; 3]]), Err(SimError::NeedsReset { env: 0 })));
}

#[test]
fn same_seed_gives_identical_frames_and_rewards() {
    let run = |seed: u64| {
        let w = world(SimConfig { domain_randomization: true, ..SimConfig::default() });
        let mut env = VecEnv::new(w.clone(), 3, backend()).unwrap();
        let starts = [w.scene.first_task(), w.scene.fixed_start(), Pose::from_degrees(25.0, -7.0, 170.0)];
        for (i, s) in starts.iter().enumerate() {
            env.reset(i, *s, seed + i as u64).unwrap();
        }
        let mut frames = Vec::new();
        let mut rewards = Vec::new();
        let mut rng = ChaCha8Rng::seed_from_u64(99);
        for _ in 0..25 {
            let actions: Vec<[f32; 3]> = (0..3)
                .map(|_| {
                    [rng.random_range(-1.0..1.0f32), rng.random_range(-1.0..1.0f32), rng.random_range(-1.0..1.0f32)]
                })
                .collect();
            let ts = env.step(&actions).unwrap().to_vec();
            rewards.extend(ts.iter().map(|t| t.reward.to_bits()));
            let f = env.render().unwrap();
            for i in 0..3 {
                frames.extend_from_slice(&f.frame(i));
            }
            drop(f);
            for (i, t) in ts.iter().enumerate() {
                if t.terminated || t.truncated {
                    env.reset(i, starts[i], seed + 100).unwrap();
                }
            }
        }
        (frames, rewards)
    };
    let a = run(7);
    let b = run(7);
    assert_eq!(a.1, b.1, "rewards identical");
    assert!(a.0 == b.0, "frames identical");
    let c = run(8);
    assert_ne!(a.0, c.0, "another seed changes the randomised look");
}

#[test]
fn pedestrian_env_follows_the_gymnasium_shape() {
    let w = world(SimConfig { obs_mode: ObsMode::State, ..SimConfig::default() });
    let mut env = PedestrianEnv::new(w.clone(), backend()).unwrap();
    let (obs, info) = env.reset(Pose::from_degrees(12.0, 7.0, 0.0), 0).unwrap();
    let Observation::State(o) = obs else { panic!("state mode") };
    // Goal centre (20, 7) is 8 m straight ahead of (12, 7) facing east.
    assert!((o[0] - 8.0 / 20.0).abs() < 1e-5 && o[1].abs() < 1e-5, "{o:?}");
    assert_eq!(info.region, RegionKind::GoalSidewalk);
    let out = env.step([1.0, 0.0, 0.0]).unwrap();
    assert!(!out.terminated && (out.reward - (-0.6 + 0.25)).abs() < 1e-6);
    assert!(matches!(env.reset(Pose::from_degrees(20.0, 7.0, 0.0), 0), Err(SimError::InvalidTask { .. })));
    assert!(matches!(env.reset(Pose::from_degrees(15.0, -20.0, 0.0), 0), Err(SimError::InvalidTask { .. })));
}

fn oracle() -> &'static (Arc<SimWorld>, Oracle) {
    static ORACLE: OnceLock<(Arc<SimWorld>, Oracle)> = OnceLock::new();
    ORACLE.get_or_init(|| {
        let w = world(SimConfig { t_max: 2000, ..SimConfig::default() });
        let o = Oracle::plan(&w, OracleConfig::default());
        (w, o)
    })
}

#[test]
fn oracle_matches_the_paper_calibration_for_points_0_and_7() {
    let (w, o) = oracle();
    let ret = |k: usize| {
        let p = w.scene.validation_points()[k];
        o.rollout(w, Pose::from_degrees(p.x, p.y, p.favourable_yaw_deg), 2000)
    };
    let (p0, p7) = (ret(0), ret(7));
    assert!(p0.success && p7.success);
    assert!((p0.discounted_return - 4.0).abs() <= 3.0, "point 0: {}", p0.discounted_return);
    assert!((p7.discounted_return + 23.0).abs() <= 3.0, "point 7: {}", p7.discounted_return);
    // Difficulty rises monotonically over the interpolated points 0–7.
    let returns: Vec<f32> = (0..8).map(|k| ret(k).discounted_return).collect();
    assert!(returns.windows(2).all(|w| w[0] > w[1]), "{returns:?}");
}

#[test]
fn oracle_beats_a_hand_scripted_route() {
    // From point 7 (32, −7) facing west: walk west to x = 13, turn north, cross the
    // zebra, turn east to the goal. A legal route through the same simulator; the
    // oracle must do at least as well.
    let (w, o) = oracle();
    let mut p = Pedestrian::default();
    p.reset(Pose::from_degrees(32.0, -7.0, 180.0));
    let (mut ret, mut disc) = (0.0f32, 1.0f32);
    let turn_to =
        |p: &mut Pedestrian, target_deg: f32, until: &dyn Fn(&Pose) -> bool, ret: &mut f32, disc: &mut f32| {
            for _ in 0..400 {
                if until(&p.pose) {
                    return true;
                }
                let err = pednav_sim::scene::wrap_angle(target_deg.to_radians() - p.pose.yaw);
                let a1 = (err / (80f32.to_radians() * 0.25)).clamp(-1.0, 1.0);
                let t = p.step([1.0, a1, 0.0], w);
                *ret += *disc * t.reward;
                *disc *= 0.99;
                if t.terminated {
                    return true;
                }
            }
            false
        };
    assert!(turn_to(&mut p, 180.0, &|q| q.x <= 13.5, &mut ret, &mut disc));
    assert!(turn_to(&mut p, 90.0, &|q| q.y >= 6.5, &mut ret, &mut disc));
    assert!(turn_to(&mut p, 0.0, &|_| false, &mut ret, &mut disc) || p.done);
    let oracle = o.rollout(w, Pose::from_degrees(32.0, -7.0, 180.0), 2000).discounted_return;
    assert!(ret < -20.0, "the scripted route is a plausible route: {ret}");
    assert!(oracle >= ret - 1e-3, "oracle {oracle} < scripted {ret}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, ..ProptestConfig::default() })]

    /// Whatever the actions, the agent stays in the world, never ends up inside an
    /// obstacle, and every reward is one the scene can produce.
    #[test]
    fn random_walks_stay_in_free_space(seed in 0u64..1000, start in 0usize..14, actions in proptest::collection::vec(
        (-1.5f32..1.5, -1.5f32..1.5, -1.5f32..1.5), 60)) {
        let w = world(SimConfig::default());
        let p = w.scene.validation_points()[start];
        let mut ped = Pedestrian::default();
        ped.reset(Pose::from_degrees(p.x, p.y, seed as f32));
        let r = w.scene.rewards();
        for (a0, a1, a2) in actions {
            let v = pednav_sim::command_of([a0, a1, a2], &w.config).speed;
            let t = ped.step([a0, a1, a2], &w);
            prop_assert!(w.scene.extent.contains(t.pose.x, t.pose.y));
            for o in &w.scene.obstacles {
                prop_assert!(o.footprint.distance(t.pose.x, t.pose.y) > 0.25, "inside {:?}", o.kind);
            }
            let expected = r.map_reward(t.region) + r.speed * v + if t.collided { r.collision } else { 0.0 };
            prop_assert!((t.reward - expected).abs() < 1e-5);
            if t.terminated { break; }
        }
    }
}
