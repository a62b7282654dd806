//! The fused AdamW step (`ops::fused`) over as many parameters as the default
//! preset's learner steps (≈ 1.05 M), on every instruction set this CPU runs, with
//! moments as a fresh run has them and as a long run leaves them.
//!
//! `cargo bench -p pednav-nets --bench adam_step [-- --quick]`
//!
//! "Dead features": 7.5 % of the first moments subnormal and their gradients zero —
//! what a checkpoint of the default preset held after 300 k env steps (a parameter
//! whose feature no sample activates has its first moment shrink by β₁ a step,
//! through the subnormal range). Each case runs consecutive steps on the same arrays,
//! as training does, and reports the first step and the median of the rest: the
//! kernel stores no subnormal moment (module docs of `ops::fused`, *Subnormals*), so
//! only the first step of the second case meets subnormal operands. On Intel cores a
//! multiply or fused multiply-add with one takes a microcode assist (before the floors,
//! the second case ran 8–11× slower than the first on a Xeon).

use std::time::Instant;

use pednav_nets::init_cpu_runtime;
use pednav_nets::ops::Isa;
use pednav_nets::ops::fused::{AdamScalars, adam_slices};
use pednav_nets::optim::AdamWConfig;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Parameters of the default preset's learner (policy, both critics, the fraction
/// proposal and the contrastive head).
const PARAMETERS: usize = 1_046_892;

/// Share of first moments that were subnormal in the 300 k-step checkpoint.
const DEAD_SHARE: f64 = 0.075;

struct State {
    p: Vec<f32>,
    g: Vec<f32>,
    m: Vec<f32>,
    v: Vec<f32>,
}

fn state(dead: bool, rng: &mut ChaCha8Rng) -> State {
    let n = PARAMETERS;
    let mut s = State { p: vec![0f32; n], g: vec![0f32; n], m: vec![0f32; n], v: vec![0f32; n] };
    for i in 0..n {
        s.p[i] = rng.random_range(-0.1..0.1);
        if dead && rng.random_bool(DEAD_SHARE) {
            // A subnormal first moment, a small second one, no gradient.
            s.m[i] = f32::from_bits(rng.random_range(1..0x0080_0000)) * if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            s.v[i] = rng.random_range(1e-12..1e-8);
        } else {
            s.g[i] = rng.random_range(-1e-2..1e-2);
            s.m[i] = rng.random_range(-1e-3..1e-3);
            s.v[i] = rng.random_range(1e-8..1e-5);
        }
    }
    s
}

fn main() {
    let threads = init_cpu_runtime(None);
    let quick = std::env::args().any(|a| a == "--quick");
    let steps = if quick { 8 } else { 30 };
    // Step 1,000 of PyTorch's defaults with the presets' learning rate.
    let k = AdamScalars::of_step(&AdamWConfig::with_lr(3e-4), 1000, 1.0);
    println!("threads: {threads}, {PARAMETERS} parameters, {steps} consecutive steps per case");
    println!("| path | moments | first step ms | median of the rest ms | GB/s (median) |");
    println!("|---|---|---|---|---|");
    for isa in Isa::supported() {
        for (dead, label) in [(false, "fresh"), (true, "dead features (7.5 % subnormal)")] {
            let mut s = state(dead, &mut ChaCha8Rng::seed_from_u64(7));
            let mut times: Vec<f64> = (0..steps)
                .map(|_| {
                    let t = Instant::now();
                    adam_slices(isa, &mut s.p, &s.g, &mut s.m, &mut s.v, &k);
                    t.elapsed().as_secs_f64() * 1e3
                })
                .collect();
            let first = times.remove(0);
            times.sort_by(f64::total_cmp);
            let median = times[times.len() / 2];
            // Read p, g, m, v and write p, m, v: 7 floats per parameter.
            let gbs = 7.0 * 4.0 * PARAMETERS as f64 / (median * 1e-3) / 1e9;
            println!("| {isa} | {label} | {first:.2} | {median:.2} | {gbs:.1} |");
            std::hint::black_box(&s.p);
        }
    }
}
