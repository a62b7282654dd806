//! Mixed-precision (bf16 × bf16 → f32) variants of the direct convolution kernels
//! (forward, weight and input gradients), for CPUs with AVX-512 BF16
//! (`ConvSpec::bf16`).
//!
//! `vdpbf16ps` multiplies 16 pairs of bf16 values per lane group and adds both
//! products to 16 f32 accumulators: twice the multiply-adds of an f32 fused
//! multiply-add per instruction, at the same throughput on Zen 4. Each kernel here
//! is its f32 counterpart in [`super::direct`] with the reduction taken two terms
//! at a time:
//! - forward: pairs of consecutive taps (inside one run of k_w·C_in inputs, so the
//!   pair is two adjacent bf16 values of the padded input, one 32-bit broadcast)
//!   against weights packed as (tap pair, C_out, 2);
//! - input gradient: pairs of consecutive output channels (two adjacent bf16 values
//!   of the output-gradient row) against Wᵀ packed as (channel pair, tap, 2);
//! - weight gradient: pairs of neighbouring output positions of one output row
//!   (w_out, w_out + 1), whose inputs for any tap lie s_w·C_in apart: the padded
//!   input is packed once per sample with each value beside the one s_w·C_in
//!   further ([`pair_positions`]) and the output gradient as (position pair, C_out,
//!   2) ([`pair_gradients`]); a row of odd length pairs its last position with a
//!   zero gradient.
//!
//! Inputs, weights and output gradients are rounded to bf16 (nearest even, as
//! `vcvtneps2bf16`, subnormals to zero); every sum, the bias, the ReLU, the padded
//! input gradient and the weight gradient stay f32.
//!
//! Length: one kernel family that reads top to bottom (over the project's 600-line
//! limit on purpose, like [`super::direct`]): the conditions, the bf16 layouts
//! (rounding, padding, packed weights, position pairs), the entry points, then the
//! vector kernels that read exactly those layouts; split, a layout and the kernel
//! indexing it would sit in different files.
//!
//! Invariant: for the geometry it is given, each function computes the same sums as
//! its f32 counterpart with every factor rounded to bf16 ([`to_bf16`]); the unit
//! tests check them against the f32 kernels run on bf16-rounded data. A layer takes
//! these kernels only where [`forward_supported`] (forward, weight gradient) and
//! [`input_grad_supported`] (input gradient) hold; the rest stays f32.

use std::ops::Range;

use super::{Geometry, direct};
use crate::ops::Isa;

/// Whether this CPU has AVX-512 BF16 (with AVX-512F and BW, which the kernels also use).
pub fn cpu_has_bf16() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512bw")
            && std::arch::is_x86_feature_detected!("avx512bf16")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether `ConvPrecision::Bf16` can run in this process: the CPU has AVX-512 BF16
/// and the active instruction-set path is `avx512` (a forced narrower path keeps
/// f32, so asking for bf16 there is refused rather than silently ignored).
pub fn bf16_available() -> bool {
    Isa::active() == Isa::Avx512 && cpu_has_bf16()
}

/// Whether the bf16 forward takes this layer on `isa`: bf16 asked for, the CPU
/// has it on the `avx512` path, C_out a whole number of 16-lane tiles, and runs of
/// k_w·C_in inputs of even length (so tap pairs never straddle two runs).
pub(super) fn forward_supported(g: &Geometry, isa: Isa) -> bool {
    g.spec.bf16
        && isa == Isa::Avx512
        && cpu_has_bf16()
        && matches!(g.co, 16 | 32 | 64)
        && (g.spec.kernel[2] * g.ci).is_multiple_of(2)
}

/// Whether the bf16 input gradient takes this layer on `isa`: the forward's
/// conditions and those of the f32 direct input gradient (tiles of 32 taps).
pub(super) fn input_grad_supported(g: &Geometry, isa: Isa) -> bool {
    forward_supported(g, isa) && direct::input_grad_supported(g, isa)
}

/// `v` rounded to bf16 (nearest, ties to even), as `vcvtneps2bf16` does: NaN stays
/// a quiet NaN, subnormals become zero of the same sign.
pub(super) fn to_bf16(v: f32) -> u16 {
    let bits = v.to_bits();
    if v.is_nan() {
        return ((bits >> 16) | 0x40) as u16;
    }
    if bits & 0x7f80_0000 == 0 {
        return ((bits >> 16) & 0x8000) as u16;
    }
    let round = 0x7fff + ((bits >> 16) & 1);
    ((bits + round) >> 16) as u16
}

/// `dst[i] = to_bf16(src[i])` (vectorised where the CPU has AVX-512 BF16).
pub(super) fn convert(src: &[f32], dst: &mut [u16]) {
    assert!(dst.len() >= src.len(), "bf16 destination too short");
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has the features (checked); lengths checked above.
    let done = if cpu_has_bf16() { unsafe { vector::convert(src, dst) } } else { 0 };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    for (d, &s) in dst[done..].iter_mut().zip(&src[done..]) {
        *d = to_bf16(s);
    }
}

/// [`direct::pad_frames`] into bf16: one sample's input (T, H, W, C_in) as
/// (T, H + 2p_h, W + 2p_w, C_in) bf16 values with zero borders; every element of
/// `xp[..padded_len]` is written.
pub(super) fn pad_frames(g: &Geometry, x: &[f32], xp: &mut [u16]) {
    direct::pad_frames_with(g, x, xp, 0, convert);
}

/// Forward weights W (K, C_out) as bf16 pairs of consecutive taps: element
/// `(m·C_out + o)·2 + s` is W[2m + s, o] (K is even where the forward is supported).
pub(super) fn pack_forward_weights(g: &Geometry, w: &[f32]) -> Vec<u16> {
    let (k, co) = (g.spec.weight_rows(g.ci), g.co);
    assert!(k.is_multiple_of(2) && w.len() >= k * co, "forward weights: K even, K·C_out floats");
    let mut packed = vec![0u16; k * co];
    for (m, rows) in w[..k * co].chunks_exact(2 * co).enumerate() {
        let (even, odd) = rows.split_at(co);
        let out = &mut packed[m * 2 * co..(m + 1) * 2 * co];
        for (o, pair) in out.chunks_exact_mut(2).enumerate() {
            pair[0] = to_bf16(even[o]);
            pair[1] = to_bf16(odd[o]);
        }
    }
    packed
}

/// Wᵀ for the input gradient as bf16 pairs of consecutive output channels: element
/// `(p·K + k)·2 + s` is W[k, 2p + s] (C_out is even where the kernel is supported).
pub(super) fn pack_input_grad_weights(g: &Geometry, w: &[f32]) -> Vec<u16> {
    let (k, co) = (g.spec.weight_rows(g.ci), g.co);
    assert!(co.is_multiple_of(2) && w.len() >= k * co, "input-gradient weights: C_out even, K·C_out floats");
    let mut packed = vec![0u16; k * co];
    for (tap, row) in w[..k * co].chunks_exact(co).enumerate() {
        for (p, pair) in row.chunks_exact(2).enumerate() {
            let at = (p * k + tap) * 2;
            packed[at] = to_bf16(pair[0]);
            packed[at + 1] = to_bf16(pair[1]);
        }
    }
    packed
}

/// Forward of output positions `positions` of one sample from its bf16 padded
/// input ([`pad_frames`]) and packed weights ([`pack_forward_weights`]):
/// y (positions.len(), C_out) in f32, bias and ReLU applied.
pub(super) fn forward(
    g: &Geometry,
    isa: Isa,
    xp: &[u16],
    wp: &[u16],
    bias: &[f32],
    y: &mut [f32],
    positions: Range<usize>,
) {
    assert!(forward_supported(g, isa), "no bf16 forward for this layer on {isa}");
    assert!(xp.len() >= g.padded_len(), "padded frames too short");
    assert!(wp.len() >= g.spec.weight_rows(g.ci) * g.co, "packed weights too short");
    assert!(positions.end <= g.to * g.ps() && y.len() >= positions.len() * g.co, "output too short");
    assert_eq!(bias.len(), g.co, "bias has C_out entries");
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX-512 BF16 (forward_supported); sizes checked above.
    // Tiles as the f32 AVX-512 forward: P·R accumulators + R weight vectors + one
    // broadcast fit the 32 registers.
    unsafe {
        match g.co {
            16 => vector::forward::<1, 8>(g, xp, wp, bias, y, positions),
            32 => vector::forward::<2, 4>(g, xp, wp, bias, y, positions),
            64 => vector::forward::<4, 6>(g, xp, wp, bias, y, positions),
            co => unreachable!("forward_supported admits C_out {co}"),
        }
    }
}

/// dxp (padded f32, as [`direct::pad_frames`]) += the input gradient of one sample
/// from its bf16 output gradient `gy` (rows of C_out) and the packed Wᵀ
/// ([`pack_input_grad_weights`]).
pub(super) fn input_grad(g: &Geometry, isa: Isa, wtp: &[u16], gy: &[u16], dxp: &mut [f32]) {
    assert!(input_grad_supported(g, isa), "no bf16 input gradient for this layer on {isa}");
    assert!(dxp.len() >= g.padded_len(), "padded input gradient too short");
    assert!(wtp.len() >= g.spec.weight_rows(g.ci) * g.co, "packed weights too short");
    assert!(gy.len() >= g.out_len(), "output gradient too short");
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX-512 BF16 (input_grad_supported); sizes checked above.
    unsafe {
        vector::input_grad::<2, 12>(g, wtp, gy, dxp)
    }
}

/// Position pairs (slots) of one sample's output: ⌈W_out / 2⌉ per output row.
fn slots(g: &Geometry) -> usize {
    g.to * g.ho * g.wo.div_ceil(2)
}

/// bf16 values of [`pair_positions`]' output for one sample (2 per padded input value).
pub(super) fn paired_input_len(g: &Geometry) -> usize {
    2 * g.padded_len()
}

/// bf16 values of [`pair_gradients`]' output for one sample.
pub(super) fn paired_gradient_len(g: &Geometry) -> usize {
    2 * slots(g) * g.co
}

/// The padded f32 input `xp` ([`direct::pad_frames`]) as bf16 pairs: element
/// `2e + s` is xp[e + s·s_w·C_in] (zero past the end), so the pair at a tap's
/// offset from position (t, h, w)'s first input holds that tap's input of (t, h, w)
/// and of (t, h, w + 1).
pub(super) fn pair_positions(g: &Geometry, xp: &[f32], out: &mut [u16]) {
    let (n, d) = (g.padded_len(), g.spec.stride[1] * g.ci);
    assert!(xp.len() >= n && out.len() >= 2 * n, "paired input: sizes");
    // The vector kernel takes whole blocks of 16 whose partners are all inside; the
    // rest (and every value on other CPUs) here.
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has the features (checked); sizes checked above.
    let done = if cpu_has_bf16() { unsafe { vector::pair_shifted(&xp[..n], d, out) } } else { 0 };
    #[cfg(not(target_arch = "x86_64"))]
    let done = 0;
    for e in done..n {
        out[2 * e] = to_bf16(xp[e]);
        out[2 * e + 1] = if e + d < n { to_bf16(xp[e + d]) } else { 0 };
    }
}

/// The f32 output gradient (rows of C_out) as bf16 position pairs: element
/// `(slot·C_out + o)·2 + s` is gy[q + s, o] for the slot's first position q, or
/// zero where the row has no position q + 1.
pub(super) fn pair_gradients(g: &Geometry, gy: &[f32], out: &mut [u16]) {
    let co = g.co;
    assert!(gy.len() >= g.out_len() && out.len() >= paired_gradient_len(g), "paired gradient: sizes");
    #[cfg(target_arch = "x86_64")]
    let simd = cpu_has_bf16() && co.is_multiple_of(16);
    let mut slot = 0;
    for row in gy[..g.out_len()].chunks_exact(g.wo * co) {
        for pair in row.chunks(2 * co) {
            let (first, second) = pair.split_at(co);
            let dst = &mut out[slot * 2 * co..(slot + 1) * 2 * co];
            #[cfg(target_arch = "x86_64")]
            if simd {
                // SAFETY: the CPU has the features (checked); `first` and `dst` hold C_out
                // and 2·C_out values, `second` C_out or none.
                unsafe { vector::interleave(first, second, dst) };
                slot += 1;
                continue;
            }
            for (o, d) in dst.chunks_exact_mut(2).enumerate() {
                d[0] = to_bf16(first[o]);
                d[1] = second.get(o).map_or(0, |&v| to_bf16(v));
            }
            slot += 1;
        }
    }
}

/// dW (K, C_out) += Σ over position pairs of the paired inputs times the paired
/// gradients of one sample ([`pair_positions`], [`pair_gradients`]), in f32.
pub(super) fn weight_grad(g: &Geometry, isa: Isa, xs: &[u16], gys: &[u16], dw: &mut [f32]) {
    assert!(forward_supported(g, isa), "no bf16 weight gradient for this layer on {isa}");
    assert!(xs.len() >= paired_input_len(g), "paired input too short");
    assert!(gys.len() >= paired_gradient_len(g), "paired gradient too short");
    assert!(dw.len() >= g.spec.weight_rows(g.ci) * g.co, "weight gradient too short");
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AVX-512 BF16 (forward_supported); sizes checked above.
    // Tiles as the f32 AVX-512 weight gradient: T taps × R vectors of dW.
    unsafe {
        match g.co {
            16 => vector::weight_grad::<1, 16>(g, xs, gys, dw),
            32 => vector::weight_grad::<2, 12>(g, xs, gys, dw),
            64 => vector::weight_grad::<4, 6>(g, xs, gys, dw),
            co => unreachable!("forward_supported admits C_out {co}"),
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod vector {
    //! The AVX-512 BF16 kernels. Same structure as the f32 ones: plain loops over
    //! `#[inline(always)]` functions below `#[target_feature]` entry points.
    use std::arch::x86_64::{
        __m256bh, __m512, __m512bh, __m512i, _mm512_add_ps, _mm512_cvtne2ps_pbh, _mm512_cvtneps_pbh, _mm512_dpbf16_ps,
        _mm512_loadu_ps, _mm512_loadu_si512, _mm512_max_ps, _mm512_permutexvar_epi16, _mm512_set1_epi32,
        _mm512_setzero_ps, _mm512_storeu_ps, _mm512_storeu_si512,
    };
    use std::ops::Range;

    use super::super::Geometry;
    use super::super::direct::{input_offsets, tap_offset};

    /// 32 bf16 values from `p` (unaligned).
    #[inline(always)]
    unsafe fn load_pairs(p: *const u16) -> __m512bh {
        // SAFETY: the caller guarantees 32 readable values; same-size bit cast.
        unsafe { std::mem::transmute::<__m512i, __m512bh>(_mm512_loadu_si512(p.cast())) }
    }

    /// The two bf16 values at `p` (p[0] in the low half) in every lane.
    #[inline(always)]
    unsafe fn splat_pair(p: *const u16) -> __m512bh {
        // SAFETY: the caller guarantees 2 readable values; same-size bit cast.
        unsafe {
            let pair = p.cast::<u32>().read_unaligned();
            std::mem::transmute::<__m512i, __m512bh>(_mm512_set1_epi32(pair as i32))
        }
    }

    /// `super::convert` of the whole blocks of 16 values; returns how many it converted.
    #[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
    pub(super) unsafe fn convert(src: &[f32], dst: &mut [u16]) -> usize {
        let whole = src.len() / 16 * 16;
        // SAFETY: 16 floats read and 16 values written per step, inside both slices.
        unsafe {
            for i in (0..whole).step_by(16) {
                let v = _mm512_cvtneps_pbh(_mm512_loadu_ps(src.as_ptr().add(i)));
                dst.as_mut_ptr()
                    .add(i)
                    .cast::<[u16; 16]>()
                    .write_unaligned(std::mem::transmute::<__m256bh, [u16; 16]>(v));
            }
        }
        whole
    }

    /// 0, 16, 1, 17, …: interleaves the two halves of a 32-value vector.
    static INTERLEAVE: [u16; 32] = {
        let mut idx = [0u16; 32];
        let mut j = 0;
        while j < 16 {
            idx[2 * j] = j as u16;
            idx[2 * j + 1] = 16 + j as u16;
            j += 1;
        }
        idx
    };

    /// bf16 of 16 floats from `lo` and 16 from `hi` (`None`: zeros), interleaved
    /// (lo₀, hi₀, lo₁, hi₁, …) into `dst`.
    #[inline(always)]
    unsafe fn interleave16(lo: *const f32, hi: Option<*const f32>, dst: *mut u16) {
        // SAFETY: 16 readable floats at `lo` (and `hi`), 32 writable values at `dst`;
        // the caller has the target features.
        unsafe {
            let l = _mm512_loadu_ps(lo);
            let h = match hi {
                Some(p) => _mm512_loadu_ps(p),
                None => _mm512_setzero_ps(),
            };
            let halves = std::mem::transmute::<__m512bh, __m512i>(_mm512_cvtne2ps_pbh(h, l));
            let idx = _mm512_loadu_si512(INTERLEAVE.as_ptr().cast());
            _mm512_storeu_si512(dst.cast(), _mm512_permutexvar_epi16(idx, halves));
        }
    }

    #[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
    pub(super) unsafe fn interleave(first: &[f32], second: &[f32], dst: &mut [u16]) {
        let co = first.len();
        // SAFETY: C_out is a multiple of 16; `second` is empty or C_out long; `dst`
        // holds 2·C_out values.
        unsafe {
            for c in (0..co).step_by(16) {
                let hi = if second.is_empty() { None } else { Some(second.as_ptr().add(c)) };
                interleave16(first.as_ptr().add(c), hi, dst.as_mut_ptr().add(2 * c));
            }
        }
    }

    /// The pairs of `super::pair_positions` for the whole blocks of 16 values whose
    /// partners (e + d) all lie inside `xp`; returns how many values it paired.
    #[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
    pub(super) unsafe fn pair_shifted(xp: &[f32], d: usize, out: &mut [u16]) -> usize {
        let n = xp.len();
        let whole = if n >= d + 16 { (n - d) / 16 * 16 } else { 0 };
        // SAFETY: e + 16 ≤ whole ≤ n − d, so both loads are inside `xp`; `out` holds 2n.
        unsafe {
            for e in (0..whole).step_by(16) {
                interleave16(xp.as_ptr().add(e), Some(xp.as_ptr().add(e + d)), out.as_mut_ptr().add(2 * e));
            }
        }
        whole
    }

    /// Position pairs per chunk of the weight gradient (the chunk's paired gradient
    /// rows stay in the L1 cache while every tile of taps passes over them).
    const SLOT_CHUNK: usize = 64;

    #[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
    pub(super) unsafe fn weight_grad<const R: usize, const T: usize>(
        g: &Geometry,
        xs: &[u16],
        gys: &[u16],
        dw: &mut [f32],
    ) {
        let co = g.co;
        assert_eq!(co, 16 * R, "one tile of R vectors covers C_out");
        let [kt, kh, kw] = g.spec.kernel;
        let run = kw * g.ci;
        let taps = kt * kh * run;
        let mut tap_offsets = Vec::with_capacity(taps);
        for dt in 0..kt {
            for dh in 0..kh {
                let off = tap_offset(g, dt, dh);
                tap_offsets.extend((0..run).map(|i| off + i));
            }
        }
        // The first position's input offset of every slot.
        let mut bases = Vec::with_capacity(super::slots(g));
        for row in 0..g.to * g.ho {
            for w0 in (0..g.wo).step_by(2) {
                let [first]: [usize; 1] = input_offsets(g, row * g.wo + w0);
                bases.push(first);
            }
        }
        let (x, gy, dw) = (xs.as_ptr(), gys.as_ptr(), dw.as_mut_ptr());
        // SAFETY: every slot's paired inputs at every tap lie inside the paired input
        // (2 values per padded input value); slot rows of 2·C_out values; K rows of dW.
        unsafe {
            for (chunk, chunk_bases) in bases.chunks(SLOT_CHUNK).enumerate() {
                let s0 = chunk * SLOT_CHUNK;
                let mut k0 = 0;
                while k0 < taps {
                    let tile = T.min(taps - k0);
                    let mut offs = [0usize; T];
                    for (u, o) in offs.iter_mut().enumerate().take(tile) {
                        *o = 2 * tap_offsets[k0 + u];
                    }
                    let mut acc = [[_mm512_setzero_ps(); R]; T];
                    let mut grow = gy.add(s0 * 2 * co);
                    for &b in chunk_bases {
                        let mut gv = [std::mem::transmute::<__m512, __m512bh>(_mm512_setzero_ps()); R];
                        for (r, v) in gv.iter_mut().enumerate() {
                            *v = load_pairs(grow.add(32 * r));
                        }
                        grow = grow.add(2 * co);
                        let xb = x.add(2 * b);
                        for u in 0..T {
                            let xv = splat_pair(xb.add(offs[u]));
                            for r in 0..R {
                                acc[u][r] = _mm512_dpbf16_ps(acc[u][r], xv, gv[r]);
                            }
                        }
                    }
                    for (u, a) in acc.iter().enumerate().take(tile) {
                        let dst = dw.add((k0 + u) * co);
                        for (r, &v) in a.iter().enumerate() {
                            let p = dst.add(16 * r);
                            _mm512_storeu_ps(p, _mm512_add_ps(v, _mm512_loadu_ps(p)));
                        }
                    }
                    k0 += tile;
                }
            }
        }
    }

    #[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
    pub(super) unsafe fn forward<const R: usize, const P: usize>(
        g: &Geometry,
        xp: &[u16],
        wp: &[u16],
        bias: &[f32],
        y: &mut [f32],
        positions: Range<usize>,
    ) {
        let co = g.co;
        assert_eq!(co, 16 * R, "one tile of R vectors covers C_out");
        let (x, w, out) = (xp.as_ptr(), wp.as_ptr(), y.as_mut_ptr());
        let (first, end) = (positions.start, positions.end);
        // SAFETY: positions q..q+P (or q) and their taps are in bounds (checked by
        // the caller); the tile covers every channel.
        unsafe {
            let mut b = [_mm512_setzero_ps(); R];
            for (r, v) in b.iter_mut().enumerate() {
                *v = _mm512_loadu_ps(bias.as_ptr().add(16 * r));
            }
            let mut q = first;
            while q < end {
                let dst = out.add((q - first) * co);
                if q + P <= end {
                    block::<R, P>(g, x, w, &b, q, dst);
                    q += P;
                } else {
                    block::<R, 1>(g, x, w, &b, q, dst);
                    q += 1;
                }
            }
        }
    }

    /// y of output positions q0 .. q0 + N (all C_out = 16·R channels).
    #[inline(always)]
    unsafe fn block<const R: usize, const N: usize>(
        g: &Geometry,
        x: *const u16,
        w: *const u16,
        bias: &[__m512; R],
        q0: usize,
        out: *mut f32,
    ) {
        let co = g.co;
        let [kt, kh, kw] = g.spec.kernel;
        let run = kw * g.ci;
        let base: [usize; N] = input_offsets(g, q0);
        let mut acc = [*bias; N];
        let mut row = w;
        // SAFETY: K/2 packed rows of 2·C_out values; every input pair lies inside the
        // padded input (the output size came from the same geometry).
        unsafe {
            for dt in 0..kt {
                for dh in 0..kh {
                    let off = tap_offset(g, dt, dh);
                    let mut i = 0;
                    while i < run {
                        let mut wv = [std::mem::transmute::<__m512, __m512bh>(_mm512_setzero_ps()); R];
                        for (r, v) in wv.iter_mut().enumerate() {
                            *v = load_pairs(row.add(32 * r));
                        }
                        row = row.add(2 * co);
                        for j in 0..N {
                            let xv = splat_pair(x.add(base[j] + off + i));
                            for r in 0..R {
                                acc[j][r] = _mm512_dpbf16_ps(acc[j][r], xv, wv[r]);
                            }
                        }
                        i += 2;
                    }
                }
            }
            let zero = _mm512_setzero_ps();
            for (j, a) in acc.iter().enumerate() {
                for (r, &lane) in a.iter().enumerate() {
                    let v = if g.spec.relu { _mm512_max_ps(lane, zero) } else { lane };
                    _mm512_storeu_ps(out.add(j * co + 16 * r), v);
                }
            }
        }
    }

    #[target_feature(enable = "avx512f,avx512bw,avx512bf16")]
    pub(super) unsafe fn input_grad<const R: usize, const P: usize>(
        g: &Geometry,
        wtp: &[u16],
        gy: &[u16],
        dxp: &mut [f32],
    ) {
        let positions = g.to * g.ps();
        let (wt, gy, dx) = (wtp.as_ptr(), gy.as_ptr(), dxp.as_mut_ptr());
        let mut q = 0;
        // SAFETY: positions q..q+P (or q) are output positions of this sample.
        unsafe {
            while q < positions {
                if q + P <= positions {
                    input_block::<R, P>(g, wt, gy, dx, q);
                    q += P;
                } else {
                    input_block::<R, 1>(g, wt, gy, dx, q);
                    q += 1;
                }
            }
        }
    }

    /// The input gradient of positions q0 .. q0 + N in tiles of 16·R consecutive
    /// taps (inside one run): Σ over channel pairs of the broadcast gradient pair
    /// times the packed Wᵀ row, added into the padded input gradient. Positions of
    /// one block may overlap (stride < kernel); their additions run one after the
    /// other.
    #[inline(always)]
    unsafe fn input_block<const R: usize, const N: usize>(
        g: &Geometry,
        wt: *const u16,
        gy: *const u16,
        dx: *mut f32,
        q0: usize,
    ) {
        let (co, width) = (g.co, 16 * R);
        let [kt, kh, kw] = g.spec.kernel;
        let run = kw * g.ci;
        let taps = kt * kh * run;
        let base: [usize; N] = input_offsets(g, q0);
        // SAFETY: gradient rows q0..q0+N exist; the packed Wᵀ has C_out/2 rows of
        // 2·K values; every tile lies inside one run of the padded input.
        unsafe {
            let grows = gy.add(q0 * co);
            for dt in 0..kt {
                for dh in 0..kh {
                    let off = tap_offset(g, dt, dh);
                    let mut i0 = 0;
                    while i0 < run {
                        let mut acc = [[_mm512_setzero_ps(); R]; N];
                        let mut wrow = wt.add(((dt * kh + dh) * run + i0) * 2);
                        for pair in 0..co / 2 {
                            let mut wv = [std::mem::transmute::<__m512, __m512bh>(_mm512_setzero_ps()); R];
                            for (r, v) in wv.iter_mut().enumerate() {
                                *v = load_pairs(wrow.add(32 * r));
                            }
                            wrow = wrow.add(2 * taps);
                            for (j, aj) in acc.iter_mut().enumerate() {
                                let gv = splat_pair(grows.add(j * co + 2 * pair));
                                for r in 0..R {
                                    aj[r] = _mm512_dpbf16_ps(aj[r], gv, wv[r]);
                                }
                            }
                        }
                        for (j, aj) in acc.iter().enumerate() {
                            let dst = dx.add(base[j] + off + i0);
                            for (r, &a) in aj.iter().enumerate() {
                                let p = dst.add(16 * r);
                                _mm512_storeu_ps(p, _mm512_add_ps(a, _mm512_loadu_ps(p)));
                            }
                        }
                        i0 += width;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::ops::ConvSpec;

    /// The f32 value of bf16 `b`.
    fn from_bf16(b: u16) -> f32 {
        f32::from_bits((b as u32) << 16)
    }

    fn rounded(v: &[f32]) -> Vec<f32> {
        v.iter().map(|&x| from_bf16(to_bf16(x))).collect()
    }

    /// Round-to-nearest-even on hand-picked bit patterns, and the vector conversion
    /// equal to the scalar one on random values (with a tail).
    #[test]
    fn rounding_is_nearest_even_and_the_vector_conversion_agrees() {
        // 1 + 2⁻⁸ is halfway between two bf16 values: ties to the even one (1.0);
        // 1 + 3·2⁻⁸ rounds up to 1 + 2⁻⁶ (even).
        assert_eq!(to_bf16(1.0 + 2f32.powi(-8)), 0x3f80);
        assert_eq!(to_bf16(1.0 + 3.0 * 2f32.powi(-8)), 0x3f82);
        assert_eq!(to_bf16(-2.5), 0xc020);
        assert_eq!(to_bf16(f32::from_bits(1)), 0);
        assert_eq!(to_bf16(-f32::from_bits(1)), 0x8000);
        assert!(from_bf16(to_bf16(f32::NAN)).is_nan());
        assert_eq!(from_bf16(to_bf16(f32::INFINITY)), f32::INFINITY);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let src: Vec<f32> = (0..1000).map(|_| rng.random_range(-1e3..1e3)).collect();
        let mut dst = vec![0u16; src.len()];
        convert(&src, &mut dst);
        for (&s, &d) in src.iter().zip(&dst) {
            assert_eq!(d, to_bf16(s), "{s}");
        }
    }

    /// The bf16 forward, weight gradient and input gradient equal the f32 AVX-512 kernels (themselves
    /// checked against the portable ones in `direct`) run on the same data rounded
    /// to bf16 (up to f32 summation order), for every C_out they take, strides below
    /// and above the kernel, padding, output rows of odd length (a position without
    /// a partner) and chunked positions.
    #[test]
    fn bf16_kernels_equal_the_f32_kernels_on_rounded_data() {
        if !cpu_has_bf16() {
            eprintln!("skipped: this CPU has no AVX-512 BF16");
            return;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for (co, ci, spec, (t, h, w)) in [
            (16, 1, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), (5, 13, 21)),
            (32, 16, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), (4, 10, 13)),
            (64, 32, ConvSpec::spatiotemporal(2, 4, 3, 3, 0), (6, 10, 10)),
            (16, 8, ConvSpec::spatial(4, 2, 1), (1, 9, 10)),
            (16, 2, ConvSpec::spatial(2, 3, 1), (1, 11, 12)),
            (64, 64, ConvSpec::temporal(2, 1), (3, 3, 3)),
        ] {
            for relu in [false, true] {
                let spec = ConvSpec { relu, bf16: true, ..spec };
                let g = Geometry::new(spec, &[1, t, h, w, ci], &[spec.weight_rows(ci), co]).unwrap();
                assert!(forward_supported(&g, Isa::Avx512), "C_out {co} C_in {ci}");
                let mut rand_vec = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
                let (x, wt, bias, gy) =
                    (rand_vec(g.in_len()), rand_vec(spec.weight_rows(ci) * co), rand_vec(co), rand_vec(g.out_len()));
                let all = 0..g.to * g.ps();
                // Reference: the f32 kernels (the portable path's definition) on rounded data.
                let mut xp_ref = vec![0.0; g.padded_len()];
                direct::pad_frames(&g, &rounded(&x), &mut xp_ref);
                let mut y_ref = vec![0.0; g.out_len()];
                direct::forward(&g, Isa::Avx512, &xp_ref, &rounded(&wt), &bias, &mut y_ref, all.clone());
                let mut xp = vec![0u16; g.padded_len()];
                pad_frames(&g, &x, &mut xp);
                let packed = pack_forward_weights(&g, &wt);
                let mut y = vec![f32::NAN; g.out_len()];
                for (i, yc) in y.chunks_mut(13 * co).enumerate() {
                    let q0 = i * 13;
                    forward(&g, Isa::Avx512, &xp, &packed, &bias, yc, q0..q0 + yc.len() / co);
                }
                for (u, v) in y.iter().zip(&y_ref) {
                    assert!((u - v).abs() <= 1e-4 * (1.0 + v.abs()), "forward C_out {co} relu {relu}: {u} vs {v}");
                }
                let mut dw_ref = vec![0.5f32; wt.len()];
                direct::weight_grad(&g, Isa::Avx512, &xp_ref, &rounded(&gy), &mut dw_ref);
                let mut xp32 = vec![0.0; g.padded_len()];
                direct::pad_frames(&g, &x, &mut xp32);
                let (mut xs, mut gys) = (vec![0u16; paired_input_len(&g)], vec![0u16; paired_gradient_len(&g)]);
                pair_positions(&g, &xp32, &mut xs);
                pair_gradients(&g, &gy, &mut gys);
                let mut dw = vec![0.5f32; wt.len()];
                weight_grad(&g, Isa::Avx512, &xs, &gys, &mut dw);
                for (u, v) in dw.iter().zip(&dw_ref) {
                    assert!((u - v).abs() <= 1e-4 * (1.0 + v.abs()), "weight gradient C_out {co}: {u} vs {v}");
                }
                if !input_grad_supported(&g, Isa::Avx512) {
                    continue;
                }
                let wt_ref = direct::transpose_weights(&g, &rounded(&wt));
                let mut dx_ref = vec![0f32; g.padded_len()];
                direct::input_grad(&g, Isa::Avx512, &wt_ref, &rounded(&gy), &mut dx_ref);
                let mut gy16 = vec![0u16; gy.len()];
                convert(&gy, &mut gy16);
                let mut dx = vec![0f32; g.padded_len()];
                input_grad(&g, Isa::Avx512, &pack_input_grad_weights(&g, &wt), &gy16, &mut dx);
                for (u, v) in dx.iter().zip(&dx_ref) {
                    assert!((u - v).abs() <= 1e-4 * (1.0 + v.abs()), "input gradient C_out {co}: {u} vs {v}");
                }
            }
        }
    }
}
