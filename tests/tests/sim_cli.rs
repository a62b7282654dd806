//! The simulator's commands, run as a user runs them (README, "Look at the simulator").

use std::process::{Command, Output};

use pednav_tests::{binary, scratch_dir};

fn sim(args: &[&str]) -> Output {
    Command::new(binary("pednav-sim", "shared/sim", "pednav-sim")).args(args).output().expect("run pednav-sim")
}

fn ok(args: &[&str]) -> String {
    let out = sim(args);
    assert!(out.status.success(), "pednav-sim {args:?} failed:\n{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

#[test]
fn view_writes_the_observation_an_enlargement_and_a_large_render() {
    let dir = scratch_dir("view");
    let out = dir.join("v.png");
    ok(&["view", "--x", "14", "--y", "-7", "--yaw-deg", "180", "--people-size", "256", "--out", out.to_str().unwrap()]);
    let obs = image::open(&out).unwrap();
    assert_eq!((obs.width(), obs.height()), (84, 84));
    assert!(matches!(obs, image::DynamicImage::ImageLuma8(_)), "greyscale u8");
    let x4 = image::open(dir.join("v-x4.png")).unwrap();
    assert_eq!((x4.width(), x4.height()), (336, 336));
    let big = image::open(dir.join("v-256.png")).unwrap().to_luma8();
    assert_eq!(big.dimensions(), (256, 256));
    let (lo, hi) = big.as_raw().iter().fold((255u8, 0u8), |(l, h), &v| (l.min(v), h.max(v)));
    assert!(hi - lo > 120, "a real picture, not a blank: {lo}..{hi}");
}

/// On a headless machine without `XDG_RUNTIME_DIR`, rendering prints no
/// window-system noise (libwayland's complaint, once per probe, before the fix).
#[test]
fn rendering_without_a_runtime_dir_prints_no_window_system_noise() {
    let dir = scratch_dir("headless");
    let out = Command::new(binary("pednav-sim", "shared/sim", "pednav-sim"))
        .args(["view", "--out", dir.join("v.png").to_str().unwrap()])
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .expect("run pednav-sim");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(!err.contains("XDG_RUNTIME_DIR"), "{err}");
}

#[test]
fn map_draws_the_scene_and_the_oracle_path() {
    let dir = scratch_dir("map");
    let out = dir.join("map.png");
    let stdout = ok(&["map", "--px-per-m", "4", "--oracle-from", "7", "--out", out.to_str().unwrap()]);
    assert!(stdout.contains("oracle from point 7") && stdout.contains("success true"), "{stdout}");
    let img = image::open(&out).unwrap().to_rgb8();
    // The reference world is 80 m × 70 m.
    assert_eq!(img.dimensions(), (320, 280));
    // The oracle path is drawn in red (220, 40, 40).
    assert!(img.pixels().filter(|p| p.0 == [220, 40, 40]).count() > 50);
}

#[test]
fn record_writes_a_gif_of_the_view_beside_the_map() {
    let dir = scratch_dir("record");
    let out = dir.join("ep.gif");
    let stdout = ok(&[
        "record",
        "--policy",
        "random",
        "--start",
        "first",
        "--steps",
        "10",
        "--seed",
        "3",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert!(stdout.contains("discounted return"), "{stdout}");
    let file = std::io::BufReader::new(std::fs::File::open(&out).unwrap());
    let decoder = image::codecs::gif::GifDecoder::new(file).unwrap();
    let frames = image::AnimationDecoder::into_frames(decoder).collect_frames().unwrap();
    assert_eq!(frames.len(), 11, "the start frame plus one per step");
    assert_eq!(frames[0].buffer().dimensions(), (336 + 8 + 320, 336));
}

#[test]
fn oracle_lists_all_fourteen_points() {
    let stdout = ok(&["oracle"]);
    let rows: Vec<&str> =
        stdout.lines().filter(|l| l.trim_start().chars().next().is_some_and(|c| c.is_ascii_digit())).collect();
    assert_eq!(rows.len(), 14, "{stdout}");
    assert!(
        rows.iter().all(|r| r.trim_end().ends_with("true")),
        "the oracle reaches the goal from every point:\n{stdout}"
    );
}

#[test]
fn a_bad_scene_stops_with_the_file_and_field_named() {
    let dir = scratch_dir("bad-scene");
    let text = include_str!("../../shared/sim/scenes/corner.toml").replace("cell_size = 0.05", "cell_size = 0.0");
    let path = dir.join("bad.toml");
    std::fs::write(&path, text).unwrap();
    let out = sim(&["--scene", path.to_str().unwrap(), "info"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.toml") && err.contains("cell_size"), "{err}");
    let out = sim(&["--scene", dir.join("missing.toml").to_str().unwrap(), "info"]);
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("missing.toml"));
}

#[test]
fn bench_prints_the_ratio_table() {
    let stdout = ok(&["bench", "--envs", "2", "--seconds", "0.2"]);
    assert!(stdout.contains("full/render"), "{stdout}");
    let row = stdout.lines().find(|l| l.trim_start().starts_with("2 ")).expect("a row for 2 envs");
    let ratio: f64 = row.split_whitespace().last().unwrap().parse().unwrap();
    assert!(ratio.is_finite() && ratio > 0.0);
}

#[test]
fn no_graphics_adapter_says_what_to_install() {
    // Point the Vulkan loader at a driver list that does not exist: no adapter at all.
    let out = Command::new(binary("pednav-sim", "shared/sim", "pednav-sim"))
        .args(["--backend", "vulkan", "view", "--out"])
        .arg(scratch_dir("no-adapter").join("v.png"))
        .env("VK_DRIVER_FILES", "/nonexistent/icd.json")
        .env("VK_ICD_FILENAMES", "/nonexistent/icd.json")
        .output()
        .expect("run pednav-sim");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no graphics adapter") && err.contains("apt-get install"), "{err}");
}
