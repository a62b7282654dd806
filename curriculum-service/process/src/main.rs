//! `pednav-curriculum` — the curriculum service of a pednav run.
//!
//! `serve`: answers actors' task requests (iceoryx2 request-response), takes
//! their episode reports (pub-sub), runs Algorithm 1 ([`Curriculum`]), logs
//! per-category counts, μ, σ, the f^r loss, the phase and t_c to
//! `metrics/curriculum.csv` and TensorBoard, and saves its state to
//! `checkpoints/curriculum.json` every `runtime.curriculum_save_every_episodes`
//! reports and on stop; a restart into the same run directory resumes from it.
//!
//! `draw`: the classification of the curriculum region (easy / frontier /
//! hard-or-random per cell, like the paper's Fig. 4) from a saved state, as a PNG.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use pednav_curriculum::filter::bands;
use pednav_curriculum::{Category, Curriculum, CurriculumState, EpisodeOutcome, Fit, TaskSampler, task_features};
use pednav_runtime::messages::{Heartbeat, TaskResponse, process_kind};
use pednav_runtime::{Ipc, Metrics, RunConfig, RunDir, StopFlag, category_code, category_of, run_prefix};
use pednav_sim::{Pose, RegionMap, Scene};
use rand::SeedableRng;
use serde::{Deserialize, Serialize};

#[derive(Parser)]
#[command(version, about = "pednav curriculum service (NavACL⁺, NavACL, fixed start)")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Serve tasks for the run in RUN_DIR (its config.toml decides the variant).
    Serve {
        /// The run directory (created by `pednav-run`).
        #[arg(long)]
        run_dir: PathBuf,
    },
    /// Draw the task classification over the curriculum region from a saved state.
    Draw {
        /// The run directory.
        #[arg(long)]
        run_dir: PathBuf,
        /// Output PNG (default: <run>/plots/curriculum.png).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Grid cell size in metres.
        #[arg(long, default_value_t = 0.5)]
        cell: f32,
    },
}

/// What `checkpoints/curriculum.json` holds.
#[derive(Serialize, Deserialize)]
struct SavedService {
    curriculum: CurriculumState,
    next_task_id: u64,
    proposed: BTreeMap<String, u64>,
}

fn main() -> Result<()> {
    pednav_runtime::init_logging();
    match Cli::parse().command {
        Command::Serve { run_dir } => serve(&run_dir),
        Command::Draw { run_dir, out, cell } => {
            let out = out.unwrap_or_else(|| run_dir.join("plots").join("curriculum.png"));
            draw(&run_dir, &out, cell)?;
            println!("wrote {}", out.display());
            Ok(())
        }
    }
}

fn curriculum_seed(cfg: &RunConfig) -> u64 {
    cfg.seed ^ 0x6375_7272_6963_756c
}

/// The run's curriculum, restored from its saved state when there is one.
fn load_curriculum(dir: &RunDir, cfg: &RunConfig, scene: Scene) -> Result<(Curriculum, Option<SavedService>)> {
    let mut curriculum = Curriculum::new(cfg.curriculum.clone(), scene, curriculum_seed(cfg))?;
    let path = dir.curriculum_state();
    if !path.exists() {
        return Ok((curriculum, None));
    }
    let text = std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let saved: SavedService =
        serde_json::from_str(&text).with_context(|| format!("{} is not a curriculum state", path.display()))?;
    curriculum.restore(&saved.curriculum).with_context(|| format!("restoring {}", path.display()))?;
    Ok((curriculum, Some(saved)))
}

fn save(dir: &RunDir, curriculum: &Curriculum, next_task_id: u64, proposed: &BTreeMap<String, u64>) -> Result<()> {
    let saved = SavedService { curriculum: curriculum.state()?, next_task_id, proposed: proposed.clone() };
    let path = dir.curriculum_state();
    let tmp = path.with_extension("json.tmp");
    std::fs::write(&tmp, serde_json::to_vec(&saved)?).with_context(|| format!("writing {}", tmp.display()))?;
    std::fs::rename(&tmp, &path).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

fn category_name(c: Category) -> &'static str {
    match c {
        Category::First => "first",
        Category::Fixed => "fixed",
        Category::Easy => "easy",
        Category::Frontier => "frontier",
        Category::Random => "random",
        Category::Hard => "hard",
    }
}

fn serve(run_dir: &Path) -> Result<()> {
    let stop = StopFlag::install();
    let dir = RunDir::new(run_dir);
    let cfg = dir.load_config()?;
    let scene = cfg.scene()?;
    let (mut curriculum, saved) = load_curriculum(&dir, &cfg, scene)?;
    let (mut next_task_id, mut proposed) = match saved {
        Some(s) => {
            tracing::info!(
                episodes = curriculum.episodes(),
                t_c = curriculum.scheduler().t_c(),
                acl = curriculum.scheduler().in_acl_phase(),
                "resumed curriculum state"
            );
            (s.next_task_id, s.proposed)
        }
        None => (1, BTreeMap::new()),
    };
    let ipc = Ipc::new(
        &run_prefix(run_dir),
        "curriculum",
        cfg.runtime.step_buffer,
        Duration::from_secs_f64(cfg.runtime.give_up_secs),
        stop.clone(),
    )?;
    let server = ipc.task_server()?;
    let reports = ipc.episode_subscriber()?;
    let heartbeat = ipc.heartbeat_publisher()?;
    let mut metrics = Metrics::open(&dir.metrics(), &dir.tb(), "curriculum")?;
    tracing::info!(variant = ?cfg.curriculum.variant, "curriculum service ready");

    let mut last_fit: Option<Fit> = None;
    let mut last_loss: Option<f32> = None;
    let mut recent: std::collections::VecDeque<f32> = std::collections::VecDeque::new();
    let mut successes: std::collections::VecDeque<bool> = std::collections::VecDeque::new();
    let mut last_log = Instant::now();
    let mut since_save = 0u64;
    let log_every = Duration::from_secs_f64(cfg.runtime.metrics_every_secs);
    while !stop.is_set() {
        let mut busy = false;
        while let Some(request) = server.receive().map_err(|e| anyhow::anyhow!("task server: {e:?}"))? {
            busy = true;
            let p = curriculum.propose()?;
            if p.fit.is_some() {
                last_fit = p.fit;
            }
            *proposed.entry(category_name(p.category).to_string()).or_default() += 1;
            let response = TaskResponse {
                x: p.pose.x,
                y: p.pose.y,
                yaw: p.pose.yaw,
                category: category_code(p.category),
                task_id: next_task_id,
            };
            next_task_id += 1;
            if let Err(e) = request.send_copy(response) {
                tracing::warn!(actor = request.payload().actor, "task response not delivered: {e:?}");
            }
        }
        while let Some(sample) = reports.receive().map_err(|e| anyhow::anyhow!("episode subscriber: {e:?}"))? {
            busy = true;
            let h = *sample.user_header();
            let points = sample.payload();
            if points.len() != h.length as usize + 1 {
                tracing::warn!(
                    actor = h.actor,
                    env = h.env,
                    "episode report with {} points for {} steps: ignored",
                    points.len(),
                    h.length
                );
                continue;
            }
            let outcome = EpisodeOutcome {
                category: category_of(h.category)?,
                poses: points.iter().map(|p| Pose { x: p.x, y: p.y, yaw: p.yaw }).collect(),
                rewards: points[1..].iter().map(|p| p.reward).collect(),
                truncated: h.truncated != 0,
                success: h.success != 0,
            };
            drop(sample);
            let summary = curriculum.report(&outcome)?;
            if let Some(l) = summary.trained_loss {
                last_loss = Some(l);
            }
            recent.push_back(summary.discounted_return);
            successes.push_back(outcome.success);
            if recent.len() > 100 {
                recent.pop_front();
                successes.pop_front();
            }
            since_save += 1;
            if since_save >= cfg.runtime.curriculum_save_every_episodes {
                save(&dir, &curriculum, next_task_id, &proposed)?;
                since_save = 0;
            }
        }
        if last_log.elapsed() >= log_every {
            last_log = Instant::now();
            let s = curriculum.scheduler();
            let mean_return =
                if recent.is_empty() { f64::NAN } else { recent.iter().sum::<f32>() as f64 / recent.len() as f64 };
            let success = if successes.is_empty() {
                f64::NAN
            } else {
                successes.iter().filter(|&&s| s).count() as f64 / successes.len() as f64
            };
            let count = |c: Category| proposed.get(category_name(c)).copied().unwrap_or(0) as f64;
            let values = [
                ("episodes", curriculum.episodes() as f64),
                ("phase_acl", if s.in_acl_phase() { 1.0 } else { 0.0 }),
                ("t_c", s.t_c() as f64),
                ("first_task_mean_return", s.gate().mean().map_or(f64::NAN, |m| m as f64)),
                ("mean_return_100", mean_return),
                ("success_rate_100", success),
                ("mu", last_fit.map_or(f64::NAN, |f| f.mu as f64)),
                ("sigma", last_fit.map_or(f64::NAN, |f| f.sigma as f64)),
                ("fr_loss", last_loss.map_or(f64::NAN, |l| l as f64)),
                ("n_first", count(Category::First)),
                ("n_fixed", count(Category::Fixed)),
                ("n_easy", count(Category::Easy)),
                ("n_frontier", count(Category::Frontier)),
                ("n_random", count(Category::Random)),
                ("n_hard", count(Category::Hard)),
            ];
            metrics.log(curriculum.episodes(), &values)?;
            tracing::info!(
                episodes = curriculum.episodes(),
                acl = s.in_acl_phase(),
                t_c = s.t_c(),
                first_task_mean = ?s.gate().mean(),
                mu = ?last_fit.map(|f| f.mu),
                sigma = ?last_fit.map(|f| f.sigma),
                loss = ?last_loss,
                proposed = ?proposed,
                "curriculum"
            );
            let hb = Heartbeat {
                kind: process_kind::CURRICULUM,
                pid: std::process::id(),
                phase: s.in_acl_phase() as u32,
                steps: s.t_c(),
                count: curriculum.episodes(),
                recent_return: mean_return as f32,
                ..Heartbeat::default()
            };
            let _ = heartbeat.send_copy(hb);
        }
        if !busy {
            std::thread::sleep(Duration::from_micros(500));
        }
    }
    save(&dir, &curriculum, next_task_id, &proposed)?;
    dir.write_stats(
        "curriculum",
        &serde_json::json!({
            "episodes": curriculum.episodes(),
            "tasks_issued": next_task_id - 1,
            "proposed": proposed,
            "t_c": curriculum.scheduler().t_c(),
            "acl_phase": curriculum.scheduler().in_acl_phase(),
        }),
    )?;
    tracing::info!(episodes = curriculum.episodes(), "curriculum service stopped; state saved");
    Ok(())
}

/// Classify a grid over the curriculum region (yaw facing the goal, the
/// orientation a researcher reads Fig. 4 with) and draw it over the map.
fn draw(run_dir: &Path, out: &Path, cell: f32) -> Result<()> {
    if cell.is_nan() || cell <= 0.05 {
        bail!("--cell must be larger than 0.05 m, got {cell}");
    }
    let dir = RunDir::new(run_dir);
    let cfg = dir.load_config()?;
    let scene = cfg.scene()?;
    let (mut curriculum, saved) = load_curriculum(&dir, &cfg, scene.clone())?;
    if saved.is_none() {
        bail!("{} has no saved curriculum state yet (checkpoints/curriculum.json)", run_dir.display());
    }
    // μ, σ as the scheduler would fit them: the predictions of candidate tasks.
    let sampler = TaskSampler::new(&scene, cfg.curriculum.max_rejections);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let candidates: Vec<[f32; 3]> = (0..cfg.curriculum.candidates)
        .map(|_| sampler.sample(&scene, &mut rng).map(|p| task_features(p, scene.goal_center)))
        .collect::<Result<_, _>>()?;
    let Some(predictions) = curriculum.predict(&candidates) else {
        bail!("the fixed-start variant has no task classification to draw");
    };
    let fit = Fit::of(&predictions).expect("candidates ≥ 2");
    let b = bands(&cfg.curriculum, fit, curriculum.scheduler().t_c());
    let map = RegionMap::new(&scene);
    let mut canvas = pednav_sim::draw::draw_map(&scene, &map, 12.0);
    let bounds = scene.curriculum_region.iter().map(|p| p.bounds()).fold(None, |acc: Option<[f32; 4]>, r| {
        let [x0, y0, x1, y1] = acc.unwrap_or([f32::MAX, f32::MAX, f32::MIN, f32::MIN]);
        Some([x0.min(r.min[0]), y0.min(r.min[1]), x1.max(r.max[0]), y1.max(r.max[1])])
    });
    let [x0, y0, x1, y1] = bounds.context("the scene has no curriculum region")?;
    let mut counts = BTreeMap::new();
    let mut y = y0 + cell / 2.0;
    while y < y1 {
        let mut x = x0 + cell / 2.0;
        while x < x1 {
            if scene.in_curriculum_region(x, y) {
                let yaw = (scene.goal_center[1] - y).atan2(scene.goal_center[0] - x);
                let f = curriculum.predict(&[task_features(Pose { x, y, yaw }, scene.goal_center)]).unwrap()[0];
                let (name, colour) = if b.contains(Category::Easy, f) {
                    ("easy", [40, 170, 60])
                } else if b.contains(Category::Frontier, f) {
                    ("frontier", [240, 190, 30])
                } else if b.contains(Category::Hard, f) {
                    ("hard", [200, 40, 40])
                } else {
                    ("other", [150, 110, 170])
                };
                *counts.entry(name).or_insert(0u32) += 1;
                canvas.disc(x, y, cell * canvas.scale * 0.5, colour);
            }
            x += cell;
        }
        y += cell;
    }
    let goal = scene.goal_center;
    canvas.disc(goal[0], goal[1], 0.4 * canvas.scale, [255, 255, 255]);
    if let Some(parent) = out.parent() {
        std::fs::create_dir_all(parent)?;
    }
    pednav_sim::draw::save_png(&canvas.image, out)?;
    println!(
        "μ = {:.2}, σ = {:.2}, t_c = {}, phase = {}; cells: {counts:?} (green easy, yellow frontier, red hard, purple neither)",
        fit.mu,
        fit.sigma,
        curriculum.scheduler().t_c(),
        if curriculum.scheduler().in_acl_phase() { "ACL" } else { "first task" }
    );
    Ok(())
}
