//! `pednav-sim`: look at, plan over and benchmark the built-in simulator.
//!
//! ```text
//! pednav-sim view   --x 14 --y -7 --yaw-deg 180 --out out/view.png   # 84×84 PNG + enlarged + 512² render
//! pednav-sim map    --out out/map.png --oracle-from 7                 # bird's-eye map (+ oracle path)
//! pednav-sim record --policy oracle --start 3 --out out/episode.gif   # GIF: view beside the map
//! pednav-sim oracle                                                   # oracle returns of the 14 points
//! pednav-sim bench  --envs 1,16,64                                    # env steps/s vs render-only views/s
//! pednav-sim traffic --hours 1                                        # flow, queues, saturation flow per level
//! pednav-sim --traffic medium view --time 20 --x 13 --y -6.5 --yaw-deg 90   # any command among traffic
//! ```

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand, ValueEnum};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use pednav_sim::draw::{Film, draw_map, enlarge_gray, save_gray_png, save_png};
use pednav_sim::oracle::{Oracle, OracleConfig};
use pednav_sim::policy::{FixedPolicy, OraclePolicy, Policy, RandomPolicy};
use pednav_sim::{
    Action, BackendChoice, CameraView, Look, Pose, Renderer, RendererConfig, Scene, SimConfig, SimWorld, TrafficLevel,
    VecEnv,
};

#[derive(Parser)]
#[command(
    name = "pednav-sim",
    version,
    about = "The pednav urban crossing simulator: views, maps, episode GIFs, oracle, benchmark"
)]
struct Cli {
    /// Scene file (TOML). Default: the built-in reference corner (shared/sim/scenes/corner.toml).
    #[arg(long, global = true)]
    scene: Option<PathBuf>,
    /// Graphics backend: auto picks a real GPU first, then Mesa (Vulkan lavapipe, GL llvmpipe).
    #[arg(long, global = true, value_enum, env = "PEDNAV_BACKEND", default_value_t = BackendChoice::Auto)]
    backend: BackendChoice,
    /// Seed of every random choice (random policy, domain randomisation, traffic).
    #[arg(long, global = true, default_value_t = 0)]
    seed: u64,
    /// Traffic at the crossing (the scene's `[traffic]` levels): signals, vehicles, other pedestrians.
    #[arg(long, global = true, value_enum, default_value_t = TrafficLevel::Off)]
    traffic: TrafficLevel,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Save the first-person view at a pose as PNG: the observation itself, a ×4 enlargement, and a 512×512 render for people.
    View {
        /// Camera x in metres (default: validation point 3).
        #[arg(long, allow_hyphen_values = true)]
        x: Option<f32>,
        /// Camera y in metres.
        #[arg(long, allow_hyphen_values = true)]
        y: Option<f32>,
        /// Body yaw in degrees (0 = east, counter-clockwise).
        #[arg(long, allow_hyphen_values = true)]
        yaw_deg: Option<f32>,
        /// Head yaw offset in degrees (±60).
        #[arg(long, allow_hyphen_values = true, default_value_t = 0.0)]
        head_deg: f32,
        /// Observation size in pixels.
        #[arg(long, default_value_t = 84)]
        size: u32,
        /// Size of the render for people (0 to skip).
        #[arg(long, default_value_t = 512)]
        people_size: u32,
        /// With traffic: seconds after the episode's start (its traffic drawn from --seed) to show.
        #[arg(long, default_value_t = 0.0)]
        time: f32,
        /// Output PNG; `-x4` and `-<people_size>` variants are written beside it.
        #[arg(long, default_value = "out/view.png")]
        out: PathBuf,
    },
    /// Draw the bird's-eye map: regions, obstacles, curriculum region (hatched), validation points, first task, fixed start, goal.
    Map {
        /// Pixels per metre.
        #[arg(long, default_value_t = 8.0)]
        px_per_m: f32,
        /// Also draw the oracle's path from this validation point (at its favourable yaw).
        #[arg(long)]
        oracle_from: Option<usize>,
        /// Also draw a trajectory from a CSV file with columns x,y (header optional).
        #[arg(long)]
        trajectory: Option<PathBuf>,
        /// Output PNG.
        #[arg(long, default_value = "out/map.png")]
        out: PathBuf,
    },
    /// Record an episode as a GIF: the enlarged first-person view beside the map with the trajectory so far.
    Record {
        /// Policy driving the pedestrian.
        #[arg(long, value_enum, default_value_t = PolicyChoice::Oracle)]
        policy: PolicyChoice,
        /// Start: a validation point index 0–13, or `first` (first task).
        #[arg(long, default_value = "3")]
        start: String,
        /// Yaw at the start in degrees (default: the point's favourable yaw).
        #[arg(long, allow_hyphen_values = true)]
        yaw_deg: Option<f32>,
        /// Most steps to record.
        #[arg(long, default_value_t = 200)]
        steps: u32,
        /// Output GIF.
        #[arg(long, default_value = "out/episode.gif")]
        out: PathBuf,
    },
    /// Plan the oracle and print its discounted return from the 14 validation points.
    Oracle {
        /// Also print the return for the 8 validation yaws of each point.
        #[arg(long)]
        all_yaws: bool,
    },
    /// Benchmark env steps/s (physics + render + readback) against render-only views/s.
    Bench {
        /// Comma-separated numbers of environments per process.
        #[arg(long, default_value = "1,16,64", value_delimiter = ',')]
        envs: Vec<usize>,
        /// Seconds of measurement per configuration.
        #[arg(long, default_value_t = 3.0)]
        seconds: f64,
        /// Observation size in pixels.
        #[arg(long, default_value_t = 84)]
        size: u32,
    },
    /// Validate the traffic model as traffic engineers would: measured flow per lane
    /// against each level's set flow, queues at the stop lines, and the saturation
    /// flow of queues discharging at green (with a demand above capacity).
    Traffic {
        /// Simulated hours per level.
        #[arg(long, default_value_t = 1.0)]
        hours: f64,
    },
    /// Print the scene summary and the graphics adapter that would be used.
    Info,
}

#[derive(Clone, Copy, ValueEnum)]
enum PolicyChoice {
    /// Greedy one-step lookahead on the planned values (the oracle).
    Oracle,
    /// Uniform random actions from --seed.
    Random,
    /// Walk straight ahead at full speed.
    Straight,
}

/// The options every subcommand shares, copied out of [`Cli`].
#[derive(Clone, Copy)]
struct Globals {
    backend: BackendChoice,
    seed: u64,
    traffic: TrafficLevel,
}

/// Where and when `view` looks: the body pose, the head's yaw offset and the seconds into the episode.
#[derive(Clone, Copy)]
struct Shot {
    pose: Pose,
    head_deg: f32,
    time: f32,
}

fn main() -> Result<()> {
    pednav_sim::prepare_headless_env();
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn,wgpu_hal=off".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    let scene = Scene::load_or_reference(cli.scene.as_deref()).context("loading the scene")?;
    let g = Globals { backend: cli.backend, seed: cli.seed, traffic: cli.traffic };
    match cli.command {
        Command::View { x, y, yaw_deg, head_deg, size, people_size, time, out } => {
            let fs = scene.fixed_start();
            let pose = Pose {
                x: x.unwrap_or(fs.x),
                y: y.unwrap_or(fs.y),
                yaw: yaw_deg.map(f32::to_radians).unwrap_or(fs.yaw),
            };
            view(&scene, g, Shot { pose, head_deg, time }, size, people_size, &out)?;
        }
        Command::Map { px_per_m, oracle_from, trajectory, out } => map(scene, px_per_m, oracle_from, trajectory, &out)?,
        Command::Record { policy, start, yaw_deg, steps, out } => {
            let world = Arc::new(SimWorld::new(scene, SimConfig { traffic: g.traffic, ..SimConfig::default() })?);
            let start = if start == "first" {
                let mut p = world.scene.first_task();
                if let Some(y) = yaw_deg {
                    p.yaw = y.to_radians();
                }
                p
            } else {
                let k: usize =
                    start.parse().with_context(|| format!("--start must be 0–13 or `first`, got `{start}`"))?;
                validation_pose(&world.scene, k, yaw_deg)?
            };
            record(world, g.backend, g.seed, policy, start, steps, &out)?;
        }
        Command::Oracle { all_yaws } => oracle_table(scene, all_yaws)?,
        Command::Bench { envs, seconds, size } => {
            let sim = SimConfig { image_size: size, traffic: g.traffic, ..SimConfig::default() };
            bench(scene, sim, g.backend, &envs, seconds)?
        }
        Command::Traffic { hours } => traffic_table(scene, hours, g.seed)?,
        Command::Info => info(scene, g.backend)?,
    }
    Ok(())
}

/// `view`: saves the observation at `shot` as PNG, its ×4 enlargement and (unless 0) a `people_size` render.
fn view(scene: &Scene, g: Globals, shot: Shot, size: u32, people_size: u32, out: &std::path::Path) -> Result<()> {
    let Shot { pose, head_deg, time } = shot;
    let sim = SimConfig { image_size: size, traffic: g.traffic, ..SimConfig::default() };
    let world = SimWorld::new(scene.clone(), sim.clone())?;
    let cam = CameraView {
        x: pose.x,
        y: pose.y,
        z: world.config.eye_height,
        yaw: pose.yaw + head_deg.to_radians(),
        look: Look::default(),
    };
    let traffic_view = |size: u32| -> Result<Vec<u8>> {
        let world = Arc::new(SimWorld::new(scene.clone(), SimConfig { image_size: size, ..sim.clone() })?);
        let mut env = VecEnv::new(world.clone(), 1, g.backend)?;
        env.reset(0, pose, g.seed)?;
        let head = (head_deg / world.config.max_head_yaw_deg).clamp(-1.0, 1.0);
        for _ in 0..(time / world.config.dt).round() as u32 {
            let t = env.step(&[[-1.0, 0.0, head]])?[0];
            if t.terminated || t.truncated {
                bail!("the episode ended before --time {time} s");
            }
        }
        if let Some(t) = env.traffic(0) {
            println!(
                "traffic: {} vehicles on the lanes, {} walkers, signal clock {:.2} s",
                t.num_vehicles(),
                t.walkers.len(),
                t.t
            );
        }
        Ok(env.render()?.frame(0))
    };
    let traffic_on = g.traffic.is_on();
    let frame = if traffic_on { traffic_view(size)? } else { render_one(&world, g.backend, size, cam)? };
    save_gray_png(&frame, size, out)?;
    let x4 = sibling(out, "x4");
    save_png(&enlarge_gray(&frame, size, 4), &x4)?;
    println!("wrote {} ({size}×{size}) and {}", out.display(), x4.display());
    if people_size > 0 {
        let big =
            if traffic_on { traffic_view(people_size)? } else { render_one(&world, g.backend, people_size, cam)? };
        let p = sibling(out, &people_size.to_string());
        save_gray_png(&big, people_size, &p)?;
        println!("wrote {} ({people_size}×{people_size})", p.display());
    }
    Ok(())
}

/// `map`: draws the bird's-eye map, with the oracle's path from a validation point and a CSV trajectory if asked.
fn map(
    scene: Scene,
    px_per_m: f32,
    oracle_from: Option<usize>,
    trajectory: Option<PathBuf>,
    out: &std::path::Path,
) -> Result<()> {
    let world = SimWorld::new(scene, SimConfig::default())?;
    let mut canvas = draw_map(&world.scene, &world.map, px_per_m);
    if let Some(k) = oracle_from {
        let start = validation_pose(&world.scene, k, None)?;
        let oracle = Oracle::plan(&world, OracleConfig::default());
        let r = oracle.rollout(&world, start, 2000);
        let pts: Vec<(f32, f32)> = r.trajectory.iter().map(|p| (p.x, p.y)).collect();
        canvas.polyline(&pts, 2.0, [220, 40, 40]);
        canvas.pose_arrow(start, 1.5, [220, 40, 40]);
        println!("oracle from point {k}: return {:.2}, {} steps, success {}", r.discounted_return, r.steps, r.success);
    }
    if let Some(path) = trajectory {
        let pts = read_xy_csv(&path)?;
        canvas.polyline(&pts, 2.0, [250, 140, 0]);
    }
    save_png(&canvas.image, out)?;
    println!("wrote {} ({}×{})", out.display(), canvas.image.width(), canvas.image.height());
    Ok(())
}

/// `oracle`: plans the oracle and prints its return from each validation point (and each validation yaw if asked).
fn oracle_table(scene: Scene, all_yaws: bool) -> Result<()> {
    let world = SimWorld::new(scene, SimConfig { t_max: 2000, ..SimConfig::default() })?;
    let t0 = Instant::now();
    let oracle = Oracle::plan(&world, OracleConfig::default());
    println!("planned in {:.1} s ({} sweeps)", t0.elapsed().as_secs_f64(), oracle.sweeps());
    println!("{:>5} {:>7} {:>7} {:>8} {:>10} {:>6} {:>7}", "point", "x", "y", "yaw", "return", "steps", "success");
    for p in world.scene.validation_points() {
        let pose = Pose::from_degrees(p.x, p.y, p.favourable_yaw_deg);
        let r = oracle.rollout(&world, pose, 2000);
        println!(
            "{:>5} {:>7.1} {:>7.1} {:>8.0} {:>10.2} {:>6} {:>7}",
            p.id, p.x, p.y, p.favourable_yaw_deg, r.discounted_return, r.steps, r.success
        );
        if all_yaws {
            for yaw in [0.0f32, 45.0, -45.0, 90.0, -90.0, 135.0, -135.0, 180.0] {
                let r = oracle.rollout(&world, Pose::from_degrees(p.x, p.y, yaw), 2000);
                println!(
                    "{:>5} {:>7} {:>7} {:>8.0} {:>10.2} {:>6} {:>7}",
                    "", "", "", yaw, r.discounted_return, r.steps, r.success
                );
            }
        }
    }
    Ok(())
}

/// `info`: prints the scene summary and the graphics adapter that would be used.
fn info(scene: Scene, backend: BackendChoice) -> Result<()> {
    println!("scene: {} ({})", scene.spec.name, scene.origin);
    println!("  {}", scene.spec.description);
    println!(
        "  extent {:?}..{:?}, {} regions, {} obstacles (incl. 4 walls), goal centre {:?}",
        scene.extent.min,
        scene.extent.max,
        scene.regions.len(),
        scene.obstacles.len(),
        scene.goal_center
    );
    let world = SimWorld::new(scene, SimConfig::default())?;
    let r = Renderer::new(&world.scene, &world.map, RendererConfig::from_sim(&world.config, 1, backend))?;
    println!("adapter: {}", r.adapter_description());
    Ok(())
}

fn sibling(path: &std::path::Path, tag: &str) -> PathBuf {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_else(|| "view".into());
    path.with_file_name(format!("{stem}-{tag}.png"))
}

fn render_one(world: &SimWorld, backend: BackendChoice, size: u32, cam: CameraView) -> Result<Vec<u8>> {
    let cfg = RendererConfig { image_size: size, ..RendererConfig::from_sim(&world.config, 1, backend) };
    let mut r = Renderer::new(&world.scene, &world.map, cfg)?;
    Ok(r.render(&[cam])?.frame(0))
}

fn validation_pose(scene: &Scene, k: usize, yaw_deg: Option<f32>) -> Result<Pose> {
    let Some(p) = scene.validation_points().get(k) else {
        bail!("validation point {k} does not exist (0–{})", scene.validation_points().len() - 1)
    };
    Ok(Pose::from_degrees(p.x, p.y, yaw_deg.unwrap_or(p.favourable_yaw_deg)))
}

fn read_xy_csv(path: &std::path::Path) -> Result<Vec<(f32, f32)>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("reading trajectory {}", path.display()))?;
    let mut pts = Vec::new();
    for (n, line) in text.lines().enumerate() {
        let mut f = line.split(',').map(str::trim);
        let (Some(a), Some(b)) = (f.next(), f.next()) else { continue };
        match (a.parse::<f32>(), b.parse::<f32>()) {
            (Ok(x), Ok(y)) => pts.push((x, y)),
            _ if n == 0 => {} // header
            _ => bail!("{}:{}: expected `x,y` numbers, got `{line}`", path.display(), n + 1),
        }
    }
    Ok(pts)
}

fn record(
    world: Arc<SimWorld>,
    backend: BackendChoice,
    seed: u64,
    choice: PolicyChoice,
    start: Pose,
    steps: u32,
    out: &std::path::Path,
) -> Result<()> {
    let mut env = VecEnv::new(world.clone(), 1, backend)?;
    env.reset(0, start, seed)?;
    let mut policy: Box<dyn Policy> = match choice {
        PolicyChoice::Oracle => Box::new(OraclePolicy::new(Oracle::plan(&world, OracleConfig::default()))),
        PolicyChoice::Random => Box::new(RandomPolicy::new(seed)),
        PolicyChoice::Straight => Box::new(FixedPolicy([1.0, 0.0, 0.0])),
    };
    policy.begin(0, seed, None).map_err(anyhow::Error::from_boxed)?;
    let mut film = Film::new(&world);
    let mut trail = vec![(start.x, start.y)];
    // γ of the oracle's table (Table IV's 0.99), so the returns printed compare.
    let mut ret = pednav_sim::DiscountedReturn::new(OracleConfig::default().gamma as f64);
    let mut pose = start;
    let mut outcome = "step limit";
    let mut action: [Action; 1] = [[0.0; 3]];
    for _ in 0..=steps {
        let frame = env.render()?.frame(0);
        film.add(Some(&frame), &trail, Pose { yaw: env.pedestrian(0).camera_yaw(), ..pose });
        if env.pedestrian(0).done || film.len() > steps as usize {
            break;
        }
        policy.act(&env, &mut action).map_err(anyhow::Error::from_boxed)?;
        let t = env.step(&action)?[0];
        ret.add(t.reward);
        pose = t.pose;
        trail.push((pose.x, pose.y));
        if t.terminated {
            outcome = if t.reached_goal() { "goal reached" } else { "hit by a vehicle" };
        } else {
            policy.observe(0, action[0], t.reward, None).map_err(anyhow::Error::from_boxed)?;
        }
    }
    film.save(out)?;
    println!("wrote {} ({} frames); {outcome}; discounted return {:.2}", out.display(), film.len(), ret.value());
    Ok(())
}

fn cpu_seconds() -> f64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: clock_gettime writes into the timespec we own.
    unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9
}

struct Rate {
    per_wall_s: f64,
    per_cpu_s: f64,
}

fn measure(seconds: f64, units_per_iter: usize, mut f: impl FnMut() -> Result<()>) -> Result<Rate> {
    for _ in 0..5 {
        f()?;
    }
    let (w0, c0) = (Instant::now(), cpu_seconds());
    let mut iters = 0usize;
    while w0.elapsed().as_secs_f64() < seconds || iters < 10 {
        f()?;
        iters += 1;
    }
    let (w, c) = (w0.elapsed().as_secs_f64(), cpu_seconds() - c0);
    let units = (iters * units_per_iter) as f64;
    Ok(Rate { per_wall_s: units / w, per_cpu_s: units / c.max(1e-9) })
}

fn traffic_table(scene: Scene, hours: f64, seed: u64) -> Result<()> {
    if !(hours > 0.0 && hours <= 100.0) {
        bail!("--hours {hours} must lie in (0, 100]");
    }
    let levels = [("light", TrafficLevel::Light), ("medium", TrafficLevel::Medium), ("heavy", TrafficLevel::Heavy)];
    let world = SimWorld::new(scene.clone(), SimConfig { traffic: TrafficLevel::Light, ..SimConfig::default() })?;
    let (traffic, _) = world.traffic.clone().context("the scene has no [traffic] section")?;
    println!(
        "pednav-sim traffic: {} lanes, cycle {:.0} s, {:.0} simulated h per level after a {:.0} s warm-up, seed {seed}",
        traffic.lanes.len(),
        traffic.plan.cycle_s,
        hours,
        traffic.warmup_s
    );
    println!(
        "{:>8} {:>9} {:>22} {:>9} {:>8} {:>8} {:>8} {:>10} {:>10} {:>9}",
        "level",
        "set veh/h",
        "measured veh/h per lane",
        "mean",
        "mean/set",
        "queue",
        "max q",
        "sat. hw s",
        "sat. veh/h",
        "1st go s"
    );
    let mut rows: Vec<(String, pednav_sim::traffic::TrafficSettings)> = Vec::new();
    for (name, level) in levels {
        let w = SimWorld::new(scene.clone(), SimConfig { traffic: level, ..SimConfig::default() })?;
        rows.push((name.to_string(), w.traffic.context("traffic")?.1));
    }
    // A demand above capacity keeps a queue at every green: the saturation flow.
    let mut sat = rows[2].1;
    sat.flow = 1800.0;
    rows.push(("saturated".into(), sat));
    for (name, settings) in rows {
        let settings = pednav_sim::traffic::TrafficSettings { walkers: 0, ..settings };
        let bench = pednav_sim::traffic::measure::Bench {
            ground: &world.physics,
            far: [world.scene.extent.min[0] - 1e4, world.scene.extent.min[1] - 1e4],
            agent_radius: world.config.agent_radius,
            dt: world.config.dt,
        };
        let r = pednav_sim::traffic::measure::measure(bench, &traffic, settings, hours * 3600.0, seed);
        let lanes: Vec<String> = r.lane_flow.iter().map(|f| format!("{f:.0}")).collect();
        println!(
            "{:>8} {:>9.0} {:>22} {:>9.1} {:>8.3} {:>8.2} {:>8} {:>10.2} {:>10.0} {:>9.2}",
            name,
            r.set_flow,
            lanes.join(" "),
            r.mean_flow,
            r.mean_flow / r.set_flow as f64,
            r.mean_queue,
            r.max_queue,
            r.saturation_headway,
            r.saturation_flow,
            r.first_crossing_s
        );
    }
    println!(
        "measured = stop-line crossings; queue = vehicles under 2 m/s behind their line, sampled each second, mean per lane; \
         sat. hw = mean headway from the 5th queued vehicle on (HCM's base saturation flow is 1,900 veh/h/lane = 1.89 s)"
    );
    Ok(())
}

fn bench(scene: Scene, sim: SimConfig, backend: BackendChoice, envs: &[usize], seconds: f64) -> Result<()> {
    let traffic = sim.traffic;
    let world = Arc::new(SimWorld::new(scene, sim)?);
    let starts: Vec<Pose> =
        world.scene.validation_points().iter().map(|p| Pose::from_degrees(p.x, p.y, p.favourable_yaw_deg)).collect();
    println!(
        "pednav-sim bench: {}×{} greyscale views; {} CPU cores; LP_NUM_THREADS={} (llvmpipe rasteriser threads)",
        world.config.image_size,
        world.config.image_size,
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
        std::env::var("LP_NUM_THREADS").unwrap_or_else(|_| "unset".into())
    );
    println!("traffic: {traffic:?}");
    println!("rates per wall-second (st/s, v/s) and per CPU-second of the whole process, all threads (cpu-s)");
    println!(
        "{:>5} {:>14} {:>14} {:>14} {:>14} {:>14} {:>10}",
        "envs", "physics st/s", "render v/s", "render v/cpu-s", "full st/s", "full st/cpu-s", "full/render"
    );
    for &m in envs {
        let mut env = VecEnv::new(world.clone(), m, backend)?;
        if m == envs[0] {
            println!("adapter: {}", env.renderer().map(|r| r.adapter_description()).unwrap_or_default());
        }
        let mut rng = ChaCha8Rng::seed_from_u64(m as u64);
        let mut walk = RandomPolicy::new(m as u64);
        for i in 0..m {
            env.reset(i, starts[i % starts.len()], i as u64)?;
        }
        let size = world.config.image_size as usize;
        let mut sink = vec![0u8; m * size * size];
        let mut actions = vec![[0.0f32; 3]; m];
        let mut step_all = |env: &mut VecEnv, rng: &mut ChaCha8Rng| -> Result<()> {
            walk.act(env, &mut actions).map_err(anyhow::Error::from_boxed)?;
            let done: Vec<bool> = env.step(&actions)?.iter().map(|t| t.terminated || t.truncated).collect();
            for (i, d) in done.into_iter().enumerate() {
                if d {
                    env.reset(i, starts[rng.random_range(0..starts.len())], rng.random())?;
                }
            }
            Ok(())
        };
        let physics = measure(seconds, m, || step_all(&mut env, &mut rng))?;
        let cams: Vec<CameraView> = (0..m).map(|i| env.camera(i)).collect();
        let mut renderer =
            Renderer::new(&world.scene, &world.map, RendererConfig::from_sim(&world.config, m, backend))?;
        let render = measure(seconds, m, || {
            let frames = renderer.render(&cams)?;
            for i in 0..m {
                frames.copy_frame(i, &mut sink[i * size * size..(i + 1) * size * size]);
            }
            Ok(())
        })?;
        drop(renderer);
        let full = measure(seconds, m, || {
            step_all(&mut env, &mut rng)?;
            let frames = env.render()?;
            for i in 0..m {
                frames.copy_frame(i, &mut sink[i * size * size..(i + 1) * size * size]);
            }
            Ok(())
        })?;
        println!(
            "{:>5} {:>14.0} {:>14.0} {:>14.0} {:>14.0} {:>14.0} {:>10.2}",
            m,
            physics.per_wall_s,
            render.per_wall_s,
            render.per_cpu_s,
            full.per_wall_s,
            full.per_cpu_s,
            render.per_cpu_s / full.per_cpu_s
        );
    }
    println!(
        "full = physics step + render + readback + copy of every frame; full/render = CPU cost of a full step relative to rendering alone (goal ≤ 1.3)"
    );
    Ok(())
}
