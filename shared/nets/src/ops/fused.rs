//! In-place element-wise kernels for the optimiser's loops on the CPU: the AdamW
//! step, the Polyak average of the target networks and the squared norm of a
//! gradient.
//!
//! Why: written with candle's ops, one AdamW step is a dozen element-wise ops per
//! parameter, each allocating (and zeroing) a new array and, from 64 Ki elements,
//! meeting candle's thread pool at a barrier; over the ≈ 1 M parameters of the CPU
//! pixel preset that was ≈ 10 % of the learner's time in a real run (AdamW 7.7 %,
//! the gradient norms 1.2 %, the soft update 0.9 %, perf at 25 Hz over 25 s of a
//! 2-actor run, docs/performance.md). Here each is one pass over its arrays,
//! compiled for the instruction set of [`Isa::active`], and split over the rayon
//! pool from [`PARALLEL_MIN`] elements.
//!
//! Invariant: every kernel computes its formula (below, per element) on f32 with a
//! fused multiply-add where the instruction set has one, and writes nothing but its
//! output arrays; the tests compare every instruction set with the formula in f64,
//! and [`crate::optim`]'s compare the fused AdamW with the same step written in
//! candle's ops.
//!
//! Subnormals: the AdamW step never stores a subnormal moment, and from normal
//! gradients and moments it forms no subnormal product (a subnormal incoming gradient,
//! or an exact near-cancellation inside a fused multiply-add, can still make one, once,
//! before it is flushed). A parameter whose gradient stays zero (a feature behind a
//! ReLU that no sample of the batch activates) has its first moment shrink by β₁ every
//! step, through the subnormal range down to zero; on Intel cores a multiply or fused
//! multiply-add with a subnormal operand or result takes a microcode assist of the
//! order of a hundred cycles. After 300 k env steps of the default preset 7.5 % of the
//! moments were subnormal (a third of the policy's first fully connected layer), and
//! this kernel took 16 % of the learner's time on a Xeon (perf, docs/performance.md;
//! on a Zen 4 the step, soft update and norms together measured 2.5 %). So moments
//! below [`MOMENT_FLOOR`] (2⁻¹⁰⁰ ≈ 7.9e-31) are stored as zero, a gradient below it
//! adds nothing to the first moment, and one below [`SQUARE_FLOOR`] (2⁻⁵⁰ ≈ 8.9e-16)
//! nothing to the second. (In effect, from a zero moment, a gradient below
//! 2⁻¹⁰⁰/(1 − β₁) ≈ 7.9e-30 leaves no first moment and one below 2⁻⁵⁰/√(1 − β₂) ≈
//! 2.8e-14 no second: what they would add is itself below the floor.) What that
//! changes is far below f32's resolution: a first moment of 2⁻¹⁰⁰ moves its parameter
//! by at most lr·2⁻¹⁰⁰/((1 − β₁)·ε) ≈ lr·8e-22 a step; a second moment flushed below
//! 2⁻¹⁰⁰ moves √v̂ by at most 2⁻⁵⁰/√(1 − β₂) ≈ 2.8e-6·ε (early in training, when the
//! bias correction 1 − β₂ᵗ is smallest), and a squared gradient below 2⁻¹⁰⁰ moves it
//! by less than 10⁻⁷·ε. (PyTorch computes the same formula with the CPU's default
//! handling of subnormals, which is what made this kernel slow; flushing them
//! process-wide through MXCSR is not an option in Rust, whose compiler assumes the
//! default floating-point environment.)
//!
//! Locking: an op here holds the destination parameter's storage lock while its
//! chunks run on rayon's pool, and a waiting worker may pick up other jobs from the
//! pool. So no thread may run candle ops on the same parameters through the pool
//! at the same time (true in every process: each owns its networks and updates them
//! from one thread).

use std::cell::RefCell;

use candle_core::{CpuStorage, InplaceOp2, Layout, Tensor};
use rayon::prelude::*;

use super::Isa;
use super::{cpu_f32, with_cpu_f32};

/// Arrays this long or longer are split over the rayon pool (candle's own threshold
/// for its element-wise ops).
pub const PARALLEL_MIN: usize = 64 * 1024;

/// Elements per rayon task above [`PARALLEL_MIN`].
const CHUNK: usize = 16 * 1024;

/// Moments smaller in magnitude are stored as zero, and gradients smaller in magnitude
/// add nothing to the first moment: 2⁻¹⁰⁰ (module docs, *Subnormals*).
pub const MOMENT_FLOOR: f32 = f32::from_bits(27 << 23);

/// Gradients smaller in magnitude add nothing to the second moment (their square would
/// be below [`MOMENT_FLOOR`]): 2⁻⁵⁰.
pub const SQUARE_FLOOR: f32 = f32::from_bits(77 << 23);

/// `x`, or zero where its magnitude is below [`MOMENT_FLOOR`] (NaN stays NaN).
#[inline(always)]
fn above_floor(x: f32) -> f32 {
    if x.abs() < MOMENT_FLOOR { 0.0 } else { x }
}

/// `a·b + c`, fused where the instruction set has the instruction.
#[inline(always)]
fn madd<const FMA: bool>(a: f32, b: f32, c: f32) -> f32 {
    if FMA { a.mul_add(b, c) } else { a * b + c }
}

/// The scalars of one AdamW step (the same for every element).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AdamScalars {
    /// Learning rate.
    pub lr: f32,
    /// β₁.
    pub beta1: f32,
    /// β₂.
    pub beta2: f32,
    /// 1 − β₁ and 1 − β₂, computed in f64 (from the f32 β₂ = 0.999 the difference
    /// would be 1.3e-5 off, out of proportion with the bias correction 1 − β₂ᵗ).
    pub one_minus_beta: [f32; 2],
    /// ε.
    pub eps: f32,
    /// Bias corrections 1 − β₁ᵗ and 1 − β₂ᵗ.
    pub bias_correction: [f32; 2],
    /// 1 − lr·weight decay (decoupled decay).
    pub decay: f32,
    /// Factor on the gradient (global-norm clipping; 1 without).
    pub clip: f32,
}

/// Per element, with g = clip·gᵢ: m ← β₁m + (1 − β₁)g, v ← β₂v + (1 − β₂)g²,
/// p ← decay·p − lr·(m / bc₁) / (√(v / bc₂) + ε) — PyTorch's AdamW — with the
/// floors of the module docs (*Subnormals*) on g, g² and the stored moments.
#[inline(always)]
fn adam_impl<const FMA: bool>(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], k: &AdamScalars) {
    let n = p.len();
    let (g, m, v) = (&g[..n], &mut m[..n], &mut v[..n]);
    let [bc1, bc2] = k.bias_correction;
    let [b1c, b2c] = k.one_minus_beta;
    for i in 0..n {
        let gi = g[i] * k.clip;
        let square = if gi.abs() < SQUARE_FLOOR { 0.0 } else { gi * gi };
        let mi = above_floor(madd::<FMA>(m[i], k.beta1, above_floor(gi) * b1c));
        let vi = above_floor(madd::<FMA>(v[i], k.beta2, square * b2c));
        m[i] = mi;
        v[i] = vi;
        let step = (mi / bc1) / ((vi / bc2).sqrt() + k.eps);
        p[i] = madd::<FMA>(-k.lr, step, p[i] * k.decay);
    }
}

multiversioned! {
    /// [`adam_impl`] for the best instruction set of this CPU.
    fn adam_block(p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], k: &AdamScalars) => adam_impl
}

/// Per element: t ← keep·t + w·s (the Polyak average with keep = 1 − τ, w = τ).
#[inline(always)]
fn lerp_impl<const FMA: bool>(t: &mut [f32], s: &[f32], keep: f32, w: f32) {
    let s = &s[..t.len()];
    for (ti, &si) in t.iter_mut().zip(s) {
        *ti = madd::<FMA>(w, si, *ti * keep);
    }
}

multiversioned! {
    /// [`lerp_impl`] for the best instruction set of this CPU.
    fn lerp_block(t: &mut [f32], s: &[f32], keep: f32, w: f32) => lerp_impl
}

/// Σ xᵢ² in f64, over eight partial sums (so the additions vectorise).
#[inline(always)]
fn sum_squares_impl<const FMA: bool>(x: &[f32], out: &mut f64) {
    let mut acc = [0f64; 8];
    let blocks = x.chunks_exact(8);
    let tail = blocks.remainder();
    for b in blocks {
        for (a, &xi) in acc.iter_mut().zip(b) {
            let xi = f64::from(xi);
            *a = if FMA { xi.mul_add(xi, *a) } else { xi * xi + *a };
        }
    }
    let tail: f64 = tail.iter().map(|&xi| f64::from(xi) * f64::from(xi)).sum();
    *out = acc.iter().sum::<f64>() + tail;
}

multiversioned! {
    /// [`sum_squares_impl`] for the best instruction set of this CPU.
    fn sum_squares_block(x: &[f32], out: &mut f64) => sum_squares_impl
}

/// One AdamW step of `p` (in place) from its gradient `g` and its moments `m`, `v`
/// (updated in place), all of one length, on instruction set `isa`.
pub fn adam_slices(isa: Isa, p: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32], k: &AdamScalars) {
    assert!(g.len() == p.len() && m.len() == p.len() && v.len() == p.len(), "AdamW: arrays of different lengths");
    if p.len() < PARALLEL_MIN {
        return adam_block(isa, p, g, m, v, k);
    }
    p.par_chunks_mut(CHUNK)
        .zip(g.par_chunks(CHUNK))
        .zip(m.par_chunks_mut(CHUNK).zip(v.par_chunks_mut(CHUNK)))
        .for_each(|((p, g), (m, v))| adam_block(isa, p, g, m, v, k));
}

/// t ← keep·t + w·s in place, both of one length, on instruction set `isa`.
pub fn lerp_slices(isa: Isa, t: &mut [f32], s: &[f32], keep: f32, w: f32) {
    assert_eq!(t.len(), s.len(), "lerp: arrays of different lengths");
    if t.len() < PARALLEL_MIN {
        return lerp_block(isa, t, s, keep, w);
    }
    t.par_chunks_mut(CHUNK).zip(s.par_chunks(CHUNK)).for_each(|(t, s)| lerp_block(isa, t, s, keep, w));
}

/// Σ xᵢ² in f64 on instruction set `isa`.
pub fn sum_squares_slice(isa: Isa, x: &[f32]) -> f64 {
    let mut out = 0.0;
    sum_squares_block(isa, x, &mut out);
    out
}

/// The contiguous f32 data of a CPU storage, writable.
fn f32_mut<'a>(s: &'a mut CpuStorage, l: &Layout, what: &str) -> candle_core::Result<&'a mut [f32]> {
    let range = l.contiguous_offsets();
    match s {
        CpuStorage::F32(data) => match range {
            Some((a, b)) => Ok(&mut data[a..b]),
            None => candle_core::bail!("{what} must be contiguous"),
        },
        _ => candle_core::bail!("{what} must be f32"),
    }
}

/// The AdamW step as a candle in-place op on the parameter, with the gradient as
/// its operand and the moments borrowed from the optimiser.
struct AdamOp<'a> {
    m: RefCell<&'a mut [f32]>,
    v: RefCell<&'a mut [f32]>,
    k: AdamScalars,
}

impl InplaceOp2 for AdamOp<'_> {
    fn name(&self) -> &'static str {
        "pednav-adamw-step"
    }

    fn cpu_fwd(&self, s1: &mut CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> candle_core::Result<()> {
        let p = f32_mut(s1, l1, "AdamW: the parameter")?;
        let g = cpu_f32(s2, l2, "AdamW: the gradient")?;
        let (mut m, mut v) = (self.m.borrow_mut(), self.v.borrow_mut());
        if g.len() != p.len() || m.len() != p.len() || v.len() != p.len() {
            candle_core::bail!(
                "AdamW: parameter of {} values, gradient {}, moments {} and {}",
                p.len(),
                g.len(),
                m.len(),
                v.len()
            );
        }
        adam_slices(Isa::active(), p, g, &mut m, &mut v, &self.k);
        Ok(())
    }
}

/// One AdamW step of the CPU parameter `p` from its gradient `g` (any layout),
/// with host moments `m`, `v` updated in place.
pub fn adam_step(p: &Tensor, g: &Tensor, m: &mut [f32], v: &mut [f32], k: AdamScalars) -> candle_core::Result<()> {
    let g = g.contiguous()?;
    p.inplace_op2(&g, &AdamOp { m: RefCell::new(m), v: RefCell::new(v), k })
}

/// The Polyak average as a candle in-place op on the target parameter.
struct LerpOp {
    keep: f32,
    w: f32,
}

impl InplaceOp2 for LerpOp {
    fn name(&self) -> &'static str {
        "pednav-polyak"
    }

    fn cpu_fwd(&self, s1: &mut CpuStorage, l1: &Layout, s2: &CpuStorage, l2: &Layout) -> candle_core::Result<()> {
        let t = f32_mut(s1, l1, "soft update: the target parameter")?;
        let s = cpu_f32(s2, l2, "soft update: the source parameter")?;
        if s.len() != t.len() {
            candle_core::bail!("soft update: target of {} values, source {}", t.len(), s.len());
        }
        lerp_slices(Isa::active(), t, s, self.keep, self.w);
        Ok(())
    }
}

/// target ← (1 − τ)·target + τ·source in place, both CPU tensors of one shape.
pub fn polyak_in_place(target: &Tensor, source: &Tensor, tau: f64) -> candle_core::Result<()> {
    let source = source.contiguous()?;
    target.inplace_op2(&source, &LerpOp { keep: (1.0 - tau) as f32, w: tau as f32 })
}

/// Σ xᵢ² of a CPU f32 tensor, accumulated in f64.
pub fn sum_squares(x: &Tensor) -> candle_core::Result<f64> {
    let x = x.contiguous()?;
    with_cpu_f32(&x, "the gradient", |data| Ok(sum_squares_slice(Isa::active(), data)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::optim::AdamWConfig;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Lengths that exercise empty arrays, the 8-wide tails and the parallel split
    /// (with a last chunk shorter than the others).
    const LENGTHS: [usize; 5] = [0, 7, 33, 1000, PARALLEL_MIN + CHUNK / 2 + 3];

    fn random(rng: &mut ChaCha8Rng, n: usize, lo: f32, hi: f32) -> Vec<f32> {
        (0..n).map(|_| rng.random_range(lo..hi)).collect()
    }

    fn close(a: f32, b: f64, rel: f64) -> bool {
        (f64::from(a) - b).abs() <= rel * (1.0 + b.abs())
    }

    #[test]
    fn adam_matches_the_formula_in_f64_on_every_instruction_set() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let cfg = AdamWConfig { weight_decay: 0.01, ..AdamWConfig::with_lr(3e-4) };
        let k = AdamScalars::of_step(&cfg, 3, 0.7);
        for n in LENGTHS {
            let (p0, g) = (random(&mut rng, n, -1.0, 1.0), random(&mut rng, n, -2.0, 2.0));
            let (m0, v0) = (random(&mut rng, n, -0.1, 0.1), random(&mut rng, n, 0.0, 0.01));
            for isa in Isa::supported() {
                let (mut p, mut m, mut v) = (p0.clone(), m0.clone(), v0.clone());
                adam_slices(isa, &mut p, &g, &mut m, &mut v, &k);
                for i in 0..n {
                    let f = f64::from;
                    let gi = f(g[i]) * f(k.clip);
                    let mi = f(k.beta1) * f(m0[i]) + 0.1 * gi;
                    let vi = f(k.beta2) * f(v0[i]) + 0.001 * gi * gi;
                    let [bc1, bc2] = k.bias_correction.map(f);
                    let pi = f(k.decay) * f(p0[i]) - f(k.lr) * (mi / bc1) / ((vi / bc2).sqrt() + f(k.eps));
                    assert!(close(m[i], mi, 1e-6) && close(v[i], vi, 1e-6), "{isa} n {n} i {i}: moments");
                    assert!(close(p[i], pi, 1e-6), "{isa} n {n} i {i}: {} vs {pi}", p[i]);
                }
            }
        }
    }

    #[test]
    fn adam_never_stores_a_subnormal_moment_on_any_instruction_set() {
        // Gradients of zero (a dead feature), tiny ones around both floors and a
        // subnormal one; moments from a normal start, one just above the floor, one
        // subnormal (as a checkpoint written before the floors may hold).
        let grads = [0.0, 1e-40, 1e-35, 1.5 * MOMENT_FLOOR, 1e-17, 1e-15, 1e-3];
        let starts = [(1e-3, 1e-6), (1.1 * f64::from(MOMENT_FLOOR), 1e-30), (1e-39, 1e-40)];
        // Late in training: bias corrections of 1.
        let k = AdamScalars::of_step(&AdamWConfig::with_lr(3e-4), 1_000_000, 1.0);
        for isa in Isa::supported() {
            for &(m0, v0) in &starts {
                // 41 copies: whole vectors and a tail on every vector width.
                let n = 41 * grads.len();
                let g: Vec<f32> = grads.iter().cycle().take(n).copied().collect();
                let (mut p, mut m, mut v) = (vec![0.5f32; n], vec![m0 as f32; n], vec![v0 as f32; n]);
                for step in 0..1500 {
                    // From step 500 on, every gradient is zero: the moments decay.
                    let g = if step < 500 { g.clone() } else { vec![0.0; n] };
                    adam_slices(isa, &mut p, &g, &mut m, &mut v, &k);
                    for (i, (&mi, &vi)) in m.iter().zip(&v).enumerate() {
                        assert!(!mi.is_subnormal() && !vi.is_subnormal(), "{isa} step {step} i {i}: m {mi:e} v {vi:e}");
                        assert!(mi == 0.0 || mi.abs() >= MOMENT_FLOOR, "{isa} step {step} i {i}: m {mi:e}");
                        assert!(vi == 0.0 || vi >= MOMENT_FLOOR, "{isa} step {step} i {i}: v {vi:e}");
                    }
                }
                // 1000 steps of zero gradient bring a first moment of 1e-3 to zero
                // (0.9¹⁰⁰⁰ · 1e-3 is below the floor); the normal gradient's parameter moved.
                assert!(m.iter().all(|&mi| mi == 0.0), "{isa}: first moments left after decaying");
                assert!(p.iter().skip(grads.len() - 1).step_by(grads.len()).all(|&pi| pi < 0.5), "{isa}: no step");
            }
        }
    }

    #[test]
    fn polyak_and_sum_of_squares_match_the_formula_on_every_instruction_set() {
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for n in LENGTHS {
            let (t0, s) = (random(&mut rng, n, -1.0, 1.0), random(&mut rng, n, -1.0, 1.0));
            let expect: f64 = s.iter().map(|&x| f64::from(x) * f64::from(x)).sum();
            for isa in Isa::supported() {
                let mut t = t0.clone();
                lerp_slices(isa, &mut t, &s, 0.995, 0.005);
                for i in 0..n {
                    let want = 0.995 * f64::from(t0[i]) + 0.005 * f64::from(s[i]);
                    assert!(close(t[i], want, 1e-6), "{isa} n {n} i {i}: {} vs {want}", t[i]);
                }
                let got = sum_squares_slice(isa, &s);
                assert!((got - expect).abs() <= 1e-12 * (1.0 + expect), "{isa} n {n}: {got} vs {expect}");
            }
        }
    }

    #[test]
    fn the_ops_refuse_mismatched_operands_and_leave_the_parameter_unchanged() {
        let dev = candle_core::Device::Cpu;
        let p = candle_core::Var::new(&[1f32, 2.0, 3.0], &dev).unwrap();
        let g = Tensor::new(&[1f32, 1.0], &dev).unwrap();
        let (mut m, mut v) = (vec![0f32; 3], vec![0f32; 3]);
        let k = AdamScalars::of_step(&AdamWConfig::with_lr(0.1), 1, 1.0);
        let err = adam_step(&p, &g, &mut m, &mut v, k).unwrap_err().to_string();
        assert!(err.contains("gradient 2"), "{err}");
        assert!(polyak_in_place(&p, &g, 0.5).is_err());
        assert_eq!(p.to_vec1::<f32>().unwrap(), vec![1.0, 2.0, 3.0]);
    }
}
