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

mod service;

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::{Parser, Subcommand};
use pednav_curriculum::classify_region;
use pednav_runtime::{RunDir, StopFlag};

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

fn main() -> Result<()> {
    pednav_runtime::init_logging();
    match Cli::parse().command {
        Command::Serve { run_dir } => {
            service::CurriculumService::open(RunDir::new(run_dir), StopFlag::install())?.run()
        }
        Command::Draw { run_dir, out, cell, state } => {
            let out = out.unwrap_or_else(|| run_dir.join("plots").join("curriculum.png"));
            draw(&run_dir, state.as_deref(), &out, cell)?;
            println!("wrote {}", out.display());
            Ok(())
        }
    }
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
    if !pednav_curriculum::ServiceState::exists(&path) {
        bail!("{} does not exist: the curriculum service saves its state while a run goes on", path.display());
    }
    let (mut curriculum, _) = service::load_curriculum(&path, &cfg, scene.clone())?;
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
