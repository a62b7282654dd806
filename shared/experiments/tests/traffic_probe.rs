//! The kerb examples of `pednav-traffic-probe` are what their docs say: poses at a
//! zebra's kerb facing across it, labels that agree with the signal plan and with
//! the traffic the frames show, the same examples from the same seed and others
//! from another.

use std::sync::Arc;

use pednav_experiments::traffic_probe::{KerbExamples, KerbSetConfig, box_downsample, collect, kerb_pose};
use pednav_sim::traffic::{PedestrianSignal, TrafficState};
use pednav_sim::{BackendChoice, RegionKind, Scene, SimConfig, SimWorld, TrafficLevel};
use rand::SeedableRng;

fn world(size: u32) -> Arc<SimWorld> {
    pednav_sim::prepare_headless_env();
    let sim = SimConfig { image_size: size, traffic: TrafficLevel::Medium, ..SimConfig::default() };
    Arc::new(SimWorld::new(Scene::reference(), sim).unwrap())
}

#[test]
fn kerb_poses_stand_at_a_kerb_facing_across() {
    let w = world(42);
    let (traffic, _) = w.traffic.as_ref().unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    for _ in 0..500 {
        let (pose, z) = kerb_pose(traffic, &mut rng);
        let region = w.scene.region_kind_exact(pose.x, pose.y);
        assert!(!matches!(region, RegionKind::Road | RegionKind::Zebra), "{pose:?} on {region:?}");
        assert!(TrafficState::at_kerb(traffic, [pose.x, pose.y], region), "{pose:?} not at a kerb");
        // Facing the zebra's far end within 25° (and a bit for the lateral offset).
        let ends = traffic.zebras[z].ends();
        let far = ends.iter().max_by(|a, b| {
            let d = |p: &[f32; 2]| (p[0] - pose.x).hypot(p[1] - pose.y);
            d(a).total_cmp(&d(b))
        });
        let far = far.unwrap();
        let bearing = (far[1] - pose.y).atan2(far[0] - pose.x);
        let off = pednav_sim::scene::wrap_angle(pose.yaw - bearing).abs().to_degrees();
        assert!(off < 25.0 + 12.0, "{pose:?} looks {off:.0}° away from zebra {z}'s far end");
    }
}

#[test]
fn kerb_examples_are_labelled_by_the_plan_and_the_seed() {
    let w = world(42);
    let (traffic, _) = w.traffic.as_ref().unwrap();
    let cfg = KerbSetConfig { examples: 40, history: 3, horizon_s: 3.0, seed: 9, batch_envs: 16, supersample: 1 };
    let a = collect(&w, cfg, BackendChoice::Auto, |_| {}).unwrap();
    assert_eq!(a.frames.len(), 40);
    assert!(a.frames.iter().all(|f| f.len() == 3 * 42 * 42));
    assert_eq!(a.last_frames()[0], a.frames[0][2 * 42 * 42..]);
    for i in 0..40 {
        let shown = traffic.plan.pedestrian(a.zebra[i], a.cycle_time[i]) == PedestrianSignal::Walk;
        assert_eq!(a.walk[i] == 1, shown, "example {i}");
        w.scene.check_task(a.poses[i]).unwrap();
    }
    // Frames change as traffic moves although the pedestrian stands still.
    assert!(a.frames.iter().any(|f| f[..42 * 42] != f[2 * 42 * 42..]));
    let b = collect(&w, cfg, BackendChoice::Auto, |_| {}).unwrap();
    assert_eq!(
        (&a.frames, &a.walk, &a.vehicle_soon, &a.cycle_time),
        (&b.frames, &b.walk, &b.vehicle_soon, &b.cycle_time)
    );
    let c = collect(&w, KerbSetConfig { seed: 10, ..cfg }, BackendChoice::Auto, |_| {}).unwrap();
    assert_ne!(a.cycle_time, c.cycle_time);
    // Over a larger draw both labels take both values, WALK near its share of the cycle.
    let big = collect(&w, KerbSetConfig { examples: 400, history: 1, ..cfg }, BackendChoice::Auto, |_| {}).unwrap();
    let walk = KerbExamples::positive_share(&big.walk);
    let walk_share = traffic.plan.phases[0].walk_s / traffic.plan.cycle_s;
    assert!((walk - walk_share).abs() < 0.06, "WALK in {walk:.3} of the examples, {walk_share:.3} of the cycle");
    let soon = KerbExamples::positive_share(&big.vehicle_soon);
    assert!((0.1..0.9).contains(&soon), "vehicle soon in {soon:.3}");
}

#[test]
fn traffic_off_is_refused_with_the_field_named() {
    pednav_sim::prepare_headless_env();
    let w = Arc::new(SimWorld::new(Scene::reference(), SimConfig { image_size: 42, ..SimConfig::default() }).unwrap());
    let cfg = KerbSetConfig { examples: 4, history: 1, horizon_s: 3.0, seed: 1, batch_envs: 4, supersample: 1 };
    let e = collect(&w, cfg, BackendChoice::Auto, |_| {}).unwrap_err().to_string();
    assert!(e.contains("sim.traffic"), "{e}");
}

/// Block means by hand: a 4² frame to 2² (k 2, rounding half up) and to 1² (k 4).
#[test]
fn box_downsample_averages_blocks() {
    #[rustfmt::skip]
    let f = [
        0, 2, 10, 10,
        4, 1, 10, 11,
        255, 255, 0, 0,
        255, 254, 0, 1,
    ];
    assert_eq!(box_downsample(&f, 4, 2), vec![2, 10, 255, 0]); // 7/4 → 2, 41/4 → 10, 1019/4 → 255, 1/4 → 0
    assert_eq!(box_downsample(&f, 4, 4), vec![67]); // (1068 + 8) / 16
    assert_eq!(box_downsample(&f, 4, 1), f.to_vec());
}

/// With supersampling the examples are the rendered frames' block means, at the
/// side divided by k, and the labels are those of the same episodes.
#[test]
fn supersampled_examples_are_block_means_of_the_rendered_frames() {
    let (fine, coarse) = (world(84), 42);
    let cfg = KerbSetConfig { examples: 8, history: 2, horizon_s: 3.0, seed: 3, batch_envs: 8, supersample: 1 };
    let full = collect(&fine, cfg, BackendChoice::Auto, |_| {}).unwrap();
    let ss = collect(&fine, KerbSetConfig { supersample: 2, ..cfg }, BackendChoice::Auto, |_| {}).unwrap();
    assert_eq!((ss.size, full.size), (coarse, 84));
    assert_eq!((&ss.walk, &ss.vehicle_soon), (&full.walk, &full.vehicle_soon));
    for (a, b) in ss.frames.iter().zip(&full.frames) {
        let mine: Vec<u8> = b.chunks(84 * 84).flat_map(|f| box_downsample(f, 84, 2)).collect();
        assert_eq!(a, &mine);
    }
}
