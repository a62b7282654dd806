//! Per-layer profile of the custom convolution: ms (best of the repetitions) and
//! GFLOP/s of the forward pass and of forward + backward for every image layer of
//! the 3D-TCN and the frame-stacking encoder, at the learner's batch sizes. Use it to see which layer
//! an optimisation of `ops::conv` should target; `dsac_update` (learner) measures
//! the whole update.
//!
//! `cargo bench -p pednav-nets --bench conv_layers [-- --quick] [-- --bf16]`
//!
//! `--bf16` runs every layer in mixed precision (`ConvSpec::bf16`: the AVX-512 BF16
//! kernels, or AMX tiles for the forward and both gradients where the CPU has them
//! and `PEDNAV_AMX` is not `off`); it needs AVX-512 BF16 on the `avx512` path.

use std::time::Instant;

use candle_core::{DType, Device, Tensor, Var};
use pednav_nets::encoder::{SPATIAL_STAGES, temporal_plan};
use pednav_nets::init_cpu_runtime;
use pednav_nets::ops::{ConvSpec, conv};

struct Layer {
    name: String,
    spec: ConvSpec,
    /// (B, T, H, W, C_in)
    input: [usize; 5],
    c_out: usize,
    /// Whether the layer's input needs a gradient (every layer but the first).
    grad_input: bool,
}

/// The image layers of one 3D-TCN encoder.
fn tcn_layers(batch: usize, history: usize, size: usize) -> Vec<Layer> {
    let plan = temporal_plan(history);
    let (mut t, mut s, mut c) = (history, size, 1);
    let mut layers = Vec::new();
    for (i, (&(kt, dt), &(k, st, p, co))) in plan.iter().zip(&SPATIAL_STAGES).enumerate() {
        let spec = ConvSpec::spatiotemporal(kt, dt, k, st, p);
        layers.push(Layer {
            name: format!("tcn{i} k{kt}d{dt}"),
            spec,
            input: [batch, t, s, s, c],
            c_out: co,
            grad_input: i > 0,
        });
        let (to, so, _) = spec.output_size(t, s, s).expect("plan fits");
        (t, s, c) = (to, so, co);
    }
    let (kt, _) = plan[3];
    layers.push(Layer {
        name: format!("tcn3 k{kt}"),
        spec: ConvSpec::temporal(kt, 1),
        input: [batch, t, s, s, c],
        c_out: c,
        grad_input: true,
    });
    layers
}

/// The layers of the frame-stacking encoder.
fn stack_layers(batch: usize, history: usize, size: usize) -> Vec<Layer> {
    let (mut s, mut c) = (size, history);
    SPATIAL_STAGES
        .iter()
        .enumerate()
        .map(|(i, &(k, st, p, co))| {
            let spec = ConvSpec::spatial(k, st, p);
            let layer =
                Layer { name: format!("stack{i}"), spec, input: [batch, 1, s, s, c], c_out: co, grad_input: i > 0 };
            (s, c) = (spec.output_size(1, s, s).expect("fits").1, co);
            layer
        })
        .collect()
}

/// The fastest repetition (other tenants of a shared machine only ever add time).
fn best(v: &[f64]) -> f64 {
    v.iter().copied().fold(f64::INFINITY, f64::min)
}

fn flops(l: &Layer) -> f64 {
    let [b, t, h, w, ci] = l.input;
    let (to, ho, wo) = l.spec.output_size(t, h, w).unwrap();
    2.0 * (b * to * ho * wo * l.c_out * l.spec.weight_rows(ci)) as f64
}

fn main() -> candle_core::Result<()> {
    let quick = std::env::args().any(|a| a == "--quick");
    let bf16 = std::env::args().any(|a| a == "--bf16");
    let threads = init_cpu_runtime(None);
    if bf16 && !pednav_nets::ops::conv::bf16_available() {
        candle_core::bail!("--bf16 needs AVX-512 BF16 on the avx512 path (PEDNAV_ISA unset or avx512)");
    }
    let reps = if quick { 3 } else { 7 };
    let amx = pednav_nets::ops::conv::amx_available();
    println!(
        "threads: {threads}, kernels: {}, {}",
        pednav_nets::ops::Isa::active(),
        if !bf16 {
            "f32"
        } else if amx {
            "bf16 (forward and gradients on AMX tiles)"
        } else {
            "bf16 (AVX-512 BF16)"
        }
    );
    println!("| layer | input (B,T,H,W,C) | C_out | GFLOP fwd | fwd ms | fwd GFLOP/s | fwd+bwd ms | fwd+bwd GFLOP/s |");
    println!("|---|---|---|---|---|---|---|---|");
    let dev = Device::Cpu;
    let configs = [
        ("B 64, N_h 16, 84²", tcn_layers(64, 16, 84)),
        ("B 32, N_h 8, 42²", tcn_layers(32, 8, 42)),
        ("frame-stack B 64, N_h 16, 84²", stack_layers(64, 16, 84)),
    ];
    for (what, layers) in configs {
        println!("| **{what}** | | | | | | | |");
        for mut l in layers {
            l.spec.bf16 = bf16;
            let ci = l.input[4];
            let x = Var::from_tensor(&Tensor::rand(0f32, 1f32, &l.input[..], &dev)?)?;
            let w = Var::from_tensor(&Tensor::randn(0f32, 0.1, (l.spec.weight_rows(ci), l.c_out), &dev)?)?;
            let b = Var::from_tensor(&Tensor::zeros(l.c_out, DType::F32, &dev)?)?;
            let xin = if l.grad_input { x.as_tensor().clone() } else { x.as_tensor().detach() };
            conv(&xin, w.as_tensor(), b.as_tensor(), l.spec)?; // warm-up
            let (mut fwd, mut both) = (Vec::new(), Vec::new());
            for _ in 0..reps {
                let t0 = Instant::now();
                let y = conv(&xin, w.as_tensor(), b.as_tensor(), l.spec)?;
                fwd.push(t0.elapsed().as_secs_f64() * 1e3);
                let t0 = Instant::now();
                let y2 = conv(&xin, w.as_tensor(), b.as_tensor(), l.spec)?;
                let grads = y2.sum_all()?.backward()?;
                both.push(t0.elapsed().as_secs_f64() * 1e3);
                drop((y, grads));
            }
            let gf = flops(&l) / 1e9;
            let (f, fb) = (best(&fwd), best(&both));
            println!(
                "| {} | {:?} | {} | {gf:.2} | {f:.1} | {:.0} | {fb:.1} | {:.0} |",
                l.name,
                l.input,
                l.c_out,
                gf / (f / 1e3),
                // Backward costs two products per forward one when the input needs a
                // gradient (dW and dX), one otherwise.
                gf * if l.grad_input { 3.0 } else { 2.0 } / (fb / 1e3)
            );
        }
    }
    Ok(())
}
