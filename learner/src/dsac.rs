//! The modified DSAC update (paper §III-D, Table IV): FQF fractions, NDQFN
//! quantiles, one quantile net with a Polyak target and no target actor,
//! automatic temperature, IS ratios from the dual replay on every loss.
//!
//! One update, with η the IS ratios of the batch and α = exp(log α) held fixed:
//! - target: a′ ~ π(·|s′), τ̂′ from the fraction net at (s′, a′),
//!   yⱼ = r + γ(1 − d)(Z_target(s′, a′, τ̂′ⱼ) − α log π(a′|s′)) — the goal (d = 1)
//!   does not bootstrap; truncation at T_max is not terminal and does. With n-step
//!   transitions (`n_step` n > 1) r is the batch's return Σ_{k<n} γᵏ r_{t+k}, s′ is
//!   s_{t+n} and γ becomes γⁿ (d = 1 when the goal comes within the n steps);
//! - critic: quantile Huber loss between Z(s, a, τ̂ᵢ) and yⱼ, weighted by the target
//!   fraction widths (as DSAC), per-sample, then Σ η·ℓ / B;
//! - fractions: FQF's W₁ gradient ∂W₁/∂τᵢ = 2Z(τᵢ) − Z(τ̂ᵢ₋₁) − Z(τ̂ᵢ) (detached) times τᵢ;
//! - policy: η·(α log π(ã|s) − Σᵢ (τᵢ₊₁ − τᵢ) Z(s, ã, τ̂ᵢ)) with ã reparameterised;
//! - temperature: −η·log α·(log π(ã|s) + H̄).
//!
//! With twin critics (`twin_critics`, as the original DSAC) a second quantile net Z₂
//! with its own target is trained on the same yⱼ (the critic loss is the sum of the
//! two); yⱼ uses, per sample, the target distribution whose mean Σ widths·Z is the
//! smaller; the policy maximises min(Q₁, Q₂); the fraction loss reads Z₁ only.
//!
//! With the state-prediction auxiliary loss (`state_aux_weight` λ > 0) a linear head
//! regresses the batch's privileged state targets s from the quantile net's o_t
//! features: ℓ_s = (1/B) Σ_b ‖ŝ_b − s_b‖² (unweighted by η: it is not an RL loss),
//! and the critic's gradient is taken of ℓ_Z + λ·ℓ_s, so the encoder it trains
//! learns to carry the state; the head steps with its own optimiser.
//!
//! With the temporal contrastive loss (`contrast_weight` λ_c > 0, self-supervised)
//! the anchors are the quantile net's o_t features, the positives the target
//! encoder's o_{t+n} features of the TD target (detached), and ℓ_c is InfoNCE over
//! the batch ([`pednav_nets::ContrastHead::info_nce`], unweighted by η); the critic's
//! gradient is taken of ℓ_Z + λ·ℓ_s + λ_c·ℓ_c.
//!
//! Invariant: every loss is computed with the pre-update weights and all gradients
//! are taken before any optimiser steps; if any loss or gradient is non-finite the
//! whole update is skipped (counted and logged) and the weights stay as they were.
//! On the CPU the TD target is computed beside the critics' forward pass, and the
//! critics' gradients beside the fraction, policy and temperature losses and theirs
//! (two `rayon::join`s): the same ops on the same inputs, so the same numbers as in
//! sequence (tested bit for bit), with one part's serial work filling the other's waits.

use candle_core::{D, DType, Device, Tensor};
use pednav_nets::heads::{features_of, standard_normal};
use pednav_nets::{
    AdamW, AdamWConfig, DsacNets, NetsConfig, Obs, OptimStep, ParamStore, QuantileGrid, TransitionFeatures,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::error::Result;
use crate::replay::Batch;
use pednav_config::DsacConfig;
use pednav_config::dsac::TargetEncoder;

/// o_{t+n}'s features for the TD target (detached): the target net's own encoder's, or
/// with `target_encoder = "online"` the shared online encoder's from the update's one pass.
fn td_features(nets: &DsacNets, mode: TargetEncoder, next_shared: Option<&Tensor>, next_obs: &Obs) -> Result<Tensor> {
    match (mode, next_shared) {
        (TargetEncoder::Online, Some(f)) => Ok(f.clone()),
        (TargetEncoder::Online, None) => {
            Err(pednav_config::ConfigError::learner("target_encoder", "\"online\"", "needs a shared encoder").into())
        }
        (TargetEncoder::Polyak, _) => Ok(nets.target_features(next_obs)?.detach()),
    }
}

/// Quantile Huber loss per sample (B): (1/N) Σᵢ Σⱼ wⱼ·|τ̂ᵢ − 1{δᵢⱼ < 0}|·H_κ(δᵢⱼ)/κ
/// with δᵢⱼ = yⱼ − zᵢ; `pred` (B, N), `target` (B, N′), `taus` (B, N), `weights` (B, N′).
/// On the CPU, with no gradient wanted through `target`, `taus` or `weights` (the
/// update's case), one op computes it ([`crate::quantile_huber`]); otherwise candle's ops.
pub fn quantile_huber_loss(
    pred: &Tensor,
    target: &Tensor,
    taus: &Tensor,
    weights: &Tensor,
    kappa: f64,
) -> Result<Tensor> {
    match crate::quantile_huber::fused(pred, target, taus, weights, kappa)? {
        Some(loss) => Ok(loss),
        None => quantile_huber_composed(pred, target, taus, weights, kappa),
    }
}

/// [`quantile_huber_loss`] from candle's ops (any device; gradients through every input).
pub(crate) fn quantile_huber_composed(
    pred: &Tensor,
    target: &Tensor,
    taus: &Tensor,
    weights: &Tensor,
    kappa: f64,
) -> Result<Tensor> {
    let (b, n) = pred.dims2()?;
    let m = target.dims()[1];
    let delta = target.unsqueeze(1)?.broadcast_sub(&pred.unsqueeze(2)?)?; // (B, N, N′)
    let abs = delta.abs()?;
    let small = abs.clamp(0.0, kappa)?;
    let huber = ((small.sqr()? * 0.5)? + ((&abs - &small)? * kappa)?)?;
    let below = delta.detach().lt(0.0)?.to_dtype(DType::F32)?;
    let asym = taus.unsqueeze(2)?.broadcast_as((b, n, m))?.sub(&below)?.abs()?;
    let rho = (asym * huber)?.broadcast_mul(&weights.unsqueeze(1)?)?;
    Ok((rho.sum(D::Minus1)?.mean(D::Minus1)? / kappa)?)
}

/// FQF's fraction-loss gradient ∂W₁/∂τᵢ for the N − 1 inner fractions (B, N − 1):
/// 2·Z(τᵢ) − Z(τ̂ᵢ₋₁) − Z(τ̂ᵢ), from values at the inner fractions `z_taus` (B, N − 1)
/// and at the midpoints `z_hats` (B, N).
pub fn fraction_gradient(z_taus: &Tensor, z_hats: &Tensor) -> Result<Tensor> {
    let n = z_hats.dims()[1];
    let left = z_hats.narrow(1, 0, n - 1)?;
    let right = z_hats.narrow(1, 1, n - 1)?;
    Ok(((z_taus * 2.0)? - left)?.sub(&right)?)
}

/// Per sample, the row of `a` or `b` (B, N) whose mean under `widths` (B, N) is the
/// smaller (ties: `a`) — the twin critics' pessimistic target distribution.
pub fn smaller_mean(a: &Tensor, b: &Tensor, widths: &Tensor) -> Result<Tensor> {
    let mean_a = (a * widths)?.sum_keepdim(D::Minus1)?;
    let mean_b = (b * widths)?.sum_keepdim(D::Minus1)?;
    let take_a = mean_a.le(&mean_b)?.broadcast_as(a.shape())?;
    Ok(take_a.where_cond(a, b)?)
}

/// Name of the temperature's store (and, with `.safetensors`, its checkpoint file).
pub(crate) const LOG_ALPHA: &str = "log_alpha";

/// Mean of η·x over the batch.
fn weighted_mean(x: &Tensor, eta: &Tensor) -> Result<Tensor> {
    Ok((x * eta)?.mean_all()?)
}

/// Diagnostics of one update.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct UpdateStats {
    /// Critic (quantile Huber) loss (with twin critics the mean of the two).
    pub critic_loss: f64,
    /// Policy loss.
    pub policy_loss: f64,
    /// Fraction-proposal loss.
    pub fraction_loss: f64,
    /// Temperature loss.
    pub alpha_loss: f64,
    /// α used in this update.
    pub alpha: f64,
    /// Policy entropy estimate −E[log π].
    pub entropy: f64,
    /// Mean Q(s, a) of the batch (Σ widths·Z; with twin critics the smaller of the two per sample).
    pub q_mean: f64,
    /// State-prediction loss ℓ_s (0 when the auxiliary loss is off).
    pub state_loss: f64,
    /// Temporal contrastive loss ℓ_c (0 when it is off; ln B for features that tell
    /// the batch's transitions apart no better than chance).
    pub contrast_loss: f64,
    /// Gradient norm of the quantile net (before clipping).
    pub critic_grad_norm: f64,
    /// Gradient norm of the policy (before clipping).
    pub policy_grad_norm: f64,
    /// The update was skipped (non-finite loss or gradient).
    pub skipped: bool,
}

/// The TD target of a batch and what the rest of the update reads of its pass.
struct TdTarget {
    /// yⱼ (B, N′), detached.
    values: Tensor,
    /// The target fractions' widths (B, N′), detached.
    widths: Tensor,
    /// o_{t+n}'s features the TD target read — the target encoder's, or the online one's
    /// with `target_encoder = "online"` — detached (the contrastive positives).
    features: Tensor,
}

/// The online critics' forward pass at the batch's actions.
struct CriticsForward {
    fr: pednav_nets::heads::Fractions,
    /// τ̂, detached.
    hats: Tensor,
    grid: QuantileGrid,
    /// Z(s, a, τ̂) (B, N).
    z: Tensor,
    /// The twin's features and Z₂(s, a, τ̂) (twin critics only).
    twin: Option<(Tensor, Tensor)>,
}

/// The fraction, policy and temperature losses with their gradients.
struct ActorSide {
    fraction_loss: Tensor,
    policy_loss: Tensor,
    alpha_loss: Tensor,
    g_fraction: candle_core::backprop::GradStore,
    g_policy: candle_core::backprop::GradStore,
    g_alpha: candle_core::backprop::GradStore,
    /// −E[log π(ã|s)].
    entropy: f64,
}

/// The learner's trainable state: networks, optimisers, temperature, RNG.
pub struct Dsac {
    /// Hyper-parameters.
    pub cfg: DsacConfig,
    /// The networks.
    pub nets: DsacNets,
    /// log α as a one-parameter store.
    pub log_alpha: ParamStore,
    pub(crate) opt_policy: AdamW,
    pub(crate) opt_fraction: AdamW,
    pub(crate) opt_quantile: AdamW,
    /// The twin critic's optimiser (twin critics only).
    pub(crate) opt_quantile2: Option<AdamW>,
    /// The state head's optimiser (state-prediction auxiliary loss only).
    pub(crate) opt_state_head: Option<AdamW>,
    /// The contrastive head's optimiser (temporal contrastive loss only).
    pub(crate) opt_contrast_head: Option<AdamW>,
    pub(crate) opt_alpha: AdamW,
    /// Noise for policy samples (seeded; saved in checkpoints).
    pub rng: ChaCha8Rng,
    /// Updates applied.
    pub updates: u64,
    /// Updates skipped by the non-finite guard.
    pub skipped: u64,
}

impl Dsac {
    /// Fresh networks and optimisers from `seed`.
    pub fn new(cfg: &DsacConfig, nets_cfg: &NetsConfig, device: &Device, seed: u64) -> Result<Dsac> {
        cfg.validate()?;
        cfg.validate_with_encoder(nets_cfg.shared_encoder)?;
        let nets = DsacNets::for_learner(nets_cfg, cfg, device, seed)?;
        let mut log_alpha = ParamStore::new(LOG_ALPHA, device);
        log_alpha.insert(LOG_ALPHA, Tensor::new(&[cfg.initial_alpha.ln() as f32], device)?)?;
        let opt = |store: &ParamStore, lr: f64| {
            AdamW::new(store, AdamWConfig { max_grad_norm: cfg.max_grad_norm, ..AdamWConfig::with_lr(lr) })
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(pednav_config::rng::stream::LEARNER_UPDATE);
        Ok(Dsac {
            opt_policy: opt(&nets.policy.store, cfg.lr_policy)?,
            opt_fraction: opt(&nets.fraction.store, cfg.lr_fraction)?,
            opt_quantile: opt(&nets.quantile.store, cfg.lr_quantile)?,
            opt_quantile2: nets.twin.as_ref().map(|t| opt(&t.quantile.store, cfg.lr_quantile)).transpose()?,
            opt_state_head: nets.state_head.as_ref().map(|h| opt(&h.store, cfg.lr_quantile)).transpose()?,
            opt_contrast_head: nets.contrast_head.as_ref().map(|h| opt(&h.store, cfg.lr_quantile)).transpose()?,
            opt_alpha: AdamW::new(&log_alpha, AdamWConfig::with_lr(cfg.lr_alpha))?,
            cfg: cfg.clone(),
            nets,
            log_alpha,
            rng,
            updates: 0,
            skipped: 0,
        })
    }

    /// Current temperature α.
    pub fn alpha(&self) -> Result<f64> {
        let v = self.log_alpha.vars()[0].1.as_tensor().to_vec1::<f32>()?[0];
        Ok((v as f64).exp())
    }

    /// The optimisers by name, in checkpoint order (`quantile2` with twin critics only,
    /// `state_head` with the auxiliary loss only).
    pub(crate) fn optimizers(&mut self) -> Vec<(&'static str, &mut AdamW)> {
        let mut opts = vec![
            ("policy", &mut self.opt_policy),
            ("fraction", &mut self.opt_fraction),
            ("quantile", &mut self.opt_quantile),
            ("alpha", &mut self.opt_alpha),
        ];
        if let Some(opt) = &mut self.opt_quantile2 {
            opts.push(("quantile2", opt));
        }
        if let Some(opt) = &mut self.opt_state_head {
            opts.push(("state_head", opt));
        }
        if let Some(opt) = &mut self.opt_contrast_head {
            opts.push(("contrast_head", opt));
        }
        opts
    }

    /// Sample actions for a batch of observations (stochastic, or tanh(μ) when
    /// `deterministic`), with log-probabilities.
    pub fn act(&mut self, obs: &Obs, deterministic: bool) -> Result<(Tensor, Tensor)> {
        let f = self.nets.policy_features(obs)?;
        let dist = self.nets.policy.head(&f)?;
        if deterministic {
            let b = obs.batch();
            return Ok((dist.mode()?.detach(), Tensor::zeros(b, DType::F32, f.device())?));
        }
        let eps = standard_normal(&mut self.rng, obs.batch(), f.device())?;
        let s = dist.sample(&eps)?;
        Ok((s.action.detach(), s.log_prob.detach()))
    }

    /// One DSAC update on `batch`. On the CPU it runs on a worker of rayon's pool
    /// ([`pednav_nets::cpu::on_pool_worker`]): the update's parallel kernels then
    /// share their work inside the pool instead of each being handed over from the
    /// caller's thread.
    pub fn update(&mut self, batch: &Batch) -> Result<UpdateStats> {
        if batch.action.device().is_cpu() {
            pednav_nets::cpu::on_pool_worker(|| self.update_here(batch, true))
        } else {
            self.update_here(batch, false)
        }
    }

    /// The update; independent parts of it side by side where `split` (see
    /// [`pednav_nets::cpu::join_if`]), with the same numbers either way.
    fn update_here(&mut self, batch: &Batch, split: bool) -> Result<UpdateStats> {
        let c = self.cfg.clone();
        let alpha = self.alpha()?;
        let dev = batch.action.device().clone();
        let bsz = batch.action.dims()[0];
        // The policy's two noise draws in the order the update has always made them
        // (a′ for the target, then ã), before any work is split over threads.
        let eps_next = standard_normal(&mut self.rng, bsz, &dev)?;
        let eps_pi = standard_normal(&mut self.rng, bsz, &dev)?;
        let nets = &self.nets;
        let eta = &batch.weight;
        let log_alpha = self.log_alpha.vars()[0].1.as_tensor();
        // Independent parts side by side on the pool (one part's serial element-wise
        // work fills the other's waits); every tensor from the same ops as in sequence.
        let split = split && dev.is_cpu();

        // Encoders: o_t and o_{t+1} in one pass over each transition's frames where they can.
        let TransitionFeatures {
            online: feats,
            next_policy: next_policy_features,
            next_fraction: next_fraction_features,
            next_shared,
            obs,
            next_obs,
        } = nets.transition_features(&batch.transitions)?;

        // The TD target (no gradients) beside the critics' forward pass.
        let td_target = || -> Result<TdTarget> {
            let next_policy = nets.policy.head(&next_policy_features.detach())?;
            let next = next_policy.sample(&eps_next)?;
            let (a_next, logp_next) = (next.action.detach(), next.log_prob.detach());
            let next_fr = nets.fraction.fractions(&next_fraction_features.detach(), &a_next)?;
            let (next_hats, widths) = (next_fr.hats.detach(), next_fr.widths.detach());
            let features = td_features(nets, c.target_encoder, next_shared.as_ref(), &next_obs)?;
            let mut z_next = nets.target.grid(&features, &a_next)?.at(&next_hats)?.detach();
            if let Some(twin) = &nets.twin {
                let f2 = features_of(&twin.target.encoder, &next_obs, Some(&features))?.detach();
                let z2 = twin.target.grid(&f2, &a_next)?.at(&next_hats)?.detach();
                z_next = smaller_mean(&z_next, &z2, &widths)?;
            }
            let soft = z_next.broadcast_sub(&(logp_next * alpha)?.unsqueeze(1)?)?;
            // γⁿ: the batch's rewards are n-step returns bootstrapping from o_{t+n}.
            let not_done = (batch.done.neg()? + 1.0)?;
            let discount = c.gamma.powi(batch.n_step as i32);
            let values = soft
                .broadcast_mul(&(not_done * discount)?.unsqueeze(1)?)?
                .broadcast_add(&batch.reward.unsqueeze(1)?)?
                .detach();
            Ok(TdTarget { values, widths, features })
        };
        let critics_forward = || -> Result<CriticsForward> {
            let fr = nets.fraction.fractions(&feats.fraction, &batch.action)?;
            let hats = fr.hats.detach();
            let grid = nets.quantile.grid(&feats.quantile, &batch.action)?;
            let z = grid.at(&hats)?;
            // The twin's features: its own encoder's, or the shared encoder's *with*
            // their graph, so that both critic losses train a shared encoder.
            let twin = match &nets.twin {
                Some(t) => {
                    let f2 = match &t.quantile.encoder {
                        Some(e) => e.encode(&obs)?,
                        None => feats.quantile.clone(),
                    };
                    let z2 = t.quantile.grid(&f2, &batch.action)?.at(&hats)?;
                    Some((f2, z2))
                }
                None => None,
            };
            Ok(CriticsForward { fr, hats, grid, z, twin })
        };
        let (td, critics) = pednav_nets::cpu::join_if(split, td_target, critics_forward);
        let (td, CriticsForward { fr, hats, grid, z, twin }) = (td?, critics?);

        // Critic.
        let mut critic_loss =
            weighted_mean(&quantile_huber_loss(&z, &td.values, &hats, &td.widths, c.huber_kappa)?, eta)?;
        let mut q_batch = (&z.detach() * fr.widths.detach())?.sum(D::Minus1)?;
        if let Some((_, z2)) = &twin {
            let loss2 = weighted_mean(&quantile_huber_loss(z2, &td.values, &hats, &td.widths, c.huber_kappa)?, eta)?;
            critic_loss = (critic_loss + loss2)?;
            q_batch = q_batch.minimum(&(&z2.detach() * fr.widths.detach())?.sum(D::Minus1)?)?;
        }

        // State prediction (auxiliary): through the quantile net's encoder.
        let state_loss = match (&nets.state_head, &batch.state_target) {
            (Some(head), Some(s)) => {
                let (want, got) = (head.layer.fan_out(), s.dims().last().copied().unwrap_or(0));
                if want != got {
                    return Err(crate::error::LearnerError::Replay(format!(
                        "state targets of {got} values for a state head of {want} (`nets.state_dim`)"
                    )));
                }
                Some(head.predict(&feats.quantile)?.sub(s)?.sqr()?.sum(D::Minus1)?.mean_all()?)
            }
            (Some(_), None) => {
                return Err(crate::error::LearnerError::Replay(
                    "the state-prediction loss is on but the batch has no state targets \
                     (the replay was not built with_state_targets)"
                        .into(),
                ));
            }
            (None, _) => None,
        };

        // Temporal contrast (self-supervised): o_t's online features against the
        // o_{t+n} features the TD target read (the target encoder's, or the online
        // one's with `target_encoder = "online"`).
        let contrast_loss = match &nets.contrast_head {
            Some(head) => Some(head.info_nce(&feats.quantile, &td.features)?),
            None => None,
        };
        let mut critic_objective = critic_loss.clone();
        if let Some(l) = &state_loss {
            critic_objective = (critic_objective + (l * c.state_aux_weight)?)?;
        }
        if let Some(l) = &contrast_loss {
            critic_objective = (critic_objective + (l * c.contrast_weight)?)?;
        }

        // The critics' gradients (through the encoder: the update's largest pass)
        // beside the fraction, policy and temperature losses and their gradients.
        let actor_side = || -> Result<ActorSide> {
            // Fraction proposal (quantile values detached; gradient through τ only).
            let n = fr.taus.dims()[1] - 1;
            let fixed = QuantileGrid { values: grid.values.detach(), intervals: grid.intervals };
            let inner = fr.taus.narrow(1, 1, n - 1)?;
            let grad_w1 = fraction_gradient(&fixed.at(&inner.detach())?, &fixed.at(&hats)?)?.detach();
            let mut fraction_per = (grad_w1 * &inner)?.sum(D::Minus1)?;
            if c.fraction_entropy != 0.0 {
                fraction_per = (fraction_per - (&fr.entropy * c.fraction_entropy)?)?;
            }
            let fraction_loss = weighted_mean(&fraction_per, eta)?;

            // Policy (critic features and fractions detached; gradient through ã).
            let pi = nets.policy.head(&feats.policy)?.sample(&eps_pi)?;
            let new_fr = nets.fraction.fractions(&feats.fraction.detach(), &pi.action.detach())?;
            let z_new = nets.quantile.grid(&feats.quantile.detach(), &pi.action)?.at(&new_fr.hats.detach())?;
            let mut q_new = (z_new * new_fr.widths.detach())?.sum(D::Minus1)?;
            if let (Some(t), Some((f2, _))) = (&nets.twin, &twin) {
                let z2_new = t.quantile.grid(&f2.detach(), &pi.action)?.at(&new_fr.hats.detach())?;
                q_new = q_new.minimum(&(z2_new * new_fr.widths.detach())?.sum(D::Minus1)?)?;
            }
            let policy_loss = weighted_mean(&((&pi.log_prob * alpha)? - q_new)?, eta)?;

            // Temperature.
            let gap = (pi.log_prob.detach() + c.target_entropy)?;
            let alpha_loss = weighted_mean(&gap.broadcast_mul(log_alpha)?, eta)?.neg()?;
            let entropy = -(pi.log_prob.detach().mean_all()?.to_scalar::<f32>()? as f64);
            Ok(ActorSide {
                g_fraction: fraction_loss.backward()?,
                g_policy: policy_loss.backward()?,
                g_alpha: alpha_loss.backward()?,
                fraction_loss,
                policy_loss,
                alpha_loss,
                entropy,
            })
        };
        let (g_critic, actor) = pednav_nets::cpu::join_if(split, || critic_objective.backward(), actor_side);
        let (g_critic, actor) = (g_critic?, actor?);
        let q_mean = q_batch.mean_all()?.to_scalar::<f32>()? as f64;

        let scalar = |t: &Tensor| -> Result<f64> { Ok(t.to_scalar::<f32>()? as f64) };
        let critics = if nets.twin.is_some() { 2.0 } else { 1.0 };
        let mut stats = UpdateStats {
            critic_loss: scalar(&critic_loss)? / critics,
            policy_loss: scalar(&actor.policy_loss)?,
            fraction_loss: scalar(&actor.fraction_loss)?,
            alpha_loss: scalar(&actor.alpha_loss)?,
            alpha,
            entropy: actor.entropy,
            q_mean,
            state_loss: state_loss.as_ref().map(scalar).transpose()?.unwrap_or(0.0),
            contrast_loss: contrast_loss.as_ref().map(scalar).transpose()?.unwrap_or(0.0),
            ..Default::default()
        };
        let losses_finite = [
            stats.critic_loss,
            stats.policy_loss,
            stats.fraction_loss,
            stats.alpha_loss,
            stats.state_loss,
            stats.contrast_loss,
        ]
        .iter()
        .all(|v| v.is_finite());
        if !losses_finite {
            return Ok(self.skip(stats, "non-finite loss"));
        }
        // Each optimiser with its gradients; the twin critic's from the same critic loss.
        let mut steps: Vec<(&mut AdamW, &candle_core::backprop::GradStore)> = vec![
            (&mut self.opt_quantile, &g_critic),
            (&mut self.opt_fraction, &actor.g_fraction),
            (&mut self.opt_policy, &actor.g_policy),
            (&mut self.opt_alpha, &actor.g_alpha),
        ];
        if let Some(opt) = &mut self.opt_quantile2 {
            steps.push((opt, &g_critic));
        }
        if let Some(opt) = &mut self.opt_state_head {
            steps.push((opt, &g_critic));
        }
        if let Some(opt) = &mut self.opt_contrast_head {
            steps.push((opt, &g_critic));
        }
        let norms =
            steps.iter().map(|(opt, grads)| opt.grad_norm(grads)).collect::<std::result::Result<Vec<_>, _>>()?;
        stats.critic_grad_norm = norms[0];
        stats.policy_grad_norm = norms[2];
        if norms.iter().any(|v| !v.is_finite()) {
            return Ok(self.skip(stats, "non-finite gradient"));
        }
        for ((opt, grads), norm) in steps.into_iter().zip(norms) {
            let outcome = opt.step_with_norm(grads, norm)?;
            debug_assert!(matches!(outcome, OptimStep::Applied { .. }), "norms were checked finite");
        }
        self.nets.target.store.soft_update(&self.nets.quantile.store, c.soft_update)?;
        if let Some(twin) = &self.nets.twin {
            twin.target.store.soft_update(&twin.quantile.store, c.soft_update)?;
        }
        self.updates += 1;
        Ok(stats)
    }

    fn skip(&mut self, mut stats: UpdateStats, why: &str) -> UpdateStats {
        self.skipped += 1;
        tracing::warn!(update = self.updates, skipped = self.skipped, "{why}: update skipped, weights unchanged");
        stats.skipped = true;
        stats
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::device_check::fill_replay;
    use crate::replay::{DualReplay, FrameKind, ReplayConfig};
    use pednav_nets::ParamStore;

    fn values(stores: &[&ParamStore]) -> Vec<Vec<f32>> {
        let mut out = Vec::new();
        for store in stores {
            for (_, v) in store.vars() {
                out.push(v.flatten_all().unwrap().to_vec1().unwrap());
            }
        }
        out
    }

    /// The parts of an update run side by side give bit for bit the update run in
    /// sequence: pixels with a shared encoder, twin critics and the contrastive loss
    /// (the CPU preset), and separate encoders (the twin with its own) with the
    /// state-prediction head.
    #[test]
    fn split_update_equals_the_sequential_one_bit_for_bit() {
        let recipe =
            DsacConfig { batch_size: 16, warmup: 16, twin_critics: true, contrast_weight: 1.0, ..Default::default() };
        let state_head = DsacConfig { contrast_weight: 0.0, state_aux_weight: 0.5, ..recipe.clone() };
        let nets = NetsConfig { image_size: 42, history: 8, ..Default::default() };
        for (cfg, nets) in [(recipe, NetsConfig { shared_encoder: true, ..nets.clone() }), (state_head, nets)] {
            let kind = FrameKind::Pixels { size: 42 };
            let rc = ReplayConfig { nonterminal_capacity: 200, terminal_capacity: 50 };
            let mut replay = DualReplay::new(&rc, kind, nets.history, &Device::Cpu).unwrap();
            if cfg.builds_state_head() {
                replay = replay.with_state_targets(nets.state_dim).unwrap();
            }
            let mut rng = ChaCha8Rng::seed_from_u64(3);
            fill_replay(&mut replay, kind, 150, &mut rng).unwrap();
            let new = || Dsac::new(&cfg, &nets, &Device::Cpu, 5).unwrap();
            let (mut split, mut sequential) = (new(), new());
            for _ in 0..2 {
                let batch = replay.sample(cfg.batch_size, &mut rng).unwrap();
                let a = pednav_nets::cpu::on_pool_worker(|| split.update_here(&batch, true)).unwrap();
                let b = pednav_nets::cpu::on_pool_worker(|| sequential.update_here(&batch, false)).unwrap();
                assert!(!a.skipped);
                assert_eq!(a, b);
            }
            let stores = |d: &Dsac| values(&d.nets.stores().into_iter().chain([&d.log_alpha]).collect::<Vec<_>>());
            assert_eq!(stores(&split), stores(&sequential));
        }
    }

    /// `target_encoder = "online"`: the TD target (and the contrastive positives) read
    /// the shared online encoder's o_{t+1} features. At initialisation the target
    /// encoder is a copy of the online one and the one-pass window's o_{t+1} features
    /// equal a separate encoding, so the first update is the Polyak mode's bit for bit;
    /// with the target encoder's weights moved, the Polyak mode's update changes and the
    /// online mode's does not, while moving the target heads changes both. Without a
    /// shared encoder the setting is refused.
    #[test]
    fn online_target_features_replace_the_target_encoders_pass() {
        let polyak =
            DsacConfig { batch_size: 16, warmup: 16, twin_critics: true, contrast_weight: 1.0, ..Default::default() };
        let online = DsacConfig { target_encoder: TargetEncoder::Online, ..polyak.clone() };
        let nets = NetsConfig { image_size: 42, history: 8, shared_encoder: true, ..Default::default() };
        let kind = FrameKind::Pixels { size: 42 };
        let rc = ReplayConfig { nonterminal_capacity: 200, terminal_capacity: 50 };
        let mut replay = DualReplay::new(&rc, kind, nets.history, &Device::Cpu).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        fill_replay(&mut replay, kind, 150, &mut rng).unwrap();
        let batch = replay.sample(16, &mut rng).unwrap();
        // One update after scaling the target quantile net's encoder weights (`Some(true)`)
        // or its other weights (`Some(false)`) by 1.5.
        let update = |cfg: &DsacConfig, moved: Option<bool>| {
            let mut d = Dsac::new(cfg, &nets, &Device::Cpu, 5).unwrap();
            if let Some(encoder) = moved {
                for (name, var) in d.nets.target.store.vars() {
                    if name.contains("enc.") == encoder {
                        var.set(&(var.as_tensor() * 1.5).unwrap()).unwrap();
                    }
                }
            }
            let stats = d.update(&batch).unwrap();
            assert!(!stats.skipped);
            stats
        };
        assert_eq!(update(&online, None), update(&polyak, None), "fresh targets: both modes agree");
        assert_ne!(update(&polyak, Some(true)), update(&polyak, None), "the Polyak mode reads the target encoder");
        assert_eq!(update(&online, Some(true)), update(&online, None), "the online mode does not");
        assert_ne!(update(&online, Some(false)), update(&online, None), "but it reads the target heads");
        let separate = NetsConfig { shared_encoder: false, ..nets };
        let e = Dsac::new(&online, &separate, &Device::Cpu, 5).err().expect("refused").to_string();
        assert!(e.contains("target_encoder") && e.contains("shared_encoder"), "{e}");
    }
}
