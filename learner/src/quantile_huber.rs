//! The critics' quantile Huber loss as one CPU op: its forward pass and its gradient
//! with respect to the predicted quantiles each in one pass over the (B, N, N′) pairs,
//! instead of ≈ 15 candle element-wise ops forward and their backward (each a
//! serial pass with an allocation over the 32 K pairs of the preset's batch, per critic).
//!
//! Per sample b, with δᵢⱼ = yⱼ − zᵢ, H_κ the Huber function and ρ = |τ̂ᵢ − 1{δᵢⱼ < 0}|:
//! ℓ_b = (1/(N·κ)) Σᵢ Σⱼ wⱼ·ρᵢⱼ·H_κ(δᵢⱼ), and ∂ℓ_b/∂zᵢ = −(1/(N·κ)) Σⱼ wⱼ·ρᵢⱼ·clamp(δᵢⱼ, −κ, κ)
//! (the indicator, the fractions τ̂, the targets y and the widths w carry no gradient).
//!
//! Invariant: the op is used only where those three inputs track no gradient, on the
//! CPU, in f32 ([`fused`] says `None` otherwise and the caller composes candle ops); its
//! loss equals that composition and its gradient equals finite differences (tested).

use candle_core::{CpuStorage, CustomOp1, DType, Layout, Shape, Tensor};

/// The loss of `pred` (B, N) as one op, or `None` where the op does not apply (another
/// device or dtype, or a gradient wanted through `target`, `taus` or `weights`).
pub(crate) fn fused(
    pred: &Tensor,
    target: &Tensor,
    taus: &Tensor,
    weights: &Tensor,
    kappa: f64,
) -> candle_core::Result<Option<Tensor>> {
    let constants = [target, taus, weights];
    if !pred.device().is_cpu()
        || pred.dtype() != DType::F32
        || constants.iter().any(|t| t.track_op() || t.dtype() != DType::F32 || !t.device().is_cpu())
    {
        return Ok(None);
    }
    let (b, n) = pred.dims2()?;
    let (tb, m) = target.dims2()?;
    if taus.dims() != [b, n] || target.dims() != weights.dims() || tb != b {
        candle_core::bail!(
            "quantile Huber loss: pred {:?}, target {:?}, taus {:?}, weights {:?} (want (B, N), (B, N′), (B, N), (B, N′))",
            pred.dims(),
            target.dims(),
            taus.dims(),
            weights.dims()
        );
    }
    let host = |t: &Tensor| t.flatten_all()?.to_vec1::<f32>();
    let op =
        QuantileHuber { target: host(target)?, taus: host(taus)?, weights: host(weights)?, n, m, kappa: kappa as f32 };
    Ok(Some(pred.contiguous()?.apply_op1(op)?))
}

/// The op: the constants of one loss, host-side.
struct QuantileHuber {
    /// y (B, N′).
    target: Vec<f32>,
    /// τ̂ (B, N).
    taus: Vec<f32>,
    /// w (B, N′).
    weights: Vec<f32>,
    n: usize,
    m: usize,
    kappa: f32,
}

impl QuantileHuber {
    /// For each sample's quantile zᵢ: Σⱼ wⱼ·ρᵢⱼ·f(δᵢⱼ) over the sample's targets.
    fn per_quantile(&self, pred: &[f32], f: impl Fn(f32) -> f32) -> Vec<f32> {
        let (n, m) = (self.n, self.m);
        let mut out = vec![0f32; pred.len()];
        for (bi, zs) in pred.chunks_exact(n).enumerate() {
            let (ys, ws) = (&self.target[bi * m..(bi + 1) * m], &self.weights[bi * m..(bi + 1) * m]);
            for (i, &z) in zs.iter().enumerate() {
                let tau = self.taus[bi * n + i];
                let mut acc = 0f32;
                for (&y, &w) in ys.iter().zip(ws) {
                    let delta = y - z;
                    let rho = (tau - if delta < 0.0 { 1.0 } else { 0.0 }).abs();
                    acc += w * rho * f(delta);
                }
                out[bi * n + i] = acc;
            }
        }
        out
    }

    fn huber(&self, delta: f32) -> f32 {
        let abs = delta.abs();
        let small = abs.min(self.kappa);
        0.5 * small * small + self.kappa * (abs - small)
    }
}

impl CustomOp1 for QuantileHuber {
    fn name(&self) -> &'static str {
        "pednav-quantile-huber"
    }

    fn cpu_fwd(&self, storage: &CpuStorage, layout: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let pred = pednav_nets::ops::cpu_f32(storage, layout, "quantile Huber loss: the predictions")?;
        let rows = self.per_quantile(pred, |d| self.huber(d));
        let scale = 1.0 / (self.n as f32 * self.kappa);
        let loss: Vec<f32> = rows.chunks_exact(self.n).map(|r| r.iter().sum::<f32>() * scale).collect();
        let b = loss.len();
        Ok((CpuStorage::F32(loss), Shape::from(b)))
    }

    fn bwd(&self, pred: &Tensor, _loss: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        let z = pred.flatten_all()?.to_vec1::<f32>()?;
        let g = grad.to_vec1::<f32>()?;
        let k = self.kappa;
        let mut dz = self.per_quantile(&z, |d| d.clamp(-k, k));
        let scale = -1.0 / (self.n as f32 * k);
        for (row, gb) in dz.chunks_exact_mut(self.n).zip(g) {
            for v in row {
                *v *= gb * scale;
            }
        }
        Ok(Some(Tensor::from_vec(dz, pred.shape(), pred.device())?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dsac::quantile_huber_composed;
    use candle_core::{Device, Var};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random(rng: &mut ChaCha8Rng, shape: (usize, usize), lo: f32, hi: f32) -> Tensor {
        let v: Vec<f32> = (0..shape.0 * shape.1).map(|_| rng.random_range(lo..hi)).collect();
        Tensor::from_vec(v, shape, &Device::Cpu).unwrap()
    }

    /// The op's loss equals candle's composition, and its gradient equals central
    /// finite differences of the loss (in f64 from the op's own forward) and the
    /// composition's autograd gradient — δ on both sides of ±κ and of 0.
    #[test]
    fn loss_and_gradient_equal_the_composition_and_finite_differences() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        for (b, n, m, kappa) in [(3, 4, 5, 1.0), (2, 8, 8, 2.0), (1, 1, 3, 0.5)] {
            let pred = Var::from_tensor(&random(&mut rng, (b, n), -3.0, 3.0)).unwrap();
            let target = random(&mut rng, (b, m), -3.0, 3.0);
            let taus = random(&mut rng, (b, n), 0.0, 1.0);
            let weights = random(&mut rng, (b, m), 0.0, 1.0);
            let fused_loss = fused(pred.as_tensor(), &target, &taus, &weights, kappa).unwrap().expect("applies");
            let composed = quantile_huber_composed(pred.as_tensor(), &target, &taus, &weights, kappa).unwrap();
            let (a, c): (Vec<f32>, Vec<f32>) = (fused_loss.to_vec1().unwrap(), composed.to_vec1().unwrap());
            for (u, v) in a.iter().zip(&c) {
                assert!((u - v).abs() <= 1e-5 * (1.0 + v.abs()), "loss {u} vs {v}");
            }
            // Weighted sums so every sample's gradient is scaled differently.
            let coef = random(&mut rng, (1, b), 0.5, 2.0).squeeze(0).unwrap();
            let grad_of = |loss: &Tensor| {
                let g = (loss * &coef).unwrap().sum_all().unwrap().backward().unwrap();
                g.get(pred.as_tensor()).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap()
            };
            let (g_fused, g_composed) = (grad_of(&fused_loss), grad_of(&composed));
            let z0 = pred.as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let cw = coef.to_vec1::<f32>().unwrap();
            let objective = |z: &[f32]| -> f64 {
                let t = Tensor::from_vec(z.to_vec(), (b, n), &Device::Cpu).unwrap();
                let l = fused(&t, &target, &taus, &weights, kappa).unwrap().unwrap().to_vec1::<f32>().unwrap();
                l.iter().zip(&cw).map(|(x, c)| *x as f64 * *c as f64).sum()
            };
            let eps = 1e-3f32;
            for i in 0..b * n {
                let (mut up, mut down) = (z0.clone(), z0.clone());
                up[i] += eps;
                down[i] -= eps;
                let fd = (objective(&up) - objective(&down)) / (2.0 * eps as f64);
                let tol = 2e-3 * (1.0 + fd.abs());
                assert!((g_fused[i] as f64 - fd).abs() <= tol, "z[{i}]: op {} vs finite differences {fd}", g_fused[i]);
                assert!(
                    (g_fused[i] - g_composed[i]).abs() <= 1e-5 * (1.0 + g_composed[i].abs()),
                    "z[{i}]: op vs autograd"
                );
            }
        }
    }

    /// Where a gradient is wanted through the constants, or off the CPU's f32, the op
    /// stands aside.
    #[test]
    fn stands_aside_when_a_constant_tracks_a_gradient() {
        let mut rng = ChaCha8Rng::seed_from_u64(2);
        let pred = random(&mut rng, (2, 3), -1.0, 1.0);
        let target = Var::from_tensor(&random(&mut rng, (2, 4), -1.0, 1.0)).unwrap();
        let (taus, weights) = (random(&mut rng, (2, 3), 0.0, 1.0), random(&mut rng, (2, 4), 0.0, 1.0));
        assert!(fused(&pred, target.as_tensor(), &taus, &weights, 1.0).unwrap().is_none());
        assert!(fused(&pred, &target.as_tensor().detach(), &taus, &weights, 1.0).unwrap().is_some());
        let half = pred.to_dtype(DType::F64).unwrap();
        assert!(fused(&half, &target.as_tensor().detach(), &taus, &weights, 1.0).unwrap().is_none());
    }
}
