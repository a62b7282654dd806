//! Parameterised layers: dense and channel-last convolution.

use candle_core::{Tensor, Var};
use rand_chacha::ChaCha8Rng;

use crate::error::Result;
use crate::ops::{ConvSpec, conv, linear};
use crate::params::ParamStore;

/// `y = x·W + b` with W stored as (in, out). Initialised like PyTorch's
/// `nn.Linear`: uniform ±1/√in for weights and bias.
#[derive(Clone)]
pub struct Dense {
    w: Var,
    b: Var,
}

impl Dense {
    /// A new layer registered in `store` under `name.w` / `name.b`.
    pub fn new(
        store: &mut ParamStore,
        name: &str,
        fan_in: usize,
        fan_out: usize,
        rng: &mut ChaCha8Rng,
    ) -> Result<Dense> {
        let bound = 1.0 / (fan_in as f64).sqrt();
        Ok(Dense {
            w: store.uniform(&format!("{name}.w"), &[fan_in, fan_out], bound, rng)?,
            b: store.uniform(&format!("{name}.b"), &[fan_out], bound, rng)?,
        })
    }

    /// Apply to (B, in).
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        Ok(linear(x, self.w.as_tensor(), self.b.as_tensor())?)
    }

    /// Output width.
    pub fn fan_out(&self) -> usize {
        self.w.dims()[1]
    }
}

/// A convolution layer on the fused channel-last kernel ([`crate::ops::conv`]).
#[derive(Clone)]
pub struct Conv {
    w: Var,
    b: Var,
    spec: ConvSpec,
    c_in: usize,
    c_out: usize,
}

impl Conv {
    /// A new layer registered in `store` (uniform ±1/√fan_in, as PyTorch's `ConvNd`).
    pub fn new(
        store: &mut ParamStore,
        name: &str,
        spec: ConvSpec,
        c_in: usize,
        c_out: usize,
        rng: &mut ChaCha8Rng,
    ) -> Result<Conv> {
        let rows = spec.weight_rows(c_in);
        let bound = 1.0 / (rows as f64).sqrt();
        Ok(Conv {
            w: store.uniform(&format!("{name}.w"), &[rows, c_out], bound, rng)?,
            b: store.uniform(&format!("{name}.b"), &[c_out], bound, rng)?,
            spec,
            c_in,
            c_out,
        })
    }

    /// Apply to (B, T, H, W, C_in).
    pub fn forward(&self, x: &Tensor) -> Result<Tensor> {
        Ok(conv(x, self.w.as_tensor(), self.b.as_tensor(), self.spec)?)
    }

    /// Apply with a different temporal dilation (the streaming cache gathers the
    /// dilated taps itself and convolves them with dilation 1).
    pub fn forward_with_dilation(&self, x: &Tensor, dilation_t: usize) -> Result<Tensor> {
        let spec = ConvSpec { dilation_t, ..self.spec };
        Ok(conv(x, self.w.as_tensor(), self.b.as_tensor(), spec)?)
    }

    /// The layer's weight, bias and geometry, as [`crate::ops::conv_chain`] takes them.
    pub fn chain_link(&self) -> (&Tensor, &Tensor, ConvSpec) {
        (self.w.as_tensor(), self.b.as_tensor(), self.spec)
    }

    /// The layer's geometry.
    pub fn spec(&self) -> ConvSpec {
        self.spec
    }

    /// Input channels.
    pub fn c_in(&self) -> usize {
        self.c_in
    }

    /// Output channels.
    pub fn c_out(&self) -> usize {
        self.c_out
    }
}

/// So a [`Dense`] composes with candle-nn code (`x.apply(&layer)`, `candle_nn::seq`).
impl candle_nn::Module for Dense {
    fn forward(&self, xs: &Tensor) -> candle_core::Result<Tensor> {
        linear(xs, self.w.as_tensor(), self.b.as_tensor())
    }
}

/// So a [`Conv`] composes with candle-nn code; the input is (B, T, H, W, C_in).
impl candle_nn::Module for Conv {
    fn forward(&self, xs: &Tensor) -> candle_core::Result<Tensor> {
        conv(xs, self.w.as_tensor(), self.b.as_tensor(), self.spec)
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{Device, Tensor};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::Dense;
    use crate::params::ParamStore;

    /// The `Module` view of a layer is the layer: same output as `forward`, and as
    /// x·W + b computed by candle's own matmul.
    #[test]
    fn dense_as_a_module_is_x_w_plus_b() {
        let mut store = ParamStore::new("t", &Device::Cpu);
        let layer = Dense::new(&mut store, "l", 3, 2, &mut ChaCha8Rng::seed_from_u64(1)).unwrap();
        let x = Tensor::new(&[[1.0f32, -2.0, 0.5], [0.0, 3.0, -1.0]], &Device::Cpu).unwrap();
        let via_module = x.apply(&layer).unwrap().to_vec2::<f32>().unwrap();
        let via_forward = layer.forward(&x).unwrap().to_vec2::<f32>().unwrap();
        let tensors = store.tensors();
        let expected = x.matmul(&tensors["l.w"]).unwrap().broadcast_add(&tensors["l.b"]).unwrap();
        assert_eq!(via_module, via_forward);
        for (a, b) in via_module.iter().flatten().zip(expected.to_vec2::<f32>().unwrap().iter().flatten()) {
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
    }
}
