//! AdamW with inspectable state (for exact checkpoints), global-norm gradient
//! clipping and a non-finite guard.
//!
//! candle-nn's `AdamW` keeps its moments private, so a checkpoint could not restore
//! them; this one exposes them. The update is the same as PyTorch's `AdamW`
//! (decoupled weight decay, bias-corrected moments).
//!
//! On the CPU the moments are plain host arrays and each parameter's step is one
//! in-place pass over parameter, gradient and moments ([`crate::ops::fused`]);
//! on other devices the moments are tensors and the step is written in candle's
//! ops. Both compute the same formula (tested against each other on the CPU), except
//! that the fused step stores no subnormal moment: moments and gradients far below
//! f32's resolution of any step are taken as zero (`ops::fused`, *Subnormals*).
//!
//! Invariant: [`AdamW::step`] either applies a complete update to every parameter
//! or, when any gradient is non-finite, changes nothing and reports it.

use candle_core::backprop::GradStore;
use candle_core::{Device, Tensor, Var};
use serde::{Deserialize, Serialize};

use crate::error::{NetError, Result};
use crate::ops::fused::{self, AdamScalars};
use crate::params::ParamStore;

/// Optimiser settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct AdamWConfig {
    /// Learning rate.
    pub lr: f64,
    /// β₁.
    pub beta1: f64,
    /// β₂.
    pub beta2: f64,
    /// ε.
    pub eps: f64,
    /// Decoupled weight decay (Table IV's runs use 0).
    pub weight_decay: f64,
    /// Clip the global gradient norm to this value before the step (`None`: no clipping).
    pub max_grad_norm: Option<f64>,
}

impl AdamWConfig {
    /// PyTorch's defaults with the given learning rate and no weight decay.
    pub fn with_lr(lr: f64) -> AdamWConfig {
        AdamWConfig { lr, beta1: 0.9, beta2: 0.999, eps: 1e-8, weight_decay: 0.0, max_grad_norm: None }
    }
}

impl AdamScalars {
    /// The scalars of step `t` (1-based) of `cfg` with the gradient scaled by `clip`,
    /// computed in f64 and rounded once to f32.
    pub fn of_step(cfg: &AdamWConfig, t: i32, clip: f64) -> AdamScalars {
        AdamScalars {
            lr: cfg.lr as f32,
            beta1: cfg.beta1 as f32,
            beta2: cfg.beta2 as f32,
            one_minus_beta: [(1.0 - cfg.beta1) as f32, (1.0 - cfg.beta2) as f32],
            eps: cfg.eps as f32,
            bias_correction: [(1.0 - cfg.beta1.powi(t)) as f32, (1.0 - cfg.beta2.powi(t)) as f32],
            decay: (1.0 - cfg.lr * cfg.weight_decay) as f32,
            clip: clip as f32,
        }
    }
}

/// What one step did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum OptimStep {
    /// Parameters were updated; the global gradient norm before clipping.
    Applied {
        /// ‖g‖₂ over all parameters.
        grad_norm: f64,
    },
    /// A gradient was NaN or infinite; nothing changed.
    SkippedNonFinite,
}

/// The first and second moments of every parameter, in the parameters' order.
enum Moments {
    /// Parameters on the CPU: host arrays the fused step updates in place.
    Host { m: Vec<Vec<f32>>, v: Vec<Vec<f32>> },
    /// Parameters on another device: tensors the stock ops replace each step.
    Device { m: Vec<Tensor>, v: Vec<Tensor> },
}

/// AdamW over the parameters of one [`ParamStore`].
pub struct AdamW {
    cfg: AdamWConfig,
    params: Vec<(String, Var)>,
    moments: Moments,
    steps: u64,
}

impl AdamW {
    /// An optimiser for every parameter of `store`.
    pub fn new(store: &ParamStore, cfg: AdamWConfig) -> Result<AdamW> {
        let params = store.vars().to_vec();
        let moments = if store.device().is_cpu() {
            let zeros: Vec<Vec<f32>> = params.iter().map(|(_, p)| vec![0f32; p.elem_count()]).collect();
            Moments::Host { m: zeros.clone(), v: zeros }
        } else {
            let m = params.iter().map(|(_, v)| v.zeros_like()).collect::<candle_core::Result<Vec<_>>>()?;
            Moments::Device { v: m.clone(), m }
        };
        Ok(AdamW { cfg, params, moments, steps: 0 })
    }

    /// Settings.
    pub fn config(&self) -> &AdamWConfig {
        &self.cfg
    }

    /// Change the learning rate.
    pub fn set_lr(&mut self, lr: f64) {
        self.cfg.lr = lr;
    }

    /// Steps applied so far.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// Global L2 norm of the gradients of this optimiser's parameters (missing gradients
    /// count as 0). The per-tensor sums stay on the gradients' device and are added
    /// there: one read back to the host per call, not one per tensor (each read
    /// synchronises a GPU).
    pub fn grad_norm(&self, grads: &GradStore) -> Result<f64> {
        if let Moments::Host { .. } = self.moments {
            let mut sq = 0.0;
            for (_, p) in &self.params {
                if let Some(g) = grads.get(p.as_tensor()) {
                    sq += fused::sum_squares(g)?;
                }
            }
            // As the f32 sums of the other devices: a norm beyond f32 is not finite,
            // so the step is skipped (its squares would overflow the second moments).
            return Ok(if sq <= f64::from(f32::MAX) { sq.sqrt() } else { f64::INFINITY });
        }
        let mut parts = Vec::with_capacity(self.params.len());
        for (_, p) in &self.params {
            if let Some(g) = grads.get(p.as_tensor()) {
                parts.push(g.sqr()?.sum_all()?);
            }
        }
        if parts.is_empty() {
            return Ok(0.0);
        }
        let sq = Tensor::stack(&parts, 0)?.to_dtype(candle_core::DType::F64)?.sum_all()?.to_scalar::<f64>()?;
        Ok(sq.sqrt())
    }

    /// One AdamW step from `grads`.
    pub fn step(&mut self, grads: &GradStore) -> Result<OptimStep> {
        let norm = self.grad_norm(grads)?;
        self.step_with_norm(grads, norm)
    }

    /// One AdamW step from `grads` whose global norm the caller already computed
    /// with [`AdamW::grad_norm`] (so a caller that checks norms first does not pay twice).
    pub fn step_with_norm(&mut self, grads: &GradStore, norm: f64) -> Result<OptimStep> {
        if !norm.is_finite() {
            return Ok(OptimStep::SkippedNonFinite);
        }
        let clip = match self.cfg.max_grad_norm {
            Some(max) if norm > max => max / (norm + 1e-12),
            _ => 1.0,
        };
        self.steps += 1;
        let c = self.cfg;
        let t = self.steps as i32;
        let AdamW { params, moments, .. } = self;
        match moments {
            Moments::Host { m, v } => {
                let k = AdamScalars::of_step(&c, t, clip);
                for (((_, p), m), v) in params.iter().zip(m).zip(v) {
                    if let Some(g) = grads.get(p.as_tensor()) {
                        fused::adam_step(p.as_tensor(), g, m, v, k)?;
                    }
                }
            }
            Moments::Device { m, v } => {
                let bc1 = 1.0 - c.beta1.powi(t);
                let bc2 = 1.0 - c.beta2.powi(t);
                for (((_, p), m), v) in params.iter().zip(m).zip(v) {
                    let Some(g) = grads.get(p.as_tensor()) else { continue };
                    // Gradients come out of `backward` still attached to the update's
                    // graph (they are built from ops on tracked tensors). Detached, the
                    // moments hold plain values; attached, every step's moments would
                    // keep the previous step's moments and its whole forward/backward
                    // graph alive — memory would grow by one update's graph per step.
                    let g = g.detach();
                    let g = if clip < 1.0 { (g * clip)? } else { g };
                    *m = ((&*m * c.beta1)? + (&g * (1.0 - c.beta1))?)?.detach();
                    *v = ((&*v * c.beta2)? + (g.sqr()? * (1.0 - c.beta2))?)?.detach();
                    let m_hat = (&*m / bc1)?;
                    let v_hat = (&*v / bc2)?;
                    let update = (m_hat / (v_hat.sqrt()? + c.eps)?)?;
                    let decayed = (p.as_tensor() * (1.0 - c.lr * c.weight_decay))?;
                    p.set(&(decayed - (update * c.lr)?)?)?;
                }
            }
        }
        Ok(OptimStep::Applied { grad_norm: norm })
    }

    /// The moments as named tensors (`<param>.m`, `<param>.v`) for a checkpoint.
    pub fn state_tensors(&self) -> Vec<(String, Tensor)> {
        // A host moment has its parameter's element count (made so in `new` and
        // checked in `load_state`), so the shape always fits.
        let host = |x: &[f32], p: &Var| {
            Tensor::from_slice(x, p.shape(), &Device::Cpu).expect("a moment has its parameter's element count")
        };
        let mut out = Vec::with_capacity(2 * self.params.len());
        for (i, (name, p)) in self.params.iter().enumerate() {
            let (m, v) = match &self.moments {
                Moments::Host { m, v } => (host(&m[i], p), host(&v[i], p)),
                Moments::Device { m, v } => (m[i].clone(), v[i].clone()),
            };
            out.push((format!("{name}.m"), m));
            out.push((format!("{name}.v"), v));
        }
        out
    }

    /// Check that `tensors` holds a moment of the right shape for every parameter.
    pub fn check_state(&self, tensors: &std::collections::HashMap<String, Tensor>) -> Result<()> {
        self.prepare(tensors).map(|_| ())
    }

    /// Restore moments and step count; checks every tensor before changing anything.
    pub fn load_state(&mut self, steps: u64, tensors: &std::collections::HashMap<String, Tensor>) -> Result<()> {
        let (m, v) = self.prepare(tensors)?;
        self.moments = match self.moments {
            Moments::Host { .. } => {
                let host = |ts: Vec<Tensor>| -> Result<Vec<Vec<f32>>> {
                    ts.iter()
                        .map(|t| -> Result<Vec<f32>> {
                            Ok(t.flatten_all()?.to_dtype(candle_core::DType::F32)?.to_vec1()?)
                        })
                        .collect()
                };
                Moments::Host { m: host(m)?, v: host(v)? }
            }
            Moments::Device { .. } => Moments::Device { m, v },
        };
        self.steps = steps;
        Ok(())
    }

    fn prepare(&self, tensors: &std::collections::HashMap<String, Tensor>) -> Result<(Vec<Tensor>, Vec<Tensor>)> {
        let mut m = Vec::with_capacity(self.params.len());
        let mut v = Vec::with_capacity(self.params.len());
        for (name, p) in &self.params {
            for (suffix, out) in [("m", &mut m), ("v", &mut v)] {
                let key = format!("{name}.{suffix}");
                let t = tensors.get(&key).ok_or_else(|| NetError::Incompatible {
                    network: "optimizer".into(),
                    message: format!("moment `{key}` is missing"),
                })?;
                if t.dims() != p.dims() {
                    return Err(NetError::Incompatible {
                        network: "optimizer".into(),
                        message: format!("moment `{key}` has shape {:?}, parameter has {:?}", t.dims(), p.dims()),
                    });
                }
                out.push(t.to_device(p.device())?);
            }
        }
        Ok((m, v))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Two stores with the same random parameters, and the same loss's gradients.
    fn twin_stores(rng: &mut ChaCha8Rng) -> (ParamStore, ParamStore) {
        let (mut a, mut b) = (ParamStore::new("a", &Device::Cpu), ParamStore::new("b", &Device::Cpu));
        // One parameter below and one above the fused kernel's parallel threshold.
        for (name, n) in [("small", 37), ("large", fused::PARALLEL_MIN + 1001)] {
            let x: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
            a.insert(name, Tensor::new(x.as_slice(), &Device::Cpu).unwrap()).unwrap();
            b.insert(name, Tensor::new(x.as_slice(), &Device::Cpu).unwrap()).unwrap();
        }
        (a, b)
    }

    /// Σ c·x² over the store's parameters (non-linear, so moments and steps vary).
    fn grads(store: &ParamStore, c: &[Tensor]) -> GradStore {
        let mut loss = Tensor::new(0f32, &Device::Cpu).unwrap();
        for ((_, p), c) in store.vars().iter().zip(c) {
            loss = (loss + (p.as_tensor().sqr().unwrap() * c).unwrap().sum_all().unwrap()).unwrap();
        }
        loss.backward().unwrap()
    }

    #[test]
    fn the_fused_cpu_step_matches_the_step_in_candle_ops() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let (a, b) = twin_stores(&mut rng);
        let cfg = AdamWConfig { weight_decay: 0.01, max_grad_norm: Some(5.0), ..AdamWConfig::with_lr(1e-2) };
        let mut fused = AdamW::new(&a, cfg).unwrap();
        assert!(matches!(fused.moments, Moments::Host { .. }));
        // The same optimiser with tensor moments: the path other devices take.
        let mut stock = AdamW::new(&b, cfg).unwrap();
        let zeros = b.vars().iter().map(|(_, v)| v.zeros_like().unwrap()).collect::<Vec<_>>();
        stock.moments = Moments::Device { m: zeros.clone(), v: zeros };
        for step in 0..5 {
            let c = a
                .vars()
                .iter()
                .map(|(_, p)| {
                    let x: Vec<f32> = (0..p.elem_count()).map(|_| rng.random_range(-3.0..3.0)).collect();
                    Tensor::new(x.as_slice(), &Device::Cpu).unwrap()
                })
                .collect::<Vec<_>>();
            let (ga, gb) = (grads(&a, &c), grads(&b, &c));
            let (na, nb) = (fused.grad_norm(&ga).unwrap(), stock.grad_norm(&gb).unwrap());
            assert!((na - nb).abs() <= 1e-5 * nb, "step {step}: norms {na} vs {nb}");
            assert!(nb > 5.0 || step > 0, "the premise: clipping is active on the first step");
            fused.step_with_norm(&ga, na).unwrap();
            stock.step_with_norm(&gb, nb).unwrap();
            for ((name, p), (_, q)) in a.vars().iter().zip(b.vars()) {
                let (x, y) = (p.to_vec1::<f32>().unwrap(), q.to_vec1::<f32>().unwrap());
                for (i, (u, v)) in x.iter().zip(&y).enumerate() {
                    assert!((u - v).abs() <= 1e-5 * (1.0 + v.abs()), "step {step} {name}[{i}]: {u} vs {v}");
                }
            }
        }
        // The moments read back as tensors agree too.
        for ((k, s), (_, t)) in fused.state_tensors().iter().zip(stock.state_tensors()) {
            let (x, y) = (s.to_vec1::<f32>().unwrap(), t.to_vec1::<f32>().unwrap());
            // Relative to the array's scale (the second moments are ≈ 1e-6 here, and a
            // first moment may cancel to near zero).
            let scale = y.iter().fold(0f32, |a, v| a.max(v.abs()));
            let worst = x.iter().zip(&y).fold(0f32, |a, (u, v)| a.max((u - v).abs()));
            assert!(scale > 0.0 && worst <= 1e-5 * scale, "moment {k}: off by {worst}, scale {scale}");
        }
    }

    #[test]
    fn host_moments_survive_a_state_round_trip() {
        let mut rng = ChaCha8Rng::seed_from_u64(10);
        let (a, _) = twin_stores(&mut rng);
        let mut opt = AdamW::new(&a, AdamWConfig::with_lr(1e-3)).unwrap();
        let c = a.vars().iter().map(|(_, p)| p.ones_like().unwrap()).collect::<Vec<_>>();
        opt.step(&grads(&a, &c)).unwrap();
        let saved: std::collections::HashMap<String, Tensor> = opt.state_tensors().into_iter().collect();
        let mut restored = AdamW::new(&a, AdamWConfig::with_lr(1e-3)).unwrap();
        restored.load_state(opt.steps(), &saved).unwrap();
        for ((k, s), (_, t)) in opt.state_tensors().iter().zip(restored.state_tensors()) {
            assert_eq!(s.to_vec1::<f32>().unwrap(), t.to_vec1::<f32>().unwrap(), "moment {k}");
        }
        assert_eq!(restored.steps(), 1);
    }
}
