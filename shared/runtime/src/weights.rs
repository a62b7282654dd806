//! Policy weights as one flat `[f32]` message.
//!
//! Invariant: the order is fixed by the networks' construction — acting stores
//! in [`DsacNets::acting_stores`] order, each store's parameters in creation
//! order — so a learner and an actor built from the same `NetsConfig` agree on
//! it; the length is checked on receipt.

use pednav_nets::DsacNets;
use pednav_policy::ActingPolicy;

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

/// The learner's end of the weights channel: publishes the acting networks, versioned.
pub struct WeightsBroadcaster {
    publisher: crate::ipc::WeightsPublisher,
}

impl WeightsBroadcaster {
    /// The publisher for the acting networks of `nets` (their length fixes the message size).
    pub fn open(ipc: &crate::Ipc, nets: &DsacNets) -> Result<WeightsBroadcaster> {
        Ok(WeightsBroadcaster { publisher: ipc.weights_publisher(acting_len(nets))? })
    }

    /// Publish the acting networks of `nets` as `version` (the learner's update count).
    pub fn publish(&self, nets: &DsacNets, version: u64) -> Result<()> {
        let flat = flatten(nets)?;
        let mut sample = self
            .publisher
            .loan_slice_uninit(flat.len())
            .map_err(|e| RuntimeError::Message(format!("loan weights: {e:?}")))?;
        *sample.user_header_mut() =
            crate::messages::WeightsHeader { version, len: flat.len() as u64, published_ns: crate::now_ns() };
        sample.write_from_slice(&flat).send().map_err(|e| RuntimeError::Message(format!("send weights: {e:?}")))?;
        Ok(())
    }
}

/// An actor's end of the weights channel: it only ever moves to a newer version.
pub struct WeightsClient {
    subscriber: crate::ipc::WeightsSubscriber,
    version: u64,
}

/// What [`WeightsClient::refresh`] loaded.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewWeights {
    /// The version now held.
    pub version: u64,
    /// Milliseconds from the learner's publishing to this load.
    pub latency_ms: f64,
}

impl WeightsClient {
    /// A client holding version 0 (the initial weights every process builds from the seed).
    pub fn open(ipc: &crate::Ipc) -> Result<WeightsClient> {
        Ok(WeightsClient { subscriber: ipc.weights_subscriber()?, version: 0 })
    }

    /// The version held.
    pub fn version(&self) -> u64 {
        self.version
    }

    /// Without blocking: load the newest published weights into `policy` when they
    /// are newer than the version held (its inference cache is invalidated by the
    /// load itself), and say so; `None` when there is nothing newer.
    pub fn refresh(&mut self, policy: &mut ActingPolicy) -> Result<Option<NewWeights>> {
        let mut newest = None;
        while let Some(sample) =
            self.subscriber.receive().map_err(|e| RuntimeError::Message(format!("weights: {e:?}")))?
        {
            newest = Some(sample);
        }
        let Some(sample) = newest else { return Ok(None) };
        let h = *sample.user_header();
        if h.version <= self.version {
            return Ok(None);
        }
        policy.load_weights(|nets| load(nets, sample.payload()))?;
        self.version = h.version;
        let latency_ms = crate::now_ns().saturating_sub(h.published_ns) as f64 / 1e6;
        Ok(Some(NewWeights { version: h.version, latency_ms }))
    }
}
