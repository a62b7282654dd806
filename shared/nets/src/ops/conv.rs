//! Channel-last convolution over (time, height, width) as a candle custom op,
//! on im2col + gemm with the bias and ReLU fused.
//!
//! One kernel covers every convolution the networks use:
//! - the 3D convolutions of the 3D-TCN (temporal kernel 2 with dilation, spatial
//!   stride and padding),
//! - 2D convolutions (time 1, temporal kernel 1; frame-stacking puts the N_h frames
//!   in the channel axis),
//! - the dilated 1-D temporal convolutions of the action/reward history (height and
//!   width 1).
//!
//! Layouts (all contiguous, f32):
//! - input  `x`: (B, T, H, W, C_in)
//! - weight `w`: (K, C_out) with K = k_t·k_h·k_w·C_in, index `((dt·k_h + dh)·k_w + dw)·C_in + c`
//! - bias   `b`: (C_out)
//! - output `y`: (B, T_out, H_out, W_out, C_out), T_out = T − d_t·(k_t − 1)
//!   (no temporal padding, temporal stride 1), H_out = (H + 2p_h − k_h)/s_h + 1.
//!
//! Invariant: forward and backward compute exactly the convolution defined above
//! (checked against finite differences and against candle's `conv2d` in the tests);
//! the backward pass never materialises more than one sample's im2col matrix per
//! worker thread, so memory stays bounded at large batches.
//!
//! Parallelism: samples are spread over rayon's pool with a single-threaded gemm
//! each; with fewer samples than threads (actor inference) gemm itself runs in
//! parallel, or the direct kernel splits the sample's output positions.
//!
//! Layers with C_out ∈ {8, 16, 32, 64} (every convolution of the encoders) skip
//! im2col + gemm for the forward pass and dW: a direct kernel ([`direct`]) for the
//! instruction set of [`Isa::active`] accumulates register tiles of output positions
//! × channels (forward) or taps × channels (dW). The input gradient of every layer
//! whose rows of k_w·C_in inputs the vector tiles divide goes through a direct kernel
//! too (gy·Wᵀ added straight into a padded input gradient); the rest, and the
//! baseline instruction set, use gemm and col2im.
//!
//! With `ConvSpec::bf16` (`nets.conv_precision = "bf16"`, or `"auto"`) and a CPU with
//! AVX-512 BF16 on the `avx512` path, the direct kernels' layers multiply in bf16 and sum in
//! f32 ([`bf16`]: forward and weight gradient for C_out ∈ {16, 32, 64} with even
//! k_w·C_in, the input gradient where the f32 direct one applies); every other layer
//! and path stays f32. Where the CPU also has AMX-BF16 (and `PEDNAV_AMX` is not
//! `off`), the forward of those layers whose k_w·C_in is a multiple of 32 runs on AMX
//! tiles instead ([`amx`]: the same products and f32 sums, the same packed operands),
//! and so does the input gradient of those whose C_out is 16 or a multiple of 32, and
//! the weight gradient of those whose k_w·C_in is a multiple of 16 and whose output
//! rows hold at least 5 positions.
//!
//! Layout: this file holds the layer's spec ([`ConvSpec`]), the forward and backward
//! drivers and the candle op; [`geometry`] the sizes of a call and im2col/col2im,
//! [`gemm_call`] the gemm calls, [`pool`] the per-thread scratch buffers,
//! [`direct`] the direct kernels, [`bf16`] their mixed-precision variants and [`amx`]
//! the bf16 forward and gradients on AMX tiles; [`chain`] runs a chain of layers as one
//! op with its own backward pass ([`conv_chain`]).

mod amx;
mod bf16;
mod chain;
mod direct;
mod gemm_call;
mod geometry;
mod pool;

use candle_core::{CpuStorage, CustomOp3, Layout, Shape, Tensor};
use gemm::Parallelism;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{Isa, cpu_f32, with_cpu_f32};
pub use amx::{AMX_ENV, amx_available};
pub use bf16::{bf16_available, cpu_has_bf16};
pub use chain::conv_chain;
use geometry::{Geometry, col2im_add, im2col};
use pool::Pooled;

pub(super) use gemm_call::{matmul, matmul_new};

/// Arithmetic of the encoders' convolutions.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ConvPrecision {
    /// f32 throughout (the paper's networks, and the default).
    #[default]
    F32,
    /// Mixed precision: the encoders' direct convolution kernels (forward, input and
    /// weight gradients) multiply bf16-rounded activations, weights and output
    /// gradients and sum in f32 (AVX-512 BF16: twice the multiply-adds per
    /// instruction); parameters, gradients as stored, the optimiser and every other
    /// layer stay f32. Needs a CPU with AVX-512 BF16 on the `avx512` path (Zen 4 and
    /// later, Xeons since Cooper Lake).
    Bf16,
    /// `Bf16` where this process can run it (a CPU with AVX-512 BF16 on the `avx512`
    /// path), `F32` elsewhere: one config for every machine, each using what it has.
    /// Which one a process computes in is [`ConvPrecision::resolved`] (the learner and
    /// the actors log it).
    Auto,
}

impl ConvPrecision {
    /// The name the config file uses.
    pub fn name(self) -> &'static str {
        match self {
            ConvPrecision::F32 => "f32",
            ConvPrecision::Bf16 => "bf16",
            ConvPrecision::Auto => "auto",
        }
    }

    /// The precision this process computes in: `Auto` becomes `Bf16` where
    /// [`bf16_available`], else `F32`; the other two are themselves.
    pub fn resolved(self) -> ConvPrecision {
        match self {
            ConvPrecision::Auto if bf16_available() => ConvPrecision::Bf16,
            ConvPrecision::Auto => ConvPrecision::F32,
            p => p,
        }
    }
}

/// Geometry of one convolution layer (everything except the channel counts and the
/// input size, which come from the tensors).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConvSpec {
    /// Kernel size (k_t, k_h, k_w).
    pub kernel: [usize; 3],
    /// Spatial stride (s_h, s_w). Temporal stride is always 1.
    pub stride: [usize; 2],
    /// Spatial zero padding (p_h, p_w). There is no temporal padding: the 3D-TCN
    /// shortens the sequence with every layer (paper, Fig. 2).
    pub padding: [usize; 2],
    /// Temporal dilation d_t.
    pub dilation_t: usize,
    /// Apply ReLU to the output (fused into the kernel and its backward).
    pub relu: bool,
    /// Multiply in bf16 (products of bf16-rounded inputs and weights, summed in f32)
    /// where this module's AVX-512 BF16 kernels take the layer; f32 elsewhere
    /// ([`ConvPrecision::Bf16`] says which parts).
    pub bf16: bool,
}

impl ConvSpec {
    /// A 2D convolution (temporal kernel 1).
    pub fn spatial(k: usize, stride: usize, padding: usize) -> ConvSpec {
        ConvSpec {
            kernel: [1, k, k],
            stride: [stride, stride],
            padding: [padding, padding],
            dilation_t: 1,
            relu: true,
            bf16: false,
        }
    }

    /// A 3D convolution with temporal kernel `kt` and dilation `dt`.
    pub fn spatiotemporal(kt: usize, dt: usize, k: usize, stride: usize, padding: usize) -> ConvSpec {
        ConvSpec {
            kernel: [kt, k, k],
            stride: [stride, stride],
            padding: [padding, padding],
            dilation_t: dt,
            relu: true,
            bf16: false,
        }
    }

    /// A purely temporal convolution (spatial kernel 1×1).
    pub fn temporal(kt: usize, dt: usize) -> ConvSpec {
        ConvSpec { kernel: [kt, 1, 1], stride: [1, 1], padding: [0, 0], dilation_t: dt, relu: true, bf16: false }
    }

    /// The same convolution without the ReLU.
    pub fn linear(mut self) -> ConvSpec {
        self.relu = false;
        self
    }

    /// The same convolution multiplying in `precision`, resolved for this process
    /// (see [`ConvSpec::bf16`], [`ConvPrecision::resolved`]).
    pub fn with_precision(mut self, precision: ConvPrecision) -> ConvSpec {
        self.bf16 = precision.resolved() == ConvPrecision::Bf16;
        self
    }

    /// Output size (T_out, H_out, W_out) for an input of (T, H, W), or `None` if the
    /// kernel does not fit.
    pub fn output_size(&self, t: usize, h: usize, w: usize) -> Option<(usize, usize, usize)> {
        let [kt, kh, kw] = self.kernel;
        let span_t = self.dilation_t * (kt - 1) + 1;
        let (hp, wp) = (h + 2 * self.padding[0], w + 2 * self.padding[1]);
        if kt == 0 || kh == 0 || kw == 0 || self.stride.contains(&0) || self.dilation_t == 0 {
            return None;
        }
        if t < span_t || hp < kh || wp < kw {
            return None;
        }
        Some((t - span_t + 1, (hp - kh) / self.stride[0] + 1, (wp - kw) / self.stride[1] + 1))
    }

    /// Rows of the weight matrix for `c_in` input channels.
    pub fn weight_rows(&self, c_in: usize) -> usize {
        self.kernel.iter().product::<usize>() * c_in
    }
}

/// Parallelism inside one gemm: all threads when there are fewer samples than threads.
fn inner_parallelism(batch: usize) -> Parallelism {
    let threads = rayon::current_num_threads();
    if batch < threads { Parallelism::Rayon(threads) } else { Parallelism::None }
}

/// Samples per rayon task: one accumulator/scratch per worker, not per sample.
fn min_len(batch: usize) -> usize {
    batch.div_ceil(rayon::current_num_threads()).max(1)
}

fn forward(g: &Geometry, x: &[f32], w: &[f32], bias: &[f32]) -> Vec<f32> {
    let (ks, co, rows) = (g.ks(), g.co, g.to * g.ps());
    let mut out = pool::parallel_zeros(g.b * g.out_len());
    let par = inner_parallelism(g.b);
    let pointwise = g.spatially_pointwise();
    let direct = g.direct();
    let isa = Isa::active();
    // Mixed precision where the layer asks for it and the bf16 kernel takes it: the
    // weights packed once per call, each sample's padded input converted as it is padded.
    let half = direct && bf16::forward_supported(g, isa);
    // On AMX the same packed weights and padded input feed the tile kernel (its input
    // scratch a little longer: the tiles' unused rows read past the last position).
    let tiles = half && amx::forward_supported(g, isa);
    let packed = if half { Pooled::bf16_copy(&bf16::pack_forward_weights(g, w)) } else { Pooled::new(0) };
    let scratch_len = match (half, tiles) {
        (true, true) => (g.padded_len() + amx::slack(g)).div_ceil(2),
        (true, false) => g.padded_len().div_ceil(2),
        _ => g.input_scratch_len(direct),
    };
    let half_forward = |xp: &[u16], y: &mut [f32], q: std::ops::Range<usize>| {
        if tiles {
            amx::forward(g, xp, packed.as_bf16(), bias, y, q);
        } else {
            bf16::forward(g, isa, xp, packed.as_bf16(), bias, y, q);
        }
    };
    if direct && matches!(par, Parallelism::Rayon(_)) {
        // Fewer samples than threads (actor inference): split each sample's output
        // positions over the pool instead, in whole blocks.
        let mut xp = Pooled::new(scratch_len);
        let positions = g.to * g.ps();
        let chunk = positions.div_ceil(rayon::current_num_threads()).div_ceil(8).max(1) * 8;
        for (y, xb) in out.chunks_mut(g.out_len().max(1)).zip(x.chunks(g.in_len().max(1))) {
            let chunks = y.par_chunks_mut(chunk * co).enumerate().map(|(i, yc)| {
                let n = yc.len() / co;
                (yc, i * chunk..i * chunk + n)
            });
            if half {
                let xp16 = xp.as_bf16_mut();
                bf16::pad_frames(g, xb, xp16);
                let xp16: &[u16] = xp16;
                chunks.for_each(|(yc, q)| half_forward(xp16, yc, q));
            } else {
                direct::pad_frames(g, xb, &mut xp);
                let xp32: &[f32] = &xp;
                chunks.for_each(|(yc, q)| direct::forward(g, isa, xp32, w, bias, yc, q));
            }
        }
        return out;
    }
    out.par_chunks_mut(g.out_len().max(1))
        .zip(x.par_chunks(g.in_len().max(1)))
        .with_min_len(min_len(g.b))
        .for_each_init(
            || Pooled::new(scratch_len),
            |scratch, (y, xb)| {
                if half {
                    let xp = scratch.as_bf16_mut();
                    bf16::pad_frames(g, xb, xp);
                    half_forward(&*xp, y, 0..g.to * g.ps());
                    return;
                }
                if direct {
                    direct::pad_frames(g, xb, scratch);
                    direct::forward(g, isa, scratch, w, bias, y, 0..g.to * g.ps());
                    return;
                }
                let lhs: &[f32] = if pointwise {
                    xb
                } else {
                    im2col(g, xb, scratch);
                    scratch
                };
                for dt in 0..g.spec.kernel[0] {
                    let tap = &lhs[g.tap_row(dt) * ks..];
                    matmul(rows, co, ks, y, dt > 0, tap, (ks, 1), &w[dt * ks * co..], (co, 1), par);
                }
                // Bias and ReLU in one pass over the output.
                for row in y.chunks_exact_mut(co) {
                    for (v, b) in row.iter_mut().zip(bias) {
                        *v += b;
                    }
                    if g.spec.relu {
                        for v in row.iter_mut() {
                            *v = v.max(0.0);
                        }
                    }
                }
            },
        );
    out
}

/// Gradients of the convolution: (dx if asked, dw, db).
fn backward(
    g: &Geometry,
    x: &[f32],
    w: &[f32],
    y: &[f32],
    dy: &[f32],
    need_dx: bool,
) -> (Option<Vec<f32>>, Vec<f32>, Vec<f32>) {
    let (ks, co, rows) = (g.ks(), g.co, g.to * g.ps());
    let kt = g.spec.kernel[0];
    let par = inner_parallelism(g.b);
    let pointwise = g.spatially_pointwise();
    // The direct kernel computes dW for narrow layers, gemm over im2col the rest.
    let direct = g.direct();
    let isa = Isa::active();
    // The input gradient: the direct kernel adds each position's gy·Wᵀ straight
    // into a padded input gradient where the instruction set has one; otherwise
    // gemm writes the column matrix and col2im scatters it.
    let direct_dx = need_dx && direct::input_grad_supported(g, isa);
    // In mixed precision (where the bf16 kernel takes the layer) it multiplies the
    // bf16-rounded output gradient by bf16 weights.
    let half_dx = direct_dx && bf16::input_grad_supported(g, isa);
    // On AMX the same operands go through tiles (the gradient scratch a little
    // longer: the last block's unused rows read past the last position).
    let tiles_dx = half_dx && amx::input_grad_supported(g, isa);
    let wt = if direct_dx && !half_dx { direct::transpose_weights(g, w) } else { Vec::new() };
    let wt_half = if half_dx { Pooled::bf16_copy(&bf16::pack_input_grad_weights(g, w)) } else { Pooled::new(0) };
    // The weight gradient in mixed precision too: pairs of neighbouring positions of
    // an output row (a layer with rows of one position would only pad every pair).
    let half_dw = direct && g.wo > 1 && bf16::forward_supported(g, isa);
    // On AMX the paired input feeds tiles too (followed by zeros the last row's
    // padding positions read), with the paired gradient transposed per row chunk.
    let tiles_dw = half_dw && amx::weight_grad_supported(g, isa);
    let dw_plan = tiles_dw.then(|| amx::WeightGradPlan::new(g));
    let x_pairs_len = bf16::paired_input_len(g) + if tiles_dw { amx::weight_grad_slack(g) } else { 0 };
    let dx_scratch_len = if direct_dx {
        g.padded_len()
    } else if need_dx && !pointwise {
        g.cols_len()
    } else {
        0
    };
    let mut dx = if need_dx { pool::parallel_zeros(g.b * g.in_len()) } else { Vec::new() };
    let in_len = g.in_len().max(1);
    let out_len = g.out_len().max(1);

    struct Scratch {
        dw: Vec<f32>,
        db: Vec<f32>,
        cols: Pooled,
        dcols: Pooled,
        gy: Pooled,
        gy_half: Pooled,
        x_pairs: Pooled,
        gy_pairs: Pooled,
        gy_transposed: Pooled,
    }
    let new_scratch = || Scratch {
        dw: vec![0f32; kt * ks * co],
        db: vec![0f32; co],
        cols: Pooled::new(g.input_scratch_len(direct)),
        dcols: Pooled::new(dx_scratch_len),
        gy: Pooled::new(g.out_len()),
        gy_half: Pooled::new(match (half_dx, tiles_dx) {
            (true, true) => (g.out_len() + amx::input_grad_slack(g)).div_ceil(2),
            (true, false) => g.out_len().div_ceil(2),
            _ => 0,
        }),
        x_pairs: Pooled::new(if half_dw { x_pairs_len.div_ceil(2) } else { 0 }),
        gy_pairs: Pooled::new(if half_dw { bf16::paired_gradient_len(g).div_ceil(2) } else { 0 }),
        gy_transposed: Pooled::new(if tiles_dw { amx::transposed_gradient_len(g).div_ceil(2) } else { 0 }),
    };
    let per_sample = |mut s: Scratch, xb: &[f32], yb: &[f32], dyb: &[f32], mut dxb: Option<&mut [f32]>| {
        // Gradient at the pre-activation: the ReLU mask comes from the saved output.
        for ((gv, &yv), &dv) in s.gy.iter_mut().zip(yb).zip(dyb) {
            *gv = if g.spec.relu && yv <= 0.0 { 0.0 } else { dv };
        }
        for row in s.gy.chunks_exact(co) {
            for (d, v) in s.db.iter_mut().zip(row) {
                *d += v;
            }
        }
        if direct {
            direct::pad_frames(g, xb, &mut s.cols);
            if half_dw {
                let x_pairs = s.x_pairs.as_bf16_mut();
                bf16::pair_positions(g, &s.cols, x_pairs);
                let gy_pairs = s.gy_pairs.as_bf16_mut();
                bf16::pair_gradients(g, &s.gy, gy_pairs);
                if let Some(plan) = &dw_plan {
                    x_pairs[bf16::paired_input_len(g)..].fill(0);
                    let gy_transposed = s.gy_transposed.as_bf16_mut();
                    amx::transpose_gradients(g, gy_pairs, gy_transposed);
                    amx::weight_grad(g, plan, x_pairs, gy_transposed, &mut s.dw);
                } else {
                    bf16::weight_grad(g, isa, x_pairs, gy_pairs, &mut s.dw);
                }
            } else {
                direct::weight_grad(g, isa, &s.cols, &s.gy, &mut s.dw);
            }
        } else {
            let lhs: &[f32] = if pointwise {
                xb
            } else {
                im2col(g, xb, &mut s.cols);
                &s.cols
            };
            // dW_dt (ks×co) += tapᵀ (ks×rows) · gy (rows×co)
            for dt in 0..kt {
                let tap = &lhs[g.tap_row(dt) * ks..];
                matmul(ks, co, rows, &mut s.dw[dt * ks * co..], true, tap, (1, ks), &s.gy, (co, 1), par);
            }
        }
        if let (Some(dxb), true) = (dxb.as_deref_mut(), direct_dx) {
            s.dcols.fill(0.0);
            if half_dx {
                let gy_half = s.gy_half.as_bf16_mut();
                bf16::convert(&s.gy, gy_half);
                if tiles_dx {
                    amx::input_grad(g, wt_half.as_bf16(), gy_half, &mut s.dcols);
                } else {
                    bf16::input_grad(g, isa, wt_half.as_bf16(), gy_half, &mut s.dcols);
                }
            } else {
                direct::input_grad(g, isa, &wt, &s.gy, &mut s.dcols);
            }
            direct::unpad_frames(g, &s.dcols, dxb);
        } else if let Some(dxb) = dxb {
            // dtap (rows×ks) += gy (rows×co) · W_dtᵀ (co×ks), into the column matrix
            // (or straight into dx when im2col is the identity).
            let dcols: &mut [f32] = if pointwise { dxb } else { &mut s.dcols };
            if !pointwise {
                // Tap 0 overwrites rows 0..T_out·P; only the rows it does not reach
                // need zeros (the buffer comes from the pool with stale contents).
                dcols[rows * ks..].fill(0.0);
            }
            for dt in 0..kt {
                let off = g.tap_row(dt) * ks;
                let accumulate = pointwise || dt > 0;
                matmul(rows, ks, co, &mut dcols[off..], accumulate, &s.gy, (co, 1), &w[dt * ks * co..], (1, co), par);
            }
            if !pointwise {
                col2im_add(g, &s.dcols, dxb);
            }
        }
        s
    };
    let merge = |mut a: Scratch, b: Scratch| {
        for (u, v) in a.dw.iter_mut().zip(&b.dw) {
            *u += v;
        }
        for (u, v) in a.db.iter_mut().zip(&b.db) {
            *u += v;
        }
        a
    };
    let total = if need_dx {
        dx.par_chunks_mut(in_len)
            .zip(x.par_chunks(in_len))
            .zip(y.par_chunks(out_len).zip(dy.par_chunks(out_len)))
            .with_min_len(min_len(g.b))
            .fold(new_scratch, |s, ((dxb, xb), (yb, dyb))| per_sample(s, xb, yb, dyb, Some(dxb)))
            .reduce(new_scratch, merge)
    } else {
        x.par_chunks(in_len)
            .zip(y.par_chunks(out_len).zip(dy.par_chunks(out_len)))
            .with_min_len(min_len(g.b))
            .fold(new_scratch, |s, (xb, (yb, dyb))| per_sample(s, xb, yb, dyb, None))
            .reduce(new_scratch, merge)
    };
    (need_dx.then_some(dx), total.dw, total.db)
}

/// The custom op. Use [`conv`] rather than this directly.
struct ConvOp(ConvSpec);

impl CustomOp3 for ConvOp {
    fn name(&self) -> &'static str {
        "pednav-conv-cl"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let g = Geometry::new(self.0, l1.dims(), l2.dims())?;
        if l3.dims() != [g.co] {
            candle_core::bail!("conv: bias must be ({}), got {:?}", g.co, l3.dims());
        }
        let y = forward(&g, cpu_f32(s1, l1, "input")?, cpu_f32(s2, l2, "weight")?, cpu_f32(s3, l3, "bias")?);
        Ok((CpuStorage::F32(y), Shape::from_dims(&[g.b, g.to, g.ho, g.wo, g.co])))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _b: &Tensor,
        y: &Tensor,
        dy: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let g = Geometry::new(self.0, x.dims(), w.dims())?;
        let dy = dy.contiguous()?;
        let need_dx = x.track_op();
        let (dx, dw, db) = with_cpu_f32(x, "input", |xs| {
            with_cpu_f32(w, "weight", |ws| {
                with_cpu_f32(y, "output", |ys| {
                    with_cpu_f32(&dy, "output gradient", |dys| Ok(backward(&g, xs, ws, ys, dys, need_dx)))
                })
            })
        })?;
        let dev = x.device();
        let dx = dx.map(|v| Tensor::from_vec(v, x.shape(), dev)).transpose()?;
        Ok((dx, Some(Tensor::from_vec(dw, w.shape(), dev)?), Some(Tensor::from_vec(db, g.co, dev)?)))
    }
}

/// Channel-last convolution `y = act(conv(x, w) + b)` (see the module docs for layouts).
///
/// On the CPU this runs the fused im2col + gemm kernel; on other devices (the `cuda`
/// feature) it runs [`conv_reference`], built from candle's own `conv2d`.
pub fn conv(x: &Tensor, w: &Tensor, b: &Tensor, spec: ConvSpec) -> candle_core::Result<Tensor> {
    if x.device().is_cpu() {
        x.contiguous()?.apply_op3(&w.contiguous()?, &b.contiguous()?, ConvOp(spec))
    } else {
        conv_reference(x, w, b, spec)
    }
}

/// The same convolution from candle's stock ops: one `conv2d` per temporal tap over
/// all frames, shifted by the dilation and summed. Slower on the CPU (candle's
/// `conv2d` backward), but runs on every candle device; the tests use it as the
/// independent reference for the custom kernel.
pub fn conv_reference(x: &Tensor, w: &Tensor, b: &Tensor, spec: ConvSpec) -> candle_core::Result<Tensor> {
    let g = Geometry::new(spec, x.dims(), w.dims())?;
    let [kt, kh, kw] = spec.kernel;
    if spec.stride[0] != spec.stride[1] || spec.padding[0] != spec.padding[1] {
        candle_core::bail!("conv_reference: candle's conv2d needs equal strides and paddings per axis");
    }
    // (B, T, H, W, C) → (B·T, C, H, W)
    let frames = x.reshape((g.b * g.t, g.h, g.w, g.ci))?.permute((0, 3, 1, 2))?.contiguous()?;
    // (kt·kh·kw·C, C_out) → (kt, C_out, C, kh, kw)
    let kernels = w.reshape((kt, kh, kw, g.ci, g.co))?.permute((0, 4, 3, 1, 2))?.contiguous()?;
    let mut sum: Option<Tensor> = None;
    for dt in 0..kt {
        let k = kernels.get(dt)?;
        let y = frames.conv2d(&k, spec.padding[0], spec.stride[0], 1, 1)?; // (B·T, C_out, Ho, Wo)
        let y = y.reshape((g.b, g.t, g.co, g.ho, g.wo))?.narrow(1, dt * spec.dilation_t, g.to)?;
        sum = Some(match sum {
            None => y,
            Some(s) => (s + y)?,
        });
    }
    let sum = sum.expect("kernel has at least one tap");
    let y = sum.broadcast_add(&b.reshape((1, 1, g.co, 1, 1))?)?;
    let y = if spec.relu { y.relu()? } else { y };
    y.permute((0, 1, 3, 4, 2))?.contiguous()
}
