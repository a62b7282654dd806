//! Named parameters of one network, initialised from a seed.
//!
//! Invariant: every parameter is created through a [`ParamStore`] with values drawn
//! from the caller's seeded RNG (candle's own initialisers use an unseeded RNG), so
//! the same seed gives bit-identical networks. Names are unique within a store and
//! are the keys of the safetensors checkpoints.

use std::collections::HashMap;

use candle_core::{Device, Tensor, Var};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::error::{NetError, Result};

/// The parameters of one network, in creation order.
#[derive(Clone)]
pub struct ParamStore {
    name: String,
    vars: Vec<(String, Var)>,
    device: Device,
}

impl ParamStore {
    /// An empty store for the network called `name`.
    pub fn new(name: impl Into<String>, device: &Device) -> ParamStore {
        ParamStore { name: name.into(), vars: Vec::new(), device: device.clone() }
    }

    /// The network's name (used in error messages and checkpoint files).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The device the parameters live on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// A parameter of `shape` with entries uniform in ±`bound`.
    pub fn uniform(&mut self, name: &str, shape: &[usize], bound: f64, rng: &mut ChaCha8Rng) -> Result<Var> {
        let n: usize = shape.iter().product();
        let data: Vec<f32> = (0..n).map(|_| rng.random_range(-bound..=bound) as f32).collect();
        self.insert(name, Tensor::from_vec(data, shape, &self.device)?)
    }

    /// A parameter with the given initial value.
    pub fn insert(&mut self, name: &str, value: Tensor) -> Result<Var> {
        assert!(!self.vars.iter().any(|(n, _)| n == name), "duplicate parameter name {name} in {}", self.name);
        let var = Var::from_tensor(&value)?;
        self.vars.push((name.to_string(), var.clone()));
        Ok(var)
    }

    /// All parameters, in creation order.
    pub fn vars(&self) -> &[(String, Var)] {
        &self.vars
    }

    /// Number of scalar parameters.
    pub fn num_scalars(&self) -> usize {
        self.vars.iter().map(|(_, v)| v.elem_count()).sum()
    }

    /// Name → current value (detached copies), e.g. for `candle_core::safetensors::save`.
    pub fn tensors(&self) -> HashMap<String, Tensor> {
        self.vars.iter().map(|(n, v)| (n.clone(), v.as_tensor().detach())).collect()
    }

    /// Check that `values` has exactly this store's names and shapes.
    pub fn check(&self, values: &HashMap<String, Tensor>) -> Result<()> {
        let incompatible = |message: String| NetError::Incompatible { network: self.name.clone(), message };
        for (name, var) in &self.vars {
            let t = values.get(name).ok_or_else(|| incompatible(format!("tensor `{name}` is missing")))?;
            if t.dims() != var.dims() {
                return Err(incompatible(format!(
                    "`{name}` has shape {:?}, the network needs {:?}",
                    t.dims(),
                    var.dims()
                )));
            }
        }
        if let Some(extra) = values.keys().find(|k| !self.vars.iter().any(|(n, _)| n == *k)) {
            return Err(incompatible(format!("unexpected tensor `{extra}`")));
        }
        Ok(())
    }

    /// Replace every value from `values`. Checks names and shapes of all tensors
    /// first, so an incompatible map changes nothing.
    pub fn load(&self, values: &HashMap<String, Tensor>) -> Result<()> {
        self.check(values)?;
        for (name, var) in &self.vars {
            var.set(&values[name].to_device(&self.device)?.to_dtype(var.dtype())?)?;
        }
        Ok(())
    }

    /// Copy every value from `source` (same architecture): the target-network initialisation.
    pub fn copy_from(&self, source: &ParamStore) -> Result<()> {
        self.load(&source.tensors())
    }

    /// Polyak averaging towards `source`: θ ← (1 − τ)·θ + τ·θ_source (on the CPU in
    /// place, one pass per parameter; elsewhere with candle's ops).
    pub fn soft_update(&self, source: &ParamStore, tau: f64) -> Result<()> {
        if self.vars.len() != source.vars.len() {
            return Err(NetError::Incompatible {
                network: self.name.clone(),
                message: format!("soft update from `{}` with a different parameter count", source.name),
            });
        }
        for ((name, t), (_, s)) in self.vars.iter().zip(&source.vars) {
            if t.dims() != s.dims() {
                return Err(NetError::Incompatible {
                    network: self.name.clone(),
                    message: format!("soft update of `{name}` {:?} from a {:?} tensor", t.dims(), s.dims()),
                });
            }
        }
        for ((_, t), (_, s)) in self.vars.iter().zip(&source.vars) {
            if t.id() == s.id() {
                continue; // a clone of this store shares its parameters: nothing moves
            }
            if t.device().is_cpu() && s.device().is_cpu() {
                crate::ops::fused::polyak_in_place(t.as_tensor(), s.as_tensor(), tau)?;
            } else {
                let new = ((t.as_tensor() * (1.0 - tau))? + (s.as_tensor() * tau)?)?;
                t.set(&new)?;
            }
        }
        Ok(())
    }
}
