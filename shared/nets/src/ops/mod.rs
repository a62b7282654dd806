//! Operations candle 0.11 lacks: the channel-last convolution kernel, softplus,
//! and a few numerically careful helpers.

pub mod conv;

use candle_core::{Result, Tensor};

pub use conv::{ConvSpec, conv, conv_reference};

/// softplus(x) = log(1 + eˣ), computed as max(x, 0) + log(1 + e^{−|x|}) so it
/// neither overflows for large x nor loses precision for very negative x.
pub fn softplus(x: &Tensor) -> Result<Tensor> {
    let pos = x.relu()?;
    let tail = (x.abs()?.neg()?.exp()? + 1.0)?.log()?;
    pos + tail
}

/// log(1 − tanh²(u)) = 2·(log 2 − u − softplus(−2u)), the stable form of the tanh
/// Jacobian term of a squashed Gaussian.
pub fn log_one_minus_tanh_sq(u: &Tensor) -> Result<Tensor> {
    let sp = softplus(&(u * -2.0)?)?;
    ((u.neg()? - sp)? + std::f64::consts::LN_2)? * 2.0
}
