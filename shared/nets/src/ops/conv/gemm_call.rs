//! One matrix product on explicit strides ([`matmul`]) through gemm's generic driver
//! with the microkernels of [`Isa::active`] ([`GemmOp`]), shared by the convolution
//! and the fully connected op.
//!
//! Invariant: [`matmul`] checks that every slice covers each element its strides
//! address before any raw pointer reaches gemm, the destination is a distinct borrow
//! (it aliases neither operand), and the instruction set is asserted supported by the
//! CPU before its microkernels run.

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
    assert!(lhs.len() > (m - 1) * lhs_strides.0 + (k - 1) * lhs_strides.1);
    assert!(rhs.len() > (k - 1) * rhs_strides.0 + (n - 1) * rhs_strides.1);
    let op = GemmOp {
        m,
        n,
        k,
        dst: dst.as_mut_ptr(),
        dst_strides: (n, 1),
        accumulate,
        lhs: lhs.as_ptr(),
        lhs_strides,
        rhs: rhs.as_ptr(),
        rhs_strides,
        par,
    };
    // SAFETY: the slices cover every element addressed by the strides (asserted
    // above), and `dst` does not alias the inputs (distinct borrows).
    unsafe { op.run(Isa::active()) }
}

/// One gemm call with its operands (raw, checked by [`matmul`]).
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
