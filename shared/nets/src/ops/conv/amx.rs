//! The bf16 convolution kernels on Intel AMX tiles (`tdpbf16ps`), for CPUs that
//! have AMX-BF16 (Xeon since Sapphire Rapids): the same products and f32 sums as
//! [`super::bf16`]'s forward and input gradient, 16 × 16 × 32 multiply-adds per
//! instruction instead of 16 × 2, from the same packed operands.
//!
//! - Forward: the layer is an implicit matrix product. A block of up to 16 output
//!   positions of one output row (t, h) is the A tile — row r the 32 bf16 inputs of
//!   position w₀ + r for one chunk of taps, which in the padded input lie contiguous,
//!   and consecutive positions s_w·C_in values apart, so `tileloadd` reads them with
//!   that stride and no packing; the B tile is 16 tap pairs × 16 output channels of
//!   the weights as [`super::bf16::pack_forward_weights`] packs them; the C tiles (one
//!   per 16 output channels) hold the f32 sums. Taken where the runs of k_w·C_in
//!   inputs are whole chunks of 32 (every 3D-TCN layer but the first, whose C_in is 1).
//!   The A tile has `min(16, W_out)` rows: a block that ends early (a row's last
//!   positions, or the end of the range a worker was given) reads rows past it from
//!   the input scratch and discards them, so the scratch carries [`slack`] more values
//!   than the padded input (read, never used).
//! - Input gradient: blocks of 16 consecutive output positions (the A tile: their
//!   bf16 gradient rows, C_out apart) times the packed Wᵀ of
//!   [`super::bf16::pack_input_grad_weights`] (B: 16 channel pairs × 16 taps), each
//!   C tile added into the padded input gradient position by position; the last
//!   block's unused rows read [`input_grad_slack`] values past the gradient.
//!
//! Use needs the kernel's permission once per process (`arch_prctl`
//! `ARCH_REQ_XCOMP_PERM`, Linux ≥ 5.16); [`amx_available`] asks for it. `PEDNAV_AMX=off`
//! keeps the AVX-512 BF16 kernels (to measure one against the other).
//!
//! Invariant: [`forward`] and [`input_grad`] compute what [`super::bf16::forward`] and
//! [`super::bf16::input_grad`] compute for the same arguments (up to the order of the
//! f32 sums), and read only the padded input, its slack and the packed weights; the
//! unit tests check them on the encoder's layer shapes.

use std::ops::Range;
use std::sync::OnceLock;

use super::{Geometry, bf16};
use crate::error::{NetError, config_error};
use crate::ops::Isa;

/// Environment variable that turns the AMX kernel off (`off`) or leaves it to the
/// CPU (`auto`, the default when unset).
pub const AMX_ENV: &str = "PEDNAV_AMX";

/// Whether a `PEDNAV_AMX` value (`None`: unset) allows the AMX kernel.
fn allowed(value: Option<&str>) -> Result<bool, NetError> {
    match value.map(|v| v.trim().to_ascii_lowercase()).as_deref() {
        None | Some("" | "auto") => Ok(true),
        Some("off") => Ok(false),
        Some(_) => Err(config_error(
            AMX_ENV,
            value.unwrap_or_default(),
            "expected `auto` (AMX where the CPU has it; the default) or `off`",
        )),
    }
}

/// Whether the CPU reports AMX-TILE and AMX-BF16 (CPUID leaf 7, EDX bits 24 and 22).
// `__cpuid` is a safe function since Rust 1.94 and unsafe before (the workspace
// builds with 1.89 and later).
#[allow(unused_unsafe)]
fn cpu_reports_amx() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: CPUID is available on every x86-64 CPU.
        let leaf0 = unsafe { std::arch::x86_64::__cpuid(0) };
        if leaf0.eax < 7 {
            return false;
        }
        // SAFETY: as above; leaf 7 exists (checked).
        let leaf7 = unsafe { std::arch::x86_64::__cpuid_count(7, 0) };
        leaf7.edx & (1 << 24) != 0 && leaf7.edx & (1 << 22) != 0
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether the operating system enables the AMX tile state (XCR0 bits 17 and 18: set
/// by Linux since 5.16, which then hands it out per process on request).
fn os_enables_amx() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        // SAFETY: CPUID is available on every x86-64 CPU.
        #[allow(unused_unsafe)]
        let leaf1 = unsafe { std::arch::x86_64::__cpuid(1) };
        if leaf1.ecx & (1 << 27) == 0 {
            return false; // no OSXSAVE: XGETBV would fault
        }
        let (lo, hi): (u32, u32);
        // SAFETY: XGETBV with ECX = 0 reads XCR0; OSXSAVE (checked) makes it available.
        unsafe {
            std::arch::asm!("xgetbv", in("ecx") 0u32, out("eax") lo, out("edx") hi, options(nomem, nostack));
        }
        let xcr0 = (u64::from(hi) << 32) | u64::from(lo);
        xcr0 & (0b11 << 17) == 0b11 << 17
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Ask Linux for the AMX tile data state for this process (all its threads).
fn request_tile_permission() -> bool {
    #[cfg(all(target_arch = "x86_64", target_os = "linux"))]
    {
        const ARCH_REQ_XCOMP_PERM: libc::c_long = 0x1023;
        const XFEATURE_XTILEDATA: libc::c_long = 18;
        // SAFETY: arch_prctl with this request only changes the process's permitted
        // extended states; it reads no memory of ours.
        unsafe { libc::syscall(libc::SYS_arch_prctl, ARCH_REQ_XCOMP_PERM, XFEATURE_XTILEDATA) == 0 }
    }
    #[cfg(not(all(target_arch = "x86_64", target_os = "linux")))]
    {
        false
    }
}

/// Whether the AMX kernels run in this process: the CPU has AMX-BF16 and AVX-512
/// BF16 (for the layouts they share with the AVX-512 BF16 kernels), the operating system granted the
/// tile state, and `PEDNAV_AMX` does not say `off`. Resolved once.
///
/// # Panics
/// If `PEDNAV_AMX` has another value than `auto` or `off` (naming the variable);
/// [`crate::init_cpu_runtime`] resolves it first thing, so that stops a process at start-up.
pub fn amx_available() -> bool {
    static AVAILABLE: OnceLock<bool> = OnceLock::new();
    *AVAILABLE.get_or_init(|| {
        let setting = std::env::var(AMX_ENV).ok();
        let allowed = allowed(setting.as_deref()).unwrap_or_else(|e| panic!("{e}"));
        allowed && bf16::cpu_has_bf16() && cpu_reports_amx() && os_enables_amx() && request_tile_permission()
    })
}

/// Whether the AMX forward takes this layer on `isa`.
pub(super) fn forward_supported(g: &Geometry, isa: Isa) -> bool {
    bf16::forward_supported(g, isa) && (g.spec.kernel[2] * g.ci).is_multiple_of(32) && amx_available()
}

/// Rows of the A and C tiles for this layer: one block of positions per tile.
fn tile_rows(g: &Geometry) -> usize {
    g.wo.min(16)
}

/// bf16 values the input scratch must hold past the padded input: a block's
/// unused rows read up to 15 positions (s_w·C_in values each) beyond its last one.
pub(super) fn slack(g: &Geometry) -> usize {
    (tile_rows(g) - 1) * g.spec.stride[1] * g.ci
}

/// Forward of output positions `positions` of one sample, as [`bf16::forward`]:
/// `xp` the bf16 padded input followed by at least [`slack`] readable values,
/// `wp` the packed weights; y (positions.len(), C_out) in f32 with bias and ReLU.
pub(super) fn forward(g: &Geometry, xp: &[u16], wp: &[u16], bias: &[f32], y: &mut [f32], positions: Range<usize>) {
    assert!(forward_supported(g, Isa::active()), "no AMX forward for this layer");
    assert!(xp.len() >= g.padded_len() + slack(g), "padded frames (with the tile slack) too short");
    assert!(wp.len() >= g.spec.weight_rows(g.ci) * g.co, "packed weights too short");
    assert!(positions.end <= g.to * g.ps() && y.len() >= positions.len() * g.co, "output too short");
    assert_eq!(bias.len(), g.co, "bias has C_out entries");
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AMX-BF16 and the process its tile state (forward_supported);
    // sizes checked above.
    unsafe {
        match g.co {
            16 => tiles::forward::<1>(g, xp, wp, bias, y, positions),
            32 => tiles::forward::<2>(g, xp, wp, bias, y, positions),
            64 => tiles::forward::<4>(g, xp, wp, bias, y, positions),
            co => unreachable!("forward_supported admits C_out {co}"),
        }
    }
}

/// Whether the AMX input gradient takes this layer on `isa`: where the bf16 one
/// does (runs of whole 32-tap tiles), with C_out 16 or a multiple of 32 (the output
/// channels go in products of 32, or one of 16).
pub(super) fn input_grad_supported(g: &Geometry, isa: Isa) -> bool {
    bf16::input_grad_supported(g, isa) && (g.co == 16 || g.co.is_multiple_of(32)) && amx_available()
}

/// bf16 values the output-gradient scratch must hold past the gradient: the last
/// block's unused rows read up to 15 positions (C_out values each) beyond it.
pub(super) fn input_grad_slack(g: &Geometry) -> usize {
    15 * g.co
}

/// dxp (padded f32) += the input gradient of one sample, as [`bf16::input_grad`]:
/// `gy` the bf16 output gradient (rows of C_out) followed by at least
/// [`input_grad_slack`] readable values, `wtp` the packed Wᵀ
/// ([`bf16::pack_input_grad_weights`]).
pub(super) fn input_grad(g: &Geometry, wtp: &[u16], gy: &[u16], dxp: &mut [f32]) {
    assert!(input_grad_supported(g, Isa::active()), "no AMX input gradient for this layer");
    assert!(dxp.len() >= g.padded_len(), "padded input gradient too short");
    assert!(wtp.len() >= g.spec.weight_rows(g.ci) * g.co, "packed weights too short");
    assert!(gy.len() >= g.out_len() + input_grad_slack(g), "output gradient (with the tile slack) too short");
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AMX-BF16 and the process its tile state (input_grad_supported);
    // sizes checked above.
    unsafe {
        tiles::input_grad(g, wtp, gy, dxp)
    }
}

#[cfg(target_arch = "x86_64")]
mod tiles {
    //! The tile instructions. Tiles: tmm0–tmm3 the C accumulators (16 output
    //! channels each), tmm4 the A tile (positions × 32 inputs), tmm5 and tmm6 the B
    //! tiles (16 tap pairs × 16 channels), alternating so a load can overlap the
    //! product before it. The compiler allocates no tile registers, so they keep
    //! their contents between the `asm!` blocks of one call.
    use std::arch::asm;
    use std::ops::Range;

    use super::super::Geometry;
    use super::super::direct::{input_offsets, tap_offset};

    /// `ldtilecfg`'s 64-byte operand.
    #[repr(C, align(64))]
    struct TileConfig([u8; 64]);

    impl TileConfig {
        /// Palette 1: the C tiles (0–3) `m` rows of 16 f32, the A tile (4) `m` rows of
        /// `a_bytes`, the B tiles (5, 6) `a_bytes / 4` rows (pairs) of 16 columns.
        fn new(m: usize, a_bytes: usize) -> TileConfig {
            assert!(m <= 16 && a_bytes <= 64 && a_bytes.is_multiple_of(4), "tile shape");
            let mut c = [0u8; 64];
            c[0] = 1;
            for t in 0..7 {
                let (bytes, rows) = match t {
                    0..=3 => (64, m),
                    4 => (a_bytes, m),
                    _ => (64, a_bytes / 4),
                };
                c[16 + 2 * t] = bytes as u8;
                c[48 + t] = rows as u8;
            }
            TileConfig(c)
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
        // checked the lengths), every B row in the K/2 packed rows; C stores go to `c`.
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
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::ops::ConvSpec;

    /// Whether this test process runs the AMX kernels; a CPU that has them under an
    /// operating system that enables them, on the `avx512` path with `PEDNAV_AMX`
    /// unset, must (else Linux refused the tile state, which would silently cost the speed).
    fn runs_amx() -> bool {
        if Isa::active() != Isa::Avx512 || !bf16::cpu_has_bf16() || !cpu_reports_amx() {
            eprintln!("skipped: this CPU has no AMX-BF16 (or the avx512 path is not active)");
            return false;
        }
        if !os_enables_amx() {
            eprintln!("skipped: the operating system does not enable the AMX tile state (XCR0)");
            return false;
        }
        if std::env::var_os(AMX_ENV).is_some() && !amx_available() {
            eprintln!("skipped: {AMX_ENV} turns AMX off");
            return false;
        }
        assert!(amx_available(), "the CPU has AMX-BF16 but Linux refused the tile state (arch_prctl)");
        true
    }

    /// The AMX forward equals the AVX-512 BF16 forward (itself checked against the
    /// f32 kernels on rounded data) on the 3D-TCN's layer shapes at 42² and 84²,
    /// with and without ReLU, over the whole output and over ranges that start and
    /// end inside output rows.
    #[test]
    fn amx_forward_equals_the_avx512_bf16_forward() {
        if !runs_amx() {
            return;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for (co, ci, spec, (t, h, w)) in [
            (32, 16, ConvSpec::spatiotemporal(2, 1, 4, 2, 1), (7, 21, 21)),
            (64, 32, ConvSpec::spatiotemporal(2, 2, 3, 3, 0), (5, 10, 10)),
            (64, 64, ConvSpec::temporal(2, 1), (3, 3, 3)),
            (32, 16, ConvSpec::spatiotemporal(2, 1, 4, 2, 1), (4, 42, 42)),
            (16, 32, ConvSpec::spatial(2, 1, 0), (1, 5, 40)),
        ] {
            for relu in [false, true] {
                let spec = ConvSpec { relu, bf16: true, ..spec };
                let g = Geometry::new(spec, &[1, t, h, w, ci], &[spec.weight_rows(ci), co]).unwrap();
                assert!(forward_supported(&g, Isa::Avx512), "C_out {co} C_in {ci}");
                let mut rand_vec = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
                let (x, wt, bias) = (rand_vec(g.in_len()), rand_vec(spec.weight_rows(ci) * co), rand_vec(co));
                // The slack holds values that must not matter: NaN bit patterns.
                let mut xp = vec![0xffc0u16; g.padded_len() + slack(&g)];
                bf16::pad_frames(&g, &x, &mut xp);
                let packed = bf16::pack_forward_weights(&g, &wt);
                let all = 0..g.to * g.ps();
                let mut y_ref = vec![f32::NAN; g.out_len()];
                bf16::forward(&g, Isa::Avx512, &xp, &packed, &bias, &mut y_ref, all.clone());
                // The whole output in one call, then in ranges that start and end
                // inside output rows (as the pool splits an actor's positions).
                for per_call in [all.len(), 7, 37] {
                    let mut y = vec![f32::NAN; g.out_len()];
                    for (i, yc) in y.chunks_mut(per_call * co).enumerate() {
                        let q0 = i * per_call;
                        forward(&g, &xp, &packed, &bias, yc, q0..q0 + yc.len() / co);
                    }
                    for (u, v) in y.iter().zip(&y_ref) {
                        assert!(
                            (u - v).abs() <= 1e-4 * (1.0 + v.abs()),
                            "C_out {co} C_in {ci} relu {relu}, {per_call} positions per call: {u} vs {v}"
                        );
                    }
                }
            }
        }
    }

    /// The AMX input gradient equals the AVX-512 BF16 one on the layers that have
    /// an input gradient (C_out 32 and 64 at 42² and 84², and a 16-channel layer).
    #[test]
    fn amx_input_gradient_equals_the_avx512_bf16_one() {
        if !runs_amx() {
            return;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(6);
        for (co, ci, spec, (t, h, w)) in [
            (32, 16, ConvSpec::spatiotemporal(2, 1, 4, 2, 1), (7, 21, 21)),
            (64, 32, ConvSpec::spatiotemporal(2, 2, 3, 3, 0), (5, 10, 10)),
            (32, 16, ConvSpec::spatiotemporal(2, 1, 4, 2, 1), (4, 42, 42)),
            (64, 32, ConvSpec::spatiotemporal(2, 4, 3, 3, 0), (13, 21, 21)),
            (16, 8, ConvSpec::spatial(4, 2, 1), (1, 9, 10)),
        ] {
            let spec = ConvSpec { bf16: true, ..spec };
            let g = Geometry::new(spec, &[1, t, h, w, ci], &[spec.weight_rows(ci), co]).unwrap();
            assert!(input_grad_supported(&g, Isa::Avx512), "C_out {co} C_in {ci}");
            let mut rand_vec = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
            let (wt, gy) = (rand_vec(spec.weight_rows(ci) * co), rand_vec(g.out_len()));
            let packed = bf16::pack_input_grad_weights(&g, &wt);
            // The slack holds values that must not matter: NaN bit patterns.
            let mut gy16 = vec![0xffc0u16; g.out_len() + input_grad_slack(&g)];
            bf16::convert(&gy, &mut gy16);
            let start = rand_vec(g.padded_len());
            let mut dx_ref = start.clone();
            bf16::input_grad(&g, Isa::Avx512, &packed, &gy16, &mut dx_ref);
            let mut dx = start;
            input_grad(&g, &packed, &gy16, &mut dx);
            for (u, v) in dx.iter().zip(&dx_ref) {
                assert!((u - v).abs() <= 1e-4 * (1.0 + v.abs()), "C_out {co} C_in {ci}: {u} vs {v}");
            }
        }
    }

    #[test]
    fn pednav_amx_takes_auto_or_off_and_names_itself_otherwise() {
        assert!(allowed(None).unwrap() && allowed(Some("")).unwrap() && allowed(Some(" Auto ")).unwrap());
        assert!(!allowed(Some("off")).unwrap());
        let e = allowed(Some("yes")).unwrap_err().to_string();
        assert!(e.contains("PEDNAV_AMX") && e.contains("yes") && e.contains("`off`"), "{e}");
    }
}
