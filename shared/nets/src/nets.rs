//! The set of networks one DSAC agent trains: policy, fraction proposal, quantile
//! net and its target, built from one seed.
//!
//! Invariant: with `shared_encoder = false` each of policy, fraction and quantile
//! nets owns an encoder (the paper); with `true` the quantile net owns the only
//! online encoder and the policy and fraction heads read its features detached, so
//! only the critic loss trains it. The target quantile net always mirrors the
//! quantile net's architecture (encoder included) and starts as an exact copy.
//! An optional second critic ([`TwinCritic`], DSAC's twin critics) has its own
//! encoder when encoders are not shared and otherwise reads the quantile net's
//! features (so both critic losses train the shared encoder); its target mirrors it.
//! An optional [`StateHead`] reads the quantile net's encoder features too (the
//! state-prediction auxiliary loss trains that encoder) and is never used for acting.

use candle_core::{Device, Tensor};
use pednav_config::DsacConfig;
use pednav_config::rng::stream;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::config::NetsConfig;
use crate::encoder::{Encoder, Obs, Transitions, feature_dim};
use crate::error::Result;
use crate::heads::{FractionNet, PolicyNet, QuantileNet, features_of};
use crate::layers::Dense;
use crate::params::ParamStore;

/// Encoder features of one batch for the three online networks.
#[derive(Debug, Clone)]
pub struct OnlineFeatures {
    /// For the policy head.
    pub policy: Tensor,
    /// For the fraction-proposal head.
    pub fraction: Tensor,
    /// For the quantile head.
    pub quantile: Tensor,
}

/// Encoder features of a batch of transitions (o_t, o_{t+1}) for one DSAC update.
#[derive(Debug, Clone)]
pub struct TransitionFeatures {
    /// o_t as the encoders read it ([`DsacNets::prepare`]), for other encoders of the update.
    pub obs: Obs,
    /// o_{t+1} as the encoders read it (the target net's input).
    pub next_obs: Obs,
    /// o_t's features for the three online heads.
    pub online: OnlineFeatures,
    /// o_{t+1}'s features for the policy head (a′).
    pub next_policy: Tensor,
    /// o_{t+1}'s features for the fraction head (τ′).
    pub next_fraction: Tensor,
    /// o_{t+1}'s features from the shared online encoder, detached (`None` where no
    /// head shares the quantile net's encoder): what the TD target reads with
    /// `dsac.target_encoder = "online"`.
    pub next_shared: Option<Tensor>,
}

/// The second quantile net of twin critics and its Polyak target.
#[derive(Clone)]
pub struct TwinCritic {
    /// Z₂(s, a, τ); without an encoder of its own when encoders are shared.
    pub quantile: QuantileNet,
    /// Polyak-averaged copy of `quantile`.
    pub target: QuantileNet,
}

/// A linear map from the quantile net's encoder features to a privileged target
/// vector (the simulator's state vector): the head of the state-prediction
/// auxiliary loss. Training only; acting never reads it.
#[derive(Clone)]
pub struct StateHead {
    /// Its parameters (`state_head.safetensors` in checkpoints).
    pub store: ParamStore,
    /// features → target.
    pub layer: Dense,
}

impl StateHead {
    /// Predicted targets (B, dim) from encoder features (B, F).
    pub fn predict(&self, features: &Tensor) -> Result<Tensor> {
        self.layer.forward(features)
    }
}

/// The head of the temporal contrastive auxiliary loss (`dsac.contrast_weight`): a
/// linear map of the online critic encoder's features of o_t, whose L2-normalised
/// output is compared with the L2-normalised o_{t+n} features the TD target read
/// (`dsac.target_encoder`) of every transition in the batch. Training only; acting
/// never reads it.
#[derive(Clone)]
pub struct ContrastHead {
    /// Its parameters (`contrast_head.safetensors` in checkpoints).
    pub store: ParamStore,
    /// anchor features → the space the positives are compared in.
    pub layer: Dense,
}

impl ContrastHead {
    /// Temperature of the InfoNCE logits (cosine similarities / 0.1, as SimCLR).
    pub const TEMPERATURE: f64 = 0.1;

    /// The InfoNCE loss (1/B) Σ_i [log Σ_j exp(s_ij) − s_ii] with s_ij = cos(W a_i + b,
    /// p_j) / [`ContrastHead::TEMPERATURE`]: row i's positive is p_i, the other rows'
    /// positives its negatives. `anchors` (B, F) carry the gradient to the encoder;
    /// `positives` (B, F) should come detached (the features the TD target read).
    pub fn info_nce(&self, anchors: &Tensor, positives: &Tensor) -> Result<Tensor> {
        let q = l2_normalise(&self.layer.forward(anchors)?)?;
        let k = l2_normalise(positives)?;
        let logits = (q.matmul(&k.t()?.contiguous()?)? / Self::TEMPERATURE)?; // (B, B)
        let b = logits.dims()[0];
        // Shift by the row maximum (detached: the loss does not depend on the shift).
        let shifted = logits.broadcast_sub(&logits.max_keepdim(1)?.detach())?;
        let log_sum = shifted.exp()?.sum_keepdim(1)?.log()?;
        let own = (shifted * Tensor::eye(b, candle_core::DType::F32, logits.device())?)?.sum_keepdim(1)?;
        Ok((log_sum - own)?.mean_all()?)
    }
}

/// Rows of `x` (B, F) scaled to unit L2 norm (ε 1e-12 under the root).
fn l2_normalise(x: &Tensor) -> Result<Tensor> {
    let norm = (x.sqr()?.sum_keepdim(1)? + 1e-12)?.sqrt()?;
    Ok(x.broadcast_div(&norm)?)
}

/// Which networks a [`DsacNets`] holds beside the paper's four (policy, fraction
/// proposal, quantile critic and its target): the one place that decides it — from a
/// config ([`NetParts::of`]) or from what a checkpoint says it holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct NetParts {
    /// The second critic and its target (`dsac.twin_critics`).
    pub twin_critic: bool,
    /// The state-prediction head (`dsac.state_aux_weight` > 0).
    pub state_head: bool,
    /// The temporal contrastive head (`dsac.contrast_weight` > 0).
    pub contrast_head: bool,
}

impl NetParts {
    /// The parts a learner configured with `dsac` trains.
    pub fn of(dsac: &DsacConfig) -> NetParts {
        NetParts {
            twin_critic: dsac.builds_twin_critic(),
            state_head: dsac.builds_state_head(),
            contrast_head: dsac.builds_contrast_head(),
        }
    }
}

/// Policy, fraction-proposal, quantile and target quantile networks.
#[derive(Clone)]
pub struct DsacNets {
    /// The architecture.
    pub cfg: NetsConfig,
    /// π(a|s).
    pub policy: PolicyNet,
    /// FQF fraction proposal.
    pub fraction: FractionNet,
    /// NDQFN quantile function Z(s, a, τ).
    pub quantile: QuantileNet,
    /// Polyak-averaged copy of `quantile`.
    pub target: QuantileNet,
    /// The second critic, when twin critics are on ([`DsacNets::with_twin_critic`]).
    pub twin: Option<TwinCritic>,
    /// The auxiliary state-prediction head ([`DsacNets::with_state_head`]).
    pub state_head: Option<StateHead>,
    /// The temporal contrastive head ([`DsacNets::with_contrast_head`]).
    pub contrast_head: Option<ContrastHead>,
}

impl DsacNets {
    /// Build all networks from `seed` (each from its own stream of the seed).
    pub fn new(cfg: &NetsConfig, device: &Device, seed: u64) -> Result<DsacNets> {
        cfg.validate()?;
        let feature_dim = feature_dim(cfg);
        let own = !cfg.shared_encoder;
        let rng = |stream: u64| {
            let mut r = ChaCha8Rng::seed_from_u64(seed);
            r.set_stream(stream);
            r
        };
        let policy = PolicyNet::new(cfg, own, feature_dim, device, &mut rng(stream::POLICY_INIT))?;
        let fraction = FractionNet::new(cfg, own, feature_dim, device, &mut rng(stream::FRACTION_INIT))?;
        let quantile = QuantileNet::new("quantile", cfg, true, feature_dim, device, &mut rng(stream::QUANTILE_INIT))?;
        let target =
            QuantileNet::new("target_quantile", cfg, true, feature_dim, device, &mut rng(stream::QUANTILE_INIT))?;
        target.store.copy_from(&quantile.store)?;
        Ok(DsacNets {
            cfg: cfg.clone(),
            policy,
            fraction,
            quantile,
            target,
            twin: None,
            state_head: None,
            contrast_head: None,
        })
    }

    /// The networks a learner with `dsac` trains: [`DsacNets::new`] and the optional
    /// parts `dsac` asks for ([`NetParts::of`]).
    pub fn for_learner(cfg: &NetsConfig, dsac: &DsacConfig, device: &Device, seed: u64) -> Result<DsacNets> {
        DsacNets::with_parts(cfg, NetParts::of(dsac), device, seed)
    }

    /// [`DsacNets::new`] plus the optional `parts` (each from its own RNG stream of
    /// `seed`, so the paper's four networks are the same whatever the parts).
    pub fn with_parts(cfg: &NetsConfig, parts: NetParts, device: &Device, seed: u64) -> Result<DsacNets> {
        let mut nets = DsacNets::new(cfg, device, seed)?;
        if parts.twin_critic {
            nets = nets.with_twin_critic(seed)?;
        }
        if parts.state_head {
            nets = nets.with_state_head(cfg.state_dim, seed)?;
        }
        if parts.contrast_head {
            nets = nets.with_contrast_head(seed)?;
        }
        Ok(nets)
    }

    /// The optional parts these networks hold.
    pub fn parts(&self) -> NetParts {
        NetParts {
            twin_critic: self.twin.is_some(),
            state_head: self.state_head.is_some(),
            contrast_head: self.contrast_head.is_some(),
        }
    }

    /// Add the second critic of twin critics (from its own stream of `seed`, so the
    /// other networks are the same with and without it).
    pub fn with_twin_critic(mut self, seed: u64) -> Result<DsacNets> {
        let own = !self.cfg.shared_encoder;
        let feature_dim = feature_dim(&self.cfg);
        let device = self.quantile.store.device().clone();
        let rng = || {
            let mut r = ChaCha8Rng::seed_from_u64(seed);
            r.set_stream(stream::TWIN_CRITIC_INIT);
            r
        };
        let quantile = QuantileNet::new("quantile2", &self.cfg, own, feature_dim, &device, &mut rng())?;
        let target = QuantileNet::new("target_quantile2", &self.cfg, own, feature_dim, &device, &mut rng())?;
        target.store.copy_from(&quantile.store)?;
        self.twin = Some(TwinCritic { quantile, target });
        Ok(self)
    }

    /// Add a [`StateHead`] predicting `dim` targets from the quantile net's encoder
    /// features (from its own stream of `seed`, so the other networks are unchanged).
    pub fn with_state_head(mut self, dim: usize, seed: u64) -> Result<DsacNets> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(stream::STATE_HEAD_INIT);
        let mut store = ParamStore::new("state_head", self.quantile.store.device());
        let layer = Dense::new(&mut store, "linear", feature_dim(&self.cfg), dim, &mut rng)?;
        self.state_head = Some(StateHead { store, layer });
        Ok(self)
    }

    /// Add a [`ContrastHead`] on the quantile net's encoder features (from its own
    /// stream of `seed`, so the other networks are unchanged).
    pub fn with_contrast_head(mut self, seed: u64) -> Result<DsacNets> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(stream::CONTRAST_HEAD_INIT);
        let mut store = ParamStore::new("contrast_head", self.quantile.store.device());
        let f = feature_dim(&self.cfg);
        let layer = Dense::new(&mut store, "linear", f, f, &mut rng)?;
        self.contrast_head = Some(ContrastHead { store, layer });
        Ok(self)
    }

    /// Features of `obs` for the three online heads (shared encoder: computed once,
    /// detached for policy and fraction).
    pub fn online_features(&self, obs: &Obs) -> Result<OnlineFeatures> {
        let quantile = features_of(&self.quantile.encoder, obs, None)?;
        let policy = features_of(&self.policy.encoder, obs, Some(&quantile))?;
        let fraction = features_of(&self.fraction.encoder, obs, Some(&quantile))?;
        Ok(OnlineFeatures { policy, fraction, quantile })
    }

    /// Features for the policy head alone (acting, or a′ at the next state).
    pub fn policy_features(&self, obs: &Obs) -> Result<Tensor> {
        match &self.policy.encoder {
            Some(e) => e.encode(obs),
            None => Ok(features_of(&self.quantile.encoder, obs, None)?.detach()),
        }
    }

    /// Features for the policy and fraction heads (the next state's a′ and τ′):
    /// with a shared encoder it runs once for both.
    pub fn policy_and_fraction_features(&self, obs: &Obs) -> Result<(Tensor, Tensor)> {
        let shared = match (&self.policy.encoder, &self.fraction.encoder) {
            (Some(_), Some(_)) => None,
            _ => Some(features_of(&self.quantile.encoder, obs, None)?),
        };
        Ok((
            features_of(&self.policy.encoder, obs, shared.as_ref())?,
            features_of(&self.fraction.encoder, obs, shared.as_ref())?,
        ))
    }

    /// [`DsacNets::online_features`] of o_t together with
    /// [`DsacNets::policy_and_fraction_features`] of o_{t+1}, with each 3D-TCN encoder
    /// that needs both run once over the transitions' frames (see
    /// [`Encoder::encode_transition`]); equal to the two calls (tested).
    pub fn transition_features(&self, t: &Transitions) -> Result<TransitionFeatures> {
        let (obs, next) = (self.prepare(&t.obs()?)?, self.prepare(&t.next_obs()?)?);
        let pair = |e: &Encoder| -> Result<(Tensor, Tensor)> {
            match e.encode_window(t)? {
                Some(pair) => Ok(pair),
                None => Ok((e.encode(&obs)?, e.encode(&next)?)),
            }
        };
        let needs_shared = self.policy.encoder.is_none() || self.fraction.encoder.is_none();
        let quantile_encoder = self.quantile.encoder.as_ref().expect("the quantile net always has an encoder");
        let (quantile, shared_next) = if needs_shared {
            let (q, q_next) = pair(quantile_encoder)?;
            (q, Some(q_next))
        } else {
            (quantile_encoder.encode(&obs)?, None)
        };
        let own_or_shared = |e: &Option<Encoder>| -> Result<(Tensor, Tensor)> {
            match (e, &shared_next) {
                (Some(e), _) => pair(e),
                (None, Some(n)) => Ok((quantile.detach(), n.detach())),
                (None, None) => unreachable!("shared features exist when a head has no encoder"),
            }
        };
        let (policy, next_policy) = own_or_shared(&self.policy.encoder)?;
        let (fraction, next_fraction) = own_or_shared(&self.fraction.encoder)?;
        Ok(TransitionFeatures {
            online: OnlineFeatures { policy, fraction, quantile },
            next_policy,
            next_fraction,
            next_shared: shared_next.map(|n| n.detach()),
            obs,
            next_obs: next,
        })
    }

    /// The batch as the encoders read it best when several of them see it: frame
    /// stacking transposes the frames once here ([`Obs::stacked`]) instead of once per
    /// encoder; other encoders get the batch as it is.
    pub fn prepare(&self, obs: &Obs) -> Result<Obs> {
        match self.cfg.encoder {
            crate::config::EncoderKind::FrameStack => obs.stacked(),
            _ => Ok(obs.clone()),
        }
    }

    /// Features of the target quantile net.
    pub fn target_features(&self, obs: &Obs) -> Result<Tensor> {
        features_of(&self.target.encoder, obs, None)
    }

    /// The encoder the actor runs for the policy (own or shared).
    pub fn acting_encoder(&self) -> &Encoder {
        self.policy.encoder.as_ref().or(self.quantile.encoder.as_ref()).expect("the quantile net always has an encoder")
    }

    /// Every parameter store, in checkpoint order (the twin critic's, then the state
    /// head's, then the contrastive head's, last).
    pub fn stores(&self) -> Vec<&ParamStore> {
        let mut stores = vec![&self.policy.store, &self.fraction.store, &self.quantile.store, &self.target.store];
        if let Some(twin) = &self.twin {
            stores.extend([&twin.quantile.store, &twin.target.store]);
        }
        if let Some(head) = &self.state_head {
            stores.push(&head.store);
        }
        if let Some(head) = &self.contrast_head {
            stores.push(&head.store);
        }
        stores
    }

    /// The online networks — policy, fraction, quantile and the twin critic's quantile
    /// net — without the Polyak targets: what acting and Q(s, a) read.
    pub fn online_stores(&self) -> Vec<&ParamStore> {
        let mut stores = vec![&self.policy.store, &self.fraction.store, &self.quantile.store];
        if let Some(twin) = &self.twin {
            stores.push(&twin.quantile.store);
        }
        stores
    }

    /// What the actors need: the policy store plus, with a shared encoder, the
    /// quantile store (which holds the encoder).
    pub fn acting_stores(&self) -> Vec<&ParamStore> {
        if self.policy.encoder.is_some() {
            vec![&self.policy.store]
        } else {
            vec![&self.policy.store, &self.quantile.store]
        }
    }
}
