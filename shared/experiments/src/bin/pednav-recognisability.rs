//! `pednav-recognisability` — can a pedestrian tell from one frame where it stands?
//!
//! ```text
//! pednav-recognisability                                   # reference scene, 42², 400 test poses
//! pednav-recognisability --scene built-in:corner_plain     # the look-alike first version
//! pednav-recognisability --config deploy/configs/cpu_reduced.toml --domain-randomization
//! ```
//! Two measures over seeded random sidewalk poses (module docs of
//! `pednav_sim::recognisability` and `pednav_experiments::probe`):
//! (a) aliasing — the share of test poses whose frame is closer (L2) to one of its
//! 90° / 180° / 270° twins about the crossing's centre than to its own 0.5 m / 10°
//! step; (b) which corner — the held-out accuracy of a small CNN trained on other
//! poses to name the quadrant from one frame. Writes `recognisability.json` and
//! `twins.png` (test poses in their four rotations, one row each) to `--out`.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Parser;
use image::RgbImage;
use pednav_experiments::probe::{ClassifierConfig, EpochProgress, Frames, ProbeShape, train_and_test};
use pednav_runtime::RunConfig;
use pednav_sim::draw::{enlarge_gray, save_png};
use pednav_sim::recognisability::{PoseSet, QUADRANT_NAMES, aliasing, render_frames, rotated};
use pednav_sim::{BackendChoice, Renderer, RendererConfig, Scene, SimConfig, SimWorld};

#[derive(Parser, Debug)]
#[command(version, about = "Measure how well one frame tells which corner of the intersection a pedestrian stands at")]
struct Cli {
    /// Run config whose scene and `[sim]` settings (image size, field of view, eye
    /// height, domain randomisation) are measured; default: the reference scene with
    /// the simulator's defaults at `--image-size`.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Scene file or `built-in:<name>` (overrides the config's).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Frame side in pixels (overrides the config's; default 42, the CPU preset's).
    #[arg(long)]
    image_size: Option<u32>,
    /// Render every pose with a domain-randomised look, as episodes do when
    /// `sim.domain_randomization` is on. Turns it on when the config leaves it off;
    /// without the flag the config's setting is used.
    #[arg(long)]
    domain_randomization: bool,
    /// Test poses: the aliasing measure and the classifier's held-out set.
    #[arg(long, default_value_t = 400)]
    poses: usize,
    /// Training poses of the classifier (drawn apart from the test poses).
    #[arg(long, default_value_t = 4000)]
    train_poses: usize,
    /// Classifier epochs.
    #[arg(long, default_value_t = 20)]
    epochs: usize,
    /// Seed of the poses, their looks, the classifier's weights and batches.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Graphics backend.
    #[arg(long, value_enum, env = "PEDNAV_BACKEND", default_value_t = BackendChoice::Auto)]
    backend: BackendChoice,
    /// Output folder.
    #[arg(long, default_value = "out/recognisability")]
    out: PathBuf,
}

fn main() -> Result<()> {
    pednav_sim::prepare_headless_env();
    pednav_runtime::init_logging();
    let cli = Cli::parse();
    if cli.poses == 0 || cli.train_poses == 0 || cli.epochs == 0 {
        bail!("--poses, --train-poses and --epochs must be at least 1");
    }
    let (mut scene_path, mut sim) = match &cli.config {
        Some(path) => {
            let cfg = RunConfig::load(path).with_context(|| format!("config {}", path.display()))?;
            (cfg.scene.clone(), cfg.sim.clone())
        }
        None => (None, SimConfig { image_size: 42, ..SimConfig::default() }),
    };
    if cli.scene.is_some() {
        scene_path = cli.scene.clone();
    }
    if let Some(size) = cli.image_size {
        sim.image_size = size;
    }
    sim.domain_randomization |= cli.domain_randomization;
    sim.validate().context("simulator settings")?;
    let scene = Scene::load_or_reference(scene_path.as_deref()).context("scene")?;
    let world = SimWorld::new(scene, sim.clone())?;
    let size = sim.image_size;
    let mut renderer = Renderer::new(&world.scene, &world.map, RendererConfig::from_sim(&sim, 64, cli.backend))?;
    eprintln!(
        "scene {} at {size}², {} look, renderer {}",
        world.scene.origin,
        if sim.domain_randomization { "domain-randomised" } else { "plain" },
        renderer.adapter_description()
    );

    let started = Instant::now();
    // Test and training poses from two streams of the seed: never the same poses.
    let test = PoseSet::sidewalks(&world.scene, cli.poses, cli.seed, sim.domain_randomization)?;
    let train = PoseSet::sidewalks(&world.scene, cli.train_poses, cli.seed ^ 0x7261_696e, sim.domain_randomization)?;
    let alias = aliasing(&mut renderer, &test, sim.eye_height)?;
    eprintln!(
        "(a) aliasing: {} of {} poses ({:.1} %) look more like a rotated twin than their own step; median twin/step distance {:.2}",
        alias.aliased,
        alias.poses,
        100.0 * alias.share,
        alias.median_twin_over_step
    );

    let test_frames = render_frames(&mut renderer, &test.poses, &test.looks, sim.eye_height)?;
    let train_frames = render_frames(&mut renderer, &train.poses, &train.looks, sim.eye_height)?;
    let (test_labels, train_labels) = (test.quadrants(), train.quadrants());
    let cfg = ClassifierConfig { epochs: cli.epochs, seed: cli.seed, ..ClassifierConfig::default() };
    let progress = EpochProgress::new("classifier", cli.epochs);
    let report = train_and_test(
        Frames { frames: &train_frames, labels: &train_labels },
        Frames { frames: &test_frames, labels: &test_labels },
        ProbeShape::single_frame(size as usize, 4),
        cfg,
        |epoch, loss| progress.epoch(epoch, loss),
    )?;
    progress.done();
    eprintln!(
        "(b) which corner: {:.1} % of {} held-out frames named right (train {:.1} % of {}; chance 25 %); by corner {}",
        100.0 * report.test_accuracy,
        report.test_frames,
        100.0 * report.train_accuracy,
        report.train_frames,
        QUADRANT_NAMES
            .iter()
            .zip(&report.test_accuracy_by_class)
            .map(|(n, a)| format!("{n} {:.0} %", 100.0 * a))
            .collect::<Vec<_>>()
            .join(", ")
    );

    std::fs::create_dir_all(&cli.out).with_context(|| format!("creating {}", cli.out.display()))?;
    let json = serde_json::json!({
        "scene": world.scene.origin,
        "image_size": size,
        "fov_deg": sim.fov_deg,
        "eye_height": sim.eye_height,
        "domain_randomization": sim.domain_randomization,
        "seed": cli.seed,
        "aliasing": alias,
        "classifier": report,
        "seconds": started.elapsed().as_secs_f64(),
    });
    let path = cli.out.join("recognisability.json");
    std::fs::write(&path, serde_json::to_string_pretty(&json)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;

    // Contact sheet: the first test poses, each in its four rotations (one row).
    let rows = test.poses.len().min(6);
    let mut twins = Vec::with_capacity(rows * 4);
    let mut looks = Vec::with_capacity(rows * 4);
    for (&p, &look) in test.poses.iter().zip(&test.looks).take(rows) {
        twins.extend((0..4).map(|k| rotated(p, k)));
        looks.extend([look; 4]);
    }
    let frames = render_frames(&mut renderer, &twins, &looks, sim.eye_height)?;
    let factor = (168 / size).max(1);
    let cell = size * factor;
    let mut sheet = RgbImage::from_pixel(4 * cell + 3 * 4, rows as u32 * cell + (rows as u32 - 1) * 4, [255; 3].into());
    for (i, f) in frames.iter().enumerate() {
        let big = enlarge_gray(f, size, factor);
        let (c, r) = ((i % 4) as u32, (i / 4) as u32);
        image::imageops::replace(&mut sheet, &big, (c * (cell + 4)) as i64, (r * (cell + 4)) as i64);
    }
    save_png(&sheet, &cli.out.join("twins.png"))?;
    println!(
        "aliasing {:.1} %, which corner {:.1} % — {} and twins.png in {}",
        100.0 * alias.share,
        100.0 * report.test_accuracy,
        path.file_name().and_then(|n| n.to_str()).unwrap_or_default(),
        cli.out.display()
    );
    Ok(())
}
