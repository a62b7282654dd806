//! The AMX tile kernels behind [`super`]'s entry points, in inline `asm!`
//! (`ldtilecfg`, `tileloadd`, `tdpbf16ps`, `tilestored`; no nightly features).
//!
//! Invariant: every function here reads only what its safe caller in [`super`]
//! checked (lengths, slack, the furthest read), and ends with `tilerelease`, so no
//! tile state outlives a call.
//!
//! Tiles: forward and input gradient: tmm0–tmm3 the C
//! accumulators (16 output channels, or 16 taps, each), tmm4 the A tile
//! (positions × 32 inputs or gradients), tmm5 and tmm6 the B tiles (16 pairs × 16
//! columns), alternating so a load can overlap the product before it. Weight
//! gradient: tmm0–tmm3 the C tiles (16 channels × 16 taps), then NA A tiles
//! (channels × position pairs) and NB B tiles (position pairs × 16 taps) in
//! tmm4–tmm7 (NA + NB = 4). The compiler allocates no tile registers, so they
//! keep their contents between the `asm!` blocks of one call.

use std::arch::asm;
use std::ops::Range;

use super::super::Geometry;
use super::super::direct::{input_offsets, tap_offset};
use super::WeightGradPlan;

/// `ldtilecfg`'s 64-byte operand.
#[repr(C, align(64))]
struct TileConfig([u8; 64]);

impl TileConfig {
    /// Palette 1 with tile t `shapes[t]` = (rows, bytes per row); (0, 0) leaves it unused.
    fn with(shapes: [(usize, usize); 8]) -> TileConfig {
        let mut c = [0u8; 64];
        c[0] = 1;
        for (t, &(rows, bytes)) in shapes.iter().enumerate() {
            assert!(rows <= 16 && bytes <= 64, "tile shape");
            c[16 + 2 * t] = bytes as u8;
            c[48 + t] = rows as u8;
        }
        TileConfig(c)
    }

    /// The forward and input gradient: the C tiles (0–3) `m` rows of 16 f32, the A
    /// tile (4) `m` rows of `a_bytes`, the B tiles (5, 6) `a_bytes / 4` rows (pairs)
    /// of 16 columns.
    fn new(m: usize, a_bytes: usize) -> TileConfig {
        assert!(a_bytes.is_multiple_of(4), "tile shape");
        let (c, a, b) = ((m, 64), (m, a_bytes), (a_bytes / 4, 64));
        TileConfig::with([c, c, c, c, a, b, b, (0, 0)])
    }
}

#[inline(always)]
unsafe fn zero_c(j: usize) {
    // SAFETY: tile state configured by the caller.
    unsafe {
        match j {
            0 => asm!("tilezero tmm0", options(nostack, nomem)),
            1 => asm!("tilezero tmm1", options(nostack, nomem)),
            2 => asm!("tilezero tmm2", options(nostack, nomem)),
            _ => asm!("tilezero tmm3", options(nostack, nomem)),
        }
    }
}

/// A tile ← rows of 64 bytes at `p`, `stride` bytes apart.
#[inline(always)]
unsafe fn load_a(p: *const u16, stride: usize) {
    // SAFETY: the caller guarantees every row readable.
    unsafe { asm!("tileloadd tmm4, [{p} + {s}*1]", p = in(reg) p, s = in(reg) stride, options(nostack, readonly)) }
}

/// B tile of C tile `j` ← 16 rows of 64 bytes at `p`, `stride` bytes apart; then
/// C_j += A · B.
#[inline(always)]
unsafe fn load_b_and_multiply(j: usize, p: *const u16, stride: usize) {
    // SAFETY: the caller guarantees every row readable; tiles configured.
    unsafe {
        match j {
            0 => asm!("tileloadd tmm5, [{p} + {s}*1]", "tdpbf16ps tmm0, tmm4, tmm5",
                p = in(reg) p, s = in(reg) stride, options(nostack, readonly)),
            1 => asm!("tileloadd tmm6, [{p} + {s}*1]", "tdpbf16ps tmm1, tmm4, tmm6",
                p = in(reg) p, s = in(reg) stride, options(nostack, readonly)),
            2 => asm!("tileloadd tmm5, [{p} + {s}*1]", "tdpbf16ps tmm2, tmm4, tmm5",
                p = in(reg) p, s = in(reg) stride, options(nostack, readonly)),
            _ => asm!("tileloadd tmm6, [{p} + {s}*1]", "tdpbf16ps tmm3, tmm4, tmm6",
                p = in(reg) p, s = in(reg) stride, options(nostack, readonly)),
        }
    }
}

/// C tile `j` → rows of 16 f32 at `p`, 64 bytes apart.
#[inline(always)]
unsafe fn store_c(j: usize, p: *mut f32) {
    // SAFETY: the caller guarantees `rows` × 64 writable bytes.
    unsafe {
        match j {
            0 => asm!("tilestored [{p} + {s}*1], tmm0", p = in(reg) p, s = in(reg) 64usize, options(nostack)),
            1 => asm!("tilestored [{p} + {s}*1], tmm1", p = in(reg) p, s = in(reg) 64usize, options(nostack)),
            2 => asm!("tilestored [{p} + {s}*1], tmm2", p = in(reg) p, s = in(reg) 64usize, options(nostack)),
            _ => asm!("tilestored [{p} + {s}*1], tmm3", p = in(reg) p, s = in(reg) 64usize, options(nostack)),
        }
    }
}

/// Tile `t` (4–7) ← rows at `p`, `stride` bytes apart (as many rows and bytes as
/// the configuration gives it).
#[inline(always)]
unsafe fn load(t: usize, p: *const u16, stride: usize) {
    // SAFETY: the caller guarantees every row readable; tiles configured.
    unsafe {
        match t {
            4 => {
                asm!("tileloadd tmm4, [{p} + {s}*1]", p = in(reg) p, s = in(reg) stride, options(nostack, readonly))
            }
            5 => {
                asm!("tileloadd tmm5, [{p} + {s}*1]", p = in(reg) p, s = in(reg) stride, options(nostack, readonly))
            }
            6 => {
                asm!("tileloadd tmm6, [{p} + {s}*1]", p = in(reg) p, s = in(reg) stride, options(nostack, readonly))
            }
            _ => {
                asm!("tileloadd tmm7, [{p} + {s}*1]", p = in(reg) p, s = in(reg) stride, options(nostack, readonly))
            }
        }
    }
}

/// C tile `c` += A tile `a` · B tile `b`, for the weight gradient's two layouts:
/// A in 4 and 5 and B in 6 and 7 (C = 2·(a − 4) + b − 6), or A in 4 and B in 5–7
/// (C = b − 5).
#[inline(always)]
unsafe fn multiply(c: usize, a: usize, b: usize) {
    // SAFETY: tiles configured and loaded by the caller.
    unsafe {
        match (c, a, b) {
            (0, 4, 6) => asm!("tdpbf16ps tmm0, tmm4, tmm6", options(nostack, nomem)),
            (1, 4, 7) => asm!("tdpbf16ps tmm1, tmm4, tmm7", options(nostack, nomem)),
            (2, 5, 6) => asm!("tdpbf16ps tmm2, tmm5, tmm6", options(nostack, nomem)),
            (3, 5, 7) => asm!("tdpbf16ps tmm3, tmm5, tmm7", options(nostack, nomem)),
            (0, 4, 5) => asm!("tdpbf16ps tmm0, tmm4, tmm5", options(nostack, nomem)),
            (1, 4, 6) => asm!("tdpbf16ps tmm1, tmm4, tmm6", options(nostack, nomem)),
            (2, 4, 7) => asm!("tdpbf16ps tmm2, tmm4, tmm7", options(nostack, nomem)),
            _ => unreachable!("no weight-gradient product C{c} += A{a}·B{b}"),
        }
    }
}

/// See [`super::weight_grad`]: dW (K, C_out) += the products of `plan`'s chunks
/// (C_out = 16·NA·n). C tile (a, b) holds dWᵀ for channel group a0 + a and tap
/// group b0 + b (16 × 16); A tiles 4.. hold NA channel groups' gradients at one
/// chunk's position pairs, B tiles 4 + NA.. NB tap groups' paired inputs at those
/// pairs. Every chunk of the sample passes through before the C tiles are added
/// (transposed) into dW.
pub(super) unsafe fn weight_grad<const NA: usize, const NB: usize>(
    co: usize,
    plan: &WeightGradPlan,
    xs: &[u16],
    gyt: &[u16],
    dw: &mut [f32],
) {
    assert!(NA * NB <= 4 && NA + NB <= 4 && (co / 16).is_multiple_of(NA), "tile plan");
    let WeightGradPlan { chunk_bases, group_offsets, group_taps, pairs, pair_step } = plan;
    let (pairs, pair_step) = (*pairs, *pair_step);
    assert!((1..=16).contains(&pairs), "1 to 16 pairs a chunk");
    assert_eq!(group_taps.len(), group_offsets.len(), "a dW row per tap group");
    let block = co * pairs * 2; // bf16 values of one chunk's transposed gradient
    let (a_stride, b_stride) = (4 * pairs, 2 * 2 * pair_step);
    let mut shapes = [(0, 0); 8];
    for (t, shape) in shapes.iter_mut().enumerate() {
        *shape = match t {
            0..4 if t < NA * NB => (16, 64),
            4..8 if t < 4 + NA => (16, 4 * pairs),
            4..8 if t < 4 + NA + NB => (pairs, 64),
            _ => (0, 0),
        };
    }
    let config = TileConfig::with(shapes);
    let mut c = [[0f32; 256]; 4];
    let (x, gp) = (xs.as_ptr(), gyt.as_ptr());
    // SAFETY: A rows lie in one chunk's block of the transposed gradient; B rows at
    // the chunk's pairs and 16 taps inside the paired input or the zeros after it
    // (the caller checked the furthest read); C stores go to `c`.
    unsafe {
        asm!("ldtilecfg [{}]", in(reg) config.0.as_ptr(), options(nostack, readonly));
        for a0 in (0..co / 16).step_by(NA) {
            for b0 in (0..group_offsets.len()).step_by(NB) {
                let nb = NB.min(group_offsets.len() - b0);
                for a in 0..NA {
                    for b in 0..nb {
                        zero_c(a * NB + b);
                    }
                }
                for (i, &base) in chunk_bases.iter().enumerate() {
                    let gy = gp.add(i * block + 16 * a0 * pairs * 2);
                    for a in 0..NA {
                        load(4 + a, gy.add(16 * a * pairs * 2), a_stride);
                    }
                    for b in 0..nb {
                        load(4 + NA + b, x.add(2 * (base + group_offsets[b0 + b])), b_stride);
                        for a in 0..NA {
                            multiply(a * NB + b, 4 + a, 4 + NA + b);
                        }
                    }
                }
                for a in 0..NA {
                    for b in 0..nb {
                        let j = a * NB + b;
                        store_c(j, c[j].as_mut_ptr());
                        let (k0, o0) = (group_taps[b0 + b], 16 * (a0 + a));
                        for (o, sums) in c[j].chunks_exact(16).enumerate() {
                            for (t, &v) in sums.iter().enumerate() {
                                dw[(k0 + t) * co + o0 + o] += v;
                            }
                        }
                    }
                }
            }
        }
        asm!("tilerelease", options(nostack, nomem));
    }
}

/// See [`super::forward`]; C_out = 16·R.
pub(super) unsafe fn forward<const R: usize>(
    g: &Geometry,
    xp: &[u16],
    wp: &[u16],
    bias: &[f32],
    y: &mut [f32],
    positions: Range<usize>,
) {
    let co = g.co;
    assert_eq!(co, 16 * R, "R tiles of 16 channels cover C_out");
    let [kt, kh, kw] = g.spec.kernel;
    let run = kw * g.ci;
    let rows = super::tile_rows(g);
    let a_stride = 2 * g.spec.stride[1] * g.ci; // bytes between consecutive positions
    let b_stride = 2 * 2 * co; // bytes between tap pairs of the packed weights
    let mut tap_rows = Vec::with_capacity(kt * kh);
    for dt in 0..kt {
        for dh in 0..kh {
            tap_rows.push(tap_offset(g, dt, dh));
        }
    }
    let config = TileConfig::new(rows, 64);
    let mut c = [[0f32; 256]; R];
    let (x, w) = (xp.as_ptr(), wp.as_ptr());
    let first = positions.start;
    // SAFETY: every A row read lies in the padded input or its slack (the caller
    // checked the lengths), every B row in the packed rows (16 per 32 taps of a run,
    // or per run where runs are shorter); C stores go to `c`.
    unsafe {
        asm!("ldtilecfg [{}]", in(reg) config.0.as_ptr(), options(nostack, readonly));
        let mut q = first;
        while q < positions.end {
            let n = (g.wo - q % g.wo).min(positions.end - q).min(rows);
            let [base]: [usize; 1] = input_offsets(g, q);
            for j in 0..R {
                zero_c(j);
            }
            let mut pair_row = 0;
            for &off in &tap_rows {
                for chunk in (0..run).step_by(32) {
                    load_a(x.add(base + off + chunk), a_stride);
                    for j in 0..R {
                        load_b_and_multiply(j, w.add(pair_row * 2 * co + 32 * j), b_stride);
                    }
                    pair_row += 16;
                }
            }
            for (j, cj) in c.iter_mut().enumerate() {
                store_c(j, cj.as_mut_ptr());
            }
            for r in 0..n {
                let dst = &mut y[(q + r - first) * co..(q + r - first + 1) * co];
                for (j, cj) in c.iter().enumerate() {
                    let sums = &cj[16 * r..16 * r + 16];
                    for ((d, &s), &b) in dst[16 * j..16 * j + 16].iter_mut().zip(sums).zip(&bias[16 * j..]) {
                        let v = s + b;
                        *d = if g.spec.relu { v.max(0.0) } else { v };
                    }
                }
            }
            q += n;
        }
        asm!("tilerelease", options(nostack, nomem));
    }
}

/// See [`super::input_grad`]. Blocks of 16 consecutive output positions (their
/// gradient rows lie C_out apart, whatever output row they are in) times up to
/// four tiles of 16 consecutive taps of one run; each C tile is added to the
/// padded input gradient row by row, positions one after the other (they may
/// overlap when the stride is below the kernel).
pub(super) unsafe fn input_grad(g: &Geometry, wt: &[u16], gy: &[u16], dx: &mut [f32]) {
    let co = g.co;
    let [kt, kh, kw] = g.spec.kernel;
    let run = kw * g.ci;
    let taps = kt * kh * run;
    let chunk = co.min(32); // output channels per product
    let positions = g.to * g.ps();
    let a_stride = 2 * co; // bytes between gradient rows
    let b_stride = 2 * 2 * taps; // bytes between channel pairs of the packed Wᵀ
    let config = TileConfig::new(16, 2 * chunk);
    let mut c = [[0f32; 256]; 4];
    let (gp, wp) = (gy.as_ptr(), wt.as_ptr());
    // SAFETY: A rows lie in the gradient or its slack, B rows in the C_out/2 rows
    // of 2·K packed values; every addition into `dx` is at a real position's tap
    // (a slice index, bounds-checked).
    unsafe {
        asm!("ldtilecfg [{}]", in(reg) config.0.as_ptr(), options(nostack, readonly));
        let mut q = 0;
        while q < positions {
            let n = (positions - q).min(16);
            let bases: [usize; 16] = input_offsets(g, q);
            for dt in 0..kt {
                for dh in 0..kh {
                    let off = tap_offset(g, dt, dh);
                    let first_tap = (dt * kh + dh) * run;
                    let mut i0 = 0;
                    while i0 < run {
                        let group = ((run - i0) / 16).min(4);
                        for j in 0..group {
                            zero_c(j);
                        }
                        for c0 in (0..co).step_by(chunk) {
                            load_a(gp.add(q * co + c0), a_stride);
                            for j in 0..group {
                                let k = first_tap + i0 + 16 * j;
                                load_b_and_multiply(j, wp.add((c0 / 2 * taps + k) * 2), b_stride);
                            }
                        }
                        for (j, cj) in c.iter_mut().enumerate().take(group) {
                            store_c(j, cj.as_mut_ptr());
                        }
                        for (r, &base) in bases.iter().enumerate().take(n) {
                            let at = base + off + i0;
                            let dst = &mut dx[at..at + 16 * group];
                            for (j, cj) in c.iter().enumerate().take(group) {
                                for (d, &v) in dst[16 * j..16 * j + 16].iter_mut().zip(&cj[16 * r..16 * r + 16]) {
                                    *d += v;
                                }
                            }
                        }
                        i0 += 16 * group;
                    }
                }
            }
            q += n;
        }
        asm!("tilerelease", options(nostack, nomem));
    }
}
