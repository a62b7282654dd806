//! Direct (implicit-gemm) kernels for narrow convolutions: C_out ≤ 32, small weights.
//!
//! With few output channels the gemm after im2col gets a thin right-hand side and
//! spends its time moving memory (measured: the first 3D-TCN layer, C_in = 1, ran at
//! 14–19 GFLOP/s and the frame-stacking encoder's first layer, C_out = 16, at ≈50;
//! the wider layers reach 60–120). Here an output position is Σ over the taps and
//! input channels of x · W_row over its C_out lanes, read straight from the padded
//! channel-last input: for each (dt, dh) the k_w·C_in inputs are contiguous, so a
//! position costs k_t·k_h·k_w·C_in broadcasts and C_out/16 fused multiply-adds each,
//! with the accumulators in registers. Consecutive output positions go in blocks of
//! P (a block may span rows, each position with its own input offset), each an
//! independent chain (a single chain waits on the FMA latency at every step)
//! sharing each weight load. With C_out = 64, or weights beyond the L1 cache
//! ([`MAX_WEIGHTS`]), gemm was faster (measured), so those layers keep im2col + gemm.
//!
//! Invariant: every function here computes exactly the convolution of the parent
//! module (forward: bias, taps and ReLU; weight gradient: Σ over positions of
//! x · gy) for the geometry it is given; the AVX-512 kernels and the portable ones
//! agree (unit test below), and the parent's tests check both against candle's
//! `conv2d` and finite differences. The input is zero-padded once per sample
//! ([`pad_frames`]), so no kernel has bounds logic for the padding.

use std::ops::Range;

use super::Geometry;

/// Largest weight matrix (floats) the direct kernel takes: 32 KiB, so the rows it
/// sweeps for every block of positions stay in the L1 cache. Measured on the second
/// 3D-TCN layer (64 KiB of weights): gemm was faster at 42² (≈5 vs 8 ms forward,
/// B 32) and no slower at 84².
pub(super) const MAX_WEIGHTS: usize = 8192;

/// C_out values with a direct kernel (vector lanes: 8 for AVX2, 16 and 32 for AVX-512).
pub(super) const LANES: [usize; 3] = [8, 16, 32];

/// Copy one sample's input (T, H, W, C_in) into `xp` (T, H + 2p_h, W + 2p_w, C_in)
/// with zero borders. Every element of `xp[..padded_len]` is written (it may come
/// from the scratch pool with stale contents): the border rows and the row ends
/// with zeros, the rest with the input.
pub(super) fn pad_frames(g: &Geometry, x: &[f32], xp: &mut [f32]) {
    let (hp, wp) = g.padded();
    let [ph, pw] = g.spec.padding;
    let ci = g.ci;
    let (row_len, edge) = (wp * ci, pw * ci);
    for (t, frame) in x.chunks_exact(g.h * g.w * ci).enumerate() {
        let plane = &mut xp[t * hp * row_len..(t + 1) * hp * row_len];
        let (top, rest) = plane.split_at_mut(ph * row_len);
        let (body, bottom) = rest.split_at_mut(g.h * row_len);
        top.fill(0.0);
        bottom.fill(0.0);
        for (dst, src) in body.chunks_exact_mut(row_len).zip(frame.chunks_exact(g.w * ci)) {
            dst[..edge].fill(0.0);
            dst[edge..edge + src.len()].copy_from_slice(src);
            dst[edge + src.len()..].fill(0.0);
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
/// sample from its padded input: y (positions.len(), C_out).
pub(super) fn forward(g: &Geometry, xp: &[f32], w: &[f32], bias: &[f32], y: &mut [f32], positions: Range<usize>) {
    check_sizes(g, xp, w);
    assert!(positions.end <= g.to * g.ps() && y.len() >= positions.len() * g.co, "output too short");
    assert_eq!(bias.len(), g.co, "bias has C_out entries");
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        // Safety: the CPU has AVX-512F; sizes were checked above.
        unsafe {
            match g.co {
                16 => return avx512::forward::<1, 8>(g, xp, w, bias, y, positions),
                32 => return avx512::forward::<2, 4>(g, xp, w, bias, y, positions),
                _ => {}
            }
        }
    }
    portable_forward(g, xp, w, bias, y, positions);
}

/// dW (k_t·k_h·k_w, C_out) += Σ_positions x_tap · gy of one sample (gy already
/// masked by the ReLU).
pub(super) fn weight_grad(g: &Geometry, xp: &[f32], gy: &[f32], dw: &mut [f32]) {
    check_sizes(g, xp, dw);
    assert!(gy.len() >= g.out_len(), "output gradient too short");
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        // Safety: the CPU has AVX-512F; sizes were checked above.
        unsafe {
            match g.co {
                16 => return avx512::weight_grad::<1, 8>(g, xp, gy, dw),
                32 => return avx512::weight_grad::<2, 4>(g, xp, gy, dw),
                _ => {}
            }
        }
    }
    portable_weight_grad(g, xp, gy, dw);
}

/// Visit blocks of consecutive output positions q in `positions` (linear over
/// T_out·H_out·W_out, the output's memory order): `f(q0, len)` with `len` = `p`, and
/// single positions for the remainder. A block may span output rows and frames:
/// each position has its own input offset ([`input_offsets`]).
#[inline(always)]
fn for_each_block(positions: Range<usize>, p: usize, mut f: impl FnMut(usize, usize)) {
    let (start, end) = (positions.start, positions.end);
    let mut q = start;
    while q + p <= end {
        f(q, p);
        q += p;
    }
    for q in q..end {
        f(q, 1);
    }
}

/// Offsets in the padded input of tap (0, 0, 0), channel 0, of output positions
/// q0 .. q0 + N (one division pair per block, then stepping along the rows).
#[inline(always)]
fn input_offsets<const N: usize>(g: &Geometry, q0: usize) -> [usize; N] {
    let (hp, wp) = g.padded();
    let [sh, sw] = g.spec.stride;
    let (mut wo, rest) = (q0 % g.wo, q0 / g.wo);
    let (mut ho, mut to) = (rest % g.ho, rest / g.ho);
    std::array::from_fn(|_| {
        let offset = ((to * hp + ho * sh) * wp + wo * sw) * g.ci;
        wo += 1;
        if wo == g.wo {
            wo = 0;
            ho += 1;
            if ho == g.ho {
                ho = 0;
                to += 1;
            }
        }
        offset
    })
}

/// Offset of tap (dt, dh, 0) relative to tap (0, 0, 0): its k_w·C_in inputs follow
/// contiguously.
#[inline(always)]
fn tap_offset(g: &Geometry, dt: usize, dh: usize) -> usize {
    let (hp, wp) = g.padded();
    (dt * g.spec.dilation_t * hp + dh) * wp * g.ci
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    //! AVX-512 kernels: C_out = 16·R lanes, blocks of P positions.
    use std::arch::x86_64::{
        __m512, _mm512_fmadd_ps, _mm512_loadu_ps, _mm512_max_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_storeu_ps,
    };
    use std::ops::Range;

    use super::{Geometry, for_each_block, input_offsets, tap_offset};

    /// Safety (every function here): AVX-512F available; slices sized as checked by
    /// `check_sizes`, with C_out = 16·R; `y` starts at output position `positions.start`.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn forward<const R: usize, const P: usize>(
        g: &Geometry,
        xp: &[f32],
        w: &[f32],
        bias: &[f32],
        y: &mut [f32],
        positions: Range<usize>,
    ) {
        let (x, w, y) = (xp.as_ptr(), w.as_ptr(), y.as_mut_ptr());
        // Safety: bias has 16·R entries.
        let b: [__m512; R] = std::array::from_fn(|r| unsafe { _mm512_loadu_ps(bias.as_ptr().add(16 * r)) });
        let first = positions.start;
        for_each_block(positions, P, |q0, len| {
            // Safety: positions q0..q0+len and their taps are in bounds.
            unsafe {
                let out = y.add((q0 - first) * 16 * R);
                if len == P {
                    block::<R, P>(g, x, w, &b, q0, out);
                } else {
                    block::<R, 1>(g, x, w, &b, q0, out);
                }
            }
        });
    }

    #[target_feature(enable = "avx512f")]
    unsafe fn block<const R: usize, const N: usize>(
        g: &Geometry,
        x: *const f32,
        w: *const f32,
        bias: &[__m512; R],
        q0: usize,
        out: *mut f32,
    ) {
        let co = 16 * R;
        let [kt, kh, kw] = g.spec.kernel;
        let run = kw * g.ci;
        let base: [usize; N] = input_offsets(g, q0);
        let mut acc = [*bias; N];
        let mut row = w;
        for dt in 0..kt {
            for dh in 0..kh {
                let off = tap_offset(g, dt, dh);
                for i in 0..run {
                    // Safety: k_t·k_h·k_w·C_in weight rows of 16·R floats.
                    let wv: [__m512; R] = std::array::from_fn(|r| unsafe { _mm512_loadu_ps(row.add(16 * r)) });
                    row = unsafe { row.add(co) };
                    for (a, &bj) in acc.iter_mut().zip(&base) {
                        // Safety: inside the padded input (see check_sizes).
                        let xv = _mm512_set1_ps(unsafe { *x.add(bj + off + i) });
                        for r in 0..R {
                            a[r] = _mm512_fmadd_ps(xv, wv[r], a[r]);
                        }
                    }
                }
            }
        }
        let zero = _mm512_setzero_ps();
        for (j, a) in acc.iter().enumerate() {
            for (r, &lane) in a.iter().enumerate() {
                let v = if g.spec.relu { _mm512_max_ps(lane, zero) } else { lane };
                // Safety: N positions of 16·R floats from `out`.
                unsafe { _mm512_storeu_ps(out.add(j * co + 16 * r), v) };
            }
        }
    }

    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn weight_grad<const R: usize, const P: usize>(
        g: &Geometry,
        xp: &[f32],
        gy: &[f32],
        dw: &mut [f32],
    ) {
        let (x, gy, dw) = (xp.as_ptr(), gy.as_ptr(), dw.as_mut_ptr());
        for_each_block(0..g.to * g.ps(), P, |q0, len| {
            // Safety: as in `forward`.
            unsafe {
                if len == P {
                    grad_block::<R, P>(g, x, gy, dw, q0);
                } else {
                    grad_block::<R, 1>(g, x, gy, dw, q0);
                }
            }
        });
    }

    #[target_feature(enable = "avx512f")]
    unsafe fn grad_block<const R: usize, const N: usize>(
        g: &Geometry,
        x: *const f32,
        gy: *const f32,
        dw: *mut f32,
        q0: usize,
    ) {
        let co = 16 * R;
        let [kt, kh, kw] = g.spec.kernel;
        let run = kw * g.ci;
        let base: [usize; N] = input_offsets(g, q0);
        // Safety: N gradient rows of this block.
        let gr: [[__m512; R]; N] = std::array::from_fn(|j| {
            std::array::from_fn(|r| unsafe { _mm512_loadu_ps(gy.add((q0 + j) * co + 16 * r)) })
        });
        let mut dst = dw;
        for dt in 0..kt {
            for dh in 0..kh {
                let off = tap_offset(g, dt, dh);
                for i in 0..run {
                    // Safety: k_t·k_h·k_w·C_in gradient rows of 16·R floats.
                    let mut acc: [__m512; R] = std::array::from_fn(|r| unsafe { _mm512_loadu_ps(dst.add(16 * r)) });
                    for (gj, &bj) in gr.iter().zip(&base) {
                        // Safety: inside the padded input (see check_sizes).
                        let xv = _mm512_set1_ps(unsafe { *x.add(bj + off + i) });
                        for r in 0..R {
                            acc[r] = _mm512_fmadd_ps(xv, gj[r], acc[r]);
                        }
                    }
                    for (r, a) in acc.iter().enumerate() {
                        // Safety: as above.
                        unsafe { _mm512_storeu_ps(dst.add(16 * r), *a) };
                    }
                    dst = unsafe { dst.add(co) };
                }
            }
        }
    }
}

// Portable kernels (CPUs without AVX-512, and C_out = 8): the same blocks in plain
// Rust, compiled for AVX-512 or AVX2 + FMA when the CPU has them.

/// `a·b + c`, fused when compiled with FMA.
#[inline(always)]
fn mul_add<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

#[inline(always)]
fn portable_forward_impl<const CO: usize, const P: usize, const FMA: bool>(
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
    for_each_block(positions, P, |q0, len| {
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
                            a[c] = mul_add::<FMA>(xv, wr[c], a[c]);
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
    });
}

#[inline(always)]
fn portable_weight_grad_impl<const CO: usize, const P: usize, const FMA: bool>(
    g: &Geometry,
    xp: &[f32],
    gy: &[f32],
    dw: &mut [f32],
) {
    let (grads, _) = gy.as_chunks::<CO>();
    let (dws, _) = dw.as_chunks_mut::<CO>();
    let [kt, kh, kw] = g.spec.kernel;
    let run = kw * g.ci;
    for_each_block(0..g.to * g.ps(), P, |q0, len| {
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
                            acc[c] = mul_add::<FMA>(xv, gj[c], acc[c]);
                        }
                    }
                    *d = acc;
                }
            }
        }
    });
}

multiversioned! {
    /// [`portable_forward_impl`] for the best instruction set of this CPU.
    fn portable_forward_lanes<const CO: usize, const P: usize>(
        g: &Geometry,
        xp: &[f32],
        w: &[f32],
        bias: &[f32],
        y: &mut [f32],
        positions: Range<usize>,
    ) => portable_forward_impl
}

multiversioned! {
    /// [`portable_weight_grad_impl`] for the best instruction set of this CPU.
    fn portable_weight_grad_lanes<const CO: usize, const P: usize>(
        g: &Geometry,
        xp: &[f32],
        gy: &[f32],
        dw: &mut [f32],
    ) => portable_weight_grad_impl
}

fn portable_forward(g: &Geometry, xp: &[f32], w: &[f32], bias: &[f32], y: &mut [f32], positions: Range<usize>) {
    match g.co {
        8 => portable_forward_lanes::<8, 8>(g, xp, w, bias, y, positions),
        16 => portable_forward_lanes::<16, 4>(g, xp, w, bias, y, positions),
        32 => portable_forward_lanes::<32, 2>(g, xp, w, bias, y, positions),
        co => unreachable!("no direct kernel for C_out {co}"),
    }
}

fn portable_weight_grad(g: &Geometry, xp: &[f32], gy: &[f32], dw: &mut [f32]) {
    match g.co {
        8 => portable_weight_grad_lanes::<8, 8>(g, xp, gy, dw),
        16 => portable_weight_grad_lanes::<16, 4>(g, xp, gy, dw),
        32 => portable_weight_grad_lanes::<32, 2>(g, xp, gy, dw),
        co => unreachable!("no direct kernel for C_out {co}"),
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::ops::ConvSpec;

    /// The dispatched kernels (AVX-512 on CPUs that have it) equal the portable ones
    /// for every lane count, one and several input channels, odd row lengths (block
    /// remainders) and ReLU on and off.
    #[test]
    fn dispatched_kernels_equal_the_portable_ones() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for (co, ci, spec, (t, h, w)) in [
            (16, 1, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), (5, 13, 21)),
            (32, 1, ConvSpec::spatiotemporal(2, 1, 3, 1, 1), (3, 7, 11)),
            (32, 16, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), (4, 10, 13)),
            (16, 5, ConvSpec::spatial(4, 2, 2), (1, 9, 10)),
            (8, 2, ConvSpec::spatiotemporal(3, 1, 3, 3, 0), (4, 9, 12)),
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
                let (mut y1, mut y2) = (vec![0.0; g.out_len()], vec![0.0; g.out_len()]);
                let all = 0..g.to * g.ps();
                forward(&g, &xp, &wt, &bias, &mut y1, all.clone());
                portable_forward(&g, &xp, &wt, &bias, &mut y2, all);
                // In uneven chunks of positions (how a single sample is split over threads).
                let mut y3 = vec![0.0; g.out_len()];
                for (i, yc) in y3.chunks_mut(13 * co).enumerate() {
                    let q0 = i * 13;
                    forward(&g, &xp, &wt, &bias, yc, q0..q0 + yc.len() / co);
                }
                assert_eq!(y1, y3, "C_out {co}: chunked forward differs");
                let (mut d1, mut d2) = (vec![0.5; wt.len()], vec![0.5; wt.len()]);
                weight_grad(&g, &xp, &gy, &mut d1);
                portable_weight_grad(&g, &xp, &gy, &mut d2);
                for (what, a, b) in [("output", &y1, &y2), ("weight gradient", &d1, &d2)] {
                    for (u, v) in a.iter().zip(b.iter()) {
                        assert!((u - v).abs() <= 1e-5 * (1.0 + v.abs()), "C_out {co} relu {relu} {what}: {u} vs {v}");
                    }
                }
            }
        }
    }
}
