//! `pednav-device-check`: one DSAC update on the CPU and on another device (a CUDA
//! GPU) from the same weights and batch, compared; exits non-zero when they differ
//! beyond floating-point order (tolerances in `pednav_learner::device_check`).
//!
//! ```text
//! pednav-device-check --device cuda                 # the CPU preset's networks
//! pednav-device-check --device cuda --config deploy/configs/paper/navacl_plus_s.toml
//! ```

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Parser;
use pednav_learner::compare_update;
use pednav_nets::{DeviceSpec, init_cpu_runtime};
use pednav_runtime::RunConfig;

#[derive(Parser)]
#[command(version, about = "Compare one DSAC update on the CPU and on another device")]
struct Cli {
    /// The device to check against the CPU: cuda, cuda:N (or cpu, which compares the CPU with itself).
    #[arg(long, default_value = "cuda")]
    device: DeviceSpec,
    /// Run config whose networks and DSAC settings are used (default: the CPU preset).
    #[arg(long, default_value = "deploy/configs/cpu_reduced.toml")]
    config: PathBuf,
    /// Override the config's batch size (smaller is quicker on the CPU side).
    #[arg(long)]
    batch: Option<usize>,
    /// Seed of the weights, the synthetic batch and the update's noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

fn main() -> Result<()> {
    pednav_runtime::init_logging();
    let cli = Cli::parse();
    init_cpu_runtime(None);
    let mut cfg = RunConfig::load(&cli.config)?;
    if let Some(b) = cli.batch {
        cfg.dsac.batch_size = b;
    }
    let device = cli.device.open()?;
    let c = compare_update(&cfg.dsac, &cfg.nets, cfg.frame_kind(), &candle_core::Device::Cpu, &device, cli.seed)
        .with_context(|| format!("one update on cpu and on {}", cli.device))?;
    println!("config: {} (batch {}), cpu vs {}", cli.config.display(), cfg.dsac.batch_size, cli.device);
    println!("| loss | cpu | {} |", cli.device);
    println!("|---|---|---|");
    for (name, a, b) in [
        ("critic", c.a.critic_loss, c.b.critic_loss),
        ("policy", c.a.policy_loss, c.b.policy_loss),
        ("fraction", c.a.fraction_loss, c.b.fraction_loss),
        ("alpha", c.a.alpha_loss, c.b.alpha_loss),
    ] {
        println!("| {name} | {a:.6} | {b:.6} |");
    }
    println!(
        "losses: largest relative difference {:.2e} (tolerance 1e-3); weights after the update ({}): largest \
         difference {:.2e} (tolerance 2·lr + 1e-5 = {:.2e}), 99.9th percentile {:.2e} (tolerance 1e-5)",
        c.loss_rel_diff,
        c.weights,
        c.weight_max_diff,
        2.0 * c.max_lr + 1e-5,
        c.weight_p999_diff
    );
    if !c.passes() {
        bail!("cpu and {} disagree beyond floating-point order", cli.device);
    }
    println!("device check passed");
    Ok(())
}
