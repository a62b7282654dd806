//! Operations candle 0.11 lacks or runs slowly here: the channel-last convolution
//! kernel, a fully connected layer fast at one row, the optimiser's in-place
//! element-wise steps ([`fused`]), softplus, a fast frames-to-channels transpose,
//! the CPU storage accessors the custom ops share,
//! and a few numerically careful helpers.

/// Define `fn $name<const …>(isa: Isa, args)` that runs `$imp::<…, FMA>` compiled
/// for AVX-512F with FMA, AVX2 with FMA (`FMA = true`) or the baseline (`FMA =
/// false`: plain multiply and add, since a fused multiply-add without the
/// instruction is a slow library call), as `isa` says. `$imp` must be plain loops
/// (`#[inline(always)]`, no closures around the arithmetic): a closure is compiled
/// without the wrapper's target features (docs/design.md §8).
macro_rules! multiversioned {
    ($(#[$doc:meta])* fn $name:ident($($arg:ident: $ty:ty),* $(,)?) => $imp:ident) => {
        multiversioned! { $(#[$doc])* fn $name<>($($arg: $ty),*) => $imp }
    };
    ($(#[$doc:meta])* fn $name:ident<$(const $g:ident: usize),*>($($arg:ident: $ty:ty),* $(,)?) => $imp:ident) => {
        $(#[$doc])*
        #[allow(clippy::too_many_arguments)]
        fn $name<$(const $g: usize),*>(isa: $crate::ops::Isa, $($arg: $ty),*) {
            assert!(isa.is_supported(), "instruction set {isa} is not available on this CPU");
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx512f,avx2,fma")]
                fn v4<$(const $g: usize),*>($($arg: $ty),*) {
                    $imp::<$($g,)* true>($($arg),*)
                }
                #[target_feature(enable = "avx2,fma")]
                fn v3<$(const $g: usize),*>($($arg: $ty),*) {
                    $imp::<$($g,)* true>($($arg),*)
                }
                match isa {
                    // SAFETY: the CPU supports the instruction set (asserted above).
                    $crate::ops::Isa::Avx512 => return unsafe { v4::<$($g),*>($($arg),*) },
                    // SAFETY: as above.
                    $crate::ops::Isa::Avx2 => return unsafe { v3::<$($g),*>($($arg),*) },
                    $crate::ops::Isa::Baseline => {}
                }
            }
            $imp::<$($g,)* false>($($arg),*)
        }
    };
}

pub mod conv;
pub mod fused;
pub mod isa;
pub mod linear;
mod simd;

use candle_core::{CpuStorage, Layout, Result, Storage, Tensor};
use rayon::prelude::*;

pub use conv::{ConvSpec, conv, conv_chain, conv_reference};
pub use isa::Isa;
pub use linear::linear;

/// out (p × t) = sample (t × p)ᵀ, in blocks of [`TRANSPOSE_BLOCK`] columns: each
/// block's output (block × t floats, contiguous) stays in the L1 cache while the t
/// rows are read in contiguous runs (a column at a time went to memory at every
/// store: 11 % of a frame-stacking update).
fn transpose_block_rows(sample: &[f32], out: &mut [f32], t: usize, p: usize) {
    let (sample, out) = (&sample[..t * p], &mut out[..t * p]);
    for (bi, block) in out.chunks_mut(TRANSPOSE_BLOCK * t).enumerate() {
        let px0 = bi * TRANSPOSE_BLOCK;
        let n = block.len() / t;
        for (ti, row) in sample.chunks_exact(p).enumerate() {
            for (k, &v) in row[px0..px0 + n].iter().enumerate() {
                block[k * t + ti] = v;
            }
        }
    }
}

/// Columns per block of [`transpose_block_rows`].
const TRANSPOSE_BLOCK: usize = 64;

/// softplus(x) = log(1 + eˣ), computed as max(x, 0) + log(1 + e^{−|x|}) so it
/// neither overflows for large x nor loses precision for very negative x.
pub fn softplus(x: &Tensor) -> Result<Tensor> {
    let pos = x.relu()?;
    let tail = (x.abs()?.neg()?.exp()? + 1.0)?.log()?;
    pos + tail
}

/// log(1 − tanh²(u)) = 2·(log 2 − u − softplus(−2u)), the stable form of the tanh
/// Jacobian term of a squashed Gaussian.
pub fn log_one_minus_tanh_sq(u: &Tensor) -> Result<Tensor> {
    let sp = softplus(&(u * -2.0)?)?;
    ((u.neg()? - sp)? + std::f64::consts::LN_2)? * 2.0
}

/// The contiguous f32 data of a CPU storage (`what` names it in the error), for a
/// custom op's CPU forward (here and in the learner's).
pub fn cpu_f32<'a>(s: &'a CpuStorage, l: &Layout, what: &str) -> candle_core::Result<&'a [f32]> {
    let data = s.as_slice::<f32>()?;
    match l.contiguous_offsets() {
        Some((a, b)) => Ok(&data[a..b]),
        None => candle_core::bail!("{what} must be contiguous"),
    }
}

/// Run `f` on the contiguous CPU f32 data of `t`.
pub(crate) fn with_cpu_f32<R>(
    t: &Tensor,
    what: &str,
    f: impl FnOnce(&[f32]) -> candle_core::Result<R>,
) -> candle_core::Result<R> {
    let (storage, layout) = t.storage_and_layout();
    match &*storage {
        Storage::Cpu(s) => f(cpu_f32(s, layout, what)?),
        _ => candle_core::bail!("the custom kernels run on the CPU only ({what} is on another device)"),
    }
}

/// Frames (B, T, H, W) as one T-channel image each: (B, 1, H, W, T), the
/// frame-stacking encoder's channel-last input.
///
/// candle's strided copy of the equivalent `permute((0, 2, 3, 1))` ran at ≈2 GB/s
/// and took 16 % of a frame-stacking update; observations carry no gradient, so a
/// CPU tensor that tracks none is transposed directly (samples in parallel, each
/// output pixel's T values written together). Anything else takes the permute.
pub fn frames_to_channels_last(frames: &Tensor) -> Result<Tensor> {
    let (b, t, h, w) = frames.dims4()?;
    if !frames.device().is_cpu() || frames.track_op() {
        return frames.permute((0, 2, 3, 1))?.reshape((b, 1, h, w, t));
    }
    let p = h * w;
    let mut dst = vec![0f32; b * t * p];
    with_cpu_f32(&frames.contiguous()?, "frames", |src| {
        dst.par_chunks_mut((t * p).max(1))
            .zip(src.par_chunks((t * p).max(1)))
            .for_each(|(out, sample)| transpose_block_rows(sample, out, t, p));
        Ok(())
    })?;
    Tensor::from_vec(dst, (b, 1, h, w, t), frames.device())
}
