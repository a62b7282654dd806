//! Direct (implicit-gemm) kernels: convolutions read straight from the padded
//! channel-last input, with no column matrix. One kernel family (forward, weight
//! gradient, input gradient over one SIMD abstraction) that reads top to bottom, so
//! it stays in one file.
//!
//! With few output channels the gemm after im2col gets a thin right-hand side and
//! spends its time moving memory (measured: the first 3D-TCN layer, C_in = 1, ran at
//! 14–19 GFLOP/s and the frame-stacking encoder's first layer, C_out = 16, at ≈50).
//! Here, for each (dt, dh) the k_w·C_in inputs a tap row reads are contiguous, and
//! three register-tiled kernels, each written once over [`crate::ops::simd::Simd`]
//! and compiled for AVX2 (8 lanes) and AVX-512 (16 lanes), do the work:
//! - forward: P output positions × R vectors of channels, each position an
//!   independent chain of fused multiply-adds sharing every weight load;
//! - weight gradient: T taps × R vectors of dW stay in registers while they sum over
//!   a chunk of positions;
//! - input gradient: P positions × a run-aligned tile of taps, Σ over the output
//!   channels of gy·Wᵀ, added into the padded input gradient (no col2im).
//!
//! Channels wider than one tile go in groups of R vectors. The baseline instruction
//! set keeps portable forward and weight-gradient loops (also the reference of the
//! vector kernels in the tests) and gemm for the input gradient.
//!
//! Invariant: every function here computes exactly the convolution of the parent
//! module (forward: bias, taps and ReLU; weight gradient: Σ over positions of
//! x · gy; input gradient: Σ over positions of gy·Wᵀ at the inputs each tap read) for
//! the geometry it is given; every instruction set agrees with the portable kernels
//! and the column-matrix definition (unit tests below), and the parent's tests check
//! the whole op against candle's `conv2d` and finite differences on every path. The
//! input is zero-padded once per sample ([`pad_frames`]), so no kernel has bounds
//! logic for the padding.
//!
//! Length: one kernel family read top to bottom (over the project's 600-line limit
//! on purpose): the entry points with their instruction-set dispatch, the index
//! helpers every variant shares, the vector kernels, then the portable kernels
//! those must agree with. The portable loops are the baseline path and the tests'
//! reference for the same blocks, and the helpers define the offsets all of them
//! read, so a split would put a kernel and the definition it is checked against in
//! different files.

use std::ops::Range;

use super::Geometry;
use crate::ops::Isa;

/// C_out values with a direct kernel: whole register tiles on AVX2 (8 lanes) and
/// AVX-512 (16); wider channels go in groups of tiles.
pub(super) const LANES: [usize; 4] = [8, 16, 32, 64];

/// Copy one sample's input (T, H, W, C_in) into `xp` (T, H + 2p_h, W + 2p_w, C_in)
/// with zero borders. Every element of `xp[..padded_len]` is written (it may come
/// from the scratch pool with stale contents): the border rows and the row ends
/// with zeros, the rest with the input.
pub(super) fn pad_frames(g: &Geometry, x: &[f32], xp: &mut [f32]) {
    pad_frames_with(g, x, xp, 0.0, |src, dst| dst.copy_from_slice(src));
}

/// [`pad_frames`] into any element type: zero borders of `zero`, each input row
/// written by `row` (a copy, or a conversion as the bf16 kernels' padding does).
pub(super) fn pad_frames_with<T: Copy>(g: &Geometry, x: &[f32], xp: &mut [T], zero: T, row: impl Fn(&[f32], &mut [T])) {
    let (hp, wp) = g.padded();
    let [ph, pw] = g.spec.padding;
    let ci = g.ci;
    let (row_len, edge) = (wp * ci, pw * ci);
    for (t, frame) in x.chunks_exact(g.h * g.w * ci).enumerate() {
        let plane = &mut xp[t * hp * row_len..(t + 1) * hp * row_len];
        let (top, rest) = plane.split_at_mut(ph * row_len);
        let (body, bottom) = rest.split_at_mut(g.h * row_len);
        top.fill(zero);
        bottom.fill(zero);
        for (dst, src) in body.chunks_exact_mut(row_len).zip(frame.chunks_exact(g.w * ci)) {
            dst[..edge].fill(zero);
            row(src, &mut dst[edge..edge + src.len()]);
            dst[edge + src.len()..].fill(zero);
        }
    }
}

/// Check once per sample that every index the kernels compute is in bounds.
fn check_sizes(g: &Geometry, xp: &[f32], w: &[f32]) {
    let taps = g.spec.weight_rows(g.ci);
    assert!(xp.len() >= g.padded_len(), "padded frames too short");
    assert!(w.len() >= taps * g.co, "weights too short");
    // The furthest input a kernel reads lies inside the padded frames because the
    // output size came from `ConvSpec::output_size` of the same geometry.
    debug_assert!(g.spec.output_size(g.t, g.h, g.w) == Some((g.to, g.ho, g.wo)));
}

/// Forward of output positions `positions` (linear over T_out·H_out·W_out) of one
/// sample from its padded input: y (positions.len(), C_out), on instruction set `isa`.
pub(super) fn forward(
    g: &Geometry,
    isa: Isa,
    xp: &[f32],
    w: &[f32],
    bias: &[f32],
    y: &mut [f32],
    positions: Range<usize>,
) {
    check_sizes(g, xp, w);
    assert!(positions.end <= g.to * g.ps() && y.len() >= positions.len() * g.co, "output too short");
    assert_eq!(bias.len(), g.co, "bias has C_out entries");
    #[cfg(target_arch = "x86_64")]
    {
        assert!(isa.is_supported(), "instruction set {isa} is not available on this CPU");
        // SAFETY: the CPU has the instruction set (asserted); sizes were checked above.
        // Register tiles (R vectors of C_out × P positions): AVX2 has 16 registers,
        // AVX-512 32; P·R accumulators + R weight vectors + one broadcast fit.
        unsafe {
            match (isa, g.co) {
                (Isa::Avx512, 16) => return vector::forward_avx512::<1, 8>(g, xp, w, bias, y, positions),
                (Isa::Avx512, 32) => return vector::forward_avx512::<2, 4>(g, xp, w, bias, y, positions),
                (Isa::Avx2 | Isa::Avx512, 8) => return vector::forward_avx2::<1, 8>(g, xp, w, bias, y, positions),
                (Isa::Avx2, 16) => return vector::forward_avx2::<2, 6>(g, xp, w, bias, y, positions),
                (Isa::Avx2, 32 | 64) => return vector::forward_avx2::<2, 6>(g, xp, w, bias, y, positions),
                (Isa::Avx512, 64) => return vector::forward_avx512::<4, 6>(g, xp, w, bias, y, positions),
                _ => {}
            }
        }
    }
    let _ = isa;
    portable_forward(g, xp, w, bias, y, positions);
}

/// dW (k_t·k_h·k_w, C_out) += Σ_positions x_tap · gy of one sample (gy already
/// masked by the ReLU), on instruction set `isa`.
pub(super) fn weight_grad(g: &Geometry, isa: Isa, xp: &[f32], gy: &[f32], dw: &mut [f32]) {
    check_sizes(g, xp, dw);
    assert!(gy.len() >= g.out_len(), "output gradient too short");
    #[cfg(target_arch = "x86_64")]
    {
        assert!(isa.is_supported(), "instruction set {isa} is not available on this CPU");
        // SAFETY: as in `forward`. Tiles of T taps × R vectors of dW stay in
        // registers (T·R accumulators + R gradient vectors + one broadcast).
        unsafe {
            match (isa, g.co) {
                (Isa::Avx512, 16) => return vector::weight_grad_avx512::<1, 16>(g, xp, gy, dw),
                (Isa::Avx512, 32) => return vector::weight_grad_avx512::<2, 12>(g, xp, gy, dw),
                (Isa::Avx2 | Isa::Avx512, 8) => return vector::weight_grad_avx2::<1, 12>(g, xp, gy, dw),
                (Isa::Avx2, 16) => return vector::weight_grad_avx2::<2, 6>(g, xp, gy, dw),
                (Isa::Avx2, 32 | 64) => return vector::weight_grad_avx2::<2, 6>(g, xp, gy, dw),
                (Isa::Avx512, 64) => return vector::weight_grad_avx512::<4, 6>(g, xp, gy, dw),
                _ => {}
            }
        }
    }
    let _ = isa;
    portable_weight_grad(g, xp, gy, dw);
}

/// Floats per tile of the direct input-gradient kernel on `isa`, if it has one.
fn input_grad_width(isa: Isa) -> Option<usize> {
    match isa {
        Isa::Avx512 => Some(32),
        Isa::Avx2 => Some(16),
        Isa::Baseline => None,
    }
}

/// Whether [`input_grad`] takes this layer on `isa`: a vector instruction set, a
/// spatial kernel, and runs of k_w·C_in contiguous inputs that the kernel's tiles
/// divide (so no tile straddles two input rows).
pub(super) fn input_grad_supported(g: &Geometry, isa: Isa) -> bool {
    let run = g.spec.kernel[2] * g.ci;
    !g.spatially_pointwise() && input_grad_width(isa).is_some_and(|w| run.is_multiple_of(w))
}

/// Wᵀ (C_out, K) from W (K, C_out): the input-gradient kernel reads, for each
/// output channel, the K weights it spreads back over the taps contiguously.
pub(super) fn transpose_weights(g: &Geometry, w: &[f32]) -> Vec<f32> {
    let k = g.spec.weight_rows(g.ci);
    let mut wt = vec![0f32; k * g.co];
    for (row, wr) in w.chunks_exact(g.co).enumerate() {
        for (o, &v) in wr.iter().enumerate() {
            wt[o * k + row] = v;
        }
    }
    wt
}

/// dxp (padded like [`pad_frames`]) += the input gradient of one sample: for every
/// output position q and tap, Σ_o gy[q, o]·W[tap, o] added at the input the tap
/// read. Computed in register tiles of P positions × one run-aligned tile of taps
/// and added straight into `dxp`, instead of writing the whole T·H_out·W_out × K
/// column matrix and scattering it back (col2im). `wt` from [`transpose_weights`];
/// only for layers where [`input_grad_supported`] holds.
pub(super) fn input_grad(g: &Geometry, isa: Isa, wt: &[f32], gy: &[f32], dxp: &mut [f32]) {
    assert!(input_grad_supported(g, isa), "no direct input gradient for this layer on {isa}");
    assert!(isa.is_supported(), "instruction set {isa} is not available on this CPU");
    assert!(dxp.len() >= g.padded_len(), "padded input gradient too short");
    assert!(wt.len() >= g.spec.weight_rows(g.ci) * g.co, "weights too short");
    assert!(gy.len() >= g.out_len(), "output gradient too short");
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the instruction set is available and the sizes were checked above.
    unsafe {
        match isa {
            Isa::Avx512 => vector::input_grad_avx512::<2, 12>(g, wt, gy, dxp),
            Isa::Avx2 => vector::input_grad_avx2::<2, 6>(g, wt, gy, dxp),
            Isa::Baseline => unreachable!("checked by input_grad_supported"),
        }
    }
}

/// The inverse of [`pad_frames`]: copy the interior of the padded `xp` into `x`.
pub(super) fn unpad_frames(g: &Geometry, xp: &[f32], x: &mut [f32]) {
    let (hp, wp) = g.padded();
    let [ph, pw] = g.spec.padding;
    let ci = g.ci;
    let (row_len, edge) = (wp * ci, pw * ci);
    for (t, frame) in x.chunks_exact_mut(g.h * g.w * ci).enumerate() {
        let plane = &xp[(t * hp + ph) * row_len..];
        for (src, dst) in plane.chunks_exact(row_len).zip(frame.chunks_exact_mut(g.w * ci)) {
            dst.copy_from_slice(&src[edge..edge + dst.len()]);
        }
    }
}

/// Offsets in the padded input of tap (0, 0, 0), channel 0, of output positions
/// q0 .. q0 + N (one division pair per block, then stepping along the rows).
#[inline(always)]
pub(super) fn input_offsets<const N: usize>(g: &Geometry, q0: usize) -> [usize; N] {
    let mut offsets = [0; N];
    fill_input_offsets(g, q0, &mut offsets);
    offsets
}

/// [`input_offsets`] of output positions q0 .. q0 + out.len() into `out`.
#[inline(always)]
fn fill_input_offsets(g: &Geometry, q0: usize, out: &mut [usize]) {
    let (hp, wp) = g.padded();
    let [sh, sw] = g.spec.stride;
    let (mut wo, rest) = (q0 % g.wo, q0 / g.wo);
    let (mut ho, mut to) = (rest % g.ho, rest / g.ho);
    for offset in out {
        *offset = ((to * hp + ho * sh) * wp + wo * sw) * g.ci;
        wo += 1;
        if wo == g.wo {
            wo = 0;
            ho += 1;
            if ho == g.ho {
                ho = 0;
                to += 1;
            }
        }
    }
}

/// Offset of tap (dt, dh, 0) relative to tap (0, 0, 0): its k_w·C_in inputs follow
/// contiguously.
#[inline(always)]
pub(super) fn tap_offset(g: &Geometry, dt: usize, dh: usize) -> usize {
    let (hp, wp) = g.padded();
    (dt * g.spec.dilation_t * hp + dh) * wp * g.ci
}

#[cfg(target_arch = "x86_64")]
mod vector {
    //! The register-tiled kernels, written once over [`Simd`] and compiled for AVX2
    //! (C_out = 8·R) and AVX-512 (C_out = 16·R). Consecutive output positions go in
    //! blocks of P, each position an independent chain of fused multiply-adds
    //! sharing every weight load; single positions finish a range. Everything from
    //! the entry points down is plain loops over `#[inline(always)]` functions (no
    //! closures), so the whole kernel is compiled with the entry point's features.
    use std::ops::Range;

    use super::{Geometry, fill_input_offsets, input_offsets, tap_offset};
    use crate::ops::simd::{Avx2, Avx512, Simd};

    /// Safety (every function here): the CPU has `S`'s instruction set; slices sized
    /// as checked by `check_sizes`, with C_out a multiple of `S::LANES`·R (the
    /// channels go in groups of R vectors, each group its own register tile); `y`
    /// starts at output position `positions.start`.
    #[inline(always)]
    unsafe fn forward_blocks<S: Simd, const R: usize, const P: usize>(
        g: &Geometry,
        xp: &[f32],
        w: &[f32],
        bias: &[f32],
        y: &mut [f32],
        positions: Range<usize>,
    ) {
        let (co, width) = (g.co, S::LANES * R);
        assert_eq!(co % width, 0, "C_out is a whole number of register tiles");
        let (x, w, y) = (xp.as_ptr(), w.as_ptr(), y.as_mut_ptr());
        let (first, end) = (positions.start, positions.end);
        // SAFETY: positions q..q+P (or q) and their taps are in bounds; channel
        // groups c0..c0+width lie inside C_out.
        unsafe {
            let mut q = first;
            while q < end {
                let n = if q + P <= end { P } else { 1 };
                let mut c0 = 0;
                while c0 < co {
                    let mut b = [S::zero(); R];
                    for (r, v) in b.iter_mut().enumerate() {
                        *v = S::load(bias.as_ptr().add(c0 + S::LANES * r));
                    }
                    let out = y.add((q - first) * co + c0);
                    if n == P {
                        block::<S, R, P>(g, x, w.add(c0), &b, q, out);
                    } else {
                        block::<S, R, 1>(g, x, w.add(c0), &b, q, out);
                    }
                    c0 += width;
                }
                q += n;
            }
        }
    }

    /// y of output positions q0 .. q0 + N for one group of R·LANES channels: `w`
    /// and `out` point at the group's first channel (rows of C_out floats).
    #[inline(always)]
    unsafe fn block<S: Simd, const R: usize, const N: usize>(
        g: &Geometry,
        x: *const f32,
        w: *const f32,
        bias: &[S::V; R],
        q0: usize,
        out: *mut f32,
    ) {
        let co = g.co;
        let [kt, kh, kw] = g.spec.kernel;
        let run = kw * g.ci;
        let base: [usize; N] = input_offsets(g, q0);
        let mut acc = [*bias; N];
        let mut row = w;
        for dt in 0..kt {
            for dh in 0..kh {
                let off = tap_offset(g, dt, dh);
                for i in 0..run {
                    let mut wv = *bias;
                    for (r, v) in wv.iter_mut().enumerate() {
                        // SAFETY: k_t·k_h·k_w·C_in weight rows of C_out floats.
                        *v = unsafe { S::load(row.add(S::LANES * r)) };
                    }
                    // SAFETY: the next weight row, still inside the k_t·k_h·k_w·C_in rows.
                    row = unsafe { row.add(co) };
                    for j in 0..N {
                        // SAFETY: inside the padded input (see check_sizes).
                        let xv = unsafe { S::splat(*x.add(base[j] + off + i)) };
                        for r in 0..R {
                            // SAFETY: register arithmetic on the instruction set the caller checked.
                            acc[j][r] = unsafe { S::fma(xv, wv[r], acc[j][r]) };
                        }
                    }
                }
            }
        }
        // SAFETY: register arithmetic on the instruction set the caller checked.
        let zero = unsafe { S::zero() };
        for (j, a) in acc.iter().enumerate() {
            for (r, &lane) in a.iter().enumerate() {
                // SAFETY: N positions of C_out floats from `out`.
                unsafe {
                    let v = if g.spec.relu { S::max(lane, zero) } else { lane };
                    S::store(out.add(j * co + S::LANES * r), v);
                }
            }
        }
    }

    /// Output positions per chunk of the weight gradient: the chunk's gradient rows
    /// (≤ 16 KiB at C_out = 32) stay in the L1 cache while every tile of taps passes
    /// over them.
    const GRAD_CHUNK: usize = 128;

    /// The weight gradient with a tile of T taps × R vectors of dW (one group of
    /// channels) held in registers
    /// while it sums over a chunk of output positions (one gradient-row load and T
    /// broadcasts per position feed T·R independent fused multiply-adds), then added
    /// to dW once per chunk. The last tile of taps may be partial: its missing taps
    /// re-read tap 0 and their sums are dropped.
    #[inline(always)]
    unsafe fn weight_grad_tiles<S: Simd, const R: usize, const T: usize>(
        g: &Geometry,
        xp: &[f32],
        gy: &[f32],
        dw: &mut [f32],
    ) {
        let (co, width) = (g.co, S::LANES * R);
        assert_eq!(co % width, 0, "C_out is a whole number of register tiles");
        let [kt, kh, kw] = g.spec.kernel;
        let run = kw * g.ci;
        let taps = kt * kh * run;
        // Offset of every tap relative to its position's tap (0, 0, 0).
        let mut tap_offsets = Vec::with_capacity(taps);
        for dt in 0..kt {
            for dh in 0..kh {
                let off = tap_offset(g, dt, dh);
                tap_offsets.extend((0..run).map(|i| off + i));
            }
        }
        let positions = g.to * g.ps();
        let mut base = [0usize; GRAD_CHUNK];
        let (x, gy, dw) = (xp.as_ptr(), gy.as_ptr(), dw.as_mut_ptr());
        let mut q0 = 0;
        while q0 < positions {
            let len = GRAD_CHUNK.min(positions - q0);
            fill_input_offsets(g, q0, &mut base[..len]);
            for c0 in (0..co).step_by(width) {
                let mut k0 = 0;
                while k0 < taps {
                    let tile = T.min(taps - k0);
                    let mut offs = [0usize; T];
                    for (u, o) in offs.iter_mut().enumerate().take(tile) {
                        *o = tap_offsets[k0 + u];
                    }
                    // SAFETY: q0..q0+len are output positions, k0..k0+tile taps, c0..c0+width
                    // channels; every
                    // input read lies inside the padded input (see check_sizes).
                    unsafe {
                        let mut acc = [[S::zero(); R]; T];
                        let mut grow = gy.add(q0 * co + c0);
                        for &b in &base[..len] {
                            let mut gv = [S::zero(); R];
                            for (r, v) in gv.iter_mut().enumerate() {
                                *v = S::load(grow.add(S::LANES * r));
                            }
                            grow = grow.add(co);
                            let xb = x.add(b);
                            for u in 0..T {
                                let xv = S::splat(*xb.add(offs[u]));
                                for r in 0..R {
                                    acc[u][r] = S::fma(xv, gv[r], acc[u][r]);
                                }
                            }
                        }
                        for (u, a) in acc.iter().enumerate().take(tile) {
                            let dst = dw.add((k0 + u) * co + c0);
                            for (r, &v) in a.iter().enumerate() {
                                let p = dst.add(S::LANES * r);
                                S::store(p, S::add(v, S::load(p)));
                            }
                        }
                    }
                    k0 += tile;
                }
            }
            q0 += len;
        }
    }

    /// The input gradient in tiles of P positions × R vectors of consecutive taps
    /// (inside one run of k_w·C_in inputs): Σ over output channels of the
    /// broadcast gradient times Wᵀ's row, then added into the padded input
    /// gradient at each position's inputs. Positions of one tile may read
    /// overlapping inputs (stride < kernel); their additions run one after the
    /// other, so each sees the previous one's store.
    #[inline(always)]
    unsafe fn input_grad_blocks<S: Simd, const R: usize, const P: usize>(
        g: &Geometry,
        wt: &[f32],
        gy: &[f32],
        dxp: &mut [f32],
    ) {
        let positions = g.to * g.ps();
        let (wt, gy, dx) = (wt.as_ptr(), gy.as_ptr(), dxp.as_mut_ptr());
        let mut q = 0;
        // SAFETY: positions q..q+P (or q) are output positions of this sample.
        unsafe {
            while q < positions {
                if q + P <= positions {
                    input_block::<S, R, P>(g, wt, gy, dx, q);
                    q += P;
                } else {
                    input_block::<S, R, 1>(g, wt, gy, dx, q);
                    q += 1;
                }
            }
        }
    }

    #[inline(always)]
    unsafe fn input_block<S: Simd, const R: usize, const N: usize>(
        g: &Geometry,
        wt: *const f32,
        gy: *const f32,
        dx: *mut f32,
        q0: usize,
    ) {
        let (co, width) = (g.co, S::LANES * R);
        let [kt, kh, kw] = g.spec.kernel;
        let run = kw * g.ci;
        let taps = kt * kh * run;
        let base: [usize; N] = input_offsets(g, q0);
        // SAFETY: gradient rows q0..q0+N exist; Wᵀ has C_out rows of `taps`; every
        // tile lies inside one run of the padded input (input_grad_supported).
        unsafe {
            let grows = gy.add(q0 * co);
            for dt in 0..kt {
                for dh in 0..kh {
                    let off = tap_offset(g, dt, dh);
                    let mut i0 = 0;
                    while i0 < run {
                        let mut acc = [[S::zero(); R]; N];
                        let mut wrow = wt.add((dt * kh + dh) * run + i0);
                        for o in 0..co {
                            let mut wv = [S::zero(); R];
                            for (r, v) in wv.iter_mut().enumerate() {
                                *v = S::load(wrow.add(S::LANES * r));
                            }
                            wrow = wrow.add(taps);
                            for (j, aj) in acc.iter_mut().enumerate() {
                                let gv = S::splat(*grows.add(j * co + o));
                                for r in 0..R {
                                    aj[r] = S::fma(gv, wv[r], aj[r]);
                                }
                            }
                        }
                        for j in 0..N {
                            let dst = dx.add(base[j] + off + i0);
                            for (r, &a) in acc[j].iter().enumerate() {
                                let p = dst.add(S::LANES * r);
                                S::store(p, S::add(a, S::load(p)));
                            }
                        }
                        i0 += width;
                    }
                }
            }
        }
    }

    /// Entry points: one per instruction set, each compiled with its features.
    macro_rules! entry_points {
        ($simd:ident, $features:literal, $fwd:ident, $grad:ident, $input:ident) => {
            #[target_feature(enable = $features)]
            pub(super) unsafe fn $input<const R: usize, const P: usize>(
                g: &Geometry,
                wt: &[f32],
                gy: &[f32],
                dxp: &mut [f32],
            ) {
                // SAFETY: this function's target features are enabled (its caller checked
                // the CPU has them); the slices' sizes are the caller's contract.
                unsafe { input_grad_blocks::<$simd, R, P>(g, wt, gy, dxp) }
            }

            #[target_feature(enable = $features)]
            pub(super) unsafe fn $fwd<const R: usize, const P: usize>(
                g: &Geometry,
                xp: &[f32],
                w: &[f32],
                bias: &[f32],
                y: &mut [f32],
                positions: Range<usize>,
            ) {
                // SAFETY: this function's target features are enabled (its caller checked
                // the CPU has them); the slices' sizes are the caller's contract.
                unsafe { forward_blocks::<$simd, R, P>(g, xp, w, bias, y, positions) }
            }

            #[target_feature(enable = $features)]
            pub(super) unsafe fn $grad<const R: usize, const T: usize>(
                g: &Geometry,
                xp: &[f32],
                gy: &[f32],
                dw: &mut [f32],
            ) {
                // SAFETY: this function's target features are enabled (its caller checked
                // the CPU has them); the slices' sizes are the caller's contract.
                unsafe { weight_grad_tiles::<$simd, R, T>(g, xp, gy, dw) }
            }
        };
    }
    entry_points!(Avx2, "avx2,fma", forward_avx2, weight_grad_avx2, input_grad_avx2);
    entry_points!(Avx512, "avx512f,avx2,fma", forward_avx512, weight_grad_avx512, input_grad_avx512);
}

// The baseline kernels (any CPU; the reference of the vector ones in the tests): the
// same blocks in plain Rust, a multiply then an add (a fused multiply-add without
// the instruction is a slow library call).

fn portable_forward_lanes<const CO: usize, const P: usize>(
    g: &Geometry,
    xp: &[f32],
    w: &[f32],
    bias: &[f32],
    y: &mut [f32],
    positions: Range<usize>,
) {
    let (rows, _) = w.as_chunks::<CO>();
    let bias: [f32; CO] = bias.try_into().expect("bias has C_out entries");
    let (outs, _) = y.as_chunks_mut::<CO>();
    let [kt, kh, kw] = g.spec.kernel;
    let run = kw * g.ci;
    let first = positions.start;
    let mut q0 = first;
    while q0 < positions.end {
        let len = P.min(positions.end - q0);
        let base: [usize; P] = input_offsets(g, q0);
        let mut acc = [bias; P];
        let mut row = rows.iter();
        for dt in 0..kt {
            for dh in 0..kh {
                let off = tap_offset(g, dt, dh);
                for i in 0..run {
                    let wr = row.next().expect("k_t·k_h·k_w·C_in weight rows");
                    for (a, &bj) in acc[..len].iter_mut().zip(&base) {
                        let xv = xp[bj + off + i];
                        for c in 0..CO {
                            a[c] += xv * wr[c];
                        }
                    }
                }
            }
        }
        for (o, a) in outs[q0 - first..q0 - first + len].iter_mut().zip(&acc) {
            for c in 0..CO {
                o[c] = if g.spec.relu { a[c].max(0.0) } else { a[c] };
            }
        }
        q0 += len;
    }
}

fn portable_weight_grad_lanes<const CO: usize, const P: usize>(g: &Geometry, xp: &[f32], gy: &[f32], dw: &mut [f32]) {
    let (grads, _) = gy.as_chunks::<CO>();
    let (dws, _) = dw.as_chunks_mut::<CO>();
    let [kt, kh, kw] = g.spec.kernel;
    let run = kw * g.ci;
    let end = g.to * g.ps();
    let mut q0 = 0;
    while q0 < end {
        let len = P.min(end - q0);
        let base: [usize; P] = input_offsets(g, q0);
        let gr = &grads[q0..q0 + len];
        let mut dst = dws.iter_mut();
        for dt in 0..kt {
            for dh in 0..kh {
                let off = tap_offset(g, dt, dh);
                for i in 0..run {
                    let d = dst.next().expect("k_t·k_h·k_w·C_in gradient rows");
                    let mut acc = *d;
                    for (gj, &bj) in gr.iter().zip(&base) {
                        let xv = xp[bj + off + i];
                        for c in 0..CO {
                            acc[c] += xv * gj[c];
                        }
                    }
                    *d = acc;
                }
            }
        }
        q0 += len;
    }
}

fn portable_forward(g: &Geometry, xp: &[f32], w: &[f32], bias: &[f32], y: &mut [f32], positions: Range<usize>) {
    match g.co {
        8 => portable_forward_lanes::<8, 8>(g, xp, w, bias, y, positions),
        16 => portable_forward_lanes::<16, 4>(g, xp, w, bias, y, positions),
        32 => portable_forward_lanes::<32, 2>(g, xp, w, bias, y, positions),
        64 => portable_forward_lanes::<64, 1>(g, xp, w, bias, y, positions),
        co => unreachable!("no direct kernel for C_out {co}"),
    }
}

fn portable_weight_grad(g: &Geometry, xp: &[f32], gy: &[f32], dw: &mut [f32]) {
    match g.co {
        8 => portable_weight_grad_lanes::<8, 8>(g, xp, gy, dw),
        16 => portable_weight_grad_lanes::<16, 4>(g, xp, gy, dw),
        32 => portable_weight_grad_lanes::<32, 2>(g, xp, gy, dw),
        64 => portable_weight_grad_lanes::<64, 1>(g, xp, gy, dw),
        co => unreachable!("no direct kernel for C_out {co}"),
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::ops::ConvSpec;

    /// Every instruction-set path this CPU supports equals the baseline kernels for
    /// every lane count, one and several input channels, odd row lengths (block
    /// remainders) and ReLU on and off, also when a sample's positions are split
    /// into uneven chunks (as over threads at inference).
    #[test]
    fn every_instruction_set_equals_the_baseline_kernels() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for (co, ci, spec, (t, h, w)) in [
            (16, 1, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), (5, 13, 21)),
            (32, 1, ConvSpec::spatiotemporal(2, 1, 3, 1, 1), (3, 7, 11)),
            (32, 16, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), (4, 10, 13)),
            (16, 5, ConvSpec::spatial(4, 2, 2), (1, 9, 10)),
            (8, 2, ConvSpec::spatiotemporal(3, 1, 3, 3, 0), (4, 9, 12)),
            (64, 32, ConvSpec::spatiotemporal(2, 4, 3, 3, 0), (6, 10, 10)),
            (16, 8, ConvSpec::temporal(3, 2), (7, 3, 3)),
        ] {
            for relu in [false, true] {
                let spec = ConvSpec { relu, ..spec };
                let g = Geometry::new(spec, &[1, t, h, w, ci], &[spec.weight_rows(ci), co]).unwrap();
                let mut rand_vec = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
                let x = rand_vec(g.in_len());
                let wt = rand_vec(spec.weight_rows(ci) * co);
                let bias = rand_vec(co);
                let gy = rand_vec(g.out_len());
                let mut xp = vec![0.0; g.padded_len()];
                pad_frames(&g, &x, &mut xp);
                let all = 0..g.to * g.ps();
                let mut y_ref = vec![0.0; g.out_len()];
                portable_forward(&g, &xp, &wt, &bias, &mut y_ref, all.clone());
                let mut d_ref = vec![0.5; wt.len()];
                portable_weight_grad(&g, &xp, &gy, &mut d_ref);
                for isa in Isa::supported() {
                    let mut y1 = vec![0.0; g.out_len()];
                    forward(&g, isa, &xp, &wt, &bias, &mut y1, all.clone());
                    let mut y2 = vec![0.0; g.out_len()];
                    for (i, yc) in y2.chunks_mut(13 * co).enumerate() {
                        let q0 = i * 13;
                        forward(&g, isa, &xp, &wt, &bias, yc, q0..q0 + yc.len() / co);
                    }
                    assert_eq!(y1, y2, "{isa} C_out {co}: chunked forward differs");
                    let mut d1 = vec![0.5; wt.len()];
                    weight_grad(&g, isa, &xp, &gy, &mut d1);
                    for (what, a, b) in [("output", &y1, &y_ref), ("weight gradient", &d1, &d_ref)] {
                        for (u, v) in a.iter().zip(b.iter()) {
                            assert!(
                                (u - v).abs() <= 1e-5 * (1.0 + v.abs()),
                                "{isa} C_out {co} relu {relu} {what}: {u} vs {v}"
                            );
                        }
                    }
                }
            }
        }
    }

    /// The direct input gradient equals the column-matrix definition (gy·Wᵀ per
    /// position, each entry added at the input its tap read) on every vector
    /// instruction set, for strides smaller than, equal to and larger than the
    /// kernel and several temporal taps.
    #[test]
    fn direct_input_gradient_equals_the_column_matrix_definition() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for (co, ci, spec, (t, h, w)) in [
            (32, 16, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), (5, 10, 11)),
            (64, 32, ConvSpec::spatiotemporal(2, 1, 3, 3, 0), (3, 10, 10)),
            (16, 16, ConvSpec::spatial(2, 1, 1), (1, 6, 7)),
            (8, 16, ConvSpec::spatial(3, 2, 1), (1, 7, 9)),
        ] {
            let g = Geometry::new(spec, &[1, t, h, w, ci], &[spec.weight_rows(ci), co]).unwrap();
            let mut rand_vec = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
            let wt_k = rand_vec(spec.weight_rows(ci) * co);
            let gy = rand_vec(g.out_len());
            // Reference: the column-matrix row of each position, added tap by tap.
            let mut expect = vec![0f32; g.padded_len()];
            let [kt, kh, kw] = spec.kernel;
            for q in 0..g.to * g.ps() {
                let base: [usize; 1] = input_offsets(&g, q);
                for dt in 0..kt {
                    for dh in 0..kh {
                        for i in 0..kw * ci {
                            let k = (dt * kh + dh) * kw * ci + i;
                            let v: f32 = (0..co).map(|o| gy[q * co + o] * wt_k[k * co + o]).sum();
                            expect[base[0] + tap_offset(&g, dt, dh) + i] += v;
                        }
                    }
                }
            }
            let wt = transpose_weights(&g, &wt_k);
            for isa in Isa::supported() {
                if !input_grad_supported(&g, isa) {
                    continue;
                }
                let mut dxp = vec![0f32; g.padded_len()];
                input_grad(&g, isa, &wt, &gy, &mut dxp);
                for (u, v) in dxp.iter().zip(&expect) {
                    assert!((u - v).abs() <= 1e-4 * (1.0 + v.abs()), "{isa} C_out {co} C_in {ci}: {u} vs {v}");
                }
                let mut dx = vec![0f32; g.in_len()];
                unpad_frames(&g, &dxp, &mut dx);
                let mut again = vec![0f32; g.padded_len()];
                pad_frames(&g, &dx, &mut again);
                unpad_frames(&g, &again, &mut dx);
                let mut dx2 = vec![0f32; g.in_len()];
                unpad_frames(&g, &dxp, &mut dx2);
                assert_eq!(dx, dx2, "pad_frames and unpad_frames are inverse on the interior");
            }
        }
    }
}
