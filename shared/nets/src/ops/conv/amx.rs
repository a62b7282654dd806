//! The bf16 convolution kernels on Intel AMX tiles (`tdpbf16ps`), for CPUs that
//! have AMX-BF16 (Xeon since Sapphire Rapids): the same products and f32 sums as
//! [`super::bf16`]'s forward, input gradient and weight gradient, 16 × 16 × 32 multiply-adds per
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
//! - Weight gradient: dWᵀ, one C tile per 16 output channels × 16 consecutive taps of
//!   one run, summed over the sample's output rows. Per output row (or chunk of at
//!   most 16 position pairs of it, all chunks of a layer one size), the A tile is
//!   16 channels' gradients at the chunk's positions — the paired gradient
//!   transposed so that a channel's pairs lie contiguous ([`transpose_gradients`]) —
//!   and the B tile the chunk's position pairs × 16 taps of the paired input
//!   [`super::bf16::pair_positions`] already builds (consecutive pairs of one output
//!   row lie 2·s_w·C_in values apart, so `tileloadd` reads them with that stride).
//!   Positions past a row's end have zero gradients; for the last row they read
//!   [`weight_grad_slack`] zeros past the paired input.
//!
//! Use needs the kernel's permission once per process (`arch_prctl`
//! `ARCH_REQ_XCOMP_PERM`, Linux ≥ 5.16); [`amx_available`] asks for it. `PEDNAV_AMX=off`
//! keeps the AVX-512 BF16 kernels (to measure one against the other).
//!
//! Layout: this file holds the conditions, the layouts the tiles read and the safe
//! entry points (which check every length); [`tiles`] the `asm!` kernels.
//!
//! Invariant: [`forward`], [`input_grad`] and [`weight_grad`] compute what
//! [`super::bf16::forward`], [`super::bf16::input_grad`] and [`super::bf16::weight_grad`]
//! compute for the same operands (up to the order of the f32 sums), and read only
//! their operands and the slack past them; the unit tests check them on the
//! encoder's layer shapes.

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
/// `wp` the packed weights ([`bf16::pack_forward_weights`]); y (positions.len(), C_out) in f32 with bias and ReLU.
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

/// Whether the AMX weight gradient takes this layer on `isa`: where the bf16 one
/// does (C_out 16, 32 or 64), with runs of k_w·C_in inputs in whole groups of 16
/// taps (the columns of a C tile) and output rows of at least 5 positions: rows of
/// 3 or 4 give products of 4 bf16 of the tile's 32, which measured slower than the
/// AVX-512 BF16 kernel (the 3D-TCN's third layer at 42², `conv_layers --bf16`:
/// 1.2–1.8 against 1.0–1.1 ms forward + backward).
pub(super) fn weight_grad_supported(g: &Geometry, isa: Isa) -> bool {
    bf16::forward_supported(g, isa) && g.wo >= 5 && (g.spec.kernel[2] * g.ci).is_multiple_of(16) && amx_available()
}

/// How the weight gradient splits an output row's ⌈W_out / 2⌉ position pairs:
/// (chunks per row, pairs per chunk) — as few chunks of at most 16 pairs (a tile's
/// K of 32 bf16) as cover the row, all of one size, since the tiles' shape is set
/// once per call.
fn row_chunks(g: &Geometry) -> (usize, usize) {
    let pairs = g.wo.div_ceil(2);
    let chunks = pairs.div_ceil(16);
    (chunks, pairs.div_ceil(chunks))
}

/// Zeros the paired input ([`bf16::pair_positions`]) must be followed by (enough,
/// with a position to spare): a row's chunks cover 2·chunks·pairs ≥ W_out positions,
/// and the last row's extra ones read s_w·C_in paired values (2 bf16 each) per
/// position past the end.
pub(super) fn weight_grad_slack(g: &Geometry) -> usize {
    let (chunks, pairs) = row_chunks(g);
    2 * (2 * chunks * pairs - g.wo) * g.spec.stride[1] * g.ci
}

/// bf16 values of [`transpose_gradients`]' output for one sample.
pub(super) fn transposed_gradient_len(g: &Geometry) -> usize {
    let (chunks, pairs) = row_chunks(g);
    g.to * g.ho * chunks * g.co * pairs * 2
}

/// The paired gradient of one sample ([`bf16::pair_gradients`]: slot, C_out, 2) with
/// each row chunk's channels first: element `((chunk·C_out + o)·pairs + p)·2 + s` of
/// a row's block is the gradient of channel o at the row's position
/// 2·(chunk·pairs + p) + s, zero past the row's end — so one channel's gradients at
/// a chunk's positions are one contiguous A-tile row.
pub(super) fn transpose_gradients(g: &Geometry, paired: &[u16], out: &mut [u16]) {
    let (chunks, pairs) = row_chunks(g);
    let (co, row_pairs) = (g.co, g.wo.div_ceil(2));
    let block = chunks * co * pairs * 2;
    assert!(paired.len() >= bf16::paired_gradient_len(g), "paired gradient too short");
    assert!(out.len() >= transposed_gradient_len(g), "transposed gradient too short");
    let rows = paired[..bf16::paired_gradient_len(g)].chunks_exact(row_pairs * co * 2);
    for (src, dst) in rows.zip(out.chunks_exact_mut(block)) {
        for (c, dst) in dst.chunks_exact_mut(co * pairs * 2).enumerate() {
            for p in 0..pairs {
                let slot = c * pairs + p;
                let from = src.get(slot * co * 2..(slot + 1) * co * 2);
                for o in 0..co {
                    let at = (o * pairs + p) * 2;
                    let pair = from.map_or([0, 0], |f| [f[2 * o], f[2 * o + 1]]);
                    dst[at..at + 2].copy_from_slice(&pair);
                }
            }
        }
    }
}

/// dW (K, C_out) += the weight gradient of one sample, as [`bf16::weight_grad`]:
/// `plan` the layer's [`WeightGradPlan`] (it depends on the geometry only: one per
/// call), `xs` the paired input ([`bf16::pair_positions`]) followed by at least
/// [`weight_grad_slack`] zeros, `gyt` the transposed paired gradient
/// ([`transpose_gradients`]).
pub(super) fn weight_grad(g: &Geometry, plan: &WeightGradPlan, xs: &[u16], gyt: &[u16], dw: &mut [f32]) {
    let k = g.spec.weight_rows(g.ci);
    assert!(weight_grad_supported(g, Isa::active()), "no AMX weight gradient for this layer");
    assert!(xs.len() >= bf16::paired_input_len(g) + weight_grad_slack(g), "paired input (with the slack) too short");
    assert!(gyt.len() >= transposed_gradient_len(g), "transposed gradient too short");
    assert!(dw.len() >= k * g.co, "weight gradient too short");
    // What the tiles read and write, from the plan they follow (independently of the
    // slack): the furthest B row inside `xs`, every chunk's A block inside `gyt`, every
    // tap group's 16 rows inside dW.
    assert!(plan.paired_input_end() <= xs.len(), "the weight gradient's last tile reads past the paired input");
    assert!(
        plan.chunk_bases.len() * g.co * plan.pairs * 2 <= gyt.len(),
        "more chunks than the transposed gradient holds"
    );
    assert!(plan.group_taps.iter().all(|&t| t + 16 <= k), "a tap group past the weight gradient's rows");
    #[cfg(target_arch = "x86_64")]
    // SAFETY: the CPU has AMX-BF16 and the process its tile state (weight_grad_supported);
    // every read and write the plan implies checked above.
    unsafe {
        tiles_weight_grad(g.co, plan, xs, gyt, dw)
    }
}

/// Which tiles of the paired input and the transposed gradient the weight gradient
/// multiplies: B rows at `2·(chunk_bases[i] + group_offsets[j] + p·pair_step)` (bf16
/// index, p < `pairs`), A rows chunk i's block of the transposed gradient.
pub(super) struct WeightGradPlan {
    /// Paired-input offset (before the doubling) of each chunk's first position pair.
    pub(super) chunk_bases: Vec<usize>,
    /// Offset of each group of 16 consecutive taps from a chunk's base.
    pub(super) group_offsets: Vec<usize>,
    /// Row of dW of each group's first tap.
    pub(super) group_taps: Vec<usize>,
    /// Position pairs per chunk (half the tiles' K), 1 to 16.
    pub(super) pairs: usize,
    /// Offset between consecutive pairs of a chunk.
    pub(super) pair_step: usize,
}

impl WeightGradPlan {
    /// The plan of layer `g`: a chunk per output row (or per part of a row,
    /// [`row_chunks`]), a group per 16 consecutive taps of each run of k_w·C_in.
    pub(super) fn new(g: &Geometry) -> WeightGradPlan {
        let [kt, kh, kw] = g.spec.kernel;
        let run = kw * g.ci;
        let (mut group_offsets, mut group_taps) = (Vec::new(), Vec::new());
        for dt in 0..kt {
            for dh in 0..kh {
                let off = super::direct::tap_offset(g, dt, dh);
                for i in (0..run).step_by(16) {
                    group_offsets.push(off + i);
                    group_taps.push((dt * kh + dh) * run + i);
                }
            }
        }
        let (chunks, pairs) = row_chunks(g);
        let pair_step = 2 * g.spec.stride[1] * g.ci; // padded values between a row's pairs
        let mut chunk_bases = Vec::with_capacity(g.to * g.ho * chunks);
        for row in 0..g.to * g.ho {
            let [first]: [usize; 1] = super::direct::input_offsets(g, row * g.wo);
            chunk_bases.extend((0..chunks).map(|c| first + c * pairs * pair_step));
        }
        WeightGradPlan { chunk_bases, group_offsets, group_taps, pairs, pair_step }
    }

    /// One past the last bf16 value of the paired input the B tiles read: the last
    /// chunk's last pair at the furthest group of 16 taps.
    fn paired_input_end(&self) -> usize {
        let (base, group) = (self.chunk_bases.iter().max(), self.group_offsets.iter().max());
        base.zip(group).map_or(0, |(b, o)| 2 * (b + (self.pairs - 1) * self.pair_step + o + 16))
    }
}

/// The tile plan for C_out (4 tiles: two channel groups × two tap groups, or one
/// channel group × three tap groups for C_out 16).
///
/// # Safety
/// The CPU has AMX-BF16 and the process its tile state; every read `plan` implies lies
/// in `xs` and `gyt`, and `dw` holds every group's rows of C_out.
#[cfg(target_arch = "x86_64")]
unsafe fn tiles_weight_grad(co: usize, plan: &WeightGradPlan, xs: &[u16], gyt: &[u16], dw: &mut [f32]) {
    // SAFETY: forwarded from the caller.
    unsafe {
        if co == 16 {
            tiles::weight_grad::<1, 3>(co, plan, xs, gyt, dw)
        } else {
            tiles::weight_grad::<2, 2>(co, plan, xs, gyt, dw)
        }
    }
}

#[cfg(target_arch = "x86_64")]
mod tiles;

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::ops::ConvSpec;

    /// Whether this test process runs the AMX kernels; a CPU that has them under an
    /// operating system that enables them, on the `avx512` path with `PEDNAV_AMX`
    /// unset, must (else Linux refused the tile state, which would silently cost the speed).
    pub(super) fn runs_amx() -> bool {
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

    /// The AMX weight gradient equals the AVX-512 BF16 one (itself checked against
    /// the f32 kernels on rounded data) on the encoders' layer shapes: rows of one
    /// chunk with even and odd W_out (the 3D-TCN's second layer at 42² and 84²), a
    /// spatial stride of 3 over 32 channels (its third layer at 84²), rows of two
    /// chunks (the frame-stacking encoder's first layer at 84², and a 2D layer of
    /// W_out 39), C_out 16 with tap groups that three does not divide, C_out 32 with
    /// an odd number of tap groups (the last pass fills half the C tiles), and a
    /// temporal layer.
    #[test]
    fn amx_weight_gradient_equals_the_avx512_bf16_one() {
        if !runs_amx() {
            return;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for (co, ci, spec, (t, h, w)) in [
            (32, 16, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), (7, 21, 21)),
            (32, 16, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), (5, 42, 42)),
            (64, 32, ConvSpec::spatiotemporal(2, 4, 3, 3, 0), (13, 21, 21)),
            (16, 16, ConvSpec::spatial(4, 2, 1), (1, 84, 84)),
            (16, 32, ConvSpec::spatial(2, 1, 0), (1, 5, 40)),
            (32, 16, ConvSpec::spatial(3, 1, 1), (1, 12, 12)),
            (64, 64, ConvSpec::temporal(2, 1), (3, 5, 5)),
        ] {
            let spec = ConvSpec { bf16: true, ..spec };
            let g = Geometry::new(spec, &[1, t, h, w, ci], &[spec.weight_rows(ci), co]).unwrap();
            assert!(weight_grad_supported(&g, Isa::Avx512), "C_out {co} C_in {ci}");
            let mut rand_vec = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.random_range(-1.0..1.0)).collect() };
            let (x, gy, start) = (rand_vec(g.in_len()), rand_vec(g.out_len()), rand_vec(spec.weight_rows(ci) * co));
            let mut xp = vec![0f32; g.padded_len()];
            super::super::direct::pad_frames(&g, &x, &mut xp);
            let mut xs = vec![0u16; bf16::paired_input_len(&g) + weight_grad_slack(&g)];
            bf16::pair_positions(&g, &xp, &mut xs);
            let mut gys = vec![0u16; bf16::paired_gradient_len(&g)];
            bf16::pair_gradients(&g, &gy, &mut gys);
            // NaN bit patterns: every transposed value must be written.
            let mut gyt = vec![0xffc0u16; transposed_gradient_len(&g)];
            transpose_gradients(&g, &gys, &mut gyt);
            let mut dw_ref = start.clone();
            bf16::weight_grad(&g, Isa::Avx512, &xs, &gys, &mut dw_ref);
            let mut dw = start;
            weight_grad(&g, &WeightGradPlan::new(&g), &xs, &gyt, &mut dw);
            for (u, v) in dw.iter().zip(&dw_ref) {
                assert!((u - v).abs() <= 1e-4 * (1.0 + v.abs()), "C_out {co} C_in {ci} ({t}, {h}, {w}): {u} vs {v}");
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
