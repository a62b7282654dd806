//! Golden-image tests of the renderer: three first-person 84×84 views compared with
//! committed PNGs under `tests/data/golden/`, with a tolerance that absorbs
//! rasteriser differences (GPU vs Mesa, Vulkan vs GL) but not a changed scene,
//! camera or shading.
//!
//! Regenerate after an intended visual change with
//! `PEDNAV_BLESS=1 cargo test --release -p pednav-sim --test golden` and look at the PNGs.

use std::path::PathBuf;

use pednav_sim::{BackendChoice, CameraView, Look, Renderer, RendererConfig, Scene, SimConfig, SimWorld};

/// (file name, x, y, camera yaw in degrees): the Non-ACL start looking at the
/// zebra, the zebra crossing seen from its south end, the goal plaza ahead.
const POSES: [(&str, f32, f32, f32); 3] =
    [("fixed_start_west", 14.0, -7.0, 180.0), ("zebra_north", 13.0, -6.0, 90.0), ("goal_ahead", 12.0, 7.0, 0.0)];

/// Mean absolute difference allowed, in grey levels.
const MAX_MEAN_ABS: f64 = 3.0;
/// Fraction of pixels allowed to differ by more than `BIG_DIFF` grey levels.
const MAX_BIG_FRACTION: f64 = 0.02;
const BIG_DIFF: i32 = 32;

fn golden_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/golden")
}

#[test]
fn views_match_the_golden_images() {
    let cams: Vec<CameraView> = POSES
        .iter()
        .map(|&(_, x, y, yaw)| CameraView { x, y, z: 1.6, yaw: yaw.to_radians(), look: Look::default() })
        .collect();
    let frames = render(&cams);
    let bless = std::env::var("PEDNAV_BLESS").is_ok_and(|v| v == "1");
    let mut failures = Vec::new();
    for (i, (name, ..)) in POSES.iter().enumerate() {
        let got = frames[i].clone();
        let path = golden_dir().join(format!("{name}.png"));
        if bless {
            std::fs::create_dir_all(golden_dir()).unwrap();
            image::GrayImage::from_raw(84, 84, got.clone()).unwrap().save(&path).unwrap();
            continue;
        }
        let want = image::open(&path)
            .unwrap_or_else(|e| panic!("{}: {e} (bless with PEDNAV_BLESS=1)", path.display()))
            .to_luma8();
        assert_eq!(want.dimensions(), (84, 84), "{name}");
        let (mean, big) = compare(&got, want.as_raw());
        eprintln!("{name}: mean |diff| {mean:.3}, {:.2}% pixels > {BIG_DIFF} on {}", big * 100.0, renderer_name());
        if !within_tolerance(mean, big) {
            let out = std::env::temp_dir().join(format!("pednav-golden-{name}-actual.png"));
            image::GrayImage::from_raw(84, 84, got).unwrap().save(&out).unwrap();
            failures.push(format!(
                "{name}: mean {mean:.2}, big {:.2}% (actual saved to {})",
                big * 100.0,
                out.display()
            ));
        }
    }
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Mean absolute difference and fraction of pixels differing by more than `BIG_DIFF`.
fn compare(got: &[u8], want: &[u8]) -> (f64, f64) {
    let diffs: Vec<i32> = got.iter().zip(want).map(|(&a, &b)| (a as i32 - b as i32).abs()).collect();
    let mean = diffs.iter().map(|&d| d as f64).sum::<f64>() / diffs.len() as f64;
    let big = diffs.iter().filter(|&&d| d > BIG_DIFF).count() as f64 / diffs.len() as f64;
    (mean, big)
}

fn within_tolerance(mean: f64, big: f64) -> bool {
    mean <= MAX_MEAN_ABS && big <= MAX_BIG_FRACTION
}

fn render(cams: &[CameraView]) -> Vec<Vec<u8>> {
    let world = SimWorld::new(Scene::reference(), SimConfig::default()).unwrap();
    let cfg = RendererConfig::from_sim(&world.config, cams.len(), BackendChoice::from_env().unwrap());
    let mut renderer = Renderer::new(&world.scene, &world.map, cfg).unwrap();
    let frames = renderer.render(cams).unwrap();
    (0..cams.len()).map(|i| frames.frame(i)).collect()
}

#[test]
fn the_tolerance_catches_a_camera_turned_by_five_degrees_or_moved_by_half_a_metre() {
    for (name, x, y, yaw) in POSES {
        let want = image::open(golden_dir().join(format!("{name}.png"))).unwrap().to_luma8();
        let moved = [
            CameraView { x, y, z: 1.6, yaw: (yaw + 5.0).to_radians(), look: Look::default() },
            CameraView {
                x: x + 0.5 * yaw.to_radians().cos(),
                y: y + 0.5 * yaw.to_radians().sin(),
                z: 1.6,
                yaw: yaw.to_radians(),
                look: Look::default(),
            },
        ];
        for (k, got) in render(&moved).iter().enumerate() {
            let (mean, big) = compare(got, want.as_raw());
            assert!(!within_tolerance(mean, big), "{name} variant {k}: mean {mean:.2}, big {:.2}% passes", big * 100.0);
        }
    }
}

#[test]
fn the_goldens_are_not_trivial() {
    // A test that cannot fail on a blank image: each golden has real contrast.
    for (name, ..) in POSES {
        let img = image::open(golden_dir().join(format!("{name}.png"))).unwrap().to_luma8();
        let (lo, hi) = img.as_raw().iter().fold((255u8, 0u8), |(l, h), &v| (l.min(v), h.max(v)));
        assert!(hi - lo > 120, "{name}: range {lo}..{hi}");
    }
}

fn renderer_name() -> String {
    std::env::var("PEDNAV_BACKEND").unwrap_or_else(|_| "auto".into())
}
