//! DSAC settings (Table IV): the `[dsac]` section of every run's config file.

use serde::{Deserialize, Serialize};

use crate::error::{ConfigError, Result};

/// Distributional Soft Actor-Critic hyper-parameters. Defaults are the paper's Table IV.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DsacConfig {
    /// Discount factor γ.
    pub gamma: f64,
    /// Target entropy for the automatic temperature (−3 = −|A|).
    pub target_entropy: f64,
    /// Initial temperature α₀.
    pub initial_alpha: f64,
    /// Learning rate of the temperature (optimised as log α).
    pub lr_alpha: f64,
    /// Learning rate of the policy network.
    pub lr_policy: f64,
    /// Learning rate of the quantile network.
    pub lr_quantile: f64,
    /// Learning rate of the fraction-proposal network (FQF's value 2.5e-9).
    pub lr_fraction: f64,
    /// Polyak coefficient τ of the target quantile network.
    pub soft_update: f64,
    /// κ of the quantile Huber loss.
    pub huber_kappa: f64,
    /// Weight of the fraction-proposal entropy bonus (FQF's default 0).
    pub fraction_entropy: f64,
    /// Clip each network's global gradient norm to this value (`null`/absent: no clipping,
    /// as in the paper).
    pub max_grad_norm: Option<f64>,
    /// Samples per update.
    pub batch_size: usize,
    /// Env steps stored before the first update.
    pub warmup: u64,
    /// Env steps per update (the replay ratio).
    pub train_interval: u64,
    /// Updates the learner may fall behind before actors are held back.
    pub rate_slack: u64,
    /// Twin critics, as in DSAC (Duan et al.): two quantile nets (each with a Polyak
    /// target) trained on the same TD target, which takes per sample the target
    /// distribution whose mean is smaller; the policy maximises the smaller of the two
    /// means. The pedestrian paper does not say whether it kept them; `false` is one
    /// quantile net. Default `true`: on the state preset, at equal env steps, twin
    /// critics reached a better Avg.Int on both seeds and the same Avg.Ext
    /// (`docs/results/cpu-state`), at 1.6× the update time of that MLP preset.
    pub twin_critics: bool,
    /// DrQ's random-shift augmentation of pixel batches (Kostrikov et al., 2021): each
    /// sampled transition's N_h + 1 frames are shifted together by up to this many
    /// pixels in x and y, edges replicated (DrQ: 4 at 84×84). 0: off, as the paper.
    /// Pixel observations only.
    pub random_shift: usize,
    /// Weight λ of the state-prediction auxiliary loss (0: off, as the paper). When
    /// positive, a linear head on the critic encoder's features regresses the
    /// simulator's state vector of o_t (`nets.state_dim` floats: goal in the body
    /// frame, heading, head yaw, map rewards around the agent — the state preset's
    /// observation), and λ·E[‖ŝ − s‖²] is added to the critic loss so its gradient
    /// shapes the encoder — the "game features" auxiliary of Lample & Chaplot (2017).
    /// The state is privileged: it is a training target only and never reaches the
    /// policy's input, which stays pixels.
    pub state_aux_weight: f64,
    /// n of the n-step TD target (1: the paper's one-step target). With n > 1 the
    /// critic regresses on Σ_{k<n} γᵏ r_{t+k} + γⁿ (Z(s_{t+n}, a′) − α log π(a′|s_{t+n})),
    /// cut at the goal (no bootstrap past it), as Rainbow and DrQ-v2 (n = 3) do. Value
    /// information then travels n steps per backup instead of one; the price is a
    /// target that mixes in up to n − 1 steps of the older, behaviour policy's actions
    /// (no off-policy correction, as in those methods). Each sampled transition
    /// carries N_h + n frames; the terminal pool keeps the n transitions before every
    /// goal (so |B_T| grows n-fold, as Algorithm 2 counts done transitions).
    pub n_step: usize,
    /// Weight λ_c of the temporal contrastive auxiliary loss (0: off, as the paper). A
    /// self-supervised loss that needs nothing privileged: ATC's augmented temporal
    /// contrast (Stooke et al., 2021) on the two views the update already has — the
    /// online critic encoder's features of o_t (the anchor) and the Polyak target
    /// encoder's features of o_{t+n} (the positive, computed for the TD target
    /// anyway). A linear map of the anchor and the positive are L2-normalised; the
    /// InfoNCE loss over the batch (each anchor's positive against the batch's other
    /// positives, temperature 0.1) is added as λ_c·ℓ_c to the critic loss, so its
    /// gradient teaches the encoder to tell states apart — what the pixel critic's
    /// features were measured to lack. The map steps with its own optimiser.
    pub contrast_weight: f64,
}

impl Default for DsacConfig {
    fn default() -> Self {
        DsacConfig {
            gamma: 0.99,
            target_entropy: -3.0,
            initial_alpha: 0.25,
            lr_alpha: 1e-5,
            lr_policy: 1e-4,
            lr_quantile: 5e-5,
            lr_fraction: 2.5e-9,
            soft_update: 2.5e-3,
            huber_kappa: 1.0,
            fraction_entropy: 0.0,
            max_grad_norm: None,
            batch_size: 64,
            warmup: 50_000,
            train_interval: 8,
            rate_slack: 4,
            twin_critics: true,
            random_shift: 0,
            state_aux_weight: 0.0,
            n_step: 1,
            contrast_weight: 0.0,
        }
    }
}

impl DsacConfig {
    /// The largest `n_step` accepted (each sample carries N_h + n frames; beyond a few
    /// dozen steps γⁿ no longer bootstraps much anyway).
    pub const MAX_N_STEP: usize = 64;

    /// Whether the learner builds a second critic and its target (twin critics). With
    /// [`DsacConfig::builds_state_head`], the one rule for which networks a learner
    /// has beyond the paper's three: the learner, the memory estimate and the
    /// checkpoint check all ask here.
    pub fn builds_twin_critic(&self) -> bool {
        self.twin_critics
    }

    /// Whether the learner builds the state-prediction head (and the replay keeps
    /// state targets): only with a positive `state_aux_weight`.
    pub fn builds_state_head(&self) -> bool {
        self.state_aux_weight > 0.0
    }

    /// Whether the learner builds the contrastive head: only with a positive
    /// `contrast_weight`.
    pub fn builds_contrast_head(&self) -> bool {
        self.contrast_weight > 0.0
    }

    /// Reject impossible values, naming the field.
    // `!(x > 0.0)` on purpose: it also rejects NaN.
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    pub fn validate(&self) -> Result<()> {
        if !(0.0..1.0).contains(&self.gamma) {
            return Err(ConfigError::learner("gamma", self.gamma, "must be in [0, 1)"));
        }
        if !self.target_entropy.is_finite() {
            return Err(ConfigError::learner("target_entropy", self.target_entropy, "must be finite (−|A| = −3)"));
        }
        if !(self.initial_alpha > 0.0 && self.initial_alpha.is_finite()) {
            return Err(ConfigError::learner("initial_alpha", self.initial_alpha, "must be finite and positive"));
        }
        for (field, v) in [
            ("lr_alpha", self.lr_alpha),
            ("lr_policy", self.lr_policy),
            ("lr_quantile", self.lr_quantile),
            ("lr_fraction", self.lr_fraction),
        ] {
            if !(v >= 0.0 && v.is_finite()) {
                return Err(ConfigError::learner(field, v, "must be a finite non-negative learning rate"));
            }
        }
        if !(self.soft_update > 0.0 && self.soft_update <= 1.0) {
            return Err(ConfigError::learner("soft_update", self.soft_update, "must be in (0, 1]"));
        }
        if !(self.huber_kappa > 0.0 && self.huber_kappa.is_finite()) {
            return Err(ConfigError::learner("huber_kappa", self.huber_kappa, "must be finite and positive"));
        }
        if !(self.fraction_entropy >= 0.0 && self.fraction_entropy.is_finite()) {
            return Err(ConfigError::learner(
                "fraction_entropy",
                self.fraction_entropy,
                "must be finite and ≥ 0 (0: off)",
            ));
        }
        if let Some(m) = self.max_grad_norm
            && !(m > 0.0 && m.is_finite())
        {
            return Err(ConfigError::learner(
                "max_grad_norm",
                m,
                "must be finite and positive (omit it to disable clipping)",
            ));
        }
        if !(self.state_aux_weight >= 0.0 && self.state_aux_weight.is_finite()) {
            return Err(ConfigError::learner(
                "state_aux_weight",
                self.state_aux_weight,
                "must be finite and ≥ 0 (0: off)",
            ));
        }
        if !(self.contrast_weight >= 0.0 && self.contrast_weight.is_finite()) {
            return Err(ConfigError::learner(
                "contrast_weight",
                self.contrast_weight,
                "must be finite and ≥ 0 (0: off)",
            ));
        }
        if !(1..=Self::MAX_N_STEP).contains(&self.n_step) {
            return Err(ConfigError::learner(
                "n_step",
                self.n_step,
                format!("must be in 1..={} (1: the paper's one-step target)", Self::MAX_N_STEP),
            ));
        }
        if self.batch_size < 2 {
            return Err(ConfigError::learner("batch_size", self.batch_size, "must be at least 2"));
        }
        if !(1..=1_000_000).contains(&self.train_interval) {
            return Err(ConfigError::learner(
                "train_interval",
                self.train_interval,
                "must be in 1..=1000000 env steps",
            ));
        }
        if self.rate_slack == 0 {
            return Err(ConfigError::learner("rate_slack", self.rate_slack, "must be at least 1 update"));
        }
        if self.warmup < self.batch_size as u64 {
            return Err(ConfigError::learner(
                "warmup",
                self.warmup,
                format!("must be at least batch_size ({})", self.batch_size),
            ));
        }
        Ok(())
    }
}
