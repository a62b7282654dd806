//! Direct kernels for convolutions with one input channel (the 3D-TCN's first layer).
//!
//! With C_in = 1 the column matrix has only k_t·k_h·k_w columns, so im2col + gemm
//! mostly moves memory (measured 14–19 GFLOP/s there, against 60–120 on the other
//! layers). Here an output position is Σ_taps x_tap · W_tap over its C_out lanes:
//! one broadcast and C_out/16 fused multiply-adds per tap, accumulators in registers.
//! Positions go in blocks of P along the output row, each an independent chain (a
//! single chain waits on the FMA latency at every tap) sharing each weight load.
//!
//! Invariant: every function here computes exactly the convolution of the parent
//! module (forward: bias, taps and ReLU; weight gradient: Σ over positions of
//! x_tap · gy) for the geometry it is given; the AVX-512 kernels and the portable
//! ones agree (unit test below), and the parent's tests check both against candle's
//! `conv2d` and finite differences. Frames are zero-padded once per sample
//! ([`pad_frames`]), so no kernel has bounds logic for the padding.

use super::Geometry;

/// C_out values with a direct kernel.
pub(super) const LANES: [usize; 4] = [8, 16, 32, 64];

/// Copy one sample's frames (T, H, W) into `xp` (T, H + 2p_h, W + 2p_w) with zero borders.
pub(super) fn pad_frames(g: &Geometry, x: &[f32], xp: &mut [f32]) {
    let (hp, wp) = g.padded();
    let [ph, pw] = g.spec.padding;
    xp.fill(0.0);
    for (t, frame) in x.chunks_exact(g.h * g.w).enumerate() {
        for (h, row) in frame.chunks_exact(g.w).enumerate() {
            let dst = (t * hp + h + ph) * wp + pw;
            xp[dst..dst + g.w].copy_from_slice(row);
        }
    }
}

/// Check once per sample that every index the kernels compute is in bounds.
fn check_sizes(g: &Geometry, xp: &[f32], w: &[f32], y_or_gy: &[f32]) {
    let taps: usize = g.spec.kernel.iter().product();
    assert!(xp.len() >= g.padded_len(), "padded frames too short");
    assert!(w.len() >= taps * g.co, "weights too short");
    assert!(y_or_gy.len() >= g.out_len(), "output too short");
    // The furthest input a kernel reads lies inside the padded frames because the
    // output size came from `ConvSpec::output_size` of the same geometry.
    debug_assert!(g.spec.output_size(g.t, g.h, g.w) == Some((g.to, g.ho, g.wo)));
}

/// Forward of one sample from its padded frames: y (T_out·H_out·W_out, C_out).
pub(super) fn forward(g: &Geometry, xp: &[f32], w: &[f32], bias: &[f32], y: &mut [f32]) {
    check_sizes(g, xp, w, y);
    assert_eq!(bias.len(), g.co, "bias has C_out entries");
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        // Safety: the CPU has AVX-512F; sizes were checked above.
        unsafe {
            match g.co {
                16 => return avx512::forward::<1, 8>(g, xp, w, bias, y),
                32 => return avx512::forward::<2, 4>(g, xp, w, bias, y),
                64 => return avx512::forward::<4, 2>(g, xp, w, bias, y),
                _ => {}
            }
        }
    }
    portable_forward(g, xp, w, bias, y);
}

/// dW (k_t·k_h·k_w, C_out) += Σ_positions x_tap · gy of one sample (gy already
/// masked by the ReLU).
pub(super) fn weight_grad(g: &Geometry, xp: &[f32], gy: &[f32], dw: &mut [f32]) {
    check_sizes(g, xp, dw, gy);
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") {
        // Safety: the CPU has AVX-512F; sizes were checked above.
        unsafe {
            match g.co {
                16 => return avx512::weight_grad::<1, 8>(g, xp, gy, dw),
                32 => return avx512::weight_grad::<2, 4>(g, xp, gy, dw),
                64 => return avx512::weight_grad::<4, 2>(g, xp, gy, dw),
                _ => {}
            }
        }
    }
    portable_weight_grad(g, xp, gy, dw);
}

/// Visit the blocks of one sample: `f(to, ho, wo0, len)` with `len` = `p` or 1 (the
/// row's remainder).
#[inline(always)]
fn for_each_block(g: &Geometry, p: usize, mut f: impl FnMut(usize, usize, usize, usize)) {
    for to in 0..g.to {
        for ho in 0..g.ho {
            let mut wo = 0;
            while wo + p <= g.wo {
                f(to, ho, wo, p);
                wo += p;
            }
            for wo in wo..g.wo {
                f(to, ho, wo, 1);
            }
        }
    }
}

/// Offset in the padded frames of tap (dt, dh, 0) for output position (to, ho, wo).
#[inline(always)]
fn tap_row(g: &Geometry, to: usize, ho: usize, wo: usize, dt: usize, dh: usize) -> usize {
    let (hp, wp) = g.padded();
    ((to + dt * g.spec.dilation_t) * hp + ho * g.spec.stride[0] + dh) * wp + wo * g.spec.stride[1]
}

#[cfg(target_arch = "x86_64")]
mod avx512 {
    //! AVX-512 kernels: C_out = 16·R lanes, blocks of P positions.
    use std::arch::x86_64::{
        __m512, _mm512_fmadd_ps, _mm512_loadu_ps, _mm512_max_ps, _mm512_set1_ps, _mm512_setzero_ps, _mm512_storeu_ps,
    };

    use super::{Geometry, for_each_block, tap_row};

    /// Safety (every function here): AVX-512F available; slices sized as checked by
    /// `check_sizes`, with C_out = 16·R.
    #[target_feature(enable = "avx512f")]
    pub(super) unsafe fn forward<const R: usize, const P: usize>(
        g: &Geometry,
        xp: &[f32],
        w: &[f32],
        bias: &[f32],
        y: &mut [f32],
    ) {
        let co = 16 * R;
        let [kt, kh, kw] = g.spec.kernel;
        let sw = g.spec.stride[1];
        let relu = g.spec.relu;
        let (x, w, y) = (xp.as_ptr(), w.as_ptr(), y.as_mut_ptr());
        // Safety: bias has 16·R entries.
        let b: [__m512; R] = std::array::from_fn(|r| unsafe { _mm512_loadu_ps(bias.as_ptr().add(16 * r)) });
        for_each_block(g, P, |to, ho, wo0, len| {
            let out = ((to * g.ho + ho) * g.wo + wo0) * co;
            // Safety: positions wo0..wo0+len of this row and their taps are in bounds.
            unsafe {
                if len == P {
                    block::<R, P>(g, x, w, &b, to, ho, wo0, kt, kh, kw, sw, relu, y.add(out));
                } else {
                    block::<R, 1>(g, x, w, &b, to, ho, wo0, kt, kh, kw, sw, relu, y.add(out));
                }
            }
        });
    }

    #[target_feature(enable = "avx512f")]
    #[allow(clippy::too_many_arguments)]
    unsafe fn block<const R: usize, const N: usize>(
        g: &Geometry,
        x: *const f32,
        w: *const f32,
        bias: &[__m512; R],
        to: usize,
        ho: usize,
        wo0: usize,
        kt: usize,
        kh: usize,
        kw: usize,
        sw: usize,
        relu: bool,
        out: *mut f32,
    ) {
        let co = 16 * R;
        let mut acc = [*bias; N];
        let mut tap = 0;
        for dt in 0..kt {
            for dh in 0..kh {
                let row = tap_row(g, to, ho, wo0, dt, dh);
                for dx in 0..kw {
                    // Safety: tap < k_t·k_h·k_w weight rows of 16·R floats.
                    let wv: [__m512; R] = std::array::from_fn(|r| unsafe { _mm512_loadu_ps(w.add(tap * co + 16 * r)) });
                    for (j, a) in acc.iter_mut().enumerate() {
                        // Safety: inside the padded frames (see check_sizes).
                        let xv = _mm512_set1_ps(unsafe { *x.add(row + j * sw + dx) });
                        for r in 0..R {
                            a[r] = _mm512_fmadd_ps(xv, wv[r], a[r]);
                        }
                    }
                    tap += 1;
                }
            }
        }
        let zero = _mm512_setzero_ps();
        for (j, a) in acc.iter().enumerate() {
            for (r, &lane) in a.iter().enumerate() {
                let v = if relu { _mm512_max_ps(lane, zero) } else { lane };
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
        for_each_block(g, P, |to, ho, wo0, len| {
            // Safety: as in `forward`.
            unsafe {
                if len == P {
                    grad_block::<R, P>(g, x, gy, dw, to, ho, wo0);
                } else {
                    grad_block::<R, 1>(g, x, gy, dw, to, ho, wo0);
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
        to: usize,
        ho: usize,
        wo0: usize,
    ) {
        let co = 16 * R;
        let [kt, kh, kw] = g.spec.kernel;
        let sw = g.spec.stride[1];
        let first = ((to * g.ho + ho) * g.wo + wo0) * co;
        // Safety: N gradient rows of this block.
        let gr: [[__m512; R]; N] = std::array::from_fn(|j| {
            std::array::from_fn(|r| unsafe { _mm512_loadu_ps(gy.add(first + j * co + 16 * r)) })
        });
        let mut tap = 0;
        for dt in 0..kt {
            for dh in 0..kh {
                let row = tap_row(g, to, ho, wo0, dt, dh);
                for dx in 0..kw {
                    // Safety: tap < k_t·k_h·k_w gradient rows of 16·R floats.
                    let dst = unsafe { dw.add(tap * co) };
                    let mut acc: [__m512; R] = std::array::from_fn(|r| unsafe { _mm512_loadu_ps(dst.add(16 * r)) });
                    for (j, gj) in gr.iter().enumerate() {
                        // Safety: inside the padded frames (see check_sizes).
                        let xv = _mm512_set1_ps(unsafe { *x.add(row + j * sw + dx) });
                        for r in 0..R {
                            acc[r] = _mm512_fmadd_ps(xv, gj[r], acc[r]);
                        }
                    }
                    for (r, a) in acc.iter().enumerate() {
                        // Safety: as above.
                        unsafe { _mm512_storeu_ps(dst.add(16 * r), *a) };
                    }
                    tap += 1;
                }
            }
        }
    }
}

// Portable kernels (CPUs without AVX-512, and C_out = 8): the same blocks in plain
// Rust, compiled for AVX2 + FMA when the CPU has them.

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
) {
    let (taps, _) = w.as_chunks::<CO>();
    let bias: [f32; CO] = bias.try_into().expect("bias has C_out entries");
    let (outs, _) = y.as_chunks_mut::<CO>();
    let [kt, kh, kw] = g.spec.kernel;
    let sw = g.spec.stride[1];
    for_each_block(g, P, |to, ho, wo0, len| {
        let mut acc = [bias; P];
        let mut tap = taps.iter();
        for dt in 0..kt {
            for dh in 0..kh {
                let row = &xp[tap_row(g, to, ho, wo0, dt, dh)..];
                for dx in 0..kw {
                    let wr = tap.next().expect("k_t·k_h·k_w weight rows");
                    for (j, a) in acc[..len].iter_mut().enumerate() {
                        let xv = row[j * sw + dx];
                        for c in 0..CO {
                            a[c] = mul_add::<FMA>(xv, wr[c], a[c]);
                        }
                    }
                }
            }
        }
        let first = (to * g.ho + ho) * g.wo + wo0;
        for (o, a) in outs[first..first + len].iter_mut().zip(&acc) {
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
    let sw = g.spec.stride[1];
    for_each_block(g, P, |to, ho, wo0, len| {
        let first = (to * g.ho + ho) * g.wo + wo0;
        let gr = &grads[first..first + len];
        let mut tap = dws.iter_mut();
        for dt in 0..kt {
            for dh in 0..kh {
                let row = &xp[tap_row(g, to, ho, wo0, dt, dh)..];
                for dx in 0..kw {
                    let dst = tap.next().expect("k_t·k_h·k_w gradient rows");
                    let mut acc = *dst;
                    for (j, gj) in gr.iter().enumerate() {
                        let xv = row[j * sw + dx];
                        for c in 0..CO {
                            acc[c] = mul_add::<FMA>(xv, gj[c], acc[c]);
                        }
                    }
                    *dst = acc;
                }
            }
        }
    });
}

/// Define `$name::<CO, P>`, which runs `$imp::<CO, P, FMA>` compiled for AVX2 + FMA
/// when the CPU has them (checked at run time), and for the baseline otherwise.
macro_rules! avx2_or_baseline {
    ($name:ident($($arg:ident: $ty:ty),*) => $imp:ident) => {
        fn $name<const CO: usize, const P: usize>($($arg: $ty),*) {
            #[cfg(target_arch = "x86_64")]
            {
                #[target_feature(enable = "avx2,fma")]
                fn v3<const CO: usize, const P: usize>($($arg: $ty),*) {
                    $imp::<CO, P, true>($($arg),*)
                }
                if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma") {
                    // Safety: the CPU supports every feature `v3` is compiled with.
                    return unsafe { v3::<CO, P>($($arg),*) };
                }
            }
            $imp::<CO, P, false>($($arg),*)
        }
    };
}

avx2_or_baseline!(portable_forward_lanes(g: &Geometry, xp: &[f32], w: &[f32], bias: &[f32], y: &mut [f32]) => portable_forward_impl);
avx2_or_baseline!(portable_weight_grad_lanes(g: &Geometry, xp: &[f32], gy: &[f32], dw: &mut [f32]) => portable_weight_grad_impl);

fn portable_forward(g: &Geometry, xp: &[f32], w: &[f32], bias: &[f32], y: &mut [f32]) {
    match g.co {
        8 => portable_forward_lanes::<8, 8>(g, xp, w, bias, y),
        16 => portable_forward_lanes::<16, 4>(g, xp, w, bias, y),
        32 => portable_forward_lanes::<32, 2>(g, xp, w, bias, y),
        64 => portable_forward_lanes::<64, 1>(g, xp, w, bias, y),
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

    /// The dispatched kernels (AVX-512 on CPUs that have it) equal the portable ones
    /// for every lane count, odd row lengths (block remainders) and ReLU on and off.
    #[test]
    fn dispatched_kernels_equal_the_portable_ones() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for (co, spec, (t, h, w)) in [
            (16, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), (5, 13, 21)),
            (32, ConvSpec::spatiotemporal(2, 1, 3, 1, 1), (3, 7, 11)),
            (64, ConvSpec::spatial(4, 2, 2), (1, 9, 10)),
            (8, ConvSpec::spatiotemporal(3, 1, 3, 3, 0), (4, 9, 12)),
        ] {
            for relu in [false, true] {
                let spec = ConvSpec { relu, ..spec };
                let g = Geometry::new(spec, &[1, t, h, w, 1], &[spec.weight_rows(1), co]).unwrap();
                let mut rand_vec = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
                let x = rand_vec(g.in_len());
                let wt = rand_vec(spec.weight_rows(1) * co);
                let bias = rand_vec(co);
                let gy = rand_vec(g.out_len());
                let mut xp = vec![0.0; g.padded_len()];
                pad_frames(&g, &x, &mut xp);
                let (mut y1, mut y2) = (vec![0.0; g.out_len()], vec![0.0; g.out_len()]);
                forward(&g, &xp, &wt, &bias, &mut y1);
                portable_forward(&g, &xp, &wt, &bias, &mut y2);
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
