//! Sizes of one convolution call ([`Geometry`]) and the column-matrix layout built
//! from them: [`im2col`] gathers one sample's spatial patches into the column matrix,
//! [`col2im_add`] scatters a column-matrix gradient back onto the input gradient.
//!
//! Invariant: a [`Geometry`] only exists for a kernel that fits its input (built by
//! [`Geometry::new`] from `ConvSpec::output_size`), and `im2col` and `col2im_add`
//! visit exactly the same (column, input) runs through one walk (`for_each_run`), so
//! col2im is the exact adjoint of im2col and no run leaves one sample's input or
//! column matrix; padding runs are zeros in the columns and touch no input.

use super::{ConvSpec, direct};

/// Sizes of one call.
#[derive(Debug, Clone, Copy)]
pub(super) struct Geometry {
    pub(super) b: usize,
    pub(super) t: usize,
    pub(super) h: usize,
    pub(super) w: usize,
    pub(super) ci: usize,
    pub(super) to: usize,
    pub(super) ho: usize,
    pub(super) wo: usize,
    pub(super) co: usize,
    pub(super) spec: ConvSpec,
}

impl Geometry {
    pub(super) fn new(spec: ConvSpec, x: &[usize], w: &[usize]) -> candle_core::Result<Geometry> {
        let [b, t, h, wd, ci] = x else {
            candle_core::bail!("conv: input must be (B, T, H, W, C), got {x:?}");
        };
        let [k, co] = w else {
            candle_core::bail!("conv: weight must be (K, C_out), got {w:?}");
        };
        if *k != spec.weight_rows(*ci) {
            candle_core::bail!(
                "conv: weight has {k} rows, kernel {:?} × {ci} channels needs {}",
                spec.kernel,
                spec.weight_rows(*ci)
            );
        }
        let Some((to, ho, wo)) = spec.output_size(*t, *h, *wd) else {
            candle_core::bail!(
                "conv: kernel {:?} (dilation {}) does not fit input {x:?}",
                spec.kernel,
                spec.dilation_t
            );
        };
        Ok(Geometry { b: *b, t: *t, h: *h, w: *wd, ci: *ci, to, ho, wo, co: *co, spec })
    }
    /// Columns of the per-frame (spatial) im2col matrix: k_h·k_w·C_in.
    pub(super) fn ks(&self) -> usize {
        self.spec.kernel[1] * self.spec.kernel[2] * self.ci
    }
    /// Output positions per frame.
    pub(super) fn ps(&self) -> usize {
        self.ho * self.wo
    }
    pub(super) fn in_len(&self) -> usize {
        self.t * self.h * self.w * self.ci
    }
    pub(super) fn out_len(&self) -> usize {
        self.to * self.ps() * self.co
    }
    pub(super) fn cols_len(&self) -> usize {
        self.t * self.ps() * self.ks()
    }
    /// Spatial size of a frame with the zero padding applied: (H + 2p_h, W + 2p_w).
    pub(super) fn padded(&self) -> (usize, usize) {
        (self.h + 2 * self.spec.padding[0], self.w + 2 * self.spec.padding[1])
    }
    /// Length of one sample's padded input.
    pub(super) fn padded_len(&self) -> usize {
        let (hp, wp) = self.padded();
        self.t * hp * wp * self.ci
    }
    /// True when the direct kernels ([`direct`]) compute the forward pass and the
    /// weight gradient: C_out a multiple of the vector tiles (8, 16, 32 or 64 — every
    /// convolution of the encoders). Per-layer measurements in `benches/conv_layers.rs`:
    /// on the AVX-512 and AVX2 paths the direct kernels ran every image layer at
    /// least as fast as im2col + gemm (C_in = 1 layers 2–5× faster).
    pub(super) fn direct(&self) -> bool {
        direct::LANES.contains(&self.co)
    }
    /// Floats of the per-sample input scratch: the padded input for the direct
    /// kernel, the column matrix for gemm, nothing when the input is its own column
    /// matrix.
    pub(super) fn input_scratch_len(&self, direct: bool) -> usize {
        if direct {
            self.padded_len()
        } else if self.spatially_pointwise() {
            0
        } else {
            self.cols_len()
        }
    }
    /// True when the spatial im2col is the identity (1×1 kernel, stride 1, no padding):
    /// then the input itself is the column matrix, whatever the temporal kernel.
    pub(super) fn spatially_pointwise(&self) -> bool {
        self.spec.kernel[1] == 1
            && self.spec.kernel[2] == 1
            && self.spec.stride == [1, 1]
            && self.spec.padding == [0, 0]
    }
    /// Row offset (in frames·positions) of temporal tap `dt` in the column matrix.
    pub(super) fn tap_row(&self, dt: usize) -> usize {
        dt * self.spec.dilation_t * self.ps()
    }
}

// The temporal taps of a kernel read the *same* spatial patches, shifted by d_t
// frames. So the column matrix is built once per input frame (T·H_out·W_out rows of
// k_h·k_w·C_in), and tap dt is a contiguous block of rows starting at frame dt·d_t:
// y = Σ_dt cols[dt·d_t·P .. (dt·d_t + T_out)·P] · W_dt, one gemm per tap, no
// duplicated patches.

/// Visit every (column-matrix offset, contiguous input run) pair of one sample:
/// `f(col_offset, Some(input_offset), len)` copies, `f(col_offset, None, len)` is padding.
#[inline(always)]
fn for_each_run(g: &Geometry, mut f: impl FnMut(usize, Option<usize>, usize)) {
    let [_, kh, kw] = g.spec.kernel;
    let [sh, sw] = g.spec.stride;
    let [ph, pw] = g.spec.padding;
    let ks = g.ks();
    let ci = g.ci;
    let mut row = 0;
    for t in 0..g.t {
        for ho in 0..g.ho {
            for wo in 0..g.wo {
                let base_row = row * ks;
                for dh in 0..kh {
                    let base = base_row + dh * kw * ci;
                    let h = (ho * sh + dh) as isize - ph as isize;
                    if h < 0 || h >= g.h as isize {
                        f(base, None, kw * ci);
                        continue;
                    }
                    let plane = (t * g.h + h as usize) * g.w;
                    let w0 = (wo * sw) as isize - pw as isize;
                    if w0 >= 0 && w0 as usize + kw <= g.w {
                        f(base, Some((plane + w0 as usize) * ci), kw * ci);
                    } else {
                        for dw in 0..kw {
                            let wi = w0 + dw as isize;
                            if wi < 0 || wi >= g.w as isize {
                                f(base + dw * ci, None, ci);
                            } else {
                                f(base + dw * ci, Some((plane + wi as usize) * ci), ci);
                            }
                        }
                    }
                }
                row += 1;
            }
        }
    }
}

/// Copy short runs element by element (a `memcpy` call costs more than 4–16 floats).
#[inline(always)]
fn copy_run(dst: &mut [f32], src: &[f32]) {
    if dst.len() <= 16 {
        for (d, s) in dst.iter_mut().zip(src) {
            *d = *s;
        }
    } else {
        dst.copy_from_slice(src);
    }
}

pub(super) fn im2col(g: &Geometry, x: &[f32], cols: &mut [f32]) {
    for_each_run(g, |c, src, len| match src {
        Some(s) => copy_run(&mut cols[c..c + len], &x[s..s + len]),
        None => cols[c..c + len].fill(0.0),
    });
}

pub(super) fn col2im_add(g: &Geometry, cols: &[f32], dx: &mut [f32]) {
    for_each_run(g, |c, src, len| {
        if let Some(s) = src {
            for (d, v) in dx[s..s + len].iter_mut().zip(&cols[c..c + len]) {
                *d += v;
            }
        }
    });
}
