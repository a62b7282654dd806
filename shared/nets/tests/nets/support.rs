//! Inputs shared by the heads' and the encoders' tests.

use candle_core::{Device, Tensor};
use pednav_nets::{EncoderKind, NetsConfig};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

pub fn random(rng: &mut ChaCha8Rng, shape: &[usize], scale: f32) -> Tensor {
    let n: usize = shape.iter().product();
    let data: Vec<f32> = (0..n).map(|_| rng.random_range(-scale..scale)).collect();
    Tensor::from_vec(data, shape, &Device::Cpu).unwrap()
}

pub fn rows(t: &Tensor) -> Vec<Vec<f32>> {
    t.to_vec2().unwrap()
}

pub fn tiny(encoder: EncoderKind, shared: bool) -> NetsConfig {
    NetsConfig {
        encoder,
        image_size: 21,
        history: 4,
        state_dim: 5,
        hidden: 16,
        quantiles: 8,
        quantile_grid: 6,
        shared_encoder: shared,
        ..Default::default()
    }
}
