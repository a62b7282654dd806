//! One matrix product on explicit strides ([`matmul`] into a slice, [`matmul_new`]
//! into a fresh vector) through gemm's generic driver with the microkernels of
//! [`Isa::active`] ([`GemmOp`]), shared by the convolution and the fully connected op.
//!
//! Invariant: both go through [`product`], which checks that every operand slice
//! covers each element its strides address before any raw pointer reaches gemm; the
//! destination is a distinct borrow or a fresh allocation (it aliases neither
//! operand), and the instruction set is asserted supported by the CPU before its
//! microkernels run.

use gemm::Parallelism;

use crate::ops::Isa;

/// `dst (m×n) = [dst +] lhs (m×k) · rhs (k×n)` with explicit strides (row, column),
/// on gemm's kernels for [`Isa::active`].
#[allow(clippy::too_many_arguments)]
pub(in crate::ops) fn matmul(
    m: usize,
    n: usize,
    k: usize,
    dst: &mut [f32],
    accumulate: bool,
    lhs: &[f32],
    lhs_strides: (usize, usize),
    rhs: &[f32],
    rhs_strides: (usize, usize),
    par: Parallelism,
) {
    debug_assert!(dst.len() >= m * n);
    if m == 0 || n == 0 {
        return;
    }
    if k == 0 {
        if !accumulate {
            dst[..m * n].fill(0.0);
        }
        return;
    }
    // SAFETY: `dst` holds m·n floats (asserted in debug builds, addressed through the
    // row-major strides below) and, a distinct borrow, aliases neither operand.
    unsafe { product(Isa::active(), m, n, k, dst.as_mut_ptr(), accumulate, lhs, lhs_strides, rhs, rhs_strides, par) }
}

/// `lhs (m×k) · rhs (k×n)` as a new row-major vector that is never zero-filled: gemm
/// called without `accumulate` does not read its destination and writes each of its
/// m·n elements (a test holds a NaN-filled destination to that on every path), so
/// the fresh allocation gets its only values from the product. Used where a layer's
/// output or gradient is the product itself (zero-filling those took ≈ 1 % of a
/// pixel update in the profile).
#[allow(clippy::too_many_arguments)]
pub(in crate::ops) fn matmul_new(
    m: usize,
    n: usize,
    k: usize,
    lhs: &[f32],
    lhs_strides: (usize, usize),
    rhs: &[f32],
    rhs_strides: (usize, usize),
    par: Parallelism,
) -> Vec<f32> {
    if m <= 1 || n <= 1 || k == 0 {
        // gemm's matrix-vector paths view the destination as a slice, which must not
        // hold uninitialised floats; these products are vectors, their fill is cheap.
        let mut dst = vec![0f32; m * n];
        matmul(m, n, k, &mut dst, false, lhs, lhs_strides, rhs, rhs_strides, par);
        return dst;
    }
    let mut dst = Vec::with_capacity(m * n);
    // SAFETY: `dst` is a fresh allocation of m·n floats that aliases nothing, written
    // through its raw pointer only; gemm without `accumulate` writes every one of its
    // m·n elements before `set_len` exposes them.
    unsafe {
        product(Isa::active(), m, n, k, dst.as_mut_ptr(), false, lhs, lhs_strides, rhs, rhs_strides, par);
        dst.set_len(m * n);
    }
    dst
}

/// `dst (m×n, row-major) = [dst +] lhs · rhs` on `isa`'s kernels, after checking
/// that every element the operands' strides address lies inside its slice (m, n, k ≥ 1).
///
/// SAFETY: `dst` is valid for writes of m·n floats (and reads, with `accumulate`)
/// and aliases neither operand.
#[allow(clippy::too_many_arguments)]
unsafe fn product(
    isa: Isa,
    m: usize,
    n: usize,
    k: usize,
    dst: *mut f32,
    accumulate: bool,
    lhs: &[f32],
    lhs_strides: (usize, usize),
    rhs: &[f32],
    rhs_strides: (usize, usize),
    par: Parallelism,
) {
    assert!(lhs.len() > (m - 1) * lhs_strides.0 + (k - 1) * lhs_strides.1, "lhs too short for its strides");
    assert!(rhs.len() > (k - 1) * rhs_strides.0 + (n - 1) * rhs_strides.1, "rhs too short for its strides");
    let op = GemmOp {
        m,
        n,
        k,
        dst,
        dst_strides: (n, 1),
        accumulate,
        lhs: lhs.as_ptr(),
        lhs_strides,
        rhs: rhs.as_ptr(),
        rhs_strides,
        par,
    };
    // SAFETY: the operands cover their strides (asserted above); the caller vouches for `dst`.
    unsafe { op.run(isa) }
}

/// One gemm call with its operands (raw, checked by [`product`]).
struct GemmOp {
    m: usize,
    n: usize,
    k: usize,
    dst: *mut f32,
    /// (row, column) strides of `dst`.
    dst_strides: (usize, usize),
    accumulate: bool,
    lhs: *const f32,
    lhs_strides: (usize, usize),
    rhs: *const f32,
    rhs_strides: (usize, usize),
    par: Parallelism,
}

/// Call gemm's generic driver with the microkernels of one instruction set. The
/// `gemm` crate picks its kernels from the CPU alone; going through its public
/// generic entry point (the one its own dispatch calls) lets `PEDNAV_ISA` force
/// the AVX2 kernels on an AVX-512 CPU, so both paths can be measured on one machine.
macro_rules! gemm_with {
    ($op:expr, $simd:ty, $($uk:ident)::+, $lanes:expr) => {{
        use $($uk)::+ as uk;
        let op = $op;
        let simd = <$simd as gemm_common::simd::MixedSimd<f32, f32, f32, f32>>::try_new()
            .expect("the instruction set was checked before dispatch");
        gemm_common::gemm::gemm_basic_generic::<
            _,
            f32,
            { $lanes },
            { uk::MR_DIV_N * $lanes },
            { uk::NR },
            { uk::MR_DIV_N },
            { uk::H_M },
            { uk::H_N },
        >(
            simd,
            op.m,
            op.n,
            op.k,
            op.dst,
            op.dst_strides.1 as isize,
            op.dst_strides.0 as isize,
            op.accumulate,
            op.lhs,
            op.lhs_strides.1 as isize,
            op.lhs_strides.0 as isize,
            op.rhs,
            op.rhs_strides.1 as isize,
            op.rhs_strides.0 as isize,
            1.0,
            1.0,
            false,
            false,
            false,
            |a, b, c| a * b + c,
            &uk::UKR,
            &uk::H_UKR,
            false,
            op.par,
        )
    }};
}

impl GemmOp {
    /// The same product with a column-major destination where ours is row-major:
    /// C = A·B as Cᵀ = Bᵀ·Aᵀ (operands swapped, strides exchanged). gemm's
    /// microkernels store a column-major destination with vector stores and a
    /// row-major one through a scalar copy, so its own front end (`gemm::gemm`)
    /// makes this swap; calling the generic driver directly, we make it here.
    fn column_major(self) -> GemmOp {
        if self.dst_strides.1 >= self.dst_strides.0 {
            return self;
        }
        let flip = |(r, c): (usize, usize)| (c, r);
        GemmOp {
            m: self.n,
            n: self.m,
            dst_strides: flip(self.dst_strides),
            lhs: self.rhs,
            lhs_strides: flip(self.rhs_strides),
            rhs: self.lhs,
            rhs_strides: flip(self.lhs_strides),
            ..self
        }
    }

    /// SAFETY: the operands cover every element their strides address, `dst` aliases
    /// neither input, and `isa` is supported by this CPU (asserted).
    unsafe fn run(self, isa: Isa) {
        assert!(isa.is_supported(), "instruction set {isa} is not available on this CPU");
        let op = self.column_major();
        // SAFETY: as documented on the function.
        unsafe {
            match isa {
                #[cfg(target_arch = "x86_64")]
                Isa::Avx512 => gemm_with!(op, gemm_common::simd::V4, gemm_f32::microkernel::avx512f::f32, 16),
                #[cfg(target_arch = "x86_64")]
                Isa::Avx2 => gemm_with!(op, gemm_common::simd::V3, gemm_f32::microkernel::fma::f32, 8),
                _ => gemm_with!(op, gemm_common::simd::Scalar, gemm_f32::microkernel::scalar::f32, 1),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(len: usize, seed: u32) -> Vec<f32> {
        (0..len).map(|i| (((i as u32).wrapping_mul(2_654_435_761) ^ seed) % 1000) as f32 / 500.0 - 1.0).collect()
    }

    /// The invariant `matmul_new` rests on: without `accumulate`, gemm neither reads
    /// its destination (a NaN there would reach the result) nor leaves an element
    /// unwritten — on every path this CPU has, on one thread and on the pool, for edge
    /// tiles, k beyond gemm's cache blocks (2,100), small products (its horizontal
    /// kernel) and every combination of row- and column-major operands (the linear
    /// layer's gradients read transposed operands in place).
    #[test]
    fn a_product_without_accumulate_ignores_and_overwrites_the_destination() {
        let shapes =
            [(2, 2, 1), (3, 5, 7), (17, 9, 33), (6, 5, 1100), (70, 33, 600), (40, 24, 2100), (8, 300, 40), (129, 7, 5)];
        for isa in Isa::supported() {
            for &(m, n, k) in &shapes {
                for (lhs_cols, rhs_cols, par) in (0..8).map(|i| {
                    (i & 1 == 1, i & 2 == 2, if i & 4 == 4 { Parallelism::Rayon(2) } else { Parallelism::None })
                }) {
                    let lhs = values(m * k, 1);
                    let rhs = values(k * n, 2);
                    // Column-major operands are read through swapped strides.
                    let ls = if lhs_cols { (1, m) } else { (k, 1) };
                    let rs = if rhs_cols { (1, k) } else { (n, 1) };
                    let mut want = vec![0f64; m * n];
                    for i in 0..m {
                        for j in 0..n {
                            want[i * n + j] =
                                (0..k).map(|p| lhs[i * ls.0 + p * ls.1] as f64 * rhs[p * rs.0 + j * rs.1] as f64).sum();
                        }
                    }
                    let mut dst = vec![f32::NAN; m * n];
                    // SAFETY: dst holds m·n floats and is distinct from the operands.
                    unsafe { product(isa, m, n, k, dst.as_mut_ptr(), false, &lhs, ls, &rhs, rs, par) };
                    for (i, (&got, &w)) in dst.iter().zip(&want).enumerate() {
                        assert!(
                            (got as f64 - w).abs() <= 1e-4 * (1.0 + w.abs()),
                            "{isa} {m}x{n}x{k} lhs column-major {lhs_cols} rhs column-major {rhs_cols} {par:?}: element {i} is {got}, expected {w}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn matmul_new_equals_matmul_into_zeros() {
        for &(m, n, k) in &[(0, 4, 3), (4, 0, 3), (4, 3, 0), (1, 9, 33), (9, 1, 33), (17, 9, 33), (70, 33, 600)] {
            let (lhs, rhs) = (values(m * k, 3), values(k * n, 4));
            let mut into = vec![0f32; m * n];
            matmul(m, n, k, &mut into, false, &lhs, (k, 1), &rhs, (n, 1), Parallelism::None);
            let new = matmul_new(m, n, k, &lhs, (k, 1), &rhs, (n, 1), Parallelism::Rayon(2));
            assert_eq!(new.len(), m * n);
            for (a, b) in new.iter().zip(&into) {
                assert!((a - b).abs() <= 1e-5 * (1.0 + b.abs()), "{m}x{n}x{k}: {a} against {b}");
            }
        }
    }
}
