//! `pednav-plot` — figures from run directories.
//!
//! ```text
//! pednav-plot curves --run-dir runs/X          # Fig. 3: return and episodes vs decision steps, with oracle lines
//! pednav-plot curriculum --run-dir runs/X      # Fig. 4 over time, from the curriculum snapshots
//! pednav-plot compare --group "TCN=runs/a,runs/b" --group "FR=runs/c,runs/d" --out cmp.png
//! pednav-plot learner --run-dir runs/a --run-dir runs/b --out learner.png
//!                                              # α, entropy, Q, losses, replay terminal share vs env steps
//! pednav-plot all --run-dir runs/X             # curves + curriculum + learner
//! pednav-plot table --group "TCN=runs/a,runs/b" --random eval/random --out table.md
//!                                              # Table III layout from the runs' evaluations
//! pednav-plot interval --a "NavACL+=runs/a,runs/b,runs/c" --b "NavACL=runs/d,runs/e,runs/f"
//!                                              # 95 % interval of A − B on Avg.Int and Avg.Ext
//! ```
//! Training curves come from `metrics/episodes.csv` (one row per episode, written
//! by the curriculum service).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use pednav_experiments::bootstrap::{self, Average, RunReturns};
use pednav_experiments::plots::{self, PALETTE, Series, moving_average};
use pednav_runtime::{RunConfig, RunDir, columns};
use pednav_sim::oracle::{Oracle, OracleConfig};
use pednav_sim::{ObsMode, Pose, SimConfig, SimWorld};

#[derive(Parser)]
#[command(
    version,
    about = "Plots of pednav runs: training curves (Fig. 3), curriculum snapshots (Fig. 4), comparisons"
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// Discounted return vs decision steps (with oracle lines) and episodes vs decision steps.
    Curves {
        /// The run directory.
        #[arg(long)]
        run_dir: PathBuf,
        /// Output folder (default <run>/plots).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Moving-average window in episodes.
        #[arg(long, default_value_t = 50)]
        window: usize,
    },
    /// The curriculum classification at up to --max snapshots over the run.
    Curriculum {
        /// The run directory.
        #[arg(long)]
        run_dir: PathBuf,
        /// Output PNG (default <run>/plots/curriculum_snapshots.png).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Most snapshots to show.
        #[arg(long, default_value_t = 6)]
        max: usize,
    },
    /// Mean ± std over seeds of the smoothed return for groups of runs.
    Compare {
        /// LABEL=RUN_DIR[,RUN_DIR…] (repeatable).
        #[arg(long, required = true)]
        group: Vec<String>,
        /// Output PNG.
        #[arg(long)]
        out: PathBuf,
        /// Moving-average window in episodes (per run, before averaging).
        #[arg(long, default_value_t = 50)]
        window: usize,
    },
    /// Table III layout: Avg.Int, Avg.Ext and success per group of runs (mean ± std
    /// over its runs), beside the random walk and the oracle, with the share of the
    /// random→oracle gap each closes. Reads each run's `eval/learned/table.csv`
    /// (written by `pednav-eval`); a RUN may also be an evaluation folder or a table.csv.
    Table {
        /// LABEL=RUN[,RUN…] (repeatable; one row each).
        #[arg(long, required = true)]
        group: Vec<String>,
        /// The random walk's evaluation (`pednav-eval --policy random`): folder or table.csv.
        #[arg(long)]
        random: Option<PathBuf>,
        /// Also write the table (Markdown) here.
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// A confidence interval of the difference A − B on Avg.Int and Avg.Ext between two
    /// groups of runs, from their per-episode results (`results.csv` of `pednav-eval`):
    /// a hierarchical bootstrap over runs, then over each run's episodes per point.
    Interval {
        /// LABEL=RUN[,RUN…]: group A (a RUN is a run directory, its evaluation folder or a results.csv).
        #[arg(long)]
        a: String,
        /// LABEL=RUN[,RUN…]: group B.
        #[arg(long)]
        b: String,
        /// Bootstrap replicates.
        #[arg(long, default_value_t = 10_000)]
        replicates: usize,
        /// Coverage of the interval.
        #[arg(long, default_value_t = 0.95)]
        level: f64,
        /// Seed of the resampling.
        #[arg(long, default_value_t = 0)]
        seed: u64,
    },
    /// The learner's state over training, from `metrics/learner.csv`: temperature α,
    /// policy entropy, the batch's mean Q, critic and policy losses, and the replay's
    /// terminal share, against env steps, one curve per run.
    Learner {
        /// Run directories (repeatable; one curve each, labelled by folder name).
        #[arg(long, required = true)]
        run_dir: Vec<PathBuf>,
        /// Output PNG (default <first run>/plots/learner.png).
        #[arg(long)]
        out: Option<PathBuf>,
    },
    /// `curves`, `learner` and (when snapshots exist) `curriculum`.
    All {
        /// The run directory.
        #[arg(long)]
        run_dir: PathBuf,
    },
}

/// (decision steps, discounted return) of every episode of a run.
fn episodes(run: &Path) -> Result<Vec<(f64, f64)>> {
    let path = RunDir::new(run).metrics_csv("episodes");
    let text = std::fs::read_to_string(&path).with_context(|| {
        format!("{}: no episode log (the curriculum service writes it during a run)", path.display())
    })?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().context("empty episode log")?.split(',').collect();
    let col =
        |n: &str| header.iter().position(|h| *h == n).with_context(|| format!("{}: no `{n}` column", path.display()));
    let (cs, cr) = (col(columns::episodes::DECISION_STEPS)?, col(columns::episodes::DISCOUNTED_RETURN)?);
    let rows: Vec<(f64, f64)> = lines
        .filter_map(|l| {
            let v: Vec<&str> = l.split(',').collect();
            Some((v.get(cs)?.parse().ok()?, v.get(cr)?.parse().ok()?))
        })
        .collect();
    if rows.is_empty() {
        bail!("{}: no episodes yet", path.display());
    }
    Ok(rows)
}

fn oracle_lines(cfg: &RunConfig) -> Result<Vec<(String, f64)>> {
    let scene = cfg.scene()?;
    let world = SimWorld::new(scene, SimConfig { obs_mode: ObsMode::State, ..cfg.sim.clone() })?;
    let gamma = cfg.dsac.gamma as f32;
    let oracle = Oracle::plan(&world, OracleConfig { gamma, ..OracleConfig::default() });
    let t_max = cfg.sim.t_max;
    let mut lines = Vec::new();
    let mut add = |label: &str, pose: Pose| {
        let r = oracle.rollout(&world, pose, t_max).discounted_return as f64;
        lines.push((format!("oracle, {label}: {r:.1}"), r));
    };
    match cfg.curriculum.variant {
        pednav_curriculum::Variant::FixedStart => add("fixed start", world.scene.fixed_start()),
        _ => {
            add("first task", world.scene.first_task());
            for p in world.scene.validation_points().iter().filter(|p| p.id == 0 || p.id == 7) {
                add(&format!("point {}", p.id), Pose::from_degrees(p.x, p.y, p.favourable_yaw_deg));
            }
        }
    }
    Ok(lines)
}

fn curves(run: &Path, out: &Path, window: usize) -> Result<()> {
    let cfg = RunConfig::load(&run.join("config.toml"))?;
    let eps = episodes(run)?;
    let steps: Vec<f64> = eps.iter().map(|e| e.0).collect();
    let ret: Vec<f64> = eps.iter().map(|e| e.1).collect();
    let smooth = moving_average(&ret, window);
    let name = run.file_name().map_or("run".into(), |n| n.to_string_lossy().to_string());
    plots::line_chart(
        &out.join("training_return.png"),
        &format!("{name}: discounted return per episode ({:?})", cfg.curriculum.variant),
        "decision steps",
        "discounted return",
        &[
            Series {
                label: "episodes".into(),
                points: steps.iter().copied().zip(ret.iter().copied()).collect(),
                band: None,
                colour: PALETTE[0],
                dots: true,
            },
            Series {
                label: format!("moving average ({window} episodes)"),
                points: steps.iter().copied().zip(smooth).collect(),
                band: None,
                colour: PALETTE[0],
                dots: false,
            },
        ],
        &oracle_lines(&cfg)?,
    )?;
    plots::line_chart(
        &out.join("episodes.png"),
        &format!("{name}: episodes vs decision steps (steeper is better)"),
        "decision steps",
        "episodes",
        &[Series {
            label: "episodes".into(),
            points: steps.iter().enumerate().map(|(i, &s)| (s, i as f64 + 1.0)).collect(),
            band: None,
            colour: PALETTE[1],
            dots: false,
        }],
        &[],
    )?;
    println!(
        "wrote {}/training_return.png and episodes.png ({} episodes, {:.0} decision steps)",
        out.display(),
        eps.len(),
        steps.last().unwrap()
    );
    Ok(())
}

/// The learner metrics panels: (column, panel title, axis label).
const LEARNER_PANELS: [(&str, &str, &str); 6] = [
    (columns::learner::ALPHA, "temperature α", "α"),
    (columns::learner::ENTROPY, "policy entropy −log π (batch mean)", "nats"),
    (columns::learner::Q_MEAN, "mean Q(s, a) of the batch", "Q"),
    (columns::learner::CRITIC_LOSS, "critic loss (quantile Huber)", "loss"),
    (columns::learner::POLICY_LOSS, "policy loss", "loss"),
    ("terminal_share", "replay: terminal share of stored transitions", "share"),
];

fn learner(runs: &[PathBuf], out: &Path) -> Result<()> {
    let mut panels: Vec<plots::Panel> = LEARNER_PANELS
        .iter()
        .map(|(_, title, y)| plots::Panel {
            title: title.to_string(),
            x_label: "env steps".into(),
            y_label: y.to_string(),
            series: Vec::new(),
        })
        .collect();
    for (i, run) in runs.iter().enumerate() {
        let (header, rows) = plots::learner_log(run)?;
        let col = |n: &str| header.iter().position(|h| h == n);
        let step = col(columns::STEP).with_context(|| format!("{}: learner log without `step`", run.display()))?;
        let name = run.file_name().map_or("run".into(), |n| n.to_string_lossy().to_string());
        for (panel, (column, _, _)) in panels.iter_mut().zip(LEARNER_PANELS) {
            let value = |r: &Vec<f64>| -> Option<f64> {
                if column == "terminal_share" {
                    let (t, n) =
                        (r[col(columns::learner::REPLAY_TERMINAL)?], r[col(columns::learner::REPLAY_NONTERMINAL)?]);
                    (t + n > 0.0).then(|| t / (t + n))
                } else {
                    // Update statistics exist only for intervals with updates.
                    let v = r[col(column)?];
                    (r[col(columns::learner::UPDATES_PER_S)?] > 0.0).then_some(v)
                }
            };
            let points: Vec<(f64, f64)> =
                rows.iter().filter_map(|r| Some((r[step], value(r)?))).filter(|p| p.1.is_finite()).collect();
            panel.series.push(Series {
                label: name.clone(),
                points,
                band: None,
                colour: PALETTE[i % PALETTE.len()],
                dots: false,
            });
        }
    }
    let names: Vec<String> =
        runs.iter().map(|r| r.file_name().map_or("run".into(), |n| n.to_string_lossy().to_string())).collect();
    plots::panel_chart(out, &format!("learner state over training: {}", names.join(" vs ")), &panels, 3)?;
    println!("wrote {}", out.display());
    Ok(())
}

fn curriculum(run: &Path, out: &Path, max: usize) -> Result<()> {
    let cfg = RunConfig::load(&run.join("config.toml"))?;
    let dir = RunDir::new(run).curriculum_snapshots();
    let mut snaps: Vec<PathBuf> = std::fs::read_dir(&dir)
        .with_context(|| format!("{}: no snapshots (saved every 500 episodes)", dir.display()))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| p.extension().is_some_and(|e| e == "json"))
        .collect();
    let latest = RunDir::new(run).curriculum_state();
    snaps.sort();
    if latest.exists() {
        snaps.push(latest);
    }
    let n = plots::curriculum_snapshots(
        &cfg.scene()?,
        &cfg.curriculum,
        (cfg.sim.dt, cfg.curriculum_seed()),
        &snaps,
        max,
        out,
    )?;
    println!("wrote {} ({n} snapshots)", out.display());
    Ok(())
}

/// An evaluation's file `name` (`results.csv`, `table.csv`), given the file itself, its
/// evaluation folder, or a run directory (whose learned policy's evaluation is meant).
fn eval_file(path: &Path, name: &str) -> PathBuf {
    if path.is_file() {
        path.to_path_buf()
    } else if path.join(name).is_file() {
        path.join(name)
    } else {
        path.join("eval").join("learned").join(name)
    }
}

/// `LABEL=RUN[,RUN…]` → the label and each run's returns.
fn group_returns(spec: &str) -> Result<(String, Vec<RunReturns>)> {
    let (label, runs) = spec.split_once('=').with_context(|| format!("expected LABEL=RUN[,RUN…], got `{spec}`"))?;
    let runs: Vec<RunReturns> = runs
        .split(',')
        .filter(|r| !r.is_empty())
        .map(|r| RunReturns::read(&eval_file(Path::new(r), "results.csv")).map_err(anyhow::Error::from))
        .collect::<Result<_>>()?;
    if runs.is_empty() {
        bail!("{label}: no runs");
    }
    Ok((label.to_string(), runs))
}

fn interval(a: &str, b: &str, replicates: usize, level: f64, seed: u64) -> Result<String> {
    if !(level > 0.0 && level < 1.0) || replicates < 100 {
        bail!("--level must lie in (0, 1) and --replicates be at least 100");
    }
    let ((la, ra), (lb, rb)) = (group_returns(a)?, group_returns(b)?);
    let mut s = format!(
        "{la} (n = {}) − {lb} (n = {}): {:.0} % hierarchical bootstrap over runs, then episodes per point; {replicates} replicates\n",
        ra.len(),
        rb.len(),
        100.0 * level
    );
    for which in [Average::Int, Average::Ext] {
        let i = bootstrap::difference(&ra, &rb, which, replicates, level, seed)?;
        s += &format!(
            "Avg.{which:?}: {:+.1} [{:+.1}, {:+.1}]; A − B > 0 in {:.1} % of replicates\n",
            i.estimate,
            i.low,
            i.high,
            100.0 * i.share_above_zero
        );
    }
    Ok(s)
}

fn table(groups: &[String], random: Option<&Path>) -> Result<String> {
    use pednav_experiments::table::{EvalSummary, gap_closed, mean_and_sample_std};
    use std::fmt::Write as _;
    let read = |p: &Path| EvalSummary::read(&eval_file(p, "table.csv")).map_err(anyhow::Error::from);
    let random = random.map(read).transpose()?;
    let mut rows = Vec::new();
    let mut oracle = None;
    for g in groups {
        let (label, runs) =
            g.split_once('=').with_context(|| format!("--group expects LABEL=RUN[,RUN…], got `{g}`"))?;
        let runs: Vec<&str> = runs.split(',').filter(|s| !s.is_empty()).collect();
        if runs.is_empty() {
            bail!("--group {label}: no runs");
        }
        let evals: Vec<EvalSummary> = runs.iter().map(|r| read(Path::new(r))).collect::<Result<_>>()?;
        oracle = oracle.or_else(|| evals.iter().find_map(|e| e.oracle));
        rows.push((label.to_string(), evals));
    }
    let pm = |v: &[f64]| {
        let (m, s) = mean_and_sample_std(v);
        if v.len() > 1 { format!("{m:.1} ± {s:.1}") } else { format!("{m:.1}") }
    };
    let gap = |v: f64, which: usize| match (random, oracle) {
        (Some(r), Some(o)) => {
            let (rv, ov) = if which == 0 { (r.avg_int, o.0) } else { (r.avg_ext, o.1) };
            format!("{:.2}", gap_closed(v, rv, ov))
        }
        _ => "—".into(),
    };
    let mut s = String::new();
    let _ = writeln!(
        s,
        "| variant | runs | Avg.Int | Avg.Ext | success | Int gap closed | Ext gap closed | Avg.Int / Avg.Ext per run |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|");
    for (label, evals) in &rows {
        let ints: Vec<f64> = evals.iter().map(|e| e.avg_int).collect();
        let exts: Vec<f64> = evals.iter().map(|e| e.avg_ext).collect();
        let success = evals.iter().map(|e| e.success).sum::<f64>() / evals.len() as f64;
        let per_run: Vec<String> = evals.iter().map(|e| format!("{:.1} / {:.1}", e.avg_int, e.avg_ext)).collect();
        let _ = writeln!(
            s,
            "| {label} | {} | {} | {} | {:.1} % | {} | {} | {} |",
            evals.len(),
            pm(&ints),
            pm(&exts),
            100.0 * success,
            gap(mean_and_sample_std(&ints).0, 0),
            gap(mean_and_sample_std(&exts).0, 1),
            per_run.join(", ")
        );
    }
    if let Some(r) = random {
        let _ = writeln!(
            s,
            "| random walk | — | {:.1} | {:.1} | {:.1} % | 0 | 0 | |",
            r.avg_int,
            r.avg_ext,
            100.0 * r.success
        );
    }
    if let Some((oi, oe)) = oracle {
        let _ = writeln!(s, "| oracle | — | {oi:.1} | {oe:.1} | — | 1 | 1 | |");
    }
    let _ = writeln!(
        s,
        "\nAvg.Int / Avg.Ext: mean ± sample standard deviation over the `runs` (n) of each row, each run's \
         average over its validation points; success: over all their episodes; gap closed: of the mean."
    );
    Ok(s)
}

fn compare(groups: &[String], out: &Path, window: usize) -> Result<()> {
    let mut series = Vec::new();
    for (gi, g) in groups.iter().enumerate() {
        let (label, runs) =
            g.split_once('=').with_context(|| format!("--group expects LABEL=RUN[,RUN…], got `{g}`"))?;
        let runs: Vec<&str> = runs.split(',').filter(|s| !s.is_empty()).collect();
        let curves: Vec<Vec<(f64, f64)>> = runs
            .iter()
            .map(|r| {
                let e = episodes(Path::new(r))?;
                let s = moving_average(&e.iter().map(|x| x.1).collect::<Vec<_>>(), window);
                Ok(e.iter().map(|x| x.0).zip(s).collect())
            })
            .collect::<Result<_>>()?;
        // Common grid up to the shortest run; each curve sampled by its last value at or before x.
        let end = curves.iter().map(|c| c.last().unwrap().0).fold(f64::MAX, f64::min);
        let grid: Vec<f64> = (1..=100).map(|i| end * i as f64 / 100.0).collect();
        let mut mean = Vec::new();
        let mut std = Vec::new();
        for &x in &grid {
            let vals: Vec<f64> =
                curves.iter().filter_map(|c| c.iter().take_while(|p| p.0 <= x).last().map(|p| p.1)).collect();
            if vals.is_empty() {
                mean.push(f64::NAN);
                std.push(0.0);
                continue;
            }
            let (m, s) = pednav_experiments::table::mean_and_sample_std(&vals);
            mean.push(m);
            std.push(s);
        }
        let keep: Vec<usize> = (0..grid.len()).filter(|&i| mean[i].is_finite()).collect();
        series.push(Series {
            label: format!("{label} ({} runs)", runs.len()),
            points: keep.iter().map(|&i| (grid[i], mean[i])).collect(),
            band: Some(keep.iter().map(|&i| std[i]).collect()),
            colour: PALETTE[gi % PALETTE.len()],
            dots: false,
        });
    }
    plots::line_chart(
        out,
        "discounted return, mean ± sample std over runs",
        "decision steps",
        "discounted return (smoothed)",
        &series,
        &[],
    )?;
    println!("wrote {}", out.display());
    Ok(())
}

fn main() -> Result<()> {
    pednav_runtime::init_logging();
    match Cli::parse().command {
        Cmd::Curves { run_dir, out, window } => curves(&run_dir, &out.unwrap_or_else(|| run_dir.join("plots")), window),
        Cmd::Curriculum { run_dir, out, max } => {
            curriculum(&run_dir, &out.unwrap_or_else(|| run_dir.join("plots").join("curriculum_snapshots.png")), max)
        }
        Cmd::Compare { group, out, window } => compare(&group, &out, window),
        Cmd::Table { group, random, out } => {
            let text = table(&group, random.as_deref())?;
            print!("{text}");
            if let Some(out) = out {
                std::fs::write(&out, &text).with_context(|| format!("writing {}", out.display()))?;
            }
            Ok(())
        }
        Cmd::Interval { a, b, replicates, level, seed } => {
            print!("{}", interval(&a, &b, replicates, level, seed)?);
            Ok(())
        }
        Cmd::Learner { run_dir, out } => {
            let out = out.unwrap_or_else(|| run_dir[0].join("plots").join("learner.png"));
            learner(&run_dir, &out)
        }
        Cmd::All { run_dir } => {
            curves(&run_dir, &run_dir.join("plots"), 50)?;
            if RunDir::new(&run_dir).metrics_csv("learner").is_file() {
                learner(std::slice::from_ref(&run_dir), &run_dir.join("plots").join("learner.png"))?;
            }
            let cfg = RunConfig::load(&run_dir.join("config.toml"))?;
            // Snapshots exist once a curriculum run has reported 500 episodes (and in a
            // results folder only where they were kept).
            let has_snapshots = RunDir::new(&run_dir).curriculum_snapshots().is_dir();
            if cfg.curriculum.variant != pednav_curriculum::Variant::FixedStart && has_snapshots {
                curriculum(&run_dir, &run_dir.join("plots").join("curriculum_snapshots.png"), 6)?;
            }
            Ok(())
        }
    }
}
