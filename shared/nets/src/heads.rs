//! The three networks of DSAC: Cholesky-Gaussian policy, FQF fraction proposal and
//! NDQFN non-decreasing quantile function.
//!
//! Invariants: the policy's covariance factor is lower triangular with a positive
//! diagonal (softplus, clamped to [`MIN_DIAG`, `MAX_DIAG`]), so the density is always
//! proper; proposed fractions are strictly increasing from τ₀ = 0 to τ_N = 1 (softmax
//! then cumulative sum); quantile values are non-decreasing in τ for any weights
//! (monotone grid values, linear interpolation).

use candle_core::{D, DType, Device, IndexOp, Tensor};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use crate::config::{ACTION_DIM, NetsConfig};
use crate::encoder::{Encoder, Obs};
use crate::error::Result;
use crate::layers::Dense;
use crate::ops::{log_one_minus_tanh_sq, softplus};
use crate::params::ParamStore;

/// Smallest diagonal entry of the Cholesky factor (std-dev scale).
pub const MIN_DIAG: f64 = 1e-3;
/// Largest diagonal entry of the Cholesky factor (≈ e², SAC's log-std bound).
pub const MAX_DIAG: f64 = 7.389;

/// Standard-normal noise (B, 3) from a seeded RNG.
pub fn standard_normal(rng: &mut ChaCha8Rng, batch: usize, device: &Device) -> Result<Tensor> {
    let data: Vec<f32> = (0..batch * ACTION_DIM).map(|_| rng.sample::<f32, _>(StandardNormal)).collect();
    Ok(Tensor::from_vec(data, (batch, ACTION_DIM), device)?)
}

/// A batch of Gaussians N(μ, LLᵀ) over pre-squash actions.
#[derive(Debug, Clone)]
pub struct CholeskyGaussian {
    /// Means (B, 3).
    pub mean: Tensor,
    /// Lower-triangular factors (B, 3, 3).
    pub scale_tril: Tensor,
    /// Their diagonals (B, 3), > 0.
    pub diag: Tensor,
}

/// An action drawn from the squashed policy.
#[derive(Debug, Clone)]
pub struct PolicySample {
    /// a = tanh(u), (B, 3) in (−1, 1).
    pub action: Tensor,
    /// log π(a|s) including the tanh Jacobian, (B).
    pub log_prob: Tensor,
}

const HALF_LOG_2PI: f64 = 0.918_938_533_204_672_7;

impl CholeskyGaussian {
    /// Build from the 9 raw head outputs: 3 means, 3 diagonal pre-softplus values,
    /// 3 below-diagonal entries (L₁₀, L₂₀, L₂₁).
    pub fn from_raw(mean: Tensor, raw: &Tensor) -> Result<CholeskyGaussian> {
        let b = mean.dims()[0];
        let diag = softplus(&raw.narrow(1, 0, 3)?)?.clamp(MIN_DIAG, MAX_DIAG)?;
        let zero = Tensor::zeros((b, 1), mean.dtype(), mean.device())?;
        let (d0, d1, d2) = (diag.narrow(1, 0, 1)?, diag.narrow(1, 1, 1)?, diag.narrow(1, 2, 1)?);
        let (l10, l20, l21) = (raw.narrow(1, 3, 1)?, raw.narrow(1, 4, 1)?, raw.narrow(1, 5, 1)?);
        let scale_tril = Tensor::cat(&[&d0, &zero, &zero, &l10, &d1, &zero, &l20, &l21, &d2], 1)?
            .reshape((b, ACTION_DIM, ACTION_DIM))?;
        Ok(CholeskyGaussian { mean, scale_tril, diag })
    }

    /// u = μ + L·ε (reparameterised) for noise ε (B, 3).
    pub fn pre_squash(&self, eps: &Tensor) -> Result<Tensor> {
        let b = eps.dims()[0];
        let le = self.scale_tril.matmul(&eps.reshape((b, ACTION_DIM, 1))?)?.reshape((b, ACTION_DIM))?;
        Ok((&self.mean + le)?)
    }

    /// log N(u; μ, LLᵀ) when u = μ + Lε: −½‖ε‖² − Σ log Lᵢᵢ − (3/2) log 2π.
    pub fn log_density_of_noise(&self, eps: &Tensor) -> Result<Tensor> {
        let quad = (eps.sqr()?.sum(D::Minus1)? * -0.5)?;
        let logdet = self.diag.log()?.sum(D::Minus1)?;
        Ok(((quad - logdet)? - ACTION_DIM as f64 * HALF_LOG_2PI)?)
    }

    /// ε = L⁻¹(u − μ) by forward substitution.
    pub fn whiten(&self, u: &Tensor) -> Result<Tensor> {
        let r = (u - &self.mean)?;
        let l = |i: usize, j: usize| -> Result<Tensor> { Ok(self.scale_tril.i((.., i, j))?) };
        let r_i = |i: usize| -> Result<Tensor> { Ok(r.i((.., i))?) };
        let e0 = (r_i(0)? / l(0, 0)?)?;
        let e1 = ((r_i(1)? - (l(1, 0)? * &e0)?)? / l(1, 1)?)?;
        let e2 = (((r_i(2)? - (l(2, 0)? * &e0)?)? - (l(2, 1)? * &e1)?)? / l(2, 2)?)?;
        Ok(Tensor::stack(&[e0, e1, e2], 1)?)
    }

    /// log N(u; μ, LLᵀ) of given pre-squash actions.
    pub fn log_density(&self, u: &Tensor) -> Result<Tensor> {
        self.log_density_of_noise(&self.whiten(u)?)
    }

    /// Sample a = tanh(μ + Lε) with log π(a) = log N(u) − Σ log(1 − tanh²uᵢ).
    pub fn sample(&self, eps: &Tensor) -> Result<PolicySample> {
        let u = self.pre_squash(eps)?;
        let log_prob = (self.log_density_of_noise(eps)? - log_one_minus_tanh_sq(&u)?.sum(D::Minus1)?)?;
        Ok(PolicySample { action: u.tanh()?, log_prob })
    }

    /// The deterministic action tanh(μ) (evaluation).
    pub fn mode(&self) -> Result<Tensor> {
        Ok(self.mean.tanh()?)
    }
}

/// Gaussian policy π(a|s).
#[derive(Clone)]
pub struct PolicyNet {
    /// The parameters (the encoder's too unless it is shared).
    pub store: ParamStore,
    /// Own encoder, or `None` when the encoder is shared with the quantile net.
    pub encoder: Option<Encoder>,
    fc: Dense,
    mean: Dense,
    raw_scale: Dense,
}

impl PolicyNet {
    /// Build; `feature_dim` is the encoder width (shared or own).
    pub fn new(
        cfg: &NetsConfig,
        own_encoder: bool,
        feature_dim: usize,
        device: &Device,
        rng: &mut ChaCha8Rng,
    ) -> Result<Self> {
        let (mut store, encoder) = store_with_encoder("policy", cfg, own_encoder, device, rng)?;
        let fc = Dense::new(&mut store, "fc", feature_dim, cfg.hidden, rng)?;
        let mean = Dense::new(&mut store, "mean", cfg.hidden, ACTION_DIM, rng)?;
        let raw_scale = Dense::new(&mut store, "scale", cfg.hidden, 6, rng)?;
        Ok(PolicyNet { store, encoder, fc, mean, raw_scale })
    }

    /// The action distribution for encoder features (B, F).
    pub fn head(&self, features: &Tensor) -> Result<CholeskyGaussian> {
        let h = self.fc.forward(features)?.relu()?;
        CholeskyGaussian::from_raw(self.mean.forward(&h)?, &self.raw_scale.forward(&h)?)
    }
}

/// FQF fractions for a batch: τ₀ = 0 < τ₁ < … < τ_N = 1 and midpoints τ̂.
#[derive(Debug, Clone)]
pub struct Fractions {
    /// (B, N + 1).
    pub taus: Tensor,
    /// τ̂ᵢ = (τᵢ + τᵢ₊₁)/2, (B, N).
    pub hats: Tensor,
    /// Widths τᵢ₊₁ − τᵢ, (B, N).
    pub widths: Tensor,
    /// Entropy of the softmax over fractions, (B).
    pub entropy: Tensor,
}

/// The fraction-proposal network (FQF): state-action → N fractions.
#[derive(Clone)]
pub struct FractionNet {
    /// The parameters.
    pub store: ParamStore,
    /// Own encoder, or `None` when shared.
    pub encoder: Option<Encoder>,
    fc: Dense,
    logits: Dense,
    n: usize,
}

impl FractionNet {
    /// Build; the trunk sees the features and the current action.
    pub fn new(
        cfg: &NetsConfig,
        own_encoder: bool,
        feature_dim: usize,
        device: &Device,
        rng: &mut ChaCha8Rng,
    ) -> Result<Self> {
        let (mut store, encoder) = store_with_encoder("fraction", cfg, own_encoder, device, rng)?;
        let fc = Dense::new(&mut store, "fc", feature_dim + ACTION_DIM, cfg.hidden, rng)?;
        let logits = Dense::new(&mut store, "logits", cfg.hidden, cfg.quantiles, rng)?;
        Ok(FractionNet { store, encoder, fc, logits, n: cfg.quantiles })
    }

    /// Fractions for features (B, F) and actions (B, 3).
    pub fn fractions(&self, features: &Tensor, action: &Tensor) -> Result<Fractions> {
        let x = Tensor::cat(&[features, action], D::Minus1)?;
        let logits = self.logits.forward(&self.fc.forward(&x)?.relu()?)?;
        let log_p = candle_nn::ops::log_softmax(&logits, D::Minus1)?;
        let p = log_p.exp()?;
        let entropy = (&p * &log_p)?.sum(D::Minus1)?.neg()?;
        let b = p.dims()[0];
        let cum = p.cumsum(D::Minus1)?;
        let zero = Tensor::zeros((b, 1), p.dtype(), p.device())?;
        // The last cumulative sum is 1 up to rounding; pin it so τ_N is exactly 1.
        let taus = Tensor::cat(&[&zero, &cum.narrow(1, 0, self.n - 1)?, &(zero.ones_like()?)], 1)?;
        let lo = taus.narrow(1, 0, self.n)?;
        let hi = taus.narrow(1, 1, self.n)?;
        let hats = ((&lo + &hi)? * 0.5)?;
        let widths = (hi - lo)?;
        Ok(Fractions { taus, hats, widths, entropy })
    }
}

/// The NDQFN quantile network: state-action → monotone quantile function.
#[derive(Clone)]
pub struct QuantileNet {
    /// The parameters.
    pub store: ParamStore,
    /// Own encoder (the shared encoder lives here when encoders are shared).
    pub encoder: Option<Encoder>,
    fc: Dense,
    out: Dense,
    grid: usize,
}

/// Quantile values on the fixed grid p_j = j/M, j = 0..M, non-decreasing in j.
#[derive(Debug, Clone)]
pub struct QuantileGrid {
    /// (B, M + 1).
    pub values: Tensor,
    /// M.
    pub intervals: usize,
}

impl QuantileGrid {
    /// F⁻¹(τ) by linear interpolation between the grid values, for τ (B, n) in [0, 1].
    /// The interval index comes from τ's value; the gradient flows to the grid values
    /// (and to τ through the interpolation weight).
    pub fn at(&self, taus: &Tensor) -> Result<Tensor> {
        let m = self.intervals as f64;
        let scaled = (taus * m)?;
        let idx = scaled.detach().floor()?.clamp(0.0, m - 1.0)?;
        let frac = (scaled - &idx)?;
        let lo = self.values.gather(&idx.to_dtype(DType::U32)?, 1)?;
        let hi = self.values.gather(&(idx + 1.0)?.to_dtype(DType::U32)?, 1)?;
        Ok((&lo + (frac * (hi - &lo)?)?)?)
    }
}

impl QuantileNet {
    /// Build; `name` distinguishes the online net from its target.
    pub fn new(
        name: &str,
        cfg: &NetsConfig,
        own_encoder: bool,
        feature_dim: usize,
        device: &Device,
        rng: &mut ChaCha8Rng,
    ) -> Result<Self> {
        let (mut store, encoder) = store_with_encoder(name, cfg, own_encoder, device, rng)?;
        let fc = Dense::new(&mut store, "fc", feature_dim + ACTION_DIM, cfg.hidden, rng)?;
        let out = Dense::new(&mut store, "grid", cfg.hidden, cfg.quantile_grid + 1, rng)?;
        Ok(QuantileNet { store, encoder, fc, out, grid: cfg.quantile_grid })
    }

    /// Monotone grid values for features (B, F) and actions (B, 3): the first output
    /// is the value at τ = 0, the others are softplus increments, cumulatively summed.
    pub fn grid(&self, features: &Tensor, action: &Tensor) -> Result<QuantileGrid> {
        let x = Tensor::cat(&[features, action], D::Minus1)?;
        let raw = self.out.forward(&self.fc.forward(&x)?.relu()?)?;
        let base = raw.narrow(1, 0, 1)?;
        let inc = softplus(&raw.narrow(1, 1, self.grid)?)?.cumsum(D::Minus1)?;
        let values = Tensor::cat(&[&base, &inc.broadcast_add(&base)?], 1)?;
        Ok(QuantileGrid { values, intervals: self.grid })
    }
}

/// A parameter store for the network `name`, holding its own encoder if asked.
fn store_with_encoder(
    name: &str,
    cfg: &NetsConfig,
    own_encoder: bool,
    device: &Device,
    rng: &mut ChaCha8Rng,
) -> Result<(ParamStore, Option<Encoder>)> {
    let mut store = ParamStore::new(name, device);
    let encoder = if own_encoder { Some(Encoder::new(&mut store, cfg, rng)?) } else { None };
    Ok((store, encoder))
}

/// Run `encoder` on `obs` if there is one, else return the given shared features.
pub fn features_of(encoder: &Option<Encoder>, obs: &Obs, shared: Option<&Tensor>) -> Result<Tensor> {
    match (encoder, shared) {
        (Some(e), _) => e.encode(obs),
        (None, Some(f)) => Ok(f.detach()),
        (None, None) => {
            Err(candle_core::Error::Msg("network has no encoder and no shared features were given".into()).into())
        }
    }
}
