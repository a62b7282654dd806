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
use pednav_curriculum::{Category, Curriculum, EpisodeOutcome, Fit, ServiceState, classify_region};
use pednav_runtime::messages::{EpisodeHeader, Heartbeat, TaskResponse, process_kind};
use pednav_runtime::{Ipc, Metrics, RunConfig, RunDir, StopFlag, category_code, category_of, run_prefix};
use pednav_sim::{Pose, Scene};

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
        /// A saved state to draw instead of the latest (e.g. one of
        /// `checkpoints/curriculum-snapshots/*.json`).
        #[arg(long)]
        state: Option<PathBuf>,
    },
}

/// Reported episodes between two saved snapshots of the curriculum state
/// (`checkpoints/curriculum-snapshots/`, what `pednav-plot curriculum` draws over time).
const SNAPSHOT_EVERY_EPISODES: u64 = 500;

/// One row per reported episode: `metrics/episodes.csv`.
struct EpisodeLog {
    file: std::fs::File,
}

impl EpisodeLog {
    fn open(dir: &RunDir) -> Result<EpisodeLog> {
        let path = dir.metrics().join("episodes.csv");
        let new = !path.exists();
        let mut file = std::fs::OpenOptions::new().create(true).append(true).open(&path)?;
        if new {
            use std::io::Write;
            writeln!(
                file,
                "episode,decision_steps,actor,env,task_id,category,x,y,yaw_deg,length,discounted_return,success,truncated"
            )?;
        }
        Ok(EpisodeLog { file })
    }

    #[allow(clippy::too_many_arguments)]
    fn write(&mut self, episode: u64, steps: u64, h: &EpisodeHeader, start: Pose, ret: f32) -> Result<()> {
        use std::io::Write;
        writeln!(
            self.file,
            "{episode},{steps},{},{},{},{},{:.3},{:.3},{:.1},{},{ret:.4},{},{}",
            h.actor,
            h.env,
            h.task_id,
            category_name(category_of(h.category)?),
            start.x,
            start.y,
            start.yaw.to_degrees(),
            h.length,
            h.success,
            h.truncated
        )?;
        Ok(())
    }
}

fn main() -> Result<()> {
    pednav_runtime::init_logging();
    match Cli::parse().command {
        Command::Serve { run_dir } => serve(&run_dir),
        Command::Draw { run_dir, out, cell, state } => {
            let out = out.unwrap_or_else(|| run_dir.join("plots").join("curriculum.png"));
            draw(&run_dir, state.as_deref(), &out, cell)?;
            println!("wrote {}", out.display());
            Ok(())
        }
    }
}

fn curriculum_seed(cfg: &RunConfig) -> u64 {
    cfg.seed ^ 0x6375_7272_6963_756c
}

/// The run's curriculum, restored from the saved state at `path` when there is one.
fn load_curriculum(path: &Path, cfg: &RunConfig, scene: Scene) -> Result<(Curriculum, Option<ServiceState>)> {
    if !path.exists() {
        return Ok((Curriculum::new(cfg.curriculum.clone(), scene, curriculum_seed(cfg))?, None));
    }
    let saved = ServiceState::load(path)?;
    let curriculum = pednav_curriculum::classify::restore(&cfg.curriculum, scene, curriculum_seed(cfg), &saved)
        .with_context(|| format!("restoring {}", path.display()))?;
    Ok((curriculum, Some(saved)))
}

fn save(
    curriculum: &Curriculum,
    next_task_id: u64,
    proposed: &BTreeMap<String, u64>,
    decision_steps: u64,
    path: &Path,
) -> Result<()> {
    let state =
        ServiceState { curriculum: curriculum.state()?, next_task_id, proposed: proposed.clone(), decision_steps };
    Ok(state.save(path)?)
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
    let (mut curriculum, saved) = load_curriculum(&dir.curriculum_state(), &cfg, scene)?;
    let (mut next_task_id, mut proposed, mut decision_steps) = match saved {
        Some(s) => {
            tracing::info!(
                episodes = curriculum.episodes(),
                t_c = curriculum.scheduler().t_c(),
                acl = curriculum.scheduler().in_acl_phase(),
                "resumed curriculum state"
            );
            (s.next_task_id, s.proposed, s.decision_steps)
        }
        None => (1, BTreeMap::new(), 0),
    };
    let mut first_task_passed: Option<(u64, u64)> = None;
    let mut episode_log = EpisodeLog::open(&dir)?;
    let snapshots = dir.checkpoints().join("curriculum-snapshots");
    std::fs::create_dir_all(&snapshots)?;
    let state_path = dir.curriculum_state();
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
            let start = Pose { x: points[0].x, y: points[0].y, yaw: points[0].yaw };
            let outcome = EpisodeOutcome {
                category: category_of(h.category)?,
                poses: points.iter().map(|p| Pose { x: p.x, y: p.y, yaw: p.yaw }).collect(),
                rewards: points[1..].iter().map(|p| p.reward).collect(),
                truncated: h.truncated != 0,
                success: h.success != 0,
            };
            drop(sample);
            let was_acl = curriculum.scheduler().in_acl_phase();
            let summary = curriculum.report(&outcome)?;
            decision_steps += h.length as u64;
            if !was_acl && curriculum.scheduler().in_acl_phase() {
                // The PassFirstTask gate opened with this episode (NavACL⁺).
                first_task_passed = Some((curriculum.episodes(), decision_steps));
                tracing::info!(
                    episodes = curriculum.episodes(),
                    decision_steps,
                    "PassFirstTask passed: ACL phase starts"
                );
            }
            if let Some(l) = summary.trained_loss {
                last_loss = Some(l);
            }
            episode_log.write(curriculum.episodes(), decision_steps, &h, start, summary.discounted_return)?;
            if curriculum.episodes().is_multiple_of(SNAPSHOT_EVERY_EPISODES) {
                let path = snapshots.join(format!("ep{:08}-steps{}.json", curriculum.episodes(), decision_steps));
                save(&curriculum, next_task_id, &proposed, decision_steps, &path)?;
            }
            recent.push_back(summary.discounted_return);
            successes.push_back(outcome.success);
            if recent.len() > 100 {
                recent.pop_front();
                successes.pop_front();
            }
            since_save += 1;
            if since_save >= cfg.runtime.curriculum_save_every_episodes {
                save(&curriculum, next_task_id, &proposed, decision_steps, &state_path)?;
                since_save = 0;
            }
        }
        if last_log.elapsed() >= log_every {
            last_log = Instant::now();
            let s = curriculum.scheduler();
            // Statistics that do not exist yet (no episode, no fit) are not written.
            let mean_return = (!recent.is_empty()).then(|| recent.iter().sum::<f32>() as f64 / recent.len() as f64);
            let success = (!successes.is_empty())
                .then(|| successes.iter().filter(|&&s| s).count() as f64 / successes.len() as f64);
            let count = |c: Category| Some(proposed.get(category_name(c)).copied().unwrap_or(0) as f64);
            let values = [
                ("episodes", Some(curriculum.episodes() as f64)),
                ("phase_acl", Some(if s.in_acl_phase() { 1.0 } else { 0.0 })),
                ("t_c", Some(s.t_c() as f64)),
                ("first_task_mean_return", s.gate().mean().map(|m| m as f64)),
                ("mean_return_100", mean_return),
                ("success_rate_100", success),
                ("mu", last_fit.map(|f| f.mu as f64)),
                ("sigma", last_fit.map(|f| f.sigma as f64)),
                ("fr_loss", last_loss.map(|l| l as f64)),
                ("n_first", count(Category::First)),
                ("n_fixed", count(Category::Fixed)),
                ("n_easy", count(Category::Easy)),
                ("n_frontier", count(Category::Frontier)),
                ("n_random", count(Category::Random)),
                ("n_hard", count(Category::Hard)),
            ];
            metrics.log_optional(curriculum.episodes(), &values)?;
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
                recent_return: mean_return.map_or(f32::NAN, |m| m as f32),
                ..Heartbeat::default()
            };
            let _ = heartbeat.send_copy(hb);
        }
        if !busy {
            std::thread::sleep(Duration::from_micros(500));
        }
    }
    save(&curriculum, next_task_id, &proposed, decision_steps, &state_path)?;
    dir.write_stats(
        "curriculum",
        &serde_json::json!({
            "episodes": curriculum.episodes(),
            "tasks_issued": next_task_id - 1,
            "proposed": proposed,
            "t_c": curriculum.scheduler().t_c(),
            "decision_steps": decision_steps,
            "acl_phase": curriculum.scheduler().in_acl_phase(),
            // When this process saw the PassFirstTask gate open (null if it opened
            // before a resume, or has not): episodes and decision steps reported so far.
            "first_task_passed": first_task_passed
                .map(|(episodes, steps)| serde_json::json!({"episodes": episodes, "decision_steps": steps})),
        }),
    )?;
    tracing::info!(episodes = curriculum.episodes(), "curriculum service stopped; state saved");
    Ok(())
}

/// Classify a grid over the curriculum region (yaw facing the goal, the
/// orientation a researcher reads Fig. 4 with) and draw it over the map.
fn draw(run_dir: &Path, state: Option<&Path>, out: &Path, cell: f32) -> Result<()> {
    if cell.is_nan() || cell <= 0.05 {
        bail!("--cell must be larger than 0.05 m, got {cell}");
    }
    let dir = RunDir::new(run_dir);
    let cfg = dir.load_config()?;
    let scene = cfg.scene()?;
    let path = state.map_or_else(|| dir.curriculum_state(), Path::to_path_buf);
    if !path.exists() {
        bail!("{} does not exist: the curriculum service saves its state while a run goes on", path.display());
    }
    let (mut curriculum, _) = load_curriculum(&path, &cfg, scene.clone())?;
    let Some(c) = classify_region(&mut curriculum, &scene, &cfg.curriculum, cell)? else {
        bail!("the fixed-start variant has no task classification to draw");
    };
    if let Some(parent) = out.parent() {
        std::fs::create_dir_all(parent)?;
    }
    pednav_sim::draw::save_png(&c.draw(&scene, 12.0).image, out)?;
    println!(
        "μ = {:.2}, σ = {:.2}, t_c = {}, phase = {}; cells: {:?} (green easy, yellow frontier, red hard, purple neither)",
        c.fit.mu,
        c.fit.sigma,
        c.t_c,
        if c.acl { "ACL" } else { "first task" },
        c.counts()
    );
    Ok(())
}
