//! The runtime's measurements within one host: `stream` (step-record throughput actor
//! → learner through iceoryx2: one publisher process, one subscriber process, the
//! lossless settings of a run, 84×84 frames by default; records/s and GB/s),
//! `weights` (latency of a weights broadcast, the paper-size policy by default, from
//! the learner to 1 or more subscriber processes that poll as an actor does between
//! steps; median and p99) and `system` (env steps/s of a whole run — launcher,
//! curriculum, learner, N actors — with a random policy or with inference, the
//! learner only inserting, warm-up larger than the budget, so the figure is the
//! actors' + IPC's + replay's).

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use pednav_nets::{DsacNets, NetsConfig};
use pednav_runtime::messages::{StepHeader, WeightsHeader};
use pednav_runtime::{Ipc, StopFlag, now_ns, weights};

fn prefix() -> String {
    format!("pnb{:x}_", std::process::id())
}

fn self_exe() -> Result<PathBuf> {
    std::env::current_exe().context("locating pednav-bench")
}

/// `name`, a binary built beside this one (`pednav-run` for `system`).
pub(crate) fn sibling(name: &str) -> Result<PathBuf> {
    let exe = self_exe()?;
    let path = exe.parent().context("pednav-bench has no folder")?.join(name);
    if !path.exists() {
        bail!("{} not found (build it: cargo build --release -p {name})", path.display());
    }
    Ok(path)
}

pub(crate) fn stream(records: u64, frame: usize) -> Result<()> {
    let stop = StopFlag::install();
    let prefix = prefix();
    let ipc = Ipc::new(&prefix, "bench-learner", 2048, Duration::from_secs(60), stop)?;
    let sub = ipc.step_subscriber()?;
    let mut child = Command::new(self_exe()?)
        .args(["stream-publisher", &prefix, &records.to_string(), &frame.to_string()])
        .stdout(Stdio::null())
        .spawn()?;
    let bytes = frame * frame;
    let (mut got, mut sum, mut start) = (0u64, 0u64, None);
    let deadline = Instant::now() + Duration::from_secs(600);
    while got < records {
        match sub.receive().map_err(|e| anyhow::anyhow!("{e:?}"))? {
            Some(s) => {
                start.get_or_insert_with(Instant::now);
                // Read the whole frame, as the replay's copy does.
                sum = sum.wrapping_add(
                    s.payload()
                        .chunks_exact(8)
                        .map(|c| u64::from_le_bytes(c.try_into().unwrap()))
                        .fold(0, u64::wrapping_add),
                );
                if s.user_header().seq != got {
                    bail!("record {got} arrived as {}", s.user_header().seq);
                }
                got += 1;
            }
            None => {
                if Instant::now() > deadline {
                    bail!("only {got} of {records} records arrived");
                }
                std::hint::spin_loop();
            }
        }
    }
    let secs = start.unwrap().elapsed().as_secs_f64();
    child.wait()?;
    println!(
        "step stream, {frame}×{frame} frames, 1 publisher → 1 subscriber process: {records} records in {secs:.2} s = {:.0} records/s, {:.2} GB/s (checksum {sum:x}, lossless, in order)",
        records as f64 / secs,
        (records as f64 * bytes as f64) / secs / 1e9
    );
    Ok(())
}

pub(crate) fn stream_publisher(prefix: &str, records: u64, frame: usize) -> Result<()> {
    let stop = StopFlag::install();
    let ipc = Ipc::new(prefix, "bench-actor", 2048, Duration::from_secs(60), stop.clone())?;
    let out = ipc.step_sender(frame * frame)?;
    if !out.wait_for_subscriber(&stop, Duration::from_secs(30)) {
        bail!("no subscriber");
    }
    let pattern: Vec<u8> = (0..frame * frame).map(|i| (i * 31 % 251) as u8).collect();
    for seq in 0..records {
        let mut s = out.publisher.loan_slice_uninit(pattern.len()).map_err(|e| anyhow::anyhow!("{e:?}"))?;
        *s.user_header_mut() = StepHeader { seq, ..StepHeader::default() };
        s.write_from_slice(&pattern).send().map_err(|e| anyhow::anyhow!("{e:?}"))?;
    }
    Ok(())
}

pub(crate) fn weights_latency(subscribers: usize, repeats: usize, image_size: usize) -> Result<()> {
    let stop = StopFlag::install();
    let prefix = prefix();
    let cfg = NetsConfig { image_size, ..NetsConfig::default() };
    let nets = DsacNets::new(&cfg, &candle_core::Device::Cpu, 0)?;
    let flat = weights::flatten(&nets)?;
    let ipc = Ipc::new(&prefix, "bench-learner", 64, Duration::from_secs(60), stop)?;
    let publisher = ipc.weights_publisher(flat.len())?;
    let dir = std::env::temp_dir().join(&prefix);
    std::fs::create_dir_all(&dir)?;
    let mut children = Vec::new();
    for k in 0..subscribers {
        let ready = dir.join(format!("ready{k}"));
        children.push((
            Command::new(self_exe()?)
                .args(["weights-subscriber", &prefix, &repeats.to_string(), ready.to_str().unwrap()])
                .stdout(Stdio::piped())
                .spawn()?,
            ready,
        ));
    }
    while !children.iter().all(|(_, r)| r.exists()) {
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(200));
    for version in 1..=repeats as u64 + 5 {
        let mut s = publisher.loan_slice_uninit(flat.len()).map_err(|e| anyhow::anyhow!("{e:?}"))?;
        *s.user_header_mut() = WeightsHeader { version, len: flat.len() as u64, published_ns: now_ns() };
        s.write_from_slice(&flat).send().map_err(|e| anyhow::anyhow!("{e:?}"))?;
        std::thread::sleep(Duration::from_millis(20));
    }
    let (mut lat, mut load): (Vec<f64>, Vec<f64>) = (Vec::new(), Vec::new());
    for (c, _) in children {
        let out = c.wait_with_output()?;
        for pair in String::from_utf8_lossy(&out.stdout).split_whitespace() {
            if let Some((r, l)) = pair.split_once(':') {
                lat.push(r.parse()?);
                load.push(l.parse()?);
            }
        }
    }
    load.sort_by(f64::total_cmp);
    let _ = std::fs::remove_dir_all(&dir);
    lat.sort_by(f64::total_cmp);
    if lat.is_empty() {
        bail!("no latencies measured");
    }
    let q = |p: f64| lat[((lat.len() - 1) as f64 * p) as usize];
    println!(
        "weights broadcast, {} floats ({:.1} MB), to {subscribers} subscriber process(es), {} receipts: publish → receipt median {:.0} µs, p99 {:.0} µs, max {:.0} µs (subscriber polls every 50 µs); loading into the networks median {:.0} µs",
        flat.len(),
        flat.len() as f64 * 4.0 / 1e6,
        lat.len(),
        q(0.5),
        q(0.99),
        lat[lat.len() - 1],
        load[load.len() / 2]
    );
    Ok(())
}

pub(crate) fn weights_subscriber(prefix: &str, repeats: usize, ready: &Path) -> Result<()> {
    let stop = StopFlag::install();
    let ipc = Ipc::new(prefix, &format!("bench-actor-{}", std::process::id()), 64, Duration::from_secs(60), stop)?;
    let sub = ipc.weights_subscriber()?;
    let nets = DsacNets::new(&NetsConfig::default(), &candle_core::Device::Cpu, 0);
    std::fs::write(ready, "")?;
    let mut lat = Vec::new();
    let mut last = 0;
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut nets = nets.ok();
    while lat.len() < repeats && Instant::now() < deadline {
        if let Some(s) = sub.receive().map_err(|e| anyhow::anyhow!("{e:?}"))? {
            let h = *s.user_header();
            if h.version > last {
                last = h.version;
                let received = (now_ns().saturating_sub(h.published_ns)) as f64 / 1e3;
                let t0 = Instant::now();
                if let Some(n) = nets.as_mut().filter(|n| weights::acting_len(n) == s.payload().len()) {
                    weights::load(n, s.payload())?;
                }
                lat.push((received, t0.elapsed().as_secs_f64() * 1e6));
            }
        } else {
            std::thread::sleep(Duration::from_micros(50));
        }
    }
    println!("{}", lat.iter().map(|(r, l)| format!("{r:.1}:{l:.1}")).collect::<Vec<_>>().join(" "));
    Ok(())
}

pub(crate) fn system(actors: &[u32], envs: usize, steps: u64, inference: bool) -> Result<()> {
    let exe = sibling("pednav-run")?;
    let root = std::env::temp_dir().join(format!("pednav-bench-system-{}", std::process::id()));
    std::fs::create_dir_all(&root)?;
    let policies: &[&str] = if inference { &["random", "learned"] } else { &["random"] };
    println!("| actors × envs | policy | env steps/s (whole system) |");
    println!("|---|---|---|");
    for &policy in policies {
        for &n in actors {
            let run = root.join(format!("{policy}-{n}"));
            let config = root.join(format!("{policy}-{n}.toml"));
            // 84×84, N_h 16, TCN: the paper's observation; the learner only inserts.
            std::fs::write(
                &config,
                format!(
                    "seed = 3\n[sim]\nt_max = 400\n[dsac]\nwarmup = 1000000\n[replay]\nnonterminal_capacity = 1000000\nterminal_capacity = 100000\n\
                     [curriculum]\nvariant = \"fixed_start\"\n[runtime]\nenvs_per_actor = {envs}\npolicy = \"{policy}\"\nmax_env_steps = {steps}\nmetrics_every_secs = 1.0\n"
                ),
            )?;
            let status = Command::new(&exe)
                .args([
                    "launch",
                    "--actors",
                    &n.to_string(),
                    "--config",
                    config.to_str().unwrap(),
                    "--run-dir",
                    run.to_str().unwrap(),
                ])
                .stderr(Stdio::null())
                .status()?;
            if !status.success() {
                bail!("system run {policy}/{n} failed; see {}", run.join("logs").display());
            }
            // Rate between the first and the last metrics row (start-up and shutdown excluded).
            let csv = std::fs::read_to_string(run.join("metrics/learner.csv"))?;
            let mut lines = csv.lines();
            let header: Vec<&str> = lines.next().context("empty learner metrics")?.split(',').collect();
            let col = |name: &str| header.iter().position(|h| *h == name).with_context(|| format!("no {name} column"));
            let (c_step, c_time) =
                (col(pednav_runtime::columns::STEP)?, col(pednav_runtime::columns::learner::ELAPSED_S)?);
            let rows: Vec<(f64, f64)> = lines
                .filter_map(|l| {
                    let v: Vec<&str> = l.split(',').collect();
                    Some((v.get(c_step)?.parse().ok()?, v.get(c_time)?.parse().ok()?))
                })
                .collect();
            if rows.len() < 2 {
                bail!("run {policy}/{n} was too short to measure: raise --steps");
            }
            let (first, last) = (rows[0], rows[rows.len() - 1]);
            let mean = (last.0 - first.0) / (last.1 - first.1);
            println!("| {n} × {envs} | {policy} | {mean:.0} |");
        }
    }
    let _ = std::fs::remove_dir_all(&root);
    Ok(())
}
