//! Policy weights as one flat `[f32]` message.
//!
//! Invariant: the order is fixed by the networks' construction — acting stores
//! in [`DsacNets::acting_stores`] order, each store's parameters in creation
//! order — so a learner and an actor built from the same `NetsConfig` agree on
//! it; the length is checked on receipt.

use pednav_nets::DsacNets;

use crate::error::{Result, RuntimeError};

/// Number of floats of the acting networks.
pub fn acting_len(nets: &DsacNets) -> usize {
    nets.acting_stores().iter().map(|s| s.num_scalars()).sum()
}

/// Flatten the acting networks' parameters.
pub fn flatten(nets: &DsacNets) -> Result<Vec<f32>> {
    let mut out = Vec::with_capacity(acting_len(nets));
    for store in nets.acting_stores() {
        for (name, var) in store.vars() {
            let v = var
                .as_tensor()
                .flatten_all()
                .and_then(|t| t.to_vec1::<f32>())
                .map_err(|e| RuntimeError::Message(format!("{}/{name}: {e}", store.name())))?;
            out.extend_from_slice(&v);
        }
    }
    Ok(out)
}

/// Load flat parameters into the acting networks.
pub fn load(nets: &DsacNets, flat: &[f32]) -> Result<()> {
    let expected = acting_len(nets);
    if flat.len() != expected {
        return Err(RuntimeError::Message(format!(
            "weights message has {} floats, the acting networks {expected}: learner and actor configs differ",
            flat.len()
        )));
    }
    let mut at = 0;
    for store in nets.acting_stores() {
        for (name, var) in store.vars() {
            let shape = var.as_tensor().shape().clone();
            let n = shape.elem_count();
            candle_core::Tensor::from_slice(&flat[at..at + n], shape, store.device())
                .and_then(|t| var.set(&t))
                .map_err(|e| RuntimeError::Message(format!("{}/{name}: {e}", store.name())))?;
            at += n;
        }
    }
    Ok(())
}
