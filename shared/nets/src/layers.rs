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
