//! AdamW with inspectable state (for exact checkpoints), global-norm gradient
//! clipping and a non-finite guard.
//!
//! candle-nn's `AdamW` keeps its moments private, so a checkpoint could not restore
//! them; this one exposes them. The update is the same as PyTorch's `AdamW`
//! (decoupled weight decay, bias-corrected moments).
//!
//! Invariant: [`AdamW::step`] either applies a complete update to every parameter
//! or, when any gradient is non-finite, changes nothing and reports it.

use candle_core::backprop::GradStore;
use candle_core::{Tensor, Var};
use serde::{Deserialize, Serialize};

use crate::error::{NetError, Result};
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

/// AdamW over the parameters of one [`ParamStore`].
pub struct AdamW {
    cfg: AdamWConfig,
    params: Vec<(String, Var)>,
    m: Vec<Tensor>,
    v: Vec<Tensor>,
    steps: u64,
}

impl AdamW {
    /// An optimiser for every parameter of `store`.
    pub fn new(store: &ParamStore, cfg: AdamWConfig) -> Result<AdamW> {
        let params = store.vars().to_vec();
        let m = params.iter().map(|(_, v)| v.zeros_like()).collect::<candle_core::Result<Vec<_>>>()?;
        let v = m.clone();
        Ok(AdamW { cfg, params, m, v, steps: 0 })
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
        let c = &self.cfg;
        let t = self.steps as i32;
        let bc1 = 1.0 - c.beta1.powi(t);
        let bc2 = 1.0 - c.beta2.powi(t);
        for (((_, p), m), v) in self.params.iter().zip(&mut self.m).zip(&mut self.v) {
            let Some(g) = grads.get(p.as_tensor()) else { continue };
            // Gradients come out of `backward` still attached to the update's graph
            // (they are built from ops on tracked tensors). Detached, the moments hold
            // plain values; attached, every step's moments would keep the previous
            // step's moments and its whole forward/backward graph alive — memory
            // would grow by the size of one update's graph per step.
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
        Ok(OptimStep::Applied { grad_norm: norm })
    }

    /// The moments as named tensors (`<param>.m`, `<param>.v`) for a checkpoint.
    pub fn state_tensors(&self) -> Vec<(String, Tensor)> {
        let mut out = Vec::with_capacity(2 * self.params.len());
        for (((name, _), m), v) in self.params.iter().zip(&self.m).zip(&self.v) {
            out.push((format!("{name}.m"), m.clone()));
            out.push((format!("{name}.v"), v.clone()));
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
        self.m = m;
        self.v = v;
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
