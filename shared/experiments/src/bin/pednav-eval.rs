//! `pednav-eval` — the paper's validation protocol on a checkpoint.
//!
//! ```text
//! pednav-eval --run-dir runs/X                       # 14 points × 8 yaws × 10 runs, T_max 2000, learned policy (sampled)
//! pednav-eval --run-dir runs/X --workers 2           # the same over 2 processes
//! pednav-eval --run-dir runs/X --starts starts.csv   # any start list (x,y,yaw in degrees)
//! pednav-eval --run-dir docs/results/R --out /tmp/R  # a committed result, re-evaluated
//! pednav-eval --run-dir runs/X --checkpoint DIR      # another checkpoint of the same run
//! pednav-eval --policy random --runs 2               # the random-walk baseline (no run needed)
//! pednav-eval --policy untrained --config deploy/configs/cpu_reduced.toml --init-seed 3
//!                                                    # the networks a run starts with, before any update
//! pednav-eval --policy oracle --runs 1               # the planner, an upper reference
//! pednav-eval --run-dir runs/X --gif 3:180:0         # also a GIF of point 3, yaw 180°, run 0
//! ```
//! Prints the Table III layout and writes `table.txt`, `table.csv`, `results.csv`
//! (every episode) and `trajectories.png` (Fig. 5) to `--out` (default
//! `<run>/eval/<policy>`).

use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, ValueEnum};
use pednav_experiments::evaluate::{Evaluator, PolicyKind, load_policy, oracle_per_point};
use pednav_experiments::plots;
use pednav_experiments::protocol::{self, EvalTask, YAWS_DEG};
use pednav_experiments::table::{self, EpisodeResult};
use pednav_runtime::RunConfig;

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum, Debug)]
enum PolicyArg {
    /// The checkpoint's policy.
    Learned,
    /// The learned policy's networks as initialised, before any update: what acts
    /// in a run's first episodes (weights from `--init-seed`, default the config's seed).
    Untrained,
    /// Uniform random actions (random-walk baseline).
    Random,
    /// Standing still at the start: the return of never crossing (with traffic, a
    /// policy that never dares to cross scores this).
    StandStill,
    /// The oracle planner (with traffic: waits for WALK and for gaps in the vehicles).
    Oracle,
    /// With traffic: the oracle planner of the empty crossing, walking through signals
    /// and vehicles as if there were none (what crossing against the signal costs).
    OracleIgnoringTraffic,
}

/// How a learned policy picks its actions in evaluation.
#[derive(Clone, Copy, PartialEq, Eq, ValueEnum, Debug)]
enum ActionMode {
    /// Sample from π (the paper's protocol, §V-C: 10 sampled trajectories per pose).
    Sample,
    /// The policy's mode tanh(μ): the runs of a pose are then identical.
    Mode,
}

impl ActionMode {
    fn describe(self) -> &'static str {
        match self {
            ActionMode::Sample => "actions sampled from π",
            ActionMode::Mode => "actions = mode tanh(μ)",
        }
    }
}

#[derive(Parser, Debug)]
#[command(version, about = "Validation protocol of the paper (§V-C) on a pednav checkpoint: Table III, CSV, Fig. 5")]
struct Cli {
    /// Run config for a policy without a run (`untrained`, `random`, `oracle`): its
    /// scene, simulator and networks (default: the reference scene and defaults).
    #[arg(long, conflicts_with = "run_dir")]
    config: Option<PathBuf>,
    /// `--policy untrained`: the seed its networks are initialised from (default:
    /// the config's `seed`, as the actors and the learner of a run do).
    #[arg(long)]
    init_seed: Option<u64>,
    /// Run directory whose latest checkpoint and config are evaluated (required for `--policy learned`).
    #[arg(long)]
    run_dir: Option<PathBuf>,
    /// Checkpoint directory to evaluate instead of the run's latest
    /// (`<run-dir>/checkpoints/learner`); it must match the run's `config.toml`.
    #[arg(long, requires = "run_dir")]
    checkpoint: Option<PathBuf>,
    /// Which policy acts.
    #[arg(long, value_enum, default_value_t = PolicyArg::Learned)]
    policy: PolicyArg,
    /// How the learned policy acts: `sample` (the paper's protocol) or its `mode` tanh(μ).
    #[arg(long, value_enum, default_value_t = ActionMode::Sample)]
    mode: ActionMode,
    /// Runs per (point, yaw). Paper: 10.
    #[arg(long, default_value_t = protocol::RUNS)]
    runs: u32,
    /// Episode limit. Paper: 2000.
    #[arg(long, default_value_t = protocol::T_MAX)]
    t_max: u32,
    /// Discount of the returns reported (and of the oracle's plan). Default: the
    /// protocol's 0.99 (Table IV), whatever `dsac.gamma` the run trained with, so that
    /// runs trained with another discount compare with every other table.
    #[arg(long, default_value_t = protocol::GAMMA)]
    gamma: f32,
    /// Start poses from a CSV file (`x,y,yaw`, degrees) instead of the 14 points × 8 yaws.
    #[arg(long)]
    starts: Option<PathBuf>,
    /// Environments stepped together per process.
    #[arg(long, default_value_t = 8)]
    envs: usize,
    /// Worker processes.
    #[arg(long, default_value_t = 1)]
    workers: usize,
    /// Seed of the task list (look, policy noise).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Output folder (default: <run>/eval/<policy>, or eval/<policy> without a run).
    #[arg(long)]
    out: Option<PathBuf>,
    /// Also record these episodes as GIFs: POINT:YAW:RUN (repeatable).
    #[arg(long)]
    gif: Vec<String>,
    /// Skip the oracle column (planning takes a few seconds).
    #[arg(long)]
    no_oracle: bool,
    /// Where the policy runs: cpu, cuda or cuda:N (CUDA needs the binaries of
    /// `deploy/build_cuda.sh`; rendering stays on the CPU).
    #[arg(long, default_value_t = pednav_nets::DeviceSpec::Cpu)]
    device: pednav_nets::DeviceSpec,
    /// (internal) worker index.
    #[arg(long, hide = true)]
    shard: Option<usize>,
    /// (internal) worker count.
    #[arg(long, hide = true, default_value_t = 1)]
    of: usize,
    /// (internal) worker output.
    #[arg(long, hide = true)]
    shard_out: Option<PathBuf>,
}

/// " (how the learned policy acts)" for the progress line and the table's title;
/// nothing for the random walk and the oracle.
fn action_label(cli: &Cli) -> String {
    if matches!(cli.policy, PolicyArg::Learned | PolicyArg::Untrained) {
        format!(" ({})", cli.mode.describe())
    } else {
        String::new()
    }
}

/// The `--policy` value that names `p` (for names and for the workers' command lines).
fn policy_arg(p: PolicyArg) -> &'static str {
    match p {
        PolicyArg::Learned => "learned",
        PolicyArg::Untrained => "untrained",
        PolicyArg::Random => "random",
        PolicyArg::StandStill => "stand-still",
        PolicyArg::Oracle => "oracle",
        PolicyArg::OracleIgnoringTraffic => "oracle-ignoring-traffic",
    }
}

fn kind(cli: &Cli) -> PolicyKind {
    match cli.policy {
        PolicyArg::Learned | PolicyArg::Untrained => {
            PolicyKind::Learned { deterministic: cli.mode == ActionMode::Mode }
        }
        PolicyArg::Random => PolicyKind::Random,
        PolicyArg::StandStill => PolicyKind::StandStill,
        PolicyArg::Oracle => PolicyKind::Oracle,
        PolicyArg::OracleIgnoringTraffic => PolicyKind::OracleIgnoringTraffic,
    }
}

fn setup(cli: &Cli) -> Result<(RunConfig, Option<(pednav_nets::NetsConfig, pednav_nets::DsacNets)>)> {
    // The run's config, else --config, else the defaults (reference scene).
    let config = || -> Result<RunConfig> {
        match (&cli.run_dir, &cli.config) {
            (Some(dir), _) => Ok(RunConfig::load(&dir.join("config.toml"))?),
            (None, Some(path)) => Ok(RunConfig::load(path)?),
            (None, None) => Ok(RunConfig::default()),
        }
    };
    match (&cli.run_dir, cli.policy) {
        (Some(dir), PolicyArg::Learned) => {
            let (cfg, nets) = load_policy(dir, cli.checkpoint.as_deref(), &cli.device.open()?)?;
            let nc = cfg.nets.clone();
            Ok((cfg, Some((nc, nets))))
        }
        (None, PolicyArg::Learned) => bail!("--policy learned needs --run-dir (a run with a checkpoint)"),
        (_, PolicyArg::Untrained) => {
            if cli.run_dir.is_none() && cli.config.is_none() {
                bail!("--policy untrained needs --config FILE (or --run-dir): the networks it builds are the config's");
            }
            let cfg = config()?;
            let nets = pednav_nets::DsacNets::new(&cfg.nets, &cli.device.open()?, cli.init_seed.unwrap_or(cfg.seed))?;
            Ok((cfg.clone(), Some((cfg.nets, nets))))
        }
        _ => Ok((config()?, None)),
    }
}

fn tasks(cli: &Cli, cfg: &RunConfig) -> Result<Vec<EvalTask>> {
    if cli.runs == 0 {
        bail!("--runs must be at least 1");
    }
    Ok(match &cli.starts {
        Some(path) => protocol::tasks_from_csv(path, cli.runs, cli.seed)?,
        None => protocol::validation_tasks(&cfg.scene()?, cli.runs, cli.seed),
    })
}

fn main() -> Result<()> {
    pednav_sim::prepare_headless_env();
    pednav_runtime::init_logging();
    let cli = Cli::parse();
    if cli.envs == 0 || cli.workers == 0 {
        bail!("--envs and --workers must be at least 1");
    }
    pednav_nets::init_cpu_runtime(Some(1));
    let (cfg, nets) = setup(&cli)?;
    let all = tasks(&cli, &cfg)?;
    if !(cli.gamma > 0.0 && cli.gamma < 1.0) {
        bail!("--gamma must lie in (0, 1), got {}", cli.gamma);
    }
    let gamma = cli.gamma;

    if let Some(k) = cli.shard {
        return run_shard(&cli, &cfg, nets, &all, k);
    }

    let policy_name = cli.policy.to_possible_value().expect("no policy is skipped").get_name().to_string();
    // Another checkpoint than the run's latest gets its own folder, named after it.
    let folder = match &cli.checkpoint {
        Some(c) => format!("{policy_name}-{}", c.file_name().map_or("checkpoint".into(), |n| n.to_string_lossy())),
        None => policy_name.clone(),
    };
    let out = cli.out.clone().unwrap_or_else(|| match &cli.run_dir {
        Some(d) => d.join("eval").join(&folder),
        None => PathBuf::from("eval").join(&folder),
    });
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    eprintln!(
        "pednav-eval: {} episodes ({} × {} runs), T_max {}, policy {policy_name}{}, {} worker(s) × {} envs",
        all.len(),
        if cli.starts.is_none() {
            format!("{} points × {} yaws", all.len() / cli.runs as usize / YAWS_DEG.len(), YAWS_DEG.len())
        } else {
            format!("{} start poses", all.len() / cli.runs as usize)
        },
        cli.runs,
        cli.t_max,
        action_label(&cli),
        cli.workers,
        cli.envs
    );
    let mut shown = Progress::new(all.len());
    let mut results: Vec<EpisodeResult> = if cli.workers == 1 {
        let mut ev = Evaluator::new(cfg.scene()?, &cfg.sim, cli.t_max, gamma, cli.envs, kind(&cli), nets, cli.seed)?;
        ev.run(&all, |done| shown.update(done))?
    } else {
        run_workers(&cli, &out, &mut shown)?
    };
    let cr = if shown.tty { "\r" } else { "" };
    eprintln!("{cr}  {} episodes in {:.0} s", results.len(), shown.t0.elapsed().as_secs_f64());
    let order = |r: &EpisodeResult| (r.point, YAWS_DEG.iter().position(|&y| y == r.yaw_deg).unwrap_or(99), r.run);
    results.sort_by_key(order);

    print_table_and_write_outputs(&cli, &cfg, &all, &results, &policy_name, &out)?;
    record_gifs(&cli, &cfg, &all, &out)?;
    eprintln!("wrote {}/{{table.txt,table.csv,results.csv,trajectories.png}}", out.display());
    Ok(())
}

/// Worker (`--shard K`): runs its shard of the tasks and writes the results as JSON to `--shard-out`.
fn run_shard(
    cli: &Cli,
    cfg: &RunConfig,
    nets: Option<(pednav_nets::NetsConfig, pednav_nets::DsacNets)>,
    all: &[EvalTask],
    k: usize,
) -> Result<()> {
    let mine = protocol::shard(all, k, cli.of);
    let mut ev =
        Evaluator::new(cfg.scene()?, &cfg.sim, cli.t_max, cli.gamma, cli.envs, kind(cli), nets, cli.seed ^ k as u64)?;
    let out = cli.shard_out.as_ref().context("--shard needs --shard-out")?;
    // Episodes done so far, for the parent's progress line (best effort: a failed
    // write costs the line, not the evaluation).
    let count = shard_progress_path(out);
    let results = ev.run(&mine, |done| {
        let _ = std::fs::write(&count, done.to_string());
    })?;
    std::fs::write(out, serde_json::to_vec(&results)?).with_context(|| format!("writing {}", out.display()))?;
    Ok(())
}

/// Prints the Table III layout (oracle column unless `--no-oracle`) and writes every output file to `out`.
fn print_table_and_write_outputs(
    cli: &Cli,
    cfg: &RunConfig,
    all: &[EvalTask],
    results: &[EpisodeResult],
    policy_name: &str,
    out: &Path,
) -> Result<()> {
    let oracle = if cli.no_oracle {
        Default::default()
    } else {
        let mut starts: Vec<(u32, f32, f32)> = Vec::new();
        for t in all {
            if !starts.iter().any(|s| s.0 == t.point) {
                starts.push((t.point, t.x, t.y));
            }
        }
        oracle_per_point(&cfg.scene()?, &cfg.sim, cli.gamma, cli.t_max, &starts)?
    };
    let rows = if cli.starts.is_some() { table::Rows::StartList } else { table::Rows::ValidationPoints };
    let t = table::aggregate(results, &oracle, rows);
    let title = format!(
        "{}{} — {policy_name} policy{}, {} episodes, T_max {}",
        cli.run_dir.as_ref().map_or("no run".into(), |d| d.display().to_string()),
        cli.checkpoint.as_ref().map_or(String::new(), |c| format!(" (checkpoint {})", c.display())),
        action_label(cli),
        results.len(),
        cli.t_max
    );
    let text = t.render(&title);
    print!("{text}");
    // Each output on its own: a full disk or a read-only folder costs the files it
    // refuses, never the others (the per-episode results first: the table and the plot
    // can be made again from them).
    let scene = cfg.scene()?;
    type WriteTo<'a> = &'a dyn Fn(&Path) -> Result<()>;
    let outputs: [(&str, WriteTo); 4] = [
        ("results.csv", &|p| Ok(table::write_results_csv(results, p)?)),
        ("table.txt", &|p| Ok(std::fs::write(p, &text)?)),
        ("table.csv", &|p| Ok(t.write_csv(p)?)),
        ("trajectories.png", &|p| Ok(plots::trajectories(&scene, results, policy_name, p)?)),
    ];
    let failed: Vec<String> = outputs
        .iter()
        .filter_map(|(name, write)| {
            let path = out.join(name);
            write(&path).err().map(|e| format!("{}: {e:#}", path.display()))
        })
        .collect();
    if !failed.is_empty() {
        bail!(
            "the evaluation finished (its table is printed above) but {} of its outputs could not be written:\n  {}\n\
             free space or fix the folder's permissions and run the same command again",
            failed.len(),
            failed.join("\n  ")
        );
    }
    Ok(())
}

/// Records each `--gif POINT:YAW:RUN` episode as a GIF in `out`, with its own one-environment evaluator.
fn record_gifs(cli: &Cli, cfg: &RunConfig, all: &[EvalTask], out: &Path) -> Result<()> {
    for spec in &cli.gif {
        let task = gif_task(spec, all)?;
        let mut ev =
            Evaluator::new(cfg.scene()?, &cfg.sim, cli.t_max, cli.gamma, 1, kind(cli), setup(cli)?.1, task.seed)?;
        let path = out.join(format!("episode-p{}-y{}-r{}.gif", task.point, task.yaw_deg, task.run));
        let r = ev.record_gif(task, &path)?;
        eprintln!(
            "wrote {} (return {:.2}, {} steps, success {})",
            path.display(),
            r.discounted_return,
            r.steps,
            r.success
        );
    }
    Ok(())
}

/// The evaluation's progress on stderr: on a terminal one line rewritten every 20
/// episodes, otherwise a line every 30 s (and at the end), as in a log file.
struct Progress {
    n: usize,
    t0: Instant,
    tty: bool,
    last_done: usize,
    last_line: Instant,
}

impl Progress {
    fn new(n: usize) -> Progress {
        let now = Instant::now();
        Progress { n, t0: now, tty: std::io::stderr().is_terminal(), last_done: 0, last_line: now }
    }

    fn update(&mut self, done: usize) {
        if done == self.last_done {
            return;
        }
        let line = progress(done, self.n, self.t0.elapsed().as_secs_f64());
        if self.tty && (done / 20 != self.last_done / 20 || done == self.n) {
            eprint!("\r{line}");
        } else if !self.tty && (self.last_line.elapsed().as_secs() >= 30 || done == self.n) {
            eprintln!("{line}");
            self.last_line = Instant::now();
        }
        self.last_done = done;
    }
}

/// Where a worker writes how many of its episodes are done.
fn shard_progress_path(shard_out: &Path) -> PathBuf {
    let mut name = shard_out.as_os_str().to_owned();
    name.push(".done");
    PathBuf::from(name)
}

/// `  340/1120 episodes (212 s, ETA 00:08:06)`: episodes done, elapsed, and the time
/// left at the pace so far.
fn progress(done: usize, n: usize, secs: f64) -> String {
    let eta = if done == 0 {
        "—".to_string()
    } else {
        let left = (secs / done as f64 * (n - done) as f64) as u64;
        format!("{:02}:{:02}:{:02}", left / 3600, (left / 60) % 60, left % 60)
    };
    format!("  {done}/{n} episodes ({secs:.0} s, ETA {eta})")
}

fn gif_task(spec: &str, all: &[EvalTask]) -> Result<EvalTask> {
    let parts: Vec<&str> = spec.split(':').collect();
    let parse = || -> Option<(u32, f32, u32)> {
        Some((parts.first()?.parse().ok()?, parts.get(1)?.parse().ok()?, parts.get(2)?.parse().ok()?))
    };
    let (p, y, r) = parse().with_context(|| format!("--gif expects POINT:YAW:RUN, got `{spec}`"))?;
    all.iter()
        .find(|t| t.point == p && t.yaw_deg == y && t.run == r)
        .copied()
        .with_context(|| format!("--gif {spec}: no such episode in the task list"))
}

fn run_workers(cli: &Cli, out: &Path, shown: &mut Progress) -> Result<Vec<EpisodeResult>> {
    let exe = std::env::current_exe()?;
    let mut children = Vec::new();
    for k in 0..cli.workers {
        let shard_out = out.join(format!(".shard{k}.json"));
        let mut cmd = Command::new(&exe);
        if let Some(d) = &cli.run_dir {
            cmd.arg("--run-dir").arg(d);
        }
        if let Some(s) = &cli.starts {
            cmd.arg("--starts").arg(s);
        }
        if let Some(c) = &cli.checkpoint {
            cmd.arg("--checkpoint").arg(c);
        }
        if let Some(c) = &cli.config {
            cmd.arg("--config").arg(c);
        }
        if let Some(s) = cli.init_seed {
            cmd.args(["--init-seed", &s.to_string()]);
        }
        cmd.args(["--mode", &format!("{:?}", cli.mode).to_lowercase()]);
        cmd.args(["--policy", policy_arg(cli.policy)])
            .args(["--runs", &cli.runs.to_string(), "--t-max", &cli.t_max.to_string()])
            .args(["--gamma", &cli.gamma.to_string()])
            .args(["--envs", &cli.envs.to_string(), "--seed", &cli.seed.to_string()])
            .args(["--shard", &k.to_string(), "--of", &cli.workers.to_string()])
            .args(["--device", &cli.device.to_string()])
            .arg("--shard-out")
            .arg(&shard_out);
        children.push((cmd.spawn().context("starting a worker")?, shard_out));
    }
    // Wait for all of them, showing the episodes they have done between them.
    let mut exited = vec![None; children.len()];
    while exited.iter().any(Option::is_none) {
        for (k, (c, _)) in children.iter_mut().enumerate() {
            if exited[k].is_none() {
                exited[k] = c.try_wait().context("waiting for a worker")?;
            }
        }
        let done: usize = children
            .iter()
            .filter_map(|(_, path)| {
                std::fs::read_to_string(shard_progress_path(path)).ok()?.trim().parse::<usize>().ok()
            })
            .sum();
        shown.update(done);
        if exited.iter().any(Option::is_none) {
            std::thread::sleep(std::time::Duration::from_millis(500));
        }
    }
    let mut results = Vec::new();
    for ((_, path), status) in children.iter().zip(exited) {
        let status = status.expect("every worker has exited");
        let _ = std::fs::remove_file(shard_progress_path(path));
        if !status.success() {
            bail!("worker {} failed ({status})", path.display());
        }
        let read = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let part: Vec<EpisodeResult> =
            serde_json::from_slice(&read).with_context(|| format!("parsing {}", path.display()))?;
        results.extend(part);
        let _ = std::fs::remove_file(path);
    }
    Ok(results)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_eta_is_the_time_left_at_the_pace_so_far() {
        // 340 of 1120 episodes in 212 s: 780 left at 0.6235 s each = 486 s.
        assert_eq!(progress(340, 1120, 212.0), "  340/1120 episodes (212 s, ETA 00:08:06)");
        assert_eq!(progress(0, 1120, 3.0), "  0/1120 episodes (3 s, ETA —)");
        assert_eq!(progress(1120, 1120, 500.0), "  1120/1120 episodes (500 s, ETA 00:00:00)");
    }

    #[test]
    fn a_workers_count_sits_beside_its_shard() {
        assert_eq!(
            shard_progress_path(Path::new("eval/learned/.shard1.json")),
            Path::new("eval/learned/.shard1.json.done")
        );
    }
}
