//! Learner compute benchmark (issues #3/#4): ms per DSAC update for the paper's
//! and the CPU preset's network configurations, with and without replay sampling,
//! and the actor's policy step (full recompute vs streaming cache).
//!
//! `cargo bench -p pednav-learner --bench dsac_update [-- --quick] [-- --only a,c,act] [-- --json FILE] [-- --device cuda] [-- --state-aux W] [-- --batch B] [-- --online-target]`
//! (`--only` takes the update keys a–d, `d_twin` and `d_recipe` — (d) with twin critics,
//! and with the temporal contrastive loss too, ours alone —, `d_recipe_bf16` (the recipe
//! with bf16 convolutions, where the CPU has AVX-512 BF16) and `act` for the actor's
//! policy step;
//! `--state-aux W` turns on the state-prediction auxiliary loss with weight W, to
//! measure its cost against a run without it; `--batch B` runs every update case at
//! batch size B instead of its own, without the PyTorch column; `--online-target` runs
//! the shared-encoder cases with `dsac.target_encoder = "online"`)
//!
//! The custom kernels run on the instruction set [`Isa::active`] picks (the best of
//! this CPU, or `PEDNAV_ISA=baseline|avx2|avx512`); the bench prints which. With
//! `--json FILE` it also writes every figure as
//! `{"a": {"best_ms": …, "median_ms": …}, …, "act_full_1": {…}, "act_cache_1": {…},
//! "act_full_16": {…}, "act_cache_16": {…}, "isa": "avx2", "cpu": …, "threads": …,
//! "configs": {…}}` (keys a–d as in the table; act_* at N_h 16, 84²; `configs` holds
//! the exact network, update and replay settings of every case).
//!
//! Compare with the PyTorch reference of the same update in the same minute
//! (`../shared/bench/torch_ref/bench.sh`): these machines are shared and differ, so
//! only ratios measured together count (docs/design.md §8). `--pytorch FILE[,FILE…]` reads
//! that script's stdout (the fastest figure per config over the files) and the ratio
//! columns and the JSON (`"pytorch"`, `"ratio"`) use it; without it the `PyTorch ms`
//! column is the reference measured once on a 2-vCPU AVX-512 Xeon, for orientation
//! only. `deploy/bench_learner.sh` runs both side by side on every path of the CPU.

use std::time::Instant;

use pednav_learner::{Dsac, DsacConfig, DualReplay, FrameKind, ReplayConfig, fill_replay};
use pednav_nets::ops::Isa;
use pednav_nets::{ConvPrecision, EncoderKind, NetsConfig, PolicyStream, init_cpu_runtime};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

struct Case {
    key: &'static str,
    what: &'static str,
    batch: usize,
    nets: NetsConfig,
    /// Twin critics (`dsac.twin_critics`); the PyTorch reference has one critic.
    twin: bool,
    /// The temporal contrastive loss's weight (`dsac.contrast_weight`).
    contrast: f64,
    /// The reference's figure measured once on a 2-vCPU AVX-512 Xeon (orientation
    /// only); `None` where the reference has no such case.
    pytorch_ms: Option<f64>,
}

fn cases() -> Vec<Case> {
    let base = NetsConfig::default();
    vec![
        Case {
            key: "a",
            what: "3D-TCN separate, B 64, N_h 16, 84²",
            batch: 64,
            nets: base.clone(),
            twin: false,
            contrast: 0.0,
            pytorch_ms: Some(1403.0),
        },
        Case {
            key: "b",
            what: "frame-stack, B 64, N_h 16, 84²",
            batch: 64,
            nets: NetsConfig { encoder: EncoderKind::FrameStack, ..base.clone() },
            twin: false,
            contrast: 0.0,
            pytorch_ms: Some(146.0),
        },
        Case {
            key: "c",
            what: "3D-TCN separate, B 32, N_h 8, 42²",
            batch: 32,
            nets: NetsConfig { history: 8, image_size: 42, ..base.clone() },
            twin: false,
            contrast: 0.0,
            pytorch_ms: Some(69.0),
        },
        Case {
            key: "d",
            what: "3D-TCN shared, B 32, N_h 8, 42²",
            batch: 32,
            nets: NetsConfig { history: 8, image_size: 42, shared_encoder: true, ..base.clone() },
            twin: false,
            contrast: 0.0,
            pytorch_ms: Some(39.0),
        },
        // The CPU preset's own options (ours alone: the reference has one critic and no
        // auxiliary loss).
        Case {
            key: "d_twin",
            what: "(d) with twin critics",
            batch: 32,
            nets: NetsConfig { history: 8, image_size: 42, shared_encoder: true, ..base.clone() },
            twin: true,
            contrast: 0.0,
            pytorch_ms: None,
        },
        Case {
            key: "d_recipe",
            what: "(d) with twin critics + temporal contrast (the pixel recipe)",
            batch: 32,
            nets: NetsConfig { history: 8, image_size: 42, shared_encoder: true, ..base.clone() },
            twin: true,
            contrast: 1.0,
            pytorch_ms: None,
        },
        // The recipe with mixed-precision convolutions (`nets.conv_precision = "bf16"`;
        // skipped on CPUs without AVX-512 BF16).
        Case {
            key: "d_recipe_bf16",
            what: "(d_recipe) with bf16 convolutions",
            batch: 32,
            nets: NetsConfig {
                history: 8,
                image_size: 42,
                shared_encoder: true,
                conv_precision: ConvPrecision::Bf16,
                ..base
            },
            twin: true,
            contrast: 1.0,
            pytorch_ms: None,
        },
    ]
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(|a, b| a.partial_cmp(b).unwrap());
    v[v.len() / 2]
}

/// The fastest repetition: on a shared machine other tenants only ever add time, so
/// the minimum is the most repeatable estimate of the code's own cost (the median is
/// printed beside it).
fn best(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::INFINITY, f64::min)
}

/// Best and median of one figure, as the JSON report holds it.
fn figure(v: &[f64]) -> serde_json::Value {
    serde_json::json!({ "best_ms": best(v), "median_ms": median(v.to_vec()) })
}

/// The CPU's model name, for the report.
fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("model name").map(|v| v.trim_start_matches([' ', '\t', ':']).to_string()))
        })
        .unwrap_or_else(|| "unknown".into())
}

/// PyTorch's ms per config key (a–d, act_full_1, act_full_16) from the stdout of
/// `torch_ref/bench.sh` (`NAME ms` lines), the fastest over `paths`.
fn read_pytorch(paths: &str) -> std::collections::BTreeMap<String, f64> {
    let mut figures = std::collections::BTreeMap::new();
    for path in paths.split(',').filter(|p| !p.is_empty()) {
        let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("cannot read --pytorch {path}: {e}"));
        for line in text.lines() {
            let mut parts = line.split_whitespace();
            let (Some(name), Some(ms), None) = (parts.next(), parts.next(), parts.next()) else { continue };
            let Ok(ms) = ms.parse::<f64>() else { continue };
            let key = match name {
                n if n.starts_with("A_") => "a",
                n if n.starts_with("B_") => "b",
                n if n.starts_with("C_") => "c",
                n if n.starts_with("D_") => "d",
                n if n.starts_with("act_nograd_b1_") => "act_full_1",
                n if n.starts_with("act_nograd_b16_") => "act_full_16",
                _ => continue,
            };
            let best = figures.entry(key.to_string()).or_insert(f64::INFINITY);
            *best = f64::min(*best, ms);
        }
    }
    figures
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    let value_of = |flag: &str| args.iter().position(|a| a == flag).and_then(|i| args.get(i + 1)).cloned();
    let only: Option<Vec<String>> = value_of("--only").map(|v| v.split(',').map(String::from).collect());
    let json_path = value_of("--json");
    let batch_override: Option<usize> =
        value_of("--batch").map(|b| b.parse().unwrap_or_else(|e| panic!("--batch {b}: {e}")));
    let online_target = args.iter().any(|a| a == "--online-target");
    let state_aux: f64 =
        value_of("--state-aux").map_or(Ok(0.0), |w| w.parse()).unwrap_or_else(|e| panic!("--state-aux: {e}"));
    let device_spec: pednav_nets::DeviceSpec =
        value_of("--device").map_or(Ok(Default::default()), |d| d.parse()).unwrap_or_else(|e| panic!("--device: {e}"));
    let device = device_spec.open().unwrap_or_else(|e| panic!("{e}"));
    // A GPU runs asynchronously: every timed section ends with a synchronisation.
    let sync = || device.synchronize().expect("device synchronises");
    let pytorch = value_of("--pytorch").map(|p| read_pytorch(&p)).unwrap_or_default();
    let threads = init_cpu_runtime(None);
    let isa = Isa::active();
    let amx = pednav_nets::ops::conv::amx_available();
    let cpu = cpu_model();
    println!(
        "threads: {threads}, kernels: {isa} (set PEDNAV_ISA=baseline|avx2|avx512 to force one), AMX for bf16 convolutions: {amx} (PEDNAV_AMX=off to keep AVX-512 BF16), CPU: {cpu}, device: {device_spec}"
    );
    let mut report = serde_json::Map::new();
    report.insert("isa".into(), isa.name().into());
    report.insert("amx".into(), amx.into());
    report.insert("cpu".into(), cpu.clone().into());
    report.insert("threads".into(), threads.into());
    report.insert("device".into(), device_spec.to_string().into());
    let mut configs = serde_json::Map::new();
    println!(
        "| config | networks only ms/update: best (median) | sample + update ms (median) | sampling share | PyTorch ms | ratio best/PyTorch |"
    );
    println!("|---|---|---|---|---|---|");
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    for mut case in cases() {
        if let Some(b) = batch_override {
            case.batch = b;
            case.pytorch_ms = None;
        }
        if only.as_ref().is_some_and(|o| !o.iter().any(|k| k == case.key)) {
            continue;
        }
        if let Err(e) = case.nets.validate() {
            println!("| ({}) {} | skipped: {e} | | | | |", case.key, case.what);
            continue;
        }
        // One critic where the case compares with the PyTorch reference (`dsac_ref.py`
        // implements the update so).
        let cfg = DsacConfig {
            batch_size: case.batch,
            warmup: case.batch as u64,
            twin_critics: case.twin,
            contrast_weight: case.contrast,
            state_aux_weight: state_aux,
            target_encoder: if online_target && case.nets.shared_encoder {
                pednav_config::dsac::TargetEncoder::Online
            } else {
                pednav_config::dsac::TargetEncoder::Polyak
            },
            ..Default::default()
        };
        let mut dsac = Dsac::new(&cfg, &case.nets, &device, 0).unwrap();
        let rc = ReplayConfig { nonterminal_capacity: 5_000, terminal_capacity: 100 };
        let mut replay =
            DualReplay::new(&rc, FrameKind::Pixels { size: case.nets.image_size }, case.nets.history, &device).unwrap();
        if state_aux > 0.0 {
            replay = replay.with_state_targets(case.nets.state_dim).unwrap();
        }
        fill_replay(&mut replay, FrameKind::Pixels { size: case.nets.image_size }, 3_000, &mut rng).unwrap();
        let reps = if quick || case.key == "a" { 3 } else { 10 };
        let batch = replay.sample(case.batch, &mut rng).unwrap();
        dsac.update(&batch).unwrap(); // warm-up (allocator, caches)
        let mut net_ms = Vec::new();
        let mut full_ms = Vec::new();
        let mut sample_ms = Vec::new();
        for _ in 0..reps {
            let t = Instant::now();
            dsac.update(&batch).unwrap();
            sync();
            net_ms.push(t.elapsed().as_secs_f64() * 1e3);
            let t = Instant::now();
            let b = replay.sample(case.batch, &mut rng).unwrap();
            let s = t.elapsed().as_secs_f64() * 1e3;
            dsac.update(&b).unwrap();
            sync();
            full_ms.push(t.elapsed().as_secs_f64() * 1e3);
            sample_ms.push(s);
        }
        let nb = best(&net_ms);
        report.insert(case.key.into(), figure(&net_ms));
        // Exactly what ran: the networks, the update's settings and the replay.
        configs.insert(
            case.key.to_string(),
            serde_json::json!({ "what": case.what, "nets": case.nets, "dsac": cfg, "replay": rc, "replay_steps": 3_000 }),
        );
        let pytorch_ms = pytorch.get(case.key).copied().or(case.pytorch_ms);
        let (n, f, s) = (median(net_ms), median(full_ms), median(sample_ms));
        let (reference, ratio) = pytorch_ms
            .map_or(("—".to_string(), "—".to_string()), |p| (format!("{p:.0}"), format!("{:.2}", nb / p)));
        println!(
            "| ({}) {} | {nb:.0} ({n:.0}) | {f:.0} | {:.1} % | {reference} | {ratio} |",
            case.key,
            case.what,
            100.0 * s / f,
        );
    }

    if only.as_ref().is_some_and(|o| !o.iter().any(|k| k == "act")) {
        report.insert("configs".into(), configs.into());
        write_report(json_path, report, &pytorch);
        return;
    }
    println!();
    println!(
        "| actor policy step (no gradients) | envs | full recompute ms: best (median) | streaming cache ms: best (median) | cache/full (best) |"
    );
    println!("|---|---|---|---|---|");
    for (history, size) in [(16, 84), (8, 42)] {
        let nets_cfg = NetsConfig { history, image_size: size, ..Default::default() };
        configs.insert(format!("act_h{history}_{size}"), serde_json::json!({ "nets": nets_cfg }));
        let nets = pednav_nets::DsacNets::new(&nets_cfg, &device, 0).unwrap();
        for envs in [1usize, 16] {
            let ids: Vec<usize> = (0..envs).collect();
            let mut stream = PolicyStream::new(&nets_cfg, envs, &device);
            let mut frame = vec![0u8; size * size];
            for e in 0..envs {
                rng.fill(&mut frame[..]);
                stream.reset(e, &frame).unwrap();
            }
            let enc = nets.acting_encoder();
            let reps = if quick { 5 } else { 30 };
            let (mut full, mut cached) = (Vec::new(), Vec::new());
            for _ in 0..reps {
                for e in 0..envs {
                    rng.fill(&mut frame[..]);
                    stream.push(e, [0.1, 0.2, 0.3], -0.1, &frame).unwrap();
                }
                let t = Instant::now();
                let f = stream.features(enc, &ids).unwrap();
                nets.policy.head(&f).unwrap();
                sync();
                cached.push(t.elapsed().as_secs_f64() * 1e3);
                let t = Instant::now();
                let obs = stream.observation(&ids).unwrap();
                let f = enc.encode(&obs).unwrap();
                nets.policy.head(&f).unwrap();
                sync();
                full.push(t.elapsed().as_secs_f64() * 1e3);
            }
            if (history, size) == (16, 84) {
                report.insert(format!("act_full_{envs}"), figure(&full));
                report.insert(format!("act_cache_{envs}"), figure(&cached));
                if let Some(p) = pytorch.get(&format!("act_full_{envs}")) {
                    println!(
                        "|   PyTorch act_nograd, {envs} obs: {p:.2} ms; full recompute / PyTorch {:.2} |",
                        best(&full) / p
                    );
                }
            }
            let (fb, cb) = (best(&full), best(&cached));
            let (fm, cm) = (median(full), median(cached));
            println!(
                "| 3D-TCN N_h {history}, {size}² | {envs} | {fb:.2} ({fm:.2}) | {cb:.2} ({cm:.2}) | {:.3} |",
                cb / fb
            );
        }
    }
    report.insert("configs".into(), configs.into());
    write_report(json_path, report, &pytorch);
}

/// Write the figures as JSON when `--json FILE` was given, with PyTorch's figures
/// and ours/PyTorch (best over best) where `--pytorch` gave them.
fn write_report(
    path: Option<String>,
    mut report: serde_json::Map<String, serde_json::Value>,
    pytorch: &std::collections::BTreeMap<String, f64>,
) {
    if !pytorch.is_empty() {
        let ratios: serde_json::Map<String, serde_json::Value> = pytorch
            .iter()
            .filter_map(|(k, p)| Some((k.clone(), (report.get(k)?.get("best_ms")?.as_f64()? / p).into())))
            .collect();
        report.insert("pytorch".into(), serde_json::json!(pytorch));
        report.insert("ratio".into(), ratios.into());
    }
    if let Some(path) = path {
        let text = serde_json::to_string_pretty(&serde_json::Value::Object(report)).expect("figures serialise");
        std::fs::write(&path, text + "\n").unwrap_or_else(|e| panic!("cannot write --json {path}: {e}"));
        println!("figures written to {path}");
    }
}
