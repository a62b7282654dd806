//! Fully connected layer `y = x·W + b` as a candle custom op.
//!
//! Why not candle's `matmul`: for the actor's policy step (one to a few rows) gemm
//! packs the whole weight matrix for every call — the encoder's 3152×256 layer is
//! 3.2 MB, so packing it cost more than the product (measured in the streaming
//! policy step). With at most [`GEMV_ROWS`] rows the kernel here reads each weight
//! row once and updates every output row from it (accumulators stay in L1), compiled
//! for AVX-512 / AVX2 + FMA when the CPU has them. Larger batches go to gemm, with
//! the bias added in the same pass over the output.
//!
//! Invariant: the forward is exactly `x·W + b` for x (M, K), W (K, N), b (N) (tested
//! against candle's matmul for small and large M and by finite differences); the
//! backward is dx = dy·Wᵀ, dW = xᵀ·dy, db = Σ_rows dy, on gemm with the transposed
//! operands read in place.

use candle_core::{CpuStorage, CustomOp3, Layout, Shape, Tensor};
use gemm::Parallelism;

use super::conv::matmul_new;
use super::{cpu_f32, with_cpu_f32};

/// Largest batch that takes the row-streaming kernel rather than gemm.
pub const GEMV_ROWS: usize = 8;

/// y (m × nc) = x (m × k) · W (k × nc) + b.
#[inline(always)]
fn small_batch_impl<const FMA: bool>(m: usize, k: usize, nc: usize, x: &[f32], w: &[f32], b: &[f32], y: &mut [f32]) {
    for row in y.chunks_exact_mut(nc) {
        row.copy_from_slice(&b[..nc]);
    }
    for i in 0..k {
        let wr = &w[i * nc..(i + 1) * nc];
        for (r, yr) in y.chunks_exact_mut(nc).take(m).enumerate() {
            let xv = x[r * k + i];
            if xv == 0.0 {
                continue; // ReLU features are often exactly zero.
            }
            for (o, &wv) in yr.iter_mut().zip(wr) {
                *o = if FMA { xv.mul_add(wv, *o) } else { xv * wv + *o };
            }
        }
    }
}

multiversioned! {
    /// `y = x·W + b` for few rows, each weight row read once, compiled for the best
    /// instruction set of this CPU. (Splitting the columns over two threads measured
    /// no faster for the 3152×256 encoder layer.)
    fn small_batch(m: usize, k: usize, nc: usize, x: &[f32], w: &[f32], b: &[f32], y: &mut [f32]) => small_batch_impl
}

struct LinearOp;

impl CustomOp3 for LinearOp {
    fn name(&self) -> &'static str {
        "pednav-linear"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (&[m, k], &[k2, n], &[n2]) = (l1.dims(), l2.dims(), l3.dims()) else {
            candle_core::bail!(
                "linear: expected x (M, K), W (K, N), b (N), got {:?}, {:?}, {:?}",
                l1.dims(),
                l2.dims(),
                l3.dims()
            );
        };
        if k != k2 || n != n2 {
            candle_core::bail!("linear: x is (M, {k}), W is ({k2}, {n}), b is ({n2}): sizes do not match");
        }
        let (x, w, b) = (cpu_f32(s1, l1, "input")?, cpu_f32(s2, l2, "weight")?, cpu_f32(s3, l3, "bias")?);
        let y = if m <= GEMV_ROWS {
            let mut y = vec![0f32; m * n];
            small_batch(super::Isa::active(), m, k, n, x, w, b, &mut y);
            y
        } else {
            let threads = rayon::current_num_threads();
            let par = if threads > 1 { Parallelism::Rayon(threads) } else { Parallelism::None };
            let mut y = matmul_new(m, n, k, x, (k, 1), w, (n, 1), par);
            for row in y.chunks_exact_mut(n.max(1)) {
                for (v, bv) in row.iter_mut().zip(b) {
                    *v += bv;
                }
            }
            y
        };
        Ok((CpuStorage::F32(y), Shape::from_dims(&[m, n])))
    }

    fn bwd(
        &self,
        x: &Tensor,
        w: &Tensor,
        _b: &Tensor,
        _y: &Tensor,
        dy: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let (m, k) = x.dims2()?;
        let n = w.dims2()?.1;
        let dy = dy.contiguous()?;
        let need_dx = x.track_op();
        let threads = rayon::current_num_threads();
        let par = if threads > 1 { Parallelism::Rayon(threads) } else { Parallelism::None };
        // The transposed operands are read in place through gemm's strides (candle's
        // strided copies of Wᵀ and xᵀ cost more than the products here).
        let (dx, dw, db) = with_cpu_f32(x, "input", |xs| {
            with_cpu_f32(w, "weight", |ws| {
                with_cpu_f32(&dy, "output gradient", |g| {
                    // dx (m×k) = dy (m×n) · Wᵀ (n×k)
                    let dx = need_dx.then(|| matmul_new(m, k, n, g, (n, 1), ws, (1, n), par));
                    // dW (k×n) = xᵀ (k×m) · dy (m×n)
                    let dw = matmul_new(k, n, m, xs, (1, k), g, (n, 1), par);
                    let mut db = vec![0f32; n];
                    for row in g.chunks_exact(n.max(1)) {
                        for (d, v) in db.iter_mut().zip(row) {
                            *d += v;
                        }
                    }
                    Ok((dx, dw, db))
                })
            })
        })?;
        let dev = x.device();
        Ok((
            dx.map(|v| Tensor::from_vec(v, (m, k), dev)).transpose()?,
            Some(Tensor::from_vec(dw, (k, n), dev)?),
            Some(Tensor::from_vec(db, n, dev)?),
        ))
    }
}

/// `y = x·W + b` for x (M, K), W (K, N), b (N); see the module docs. Other devices
/// (the `cuda` feature) use candle's matmul.
pub fn linear(x: &Tensor, w: &Tensor, b: &Tensor) -> candle_core::Result<Tensor> {
    if x.device().is_cpu() {
        x.contiguous()?.apply_op3(&w.contiguous()?, &b.contiguous()?, LinearOp)
    } else {
        x.contiguous()?.matmul(w)?.broadcast_add(b)
    }
}
