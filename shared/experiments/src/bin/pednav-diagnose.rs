//! `pednav-diagnose` — what a trained agent learned, along its own evaluation episodes.
//!
//! ```text
//! pednav-diagnose --run-dir runs/X                  # 14 points × 8 yaws × 1 run, sampled actions
//! pednav-diagnose --run-dir runs/X --runs 2 --stride 2
//! ```
//! Runs the validation protocol's start poses with the checkpoint's policy (sampling,
//! as the protocol does), and reports (see `pednav_experiments::diagnose`): a linear
//! probe of the policy encoder's features for the pose and the return-to-go, against
//! the same probe on an untrained encoder; the critic's Q against the soft Monte-Carlo
//! return; α and the policy's entropy; and the training's last logged state (replay
//! terminal share, α, entropy, mean Q of the batch). Needs the checkpoint's online
//! networks and α (`pednav_learner::agent_files`: a run's checkpoint, or a results
//! folder that keeps them), not only the acting files. Writes `diagnosis.txt`,
//! `diagnosis.json` and `q_vs_return.png` to `--out` (default `<run>/diagnosis`).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Parser;
use pednav_experiments::diagnose::DiagnosisRecorder;
use pednav_experiments::evaluate::{Evaluator, PolicyKind};
use pednav_experiments::plots::{self, PALETTE, Series};
use pednav_experiments::protocol;
use pednav_nets::DsacNets;
use pednav_runtime::{RunConfig, RunDir, columns};

#[derive(Parser, Debug)]
#[command(
    version,
    about = "Probe a pednav checkpoint: what its encoder features carry, and its critic against Monte-Carlo returns"
)]
struct Cli {
    /// Run directory whose latest full checkpoint and config are diagnosed.
    #[arg(long)]
    run_dir: PathBuf,
    /// Checkpoint directory instead of `<run-dir>/checkpoints/learner` (same configuration).
    #[arg(long)]
    checkpoint: Option<PathBuf>,
    /// Sampled runs per (point, yaw) of the validation protocol.
    #[arg(long, default_value_t = 1)]
    runs: u32,
    /// Episode limit (the protocol's 2000 by default).
    #[arg(long, default_value_t = protocol::T_MAX)]
    t_max: u32,
    /// Keep encoder features every this many decisions of an episode (memory: about
    /// 32 bytes × feature width per kept decision while fitting — two encoders,
    /// copied for the fit; ≈ 1 GB for the reduced CPU preset at the default).
    #[arg(long, default_value_t = 4)]
    stride: usize,
    /// Environments stepped together.
    #[arg(long, default_value_t = 8)]
    envs: usize,
    /// Seed of the task list and policy noise (as `pednav-eval --seed`); the
    /// untrained encoder is initialised from the run's seed + 1.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Output folder (default `<run-dir>/diagnosis`).
    #[arg(long)]
    out: Option<PathBuf>,
}

/// The learner's last metrics row with updates in it (update statistics exist only
/// for intervals with updates; the rows after the budget was spent have none), as
/// (column, value) pairs, when the run has one.
fn last_learner_metrics(run_dir: &Path) -> Option<Vec<(String, f64)>> {
    let (header, rows) = plots::learner_log(run_dir).ok()?;
    let ups = header.iter().position(|h| h == columns::learner::UPDATES_PER_S)?;
    let row = rows.iter().rev().find(|r| r[ups] > 0.0).or(rows.last())?;
    Some(header.into_iter().zip(row.iter().copied()).collect())
}

fn main() -> Result<()> {
    pednav_sim::prepare_headless_env();
    pednav_runtime::init_logging();
    let cli = Cli::parse();
    if cli.runs == 0 || cli.envs == 0 || cli.stride == 0 {
        bail!("--runs, --envs and --stride must be at least 1");
    }
    pednav_nets::init_cpu_runtime(None);
    let cfg_path = cli.run_dir.join("config.toml");
    let cfg = RunConfig::load(&cfg_path).with_context(|| format!("reading {}", cfg_path.display()))?;
    let ckpt = cli.checkpoint.clone().unwrap_or_else(|| RunDir::new(&cli.run_dir).learner_checkpoint());
    let device = candle_core::Device::Cpu;
    let agent = pednav_learner::load_agent(&ckpt, &device).with_context(|| {
        format!("loading the online networks of {} (pednav-diagnose also reads the critic: a folder with only the acting files is not enough)", ckpt.display())
    })?;
    if !agent.meta.nets.same_architecture(&cfg.nets) {
        bail!("{}: the checkpoint's networks differ from {}", ckpt.display(), cfg_path.display());
    }
    let untrained = DsacNets::new(&cfg.nets, &device, pednav_config::rng::untrained_reference_seed(cfg.seed))?;
    let gamma = cfg.dsac.gamma as f32;
    let tasks = protocol::validation_tasks(&cfg.scene()?, cli.runs, cli.seed);
    let mut recorder = DiagnosisRecorder::new(agent.nets.clone(), untrained, agent.alpha, gamma, cli.envs, cli.stride);
    let mut ev = Evaluator::new(
        cfg.scene()?,
        &cfg.sim,
        cli.t_max,
        gamma,
        cli.envs,
        PolicyKind::Learned { deterministic: false },
        Some((cfg.nets.clone(), agent.nets)),
        cli.seed,
    )?;
    eprintln!(
        "pednav-diagnose: {} episodes (validation points × 8 yaws × {} runs), T_max {}, checkpoint {} (update {})",
        tasks.len(),
        cli.runs,
        cli.t_max,
        ckpt.display(),
        agent.meta.updates
    );
    let t0 = Instant::now();
    let n = tasks.len();
    let results = ev.run_observed(
        &tasks,
        |done| {
            if done % 10 == 0 || done == n {
                eprint!("\r  {done}/{n} episodes ({:.0} s)", t0.elapsed().as_secs_f64());
            }
        },
        Some(&mut recorder),
    )?;
    eprintln!("\r  {} episodes in {:.0} s; fitting the probes", results.len(), t0.elapsed().as_secs_f64());
    let d = recorder.report()?;

    let out = cli.out.clone().unwrap_or_else(|| cli.run_dir.join("diagnosis"));
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let title = format!(
        "pednav-diagnose — {} (update {}), T_max {}, actions sampled from π",
        ckpt.display(),
        agent.meta.updates,
        cli.t_max
    );
    let mut text = d.to_text(&title);
    let training = last_learner_metrics(&cli.run_dir);
    if let Some(m) = &training {
        let get = |k: &str| m.iter().find(|(h, _)| h == k).map_or(f64::NAN, |(_, v)| *v);
        let (term, non) = (get(columns::learner::REPLAY_TERMINAL), get(columns::learner::REPLAY_NONTERMINAL));
        text.push_str(&format!(
            "\nTraining at its last log (metrics/learner.csv): env step {:.0}, update {:.0}; replay {:.0} terminal + {:.0} non-terminal transitions (terminal share {:.4}); α {:.4}, policy entropy {:.3}, batch mean Q {:.2}\n",
            get(columns::STEP),
            get(columns::learner::UPDATES),
            term,
            non,
            term / (term + non),
            get(columns::learner::ALPHA),
            get(columns::learner::ENTROPY),
            get(columns::learner::Q_MEAN)
        ));
    }
    print!("{text}");
    std::fs::write(out.join("diagnosis.txt"), &text)?;
    let mut json = serde_json::to_value(&d)?;
    json["training_last_log"] =
        serde_json::to_value(training.unwrap_or_default().into_iter().collect::<std::collections::BTreeMap<_, _>>())?;
    std::fs::write(out.join("diagnosis.json"), serde_json::to_string_pretty(&json)?)?;
    if d.scatter.is_empty() {
        eprintln!("no step has a known return (no episode reached the goal, none ran long enough): no q_vs_return.png");
    } else {
        let (lo, hi) =
            d.scatter.iter().fold((f64::MAX, f64::MIN), |(lo, hi), p| (lo.min(p.0.min(p.1)), hi.max(p.0.max(p.1))));
        plots::line_chart(
            &out.join("q_vs_return.png"),
            &format!("critic vs Monte-Carlo: corr {:.2}, Q − G {:+.1}", d.all_steps.correlation, d.all_steps.bias),
            "soft Monte-Carlo return G of the sampled episode",
            "Q(s, a)",
            &[
                Series {
                    label: "steps".into(),
                    points: d.scatter.iter().map(|p| (p.1, p.0)).collect(),
                    band: None,
                    colour: PALETTE[0],
                    dots: true,
                },
                Series {
                    label: "Q = G".into(),
                    points: vec![(lo, lo), (hi, hi)],
                    band: None,
                    colour: PALETTE[3],
                    dots: false,
                },
            ],
            &[],
        )?;
    }
    eprintln!("wrote {}/{{diagnosis.txt,diagnosis.json,q_vs_return.png}}", out.display());
    Ok(())
}
