//! `pednav-traffic-probe` — at the kerb with traffic on, can a pedestrian read from
//! its pixels whether the signal shows WALK and whether a vehicle is about to cross?
//!
//! ```text
//! pednav-traffic-probe                                         # medium traffic, 42², N_h 8 (the CPU preset)
//! pednav-traffic-probe --image-size 84 --history 16           # the paper's frames
//! pednav-traffic-probe --config deploy/configs/cpu_reduced_traffic.toml --out out/probe
//! ```
//! Four probes ([`pednav_experiments::probe`]), each trained on kerb examples drawn
//! from one seed and tested on examples from another (other poses, other phases,
//! other traffic; [`pednav_experiments::traffic_probe`]), both classes weighed
//! alike in the loss: (a) WALK from one frame and from the policy's `N_h`-frame
//! history through the policy's own encoder (the traffic's motion tells the phase
//! too); (b) a vehicle on the zebra within the next 3 s, from one frame and from the
//! history. Writes `traffic-probe.json`, `kerb.png` (test examples' last frames)
//! and `history.png` (one example's history) to `--out`.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Parser;
use image::RgbImage;
use pednav_experiments::probe::{
    ClassifierConfig, ClassifierReport, EpochProgress, Frames, ProbeShape, train_and_test,
};
use pednav_experiments::traffic_probe::{KerbExamples, KerbSetConfig, collect};
use pednav_nets::EncoderKind;
use pednav_runtime::RunConfig;
use pednav_sim::draw::{enlarge_gray, save_png};
use pednav_sim::{BackendChoice, Scene, SimConfig, SimWorld, TrafficLevel};

#[derive(Parser, Debug)]
#[command(version, about = "Measure whether the signal and oncoming vehicles can be read from the pixels at the kerb")]
struct Cli {
    /// Run config whose scene, `[sim]` settings and encoder (`nets.encoder`,
    /// `nets.history`) are probed; default: the reference scene, the simulator's
    /// defaults at 42², medium traffic, the 3D-TCN over 8 frames (the CPU preset).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Scene file or `built-in:<name>` (overrides the config's).
    #[arg(long)]
    scene: Option<PathBuf>,
    /// Traffic level (overrides the config's; `off` is refused).
    #[arg(long, value_enum)]
    traffic: Option<TrafficLevel>,
    /// Frame side in pixels (overrides the config's).
    #[arg(long)]
    image_size: Option<u32>,
    /// Render each frame at this many times its side and average k × k blocks, as a
    /// camera's pixel integrates light over its area (training episodes render one
    /// sample per pixel, at its centre: 1).
    #[arg(long, default_value_t = 1)]
    supersample: u32,
    /// Frames of the history probe (overrides the config's `nets.history`).
    #[arg(long)]
    history: Option<usize>,
    /// Training examples of every probe.
    #[arg(long, default_value_t = 4000)]
    examples: usize,
    /// Held-out test examples (drawn from another seed: other poses and phases).
    #[arg(long, default_value_t = 1000)]
    test_examples: usize,
    /// Seconds after the last frame in which a vehicle on the zebra makes the "vehicle soon" label.
    #[arg(long, default_value_t = 3.0)]
    horizon: f32,
    /// Probe epochs.
    #[arg(long, default_value_t = 20)]
    epochs: usize,
    /// Skip the history probes (the slowest).
    #[arg(long)]
    no_history: bool,
    /// Train on the plain mean loss instead of weighing both classes alike (with
    /// it, a probe that sees nothing settles on the majority class).
    #[arg(long)]
    unbalanced: bool,
    /// Seed of the examples, the probes' weights and batches.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Graphics backend.
    #[arg(long, value_enum, env = "PEDNAV_BACKEND", default_value_t = BackendChoice::Auto)]
    backend: BackendChoice,
    /// Output folder.
    #[arg(long, default_value = "out/traffic-probe")]
    out: PathBuf,
}

/// One probe's task: its name, what it reads, its labels.
struct Task<'a> {
    name: &'static str,
    shape: ProbeShape,
    train: Frames<'a>,
    test: Frames<'a>,
}

/// A task reading `frames` (training, test) labelled by `labels` (training, test).
type Pair<'a, T> = (&'a [T], &'a [T]);
fn task<'a>(name: &'static str, shape: ProbeShape, frames: Pair<'a, Vec<u8>>, labels: Pair<'a, usize>) -> Task<'a> {
    Task {
        name,
        shape,
        train: Frames { frames: frames.0, labels: labels.0 },
        test: Frames { frames: frames.1, labels: labels.1 },
    }
}

/// What is probed, after `--config` and the overrides: the scene file, the simulator, the encoder and its history.
struct Setup {
    scene_path: Option<PathBuf>,
    sim: SimConfig,
    encoder: EncoderKind,
    history: usize,
}

fn main() -> Result<()> {
    pednav_sim::prepare_headless_env();
    pednav_runtime::init_logging();
    let cli = Cli::parse();
    let s = setup(&cli)?;
    let size = s.sim.image_size as usize;
    let scene = Scene::load_or_reference(s.scene_path.as_deref()).context("scene")?;
    // The world renders at k × the side; the examples are k × k block means.
    let rendered = SimConfig { image_size: s.sim.image_size * cli.supersample, ..s.sim.clone() };
    let world = Arc::new(SimWorld::new(scene, rendered)?);
    eprintln!(
        "scene {} at {size}²{}, traffic {:?}, history {} ({:?}), {} + {} examples",
        world.scene.origin,
        if cli.supersample > 1 { format!(" ({}× supersampled)", cli.supersample) } else { String::new() },
        s.sim.traffic,
        s.history,
        s.encoder,
        cli.examples,
        cli.test_examples
    );

    let started = Instant::now();
    let (train, test) = draw_example_sets(&cli, &world, s.history)?;
    let reports = run_probes(&cli, &s, &train, &test)?;
    write_outputs(&cli, &s, &world, &train, &test, &reports, started)?;
    let summary: Vec<String> = reports
        .iter()
        .map(|(n, r)| format!("{n} {:.1} % (majority {:.1} %)", 100.0 * r.test_accuracy, 100.0 * r.test_majority))
        .collect();
    println!("{} — traffic-probe.json, kerb.png and history.png in {}", summary.join(", "), cli.out.display());
    Ok(())
}

/// Checks the counts, then reads `--config` (or the CPU preset) and applies the overrides of the command line.
fn setup(cli: &Cli) -> Result<Setup> {
    if cli.examples == 0 || cli.test_examples == 0 || cli.epochs == 0 {
        bail!("--examples, --test-examples and --epochs must be at least 1");
    }
    let (mut scene_path, mut sim, mut encoder, mut history) = match &cli.config {
        Some(path) => {
            let cfg = RunConfig::load(path).with_context(|| format!("config {}", path.display()))?;
            (cfg.scene.clone(), cfg.sim.clone(), cfg.nets.encoder, cfg.nets.history)
        }
        None => (
            None,
            SimConfig { image_size: 42, traffic: TrafficLevel::Medium, ..SimConfig::default() },
            EncoderKind::Tcn,
            8,
        ),
    };
    scene_path = cli.scene.clone().or(scene_path);
    sim.traffic = cli.traffic.unwrap_or(sim.traffic);
    sim.image_size = cli.image_size.unwrap_or(sim.image_size);
    history = cli.history.unwrap_or(history);
    if !sim.traffic.is_on() {
        bail!("--traffic: the kerb probes need traffic (light, medium or heavy); the config has it off");
    }
    if encoder == EncoderKind::Mlp {
        encoder = EncoderKind::Tcn;
    }
    if history == 0 {
        bail!("--history must be at least 1");
    }
    if cli.supersample == 0 {
        bail!("--supersample must be at least 1");
    }
    sim.validate().context("simulator settings")?;
    Ok(Setup { scene_path, sim, encoder, history })
}

/// Draws the training and the test kerb examples, from two seed streams, reporting their label shares.
fn draw_example_sets(cli: &Cli, world: &Arc<SimWorld>, history: usize) -> Result<(KerbExamples, KerbExamples)> {
    let tty = std::io::stderr().is_terminal();
    let draw = |name: &str, seed: u64, examples: usize| -> Result<KerbExamples> {
        let cfg = KerbSetConfig {
            examples,
            history,
            horizon_s: cli.horizon,
            seed,
            batch_envs: 32,
            supersample: cli.supersample,
        };
        let set = collect(world, cfg, cli.backend, |done| {
            if tty {
                eprint!("\r    {name}: {done}/{examples} examples");
            }
        })?;
        if tty {
            eprintln!();
        }
        eprintln!(
            "{name}: {} examples, WALK {:.1} %, vehicle within {} s {:.1} %",
            set.frames.len(),
            100.0 * KerbExamples::positive_share(&set.walk),
            cli.horizon,
            100.0 * KerbExamples::positive_share(&set.vehicle_soon)
        );
        Ok(set)
    };
    // Two seed streams: the test poses, phases and traffic are never trained on.
    let train = draw("training set", cli.seed, cli.examples)?;
    let test = draw("test set", cli.seed ^ 0x7465_7374, cli.test_examples)?;
    Ok((train, test))
}

/// Trains and tests each probe (one frame, and the history unless skipped), reporting each one's accuracy.
fn run_probes(
    cli: &Cli,
    s: &Setup,
    train: &KerbExamples,
    test: &KerbExamples,
) -> Result<Vec<(&'static str, ClassifierReport)>> {
    let (size, history, encoder) = (s.sim.image_size as usize, s.history, s.encoder);
    // Every probe reads one of two views of the same examples: the last frame, or the history.
    let (train_last, test_last) = (train.last_frames(), test.last_frames());
    let one = ProbeShape::single_frame(size, 2);
    let walk = (&train.walk[..], &test.walk[..]);
    let vehicle = (&train.vehicle_soon[..], &test.vehicle_soon[..]);
    let last = (&train_last[..], &test_last[..]);
    let mut tasks = vec![task("walk_one_frame", one, last, walk), task("vehicle_one_frame", one, last, vehicle)];
    if !cli.no_history && history > 1 {
        let shape = ProbeShape { size, history, encoder, classes: 2 };
        let all = (&train.frames[..], &test.frames[..]);
        tasks.push(task("walk_history", shape, all, walk));
        tasks.push(task("vehicle_history", shape, all, vehicle));
    }
    let mut reports: Vec<(&'static str, ClassifierReport)> = Vec::new();
    for task in &tasks {
        let cfg = ClassifierConfig {
            epochs: cli.epochs,
            seed: cli.seed,
            balance_classes: !cli.unbalanced,
            ..ClassifierConfig::default()
        };
        let t0 = Instant::now();
        let progress = EpochProgress::new(task.name, cli.epochs);
        let report = train_and_test(task.train, task.test, task.shape, cfg, |epoch, loss| progress.epoch(epoch, loss))?;
        progress.done();
        eprintln!(
            "{}: held-out accuracy {:.1} % (majority class {:.1} %, balanced {:.1} %; train {:.1} %) in {:.0} s",
            task.name,
            100.0 * report.test_accuracy,
            100.0 * report.test_majority,
            100.0 * report.test_balanced_accuracy,
            100.0 * report.train_accuracy,
            t0.elapsed().as_secs_f64()
        );
        reports.push((task.name, report));
    }
    Ok(reports)
}

/// Writes `traffic-probe.json` (settings, label shares, test labels, the probes' reports) and the sheets to `--out`.
fn write_outputs(
    cli: &Cli,
    s: &Setup,
    world: &SimWorld,
    train: &KerbExamples,
    test: &KerbExamples,
    reports: &[(&'static str, ClassifierReport)],
    started: Instant,
) -> Result<()> {
    let (size, sim) = (s.sim.image_size as usize, &s.sim);
    std::fs::create_dir_all(&cli.out).with_context(|| format!("creating {}", cli.out.display()))?;
    let probes: serde_json::Map<String, serde_json::Value> =
        reports.iter().map(|(n, r)| Ok(((*n).to_string(), serde_json::to_value(r)?))).collect::<Result<_>>()?;
    let json = serde_json::json!({
        "scene": world.scene.origin,
        "image_size": size,
        "supersample": cli.supersample,
        "fov_deg": sim.fov_deg,
        "traffic": sim.traffic, "ground_signals": sim.traffic_ground_signals,
        "history": s.history,
        "encoder": format!("{:?}", s.encoder),
        "horizon_s": cli.horizon,
        "seed": cli.seed,
        "epochs": cli.epochs,
        "train": { "examples": train.frames.len(), "walk_share": KerbExamples::positive_share(&train.walk),
                   "vehicle_share": KerbExamples::positive_share(&train.vehicle_soon) },
        "test": { "examples": test.frames.len(), "walk_share": KerbExamples::positive_share(&test.walk),
                  "vehicle_share": KerbExamples::positive_share(&test.vehicle_soon),
                  "walk": test.walk, "vehicle_soon": test.vehicle_soon, "zebra": test.zebra,
                  "cycle_time": test.cycle_time },
        "probes": probes,
        "seconds": started.elapsed().as_secs_f64(),
    });
    let path = cli.out.join("traffic-probe.json");
    std::fs::write(&path, serde_json::to_string_pretty(&json)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    write_sheets(test, &cli.out)?;
    Ok(())
}

/// `kerb.png`: the last frames of the first 16 test examples, WALK ones first (a
/// row of 8 each); `history.png`: the first test example's frames, oldest first.
fn write_sheets(test: &KerbExamples, out: &std::path::Path) -> Result<()> {
    let size = test.size as u32;
    let factor = (168 / size).max(1);
    let cell = size * factor;
    let last = test.last_frames();
    let pick = |walk: usize| (0..last.len()).filter(move |&i| test.walk[i] == walk).take(8);
    let rows: Vec<Vec<usize>> = vec![pick(1).collect(), pick(0).collect()];
    let sheet_of = |cells: &[Vec<&[u8]>]| -> RgbImage {
        let cols = cells.iter().map(Vec::len).max().unwrap_or(1).max(1) as u32;
        let n = cells.len().max(1) as u32;
        let mut sheet = RgbImage::from_pixel(cols * cell + (cols - 1) * 4, n * cell + (n - 1) * 4, [255; 3].into());
        for (r, row) in cells.iter().enumerate() {
            for (c, f) in row.iter().enumerate() {
                let big = enlarge_gray(f, size, factor);
                image::imageops::replace(
                    &mut sheet,
                    &big,
                    (c as u32 * (cell + 4)) as i64,
                    (r as u32 * (cell + 4)) as i64,
                );
            }
        }
        sheet
    };
    let cells: Vec<Vec<&[u8]>> = rows.iter().map(|r| r.iter().map(|&i| last[i].as_slice()).collect()).collect();
    save_png(&sheet_of(&cells), &out.join("kerb.png"))?;
    let n = (size * size) as usize;
    let history: Vec<&[u8]> = test.frames[0].chunks(n).collect();
    save_png(&sheet_of(&[history]), &out.join("history.png"))?;
    Ok(())
}
