//! # pednav-policy — the learned policy as it acts
//!
//! [`ActingPolicy`] is the one place a trained (or training) policy chooses
//! actions: the actors while training and the evaluator afterwards both drive it
//! through the simulator's [`Policy`] trait, next to the random-walk and oracle
//! reference policies of `pednav_sim::policy`.
//!
//! It owns the networks ([`DsacNets`], only the acting encoder and the policy
//! head are read) and, for pixel observations, the streaming inference cache
//! ([`PolicyStream`]) that lets a 3D-TCN step convolve one new frame per layer.
//!
//! Invariants:
//! - The cache can never hold features of older weights: weights only change
//!   through [`ActingPolicy::load_weights`], which invalidates the cache itself.
//! - An episode's sampled actions depend only on the episode's seed, its
//!   observations and the weights: each environment draws its noise from its own
//!   generator, reseeded from the seed given to [`Policy::begin`] (stream
//!   [`NOISE_STREAM`] of that seed; the simulator uses the seed's default stream).

#![warn(missing_docs)]

use candle_core::{Device, Tensor};
use pednav_nets::{DsacNets, EncoderKind, NetsConfig, Obs, PolicyStream, heads::standard_normal};
use pednav_sim::{Action, Policy, PolicyError, VecEnv};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// Stream of an episode's seed that the policy's sampling noise comes from.
pub const NOISE_STREAM: u64 = pednav_config::rng::stream::ACTING_NOISE;

/// How actions come from the policy's distribution.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Sampling {
    /// a = tanh(μ + L·ε), ε ~ N(0, I): the stochastic policy, as it trains and as
    /// the paper's validation protocol samples it (§V-C).
    Sample,
    /// a = tanh(μ): the distribution's mode.
    Mode,
}

/// One decision for every environment of a [`VecEnv`].
pub struct Decision {
    /// The actions, (M, 3).
    pub actions: Tensor,
    /// log π(a|s) of sampled actions, (M); `None` when acting with the mode.
    pub log_probs: Option<Tensor>,
    /// The observations decided on (the full N_h windows for pixels), when asked for.
    pub obs: Option<Obs>,
}

/// The learned policy of M environments: networks, inference cache, sampling noise.
pub struct ActingPolicy {
    nets: DsacNets,
    state_dim: usize,
    /// Pixel observations: windows and per-layer caches. `None`: state vectors.
    stream: Option<PolicyStream>,
    sampling: Sampling,
    noise: Vec<ChaCha8Rng>,
    device: Device,
}

impl ActingPolicy {
    /// The policy of `nets` (built from `cfg`) for `envs` environments, on the
    /// device the networks live on. Pixel encoders act from the frames given to
    /// `begin`/`observe`; the MLP encoder from each environment's state vector.
    pub fn new(nets: DsacNets, cfg: &NetsConfig, envs: usize, sampling: Sampling) -> ActingPolicy {
        let device = nets.policy.store.device().clone();
        let stream = (cfg.encoder != EncoderKind::Mlp).then(|| PolicyStream::new(cfg, envs, &device));
        ActingPolicy {
            nets,
            state_dim: cfg.state_dim,
            stream,
            sampling,
            // Placeholders: `begin` reseeds each from its episode's seed before any action.
            noise: vec![ChaCha8Rng::seed_from_u64(0); envs],
            device,
        }
    }

    /// The networks.
    pub fn nets(&self) -> &DsacNets {
        &self.nets
    }

    /// Change the weights with `load` (which writes into the networks' stores);
    /// the inference cache is invalidated afterwards whether or not `load`
    /// succeeded (a failed load may have written part of the weights).
    pub fn load_weights<T, E>(&mut self, load: impl FnOnce(&DsacNets) -> Result<T, E>) -> Result<T, E> {
        let result = load(&self.nets);
        if let Some(stream) = &mut self.stream {
            stream.invalidate();
        }
        result
    }

    /// The policy's decision for every environment of `envs`; `keep_obs` also
    /// returns the observations it decided on (for diagnosis; pixels then build
    /// the full windows, which acting alone never needs).
    pub fn decide(&mut self, envs: &VecEnv, keep_obs: bool) -> pednav_nets::Result<Decision> {
        let m = envs.num_envs();
        let (features, obs) = match &mut self.stream {
            Some(stream) => {
                let all: Vec<usize> = (0..m).collect();
                let obs = if keep_obs { Some(stream.observation(&all)?) } else { None };
                (stream.features(self.nets.acting_encoder(), &all)?, obs)
            }
            None => {
                let d = envs.state_dim();
                let s: Vec<f32> = (0..m).flat_map(|e| envs.state_obs(e).into_iter().take(d)).collect();
                let obs = Obs::State(Tensor::from_vec(s, (m, self.state_dim), &self.device)?);
                (self.nets.acting_encoder().encode(&obs)?, keep_obs.then_some(obs))
            }
        };
        let dist = self.nets.policy.head(&features)?;
        Ok(match self.sampling {
            Sampling::Mode => Decision { actions: dist.mode()?, log_probs: None, obs },
            Sampling::Sample => {
                let eps = self
                    .noise
                    .iter_mut()
                    .map(|rng| standard_normal(rng, 1, &self.device))
                    .collect::<pednav_nets::Result<Vec<_>>>()?;
                let sample = dist.sample(&Tensor::cat(&eps, 0)?)?;
                Decision { actions: sample.action, log_probs: Some(sample.log_prob), obs }
            }
        })
    }
}

/// The rows of an (M, 3) action tensor.
pub fn action_rows(actions: &Tensor) -> pednav_nets::Result<Vec<Action>> {
    Ok(actions.to_vec2::<f32>()?.into_iter().map(|v| [v[0], v[1], v[2]]).collect())
}

impl Policy for ActingPolicy {
    fn needs_frames(&self) -> bool {
        self.stream.is_some()
    }

    fn begin(&mut self, env: usize, seed: u64, frame: Option<&[u8]>) -> Result<(), PolicyError> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(NOISE_STREAM);
        self.noise[env] = rng;
        if let Some(stream) = &mut self.stream {
            stream.reset(env, frame.ok_or("a pixel policy starts an episode from its first frame")?)?;
        }
        Ok(())
    }

    fn observe(&mut self, env: usize, action: Action, reward: f32, frame: Option<&[u8]>) -> Result<(), PolicyError> {
        if let Some(stream) = &mut self.stream {
            stream.push(env, action, reward, frame.ok_or("a pixel policy needs every frame")?)?;
        }
        Ok(())
    }

    fn act(&mut self, envs: &VecEnv, actions: &mut [Action]) -> Result<(), PolicyError> {
        let decision = self.decide(envs, false)?;
        for (dst, src) in actions.iter_mut().zip(action_rows(&decision.actions)?) {
            *dst = src;
        }
        Ok(())
    }
}
