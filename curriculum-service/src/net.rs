//! The task-value network: NavACL⁺'s return predictor f^r (regression on
//! discounted returns) or NavACL's success predictor f^s (logistic regression on
//! reached/not reached), a small candle MLP.
//!
//! Inputs: φ = (dx, dy, yaw) encoded as `(dx/20, dy/20, sin yaw, cos yaw)` so the
//! yaw wrap-around is continuous. Architecture (the paper gives none): 4 → 64 → 64
//! → 1 with ReLU. Training: AdamW (lr 1e-3, weight decay 0, Table IV's lr), shuffled
//! minibatches of 64, `epochs` passes over the collected set per training round.
//!
//! Invariant: weights are initialised from the given seed (candle's own
//! initialisers draw from an unseeded RNG, so they are not used), and minibatch
//! order comes from a seeded RNG: a run is reproducible.

use candle_core::{D, DType, Device, Tensor, Var};
use candle_nn::{AdamW, Linear, Module, Optimizer, ParamsAdamW};
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::scheduler::ReturnPredictor;

/// What the network predicts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Target {
    /// Discounted return (NavACL⁺), mean-squared error.
    Return,
    /// Success probability (NavACL), binary cross-entropy on a sigmoid output.
    Success,
}

/// Settings of the task-value network.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetConfig {
    /// Hidden layer widths. The paper gives none; two layers of 64 fit a smooth
    /// function of three features without overfitting the few thousand samples of a round.
    pub hidden: Vec<usize>,
    /// Learning rate. Table IV: 1e-3.
    pub lr: f64,
    /// Minibatch size. Table IV: 64.
    pub batch: usize,
    /// Passes over the collected set per training round. The paper does not say;
    /// 5 lets a round's data move the net noticeably while Δ_ep keeps rounds frequent.
    pub epochs: usize,
}

impl Default for NetConfig {
    fn default() -> Self {
        NetConfig { hidden: vec![64, 64], lr: 1e-3, batch: 64, epochs: 5 }
    }
}

/// The MLP and its optimiser.
pub struct TaskValueNet {
    layers: Vec<Linear>,
    vars: Vec<Var>,
    opt: AdamW,
    target: Target,
    cfg: NetConfig,
    rng: ChaCha8Rng,
}

/// Encode task features as network inputs.
pub fn encode(features: &[[f32; 3]]) -> Tensor {
    let data: Vec<f32> = features.iter().flat_map(|f| [f[0] / 20.0, f[1] / 20.0, f[2].sin(), f[2].cos()]).collect();
    Tensor::from_vec(data, (features.len(), 4), &Device::Cpu).expect("shape matches data")
}

/// Saved state of a [`TaskValueNet`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NetState {
    /// Every parameter, flattened, in layer order (weight, bias, …).
    pub weights: Vec<Vec<f32>>,
    /// The minibatch-order RNG.
    pub rng: ChaCha8Rng,
}

impl TaskValueNet {
    /// A freshly initialised network (uniform ±1/√fan_in, seeded).
    pub fn new(cfg: NetConfig, target: Target, seed: u64) -> candle_core::Result<TaskValueNet> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut sizes = vec![4];
        sizes.extend(&cfg.hidden);
        sizes.push(1);
        let mut layers = Vec::new();
        let mut vars = Vec::new();
        for w in sizes.windows(2) {
            let (fan_in, fan_out) = (w[0], w[1]);
            let bound = 1.0 / (fan_in as f32).sqrt();
            let weight: Vec<f32> = (0..fan_in * fan_out).map(|_| rng.random_range(-bound..bound)).collect();
            let bias: Vec<f32> = (0..fan_out).map(|_| rng.random_range(-bound..bound)).collect();
            let weight = Var::from_tensor(&Tensor::from_vec(weight, (fan_out, fan_in), &Device::Cpu)?)?;
            let bias = Var::from_tensor(&Tensor::from_vec(bias, fan_out, &Device::Cpu)?)?;
            layers.push(Linear::new(weight.as_tensor().clone(), Some(bias.as_tensor().clone())));
            vars.push(weight);
            vars.push(bias);
        }
        let opt = AdamW::new(vars.clone(), ParamsAdamW { lr: cfg.lr, weight_decay: 0.0, ..Default::default() })?;
        Ok(TaskValueNet { layers, vars, opt, target, cfg, rng })
    }

    /// Weights and minibatch RNG, for saving with the run's checkpoints. The
    /// optimiser's moments are not included (candle-nn keeps them private): a
    /// resumed net restarts Adam's moments, which for this small MLP re-converge
    /// within one training round.
    pub fn state(&self) -> candle_core::Result<NetState> {
        let weights = self
            .vars
            .iter()
            .map(|v| v.as_tensor().flatten_all()?.to_vec1::<f32>())
            .collect::<candle_core::Result<_>>()?;
        Ok(NetState { weights, rng: self.rng.clone() })
    }

    /// Restore what [`TaskValueNet::state`] saved; the shapes must match this net's config.
    pub fn restore(&mut self, state: &NetState) -> candle_core::Result<()> {
        if state.weights.len() != self.vars.len() {
            candle_core::bail!(
                "saved task-value net has {} tensors, this config {}",
                state.weights.len(),
                self.vars.len()
            );
        }
        for (v, w) in self.vars.iter().zip(&state.weights) {
            let shape = v.as_tensor().shape().clone();
            if shape.elem_count() != w.len() {
                candle_core::bail!("saved tensor of {} values for a {:?} parameter", w.len(), shape);
            }
            v.set(&Tensor::from_slice(w, shape, &Device::Cpu)?)?;
        }
        self.rng = state.rng.clone();
        Ok(())
    }

    /// Raw output (N,): the return, or the success logit.
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let mut h = x.clone();
        for (i, l) in self.layers.iter().enumerate() {
            h = l.forward(&h)?;
            if i + 1 < self.layers.len() {
                h = h.relu()?;
            }
        }
        h.squeeze(D::Minus1)
    }

    /// Predictions: returns, or success probabilities.
    pub fn predict_values(&self, features: &[[f32; 3]]) -> candle_core::Result<Vec<f32>> {
        if features.is_empty() {
            return Ok(Vec::new());
        }
        let out = self.forward(&encode(features))?;
        let out = match self.target {
            Target::Return => out,
            Target::Success => candle_nn::ops::sigmoid(&out)?,
        };
        out.to_dtype(DType::F32)?.to_vec1()
    }

    /// One training round over `(features, target)` pairs; returns the mean loss.
    pub fn train(&mut self, data: &[([f32; 3], f32)]) -> candle_core::Result<f32> {
        let mut order: Vec<usize> = (0..data.len()).collect();
        let (mut total, mut batches) = (0.0f32, 0usize);
        for _ in 0..self.cfg.epochs {
            order.shuffle(&mut self.rng);
            for chunk in order.chunks(self.cfg.batch) {
                let feats: Vec<[f32; 3]> = chunk.iter().map(|&i| data[i].0).collect();
                let y = Tensor::from_vec(
                    chunk.iter().map(|&i| data[i].1).collect::<Vec<f32>>(),
                    chunk.len(),
                    &Device::Cpu,
                )?;
                let out = self.forward(&encode(&feats))?;
                let loss = match self.target {
                    Target::Return => (out - y)?.sqr()?.mean_all()?,
                    Target::Success => candle_nn::loss::binary_cross_entropy_with_logit(&out, &y)?,
                };
                self.opt.backward_step(&loss)?;
                total += loss.to_scalar::<f32>()?;
                batches += 1;
            }
        }
        Ok(if batches == 0 { 0.0 } else { total / batches as f32 })
    }
}

impl ReturnPredictor for TaskValueNet {
    fn predict(&mut self, features: &[[f32; 3]]) -> Vec<f32> {
        // A candle CPU forward of this MLP can only fail on a shape bug.
        self.predict_values(features).expect("task-value forward pass")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn learns_a_smooth_function_of_distance() {
        // Target: 5 − distance, over a grid of offsets.
        let data: Vec<([f32; 3], f32)> = (0..400)
            .map(|k| {
                let (dx, dy) = ((k % 20) as f32 * 2.0 - 20.0, (k / 20) as f32 * 2.0 - 20.0);
                ([dx, dy, 0.3 * k as f32], 5.0 - dx.hypot(dy))
            })
            .collect();
        let mut net = TaskValueNet::new(NetConfig { epochs: 40, ..NetConfig::default() }, Target::Return, 0).unwrap();
        let first = net.train(&data).unwrap();
        let mut last = first;
        for _ in 0..10 {
            last = net.train(&data).unwrap();
        }
        assert!(last < first * 0.05, "loss {first} → {last}");
        let p = net.predict_values(&[[0.0, 2.0, 0.0], [16.0, 12.0, 0.0]]).unwrap();
        assert!((p[0] - 3.0).abs() < 2.0 && (p[1] + 15.0).abs() < 3.0, "{p:?}");
    }

    #[test]
    fn same_seed_same_weights() {
        let a = TaskValueNet::new(NetConfig::default(), Target::Success, 7).unwrap();
        let b = TaskValueNet::new(NetConfig::default(), Target::Success, 7).unwrap();
        let f = [[1.0, 2.0, 0.5]];
        assert_eq!(a.predict_values(&f).unwrap(), b.predict_values(&f).unwrap());
        let p = a.predict_values(&f).unwrap()[0];
        assert!((0.0..=1.0).contains(&p), "a probability");
    }

    #[test]
    fn state_round_trip_restores_predictions_and_rng() {
        let data: Vec<([f32; 3], f32)> = (0..64).map(|k| ([k as f32 * 0.3, 1.0, 0.0], k as f32 * 0.1)).collect();
        let mut a = TaskValueNet::new(NetConfig::default(), Target::Return, 1).unwrap();
        a.train(&data).unwrap();
        let saved = a.state().unwrap();
        let mut b = TaskValueNet::new(NetConfig::default(), Target::Return, 99).unwrap();
        b.restore(&saved).unwrap();
        let f = [[3.0, -2.0, 1.0]];
        assert_eq!(a.predict_values(&f).unwrap(), b.predict_values(&f).unwrap());
        assert_eq!(a.state().unwrap().rng, b.state().unwrap().rng);
        let mut small =
            TaskValueNet::new(NetConfig { hidden: vec![8], ..NetConfig::default() }, Target::Return, 0).unwrap();
        assert!(small.restore(&saved).is_err(), "another architecture is refused");
    }
}
