//! The task-value network: NavACL⁺'s return predictor f^r (regression on
//! discounted returns) or NavACL's success predictor f^s (logistic regression on
//! reached/not reached), a small candle MLP.
//!
//! Inputs: φ = (dx, dy, yaw) encoded as `(dx/20, dy/20, sin yaw, cos yaw)` so the
//! yaw wrap-around is continuous; when the signal phase is part of the task, the
//! position c in the cycle joins them as `(sin 2πc, cos 2πc)` (the cycle wraps too).
//! Architecture (the paper gives none): 4 (or 6) → 64 → 64 → 1 with ReLU. Training: AdamW (lr 1e-3, weight decay 0, Table IV's lr), shuffled
//! minibatches of 64, `epochs` passes over the collected set per training round.
//!
//! Built on `pednav-nets` (its seeded [`Dense`] layers, [`ParamStore`] and the
//! checkpointable [`AdamW`]), like the DSAC networks: weights are initialised from
//! the given seed and minibatch order comes from a seeded RNG, so a run is
//! reproducible, and the saved state holds Adam's moments, so a resumed net
//! continues exactly where it stopped.

use std::collections::HashMap;

use candle_core::{D, DType, Device, Tensor};
use pednav_nets::layers::Dense;
use pednav_nets::{AdamW, AdamWConfig, ParamStore};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

pub use pednav_config::TaskNetConfig;

use crate::returns::TaskFeatures;
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

/// The MLP and its optimiser.
pub struct TaskValueNet {
    store: ParamStore,
    layers: Vec<Dense>,
    opt: AdamW,
    target: Target,
    cfg: TaskNetConfig,
    /// Whether the inputs include the position in the signal cycle.
    cycle: bool,
    rng: ChaCha8Rng,
}

/// Encode task features as network inputs: 4 columns, or 6 with the cycle.
///
/// # Panics
/// When `cycle` and a task has no position in the cycle, or the other way round (the
/// curriculum builds every task of a run the same way).
pub fn encode(features: &[TaskFeatures], cycle: bool) -> Tensor {
    let width = if cycle { 6 } else { 4 };
    let mut data = Vec::with_capacity(features.len() * width);
    for f in features {
        let [dx, dy, yaw] = f.pose;
        data.extend([dx / 20.0, dy / 20.0, yaw.sin(), yaw.cos()]);
        match (cycle, f.cycle) {
            (true, Some(c)) => {
                let a = std::f32::consts::TAU * c;
                data.extend([a.sin(), a.cos()]);
            }
            (false, None) => {}
            _ => panic!("task features {f:?} for a net {} the signal cycle", if cycle { "with" } else { "without" }),
        }
    }
    Tensor::from_vec(data, (features.len(), width), &Device::Cpu).expect("shape matches data")
}

/// One named tensor of a saved [`NetState`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SavedTensor {
    /// Parameter (`layer0.w`, …) or moment (`layer0.w.m`, …) name.
    pub name: String,
    /// Shape.
    pub shape: Vec<usize>,
    /// Values, row-major.
    pub values: Vec<f32>,
}

impl SavedTensor {
    fn of(name: &str, t: &Tensor) -> candle_core::Result<SavedTensor> {
        Ok(SavedTensor { name: name.to_string(), shape: t.dims().to_vec(), values: t.flatten_all()?.to_vec1()? })
    }
}

/// Saved state of a [`TaskValueNet`]: parameters, Adam's moments and step count, and
/// the minibatch-order RNG.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NetState {
    /// Every parameter, by name.
    #[serde(default)]
    pub params: Vec<SavedTensor>,
    /// Adam's first and second moments, by name.
    #[serde(default)]
    pub moments: Vec<SavedTensor>,
    /// Adam steps taken.
    #[serde(default)]
    pub adam_steps: u64,
    /// A state saved before the net moved to `pednav-nets` (candle-nn's layout: per
    /// layer the weight as (out, in), then the bias; no moments). [`TaskValueNet::restore`]
    /// converts it; new states never write it.
    #[serde(default, rename = "weights", skip_serializing_if = "Option::is_none")]
    pub legacy_weights: Option<Vec<Vec<f32>>>,
    /// The minibatch-order RNG.
    pub rng: ChaCha8Rng,
}

fn tensors_of(saved: &[SavedTensor]) -> candle_core::Result<HashMap<String, Tensor>> {
    saved
        .iter()
        .map(|t| {
            if t.shape.iter().product::<usize>() != t.values.len() {
                candle_core::bail!("saved tensor `{}` has {} values for shape {:?}", t.name, t.values.len(), t.shape);
            }
            Ok((t.name.clone(), Tensor::from_slice(&t.values, t.shape.as_slice(), &Device::Cpu)?))
        })
        .collect()
}

impl TaskValueNet {
    /// A freshly initialised network (uniform ±1/√fan_in, seeded); `cycle`: its inputs
    /// include the position in the signal cycle.
    pub fn new(cfg: TaskNetConfig, target: Target, cycle: bool, seed: u64) -> candle_core::Result<TaskValueNet> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut store = ParamStore::new("task_value", &Device::Cpu);
        let mut sizes = vec![if cycle { 6 } else { 4 }];
        sizes.extend(&cfg.hidden);
        sizes.push(1);
        let layers = sizes
            .windows(2)
            .enumerate()
            .map(|(i, w)| Dense::new(&mut store, &format!("layer{i}"), w[0], w[1], &mut rng))
            .collect::<pednav_nets::Result<Vec<_>>>()
            .map_err(candle_core::Error::wrap)?;
        let opt = AdamW::new(&store, AdamWConfig::with_lr(cfg.lr)).map_err(candle_core::Error::wrap)?;
        Ok(TaskValueNet { store, layers, opt, target, cfg, cycle, rng })
    }

    /// Parameters, Adam's moments and the minibatch RNG, for saving with the run's
    /// checkpoints.
    pub fn state(&self) -> candle_core::Result<NetState> {
        let params = self
            .store
            .vars()
            .iter()
            .map(|(n, v)| SavedTensor::of(n, v.as_tensor()))
            .collect::<candle_core::Result<_>>()?;
        let moments =
            self.opt.state_tensors().iter().map(|(n, t)| SavedTensor::of(n, t)).collect::<candle_core::Result<_>>()?;
        Ok(NetState { params, moments, adam_steps: self.opt.steps(), legacy_weights: None, rng: self.rng.clone() })
    }

    /// Restore what [`TaskValueNet::state`] saved; every tensor is checked against
    /// this net's config before anything changes.
    pub fn restore(&mut self, state: &NetState) -> candle_core::Result<()> {
        let wrap = |e: pednav_nets::NetError| candle_core::Error::Msg(format!("saved task-value net: {e}"));
        if let (true, Some(legacy)) = (state.params.is_empty(), &state.legacy_weights) {
            let params = self.convert_legacy(legacy)?;
            self.store.check(&params).map_err(wrap)?;
            self.store.load(&params).map_err(wrap)?;
            self.rng = state.rng.clone();
            return Ok(());
        }
        let params = tensors_of(&state.params)?;
        let moments = tensors_of(&state.moments)?;
        self.store.check(&params).map_err(wrap)?;
        self.opt.check_state(&moments).map_err(wrap)?;
        self.store.load(&params).map_err(wrap)?;
        self.opt.load_state(state.adam_steps, &moments).map_err(wrap)?;
        self.rng = state.rng.clone();
        Ok(())
    }

    /// This net's parameters from a legacy state: candle-nn's weight (out, in) is
    /// this layer's (in, out) transposed.
    fn convert_legacy(&self, legacy: &[Vec<f32>]) -> candle_core::Result<HashMap<String, Tensor>> {
        if legacy.len() != 2 * self.layers.len() {
            candle_core::bail!(
                "saved task-value net has {} tensors, this config {}",
                legacy.len(),
                2 * self.layers.len()
            );
        }
        let mut out = HashMap::new();
        for (i, pair) in legacy.chunks_exact(2).enumerate() {
            let (fan_in, fan_out) = {
                let w = &self.store.vars().iter().find(|(n, _)| *n == format!("layer{i}.w")).expect("layer").1;
                let d = w.dims();
                (d[0], d[1])
            };
            if pair[0].len() != fan_in * fan_out || pair[1].len() != fan_out {
                candle_core::bail!("saved layer {i} does not match a {fan_in} → {fan_out} layer");
            }
            let w = Tensor::from_slice(&pair[0], (fan_out, fan_in), &Device::Cpu)?.t()?.contiguous()?;
            out.insert(format!("layer{i}.w"), w);
            out.insert(format!("layer{i}.b"), Tensor::from_slice(&pair[1], fan_out, &Device::Cpu)?);
        }
        Ok(out)
    }

    /// Raw output (N,): the return, or the success logit.
    fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let mut h = x.clone();
        for (i, l) in self.layers.iter().enumerate() {
            h = l.forward(&h).map_err(candle_core::Error::wrap)?;
            if i + 1 < self.layers.len() {
                h = h.relu()?;
            }
        }
        h.squeeze(D::Minus1)
    }

    /// Predictions: returns, or success probabilities.
    pub fn predict_values(&self, features: &[TaskFeatures]) -> candle_core::Result<Vec<f32>> {
        if features.is_empty() {
            return Ok(Vec::new());
        }
        let out = self.forward(&encode(features, self.cycle))?;
        let out = match self.target {
            Target::Return => out,
            Target::Success => candle_nn::ops::sigmoid(&out)?,
        };
        out.to_dtype(DType::F32)?.to_vec1()
    }

    /// One training round over `(features, target)` pairs; returns the mean loss.
    pub fn train(&mut self, data: &[(TaskFeatures, f32)]) -> candle_core::Result<f32> {
        let mut order: Vec<usize> = (0..data.len()).collect();
        let (mut total, mut batches) = (0.0f32, 0usize);
        for _ in 0..self.cfg.epochs {
            order.shuffle(&mut self.rng);
            for chunk in order.chunks(self.cfg.batch) {
                let feats: Vec<TaskFeatures> = chunk.iter().map(|&i| data[i].0).collect();
                let y = Tensor::from_vec(
                    chunk.iter().map(|&i| data[i].1).collect::<Vec<f32>>(),
                    chunk.len(),
                    &Device::Cpu,
                )?;
                let out = self.forward(&encode(&feats, self.cycle))?;
                let loss = match self.target {
                    Target::Return => (out - y)?.sqr()?.mean_all()?,
                    Target::Success => candle_nn::loss::binary_cross_entropy_with_logit(&out, &y)?,
                };
                let grads = loss.backward()?;
                self.opt.step(&grads).map_err(candle_core::Error::wrap)?;
                total += loss.to_scalar::<f32>()?;
                batches += 1;
            }
        }
        Ok(if batches == 0 { 0.0 } else { total / batches as f32 })
    }
}

impl ReturnPredictor for TaskValueNet {
    fn predict(&mut self, features: &[TaskFeatures]) -> Vec<f32> {
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
        let data: Vec<(TaskFeatures, f32)> = (0..400)
            .map(|k| {
                let (dx, dy) = ((k % 20) as f32 * 2.0 - 20.0, (k / 20) as f32 * 2.0 - 20.0);
                ([dx, dy, 0.3 * k as f32].into(), 5.0 - dx.hypot(dy))
            })
            .collect();
        let mut net =
            TaskValueNet::new(TaskNetConfig { epochs: 40, ..TaskNetConfig::default() }, Target::Return, false, 0)
                .unwrap();
        let first = net.train(&data).unwrap();
        let mut last = first;
        for _ in 0..10 {
            last = net.train(&data).unwrap();
        }
        assert!(last < first * 0.05, "loss {first} → {last}");
        let p = net.predict_values(&[[0.0, 2.0, 0.0].into(), [16.0, 12.0, 0.0].into()]).unwrap();
        assert!((p[0] - 3.0).abs() < 2.0 && (p[1] + 15.0).abs() < 3.0, "{p:?}");
    }

    #[test]
    fn same_seed_same_weights() {
        let a = TaskValueNet::new(TaskNetConfig::default(), Target::Success, false, 7).unwrap();
        let b = TaskValueNet::new(TaskNetConfig::default(), Target::Success, false, 7).unwrap();
        let f = [[1.0, 2.0, 0.5].into()];
        assert_eq!(a.predict_values(&f).unwrap(), b.predict_values(&f).unwrap());
        let p = a.predict_values(&f).unwrap()[0];
        assert!((0.0..=1.0).contains(&p), "a probability");
    }

    #[test]
    fn state_round_trip_restores_predictions_and_rng() {
        let data: Vec<(TaskFeatures, f32)> =
            (0..64).map(|k| ([k as f32 * 0.3, 1.0, 0.0].into(), k as f32 * 0.1)).collect();
        let mut a = TaskValueNet::new(TaskNetConfig::default(), Target::Return, false, 1).unwrap();
        a.train(&data).unwrap();
        let saved = a.state().unwrap();
        let mut b = TaskValueNet::new(TaskNetConfig::default(), Target::Return, false, 99).unwrap();
        b.restore(&saved).unwrap();
        let f = [[3.0, -2.0, 1.0].into()];
        assert_eq!(a.predict_values(&f).unwrap(), b.predict_values(&f).unwrap());
        assert_eq!(a.state().unwrap(), b.state().unwrap(), "weights, moments, steps and RNG");
        // Adam's moments came back too: one more round is identical on both.
        assert_eq!(a.train(&data).unwrap(), b.train(&data).unwrap());
        assert_eq!(a.state().unwrap(), b.state().unwrap());
        let mut small =
            TaskValueNet::new(TaskNetConfig { hidden: vec![8], ..TaskNetConfig::default() }, Target::Return, false, 0)
                .unwrap();
        assert!(small.restore(&saved).is_err(), "another architecture is refused");
        let mut with_cycle = TaskValueNet::new(TaskNetConfig::default(), Target::Return, true, 0).unwrap();
        assert!(with_cycle.restore(&saved).is_err(), "a net with the cycle's inputs is another architecture");
    }

    /// A state written before the net moved to `pednav-nets` (candle-nn's (out, in)
    /// weights, no moments) restores to the same function: its prediction equals
    /// relu(x·W₀ᵀ + b₀)·W₁ᵀ + b₁ computed by hand.
    #[test]
    fn a_legacy_state_restores_the_same_function() {
        let cfg = TaskNetConfig { hidden: vec![2], ..TaskNetConfig::default() };
        // Layer 0: 4 → 2 as (out, in); layer 1: 2 → 1.
        let w0 = vec![0.5, -1.0, 0.25, 2.0, /* row 2 */ -0.5, 1.0, 1.5, 0.0];
        let (b0, w1, b1) = (vec![0.1, -0.2], vec![2.0, -3.0], vec![0.7]);
        let json = serde_json::json!({
            "weights": [w0, b0, w1, b1],
            "rng": ChaCha8Rng::seed_from_u64(5),
        });
        let legacy: NetState = serde_json::from_value(json).unwrap();
        assert!(legacy.params.is_empty() && legacy.legacy_weights.is_some());
        let mut net = TaskValueNet::new(cfg, Target::Return, false, 9).unwrap();
        net.restore(&legacy).unwrap();
        let f = [3.0f32, -4.0, 0.3];
        let x = [f[0] / 20.0, f[1] / 20.0, f[2].sin(), f[2].cos()];
        let h: Vec<f32> =
            (0..2).map(|o| (b0[o] + (0..4).map(|i| w0[o * 4 + i] * x[i]).sum::<f32>()).max(0.0)).collect();
        let by_hand = b1[0] + w1[0] * h[0] + w1[1] * h[1];
        let got = net.predict_values(&[f.into()]).unwrap()[0];
        assert!((got - by_hand).abs() < 1e-5, "{got} vs {by_hand}");
        assert!(net.state().unwrap().legacy_weights.is_none(), "new states are written in the new form");
    }

    /// With the cycle, the inputs are the pose's four and (sin 2πc, cos 2πc), and the
    /// net learns a function of the cycle alone that the pose cannot explain.
    #[test]
    fn the_cycle_inputs_are_sin_and_cos_and_a_net_learns_from_them() {
        let f = TaskFeatures { pose: [4.0, -2.0, 0.5], cycle: Some(0.25) };
        let x = encode(&[f], true).to_vec2::<f32>().unwrap();
        let want = [0.2, -0.1, 0.5f32.sin(), 0.5f32.cos(), 1.0, 0.0];
        for (a, b) in x[0].iter().zip(want) {
            assert!((a - b).abs() < 1e-6, "{:?} vs {want:?}", x[0]);
        }
        // Target: +5 in the first half of the cycle, −5 in the second, whatever the pose.
        let data: Vec<(TaskFeatures, f32)> = (0..256)
            .map(|k| {
                let c = (k as f32 * 0.618_034).fract();
                let f = TaskFeatures { pose: [(k % 7) as f32, (k % 5) as f32, 0.1 * k as f32], cycle: Some(c) };
                (f, if c < 0.5 { 5.0 } else { -5.0 })
            })
            .collect();
        let mut net =
            TaskValueNet::new(TaskNetConfig { epochs: 40, ..TaskNetConfig::default() }, Target::Return, true, 3)
                .unwrap();
        for _ in 0..5 {
            net.train(&data).unwrap();
        }
        let at = |c| TaskFeatures { pose: [3.0, 2.0, 0.0], cycle: Some(c) };
        let p = net.predict_values(&[at(0.25), at(0.75)]).unwrap();
        assert!(p[0] > 3.0 && p[1] < -3.0, "{p:?}");
    }

    #[test]
    #[should_panic(expected = "for a net with the signal cycle")]
    fn a_task_without_its_cycle_is_a_bug_for_a_net_with_one() {
        encode(&[[1.0, 2.0, 3.0].into()], true);
    }
}
