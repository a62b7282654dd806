//! DSAC settings (Table IV): the `[dsac]` section of every run's config file.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::error::{ConfigError, Result};

/// Distributional Soft Actor-Critic hyper-parameters. Defaults are the paper's Table IV.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DsacConfig {
    /// Discount factor γ. Range: [0, 1).
    pub gamma: f64,
    /// Target entropy for the automatic temperature (−3 = −|A|). Range: [−100, 100].
    pub target_entropy: f64,
    /// Initial temperature α₀. Range: (0, 100].
    pub initial_alpha: f64,
    /// Learning rate of the temperature (optimised as log α). Range: (0, 1].
    pub lr_alpha: f64,
    /// Learning rate of the policy network. Range: (0, 1].
    pub lr_policy: f64,
    /// Learning rate of the quantile network. Range: (0, 1].
    pub lr_quantile: f64,
    /// Learning rate of the fraction-proposal network (FQF's value 2.5e-9). Range: (0, 1].
    pub lr_fraction: f64,
    /// Polyak coefficient τ of the target quantile network. Range: (0, 1].
    pub soft_update: f64,
    /// κ of the quantile Huber loss. Range: (0, 100].
    pub huber_kappa: f64,
    /// Weight of the fraction-proposal entropy bonus (FQF's default 0). Range: [0, 100].
    pub fraction_entropy: f64,
    /// Clip each network's global gradient norm to this value (`null`/absent: no clipping,
    /// as in the paper). Range: (0, 1e6].
    pub max_grad_norm: Option<f64>,
    /// Samples per update. Range: 2 ..= 65536.
    pub batch_size: usize,
    /// Env steps stored before the first update. Range: `batch_size` ..=
    /// `replay.nonterminal_capacity`.
    pub warmup: u64,
    /// Env steps per update (the replay ratio). Range: 1 ..= 1000000.
    pub train_interval: u64,
    /// Updates the learner may fall behind before actors are held back. Range: 1 ..= 1000000.
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
    /// Pixel observations only. Range: 0 ..= `nets.image_size` / 4 (0 for state observations).
    pub random_shift: usize,
    /// Weight λ of the state-prediction auxiliary loss (0: off, as the paper). When
    /// positive, a linear head on the critic encoder's features regresses the
    /// simulator's state vector of o_t (`nets.state_dim` floats: goal in the body
    /// frame, heading, head yaw, map rewards around the agent — the state preset's
    /// observation), and λ·E[‖ŝ − s‖²] is added to the critic loss so its gradient
    /// shapes the encoder — the "game features" auxiliary of Lample & Chaplot (2017).
    /// The state is privileged: it is a training target only and never reaches the
    /// policy's input, which stays pixels. Range: [0, 100].
    pub state_aux_weight: f64,
    /// n of the n-step TD target (1: the paper's one-step target). With n > 1 the
    /// critic regresses on Σ_{k<n} γᵏ r_{t+k} + γⁿ (Z(s_{t+n}, a′) − α log π(a′|s_{t+n})),
    /// cut at the goal (no bootstrap past it), as Rainbow and DrQ-v2 (n = 3) do. Value
    /// information then travels n steps per backup instead of one; the price is a
    /// target that mixes in up to n − 1 steps of the older, behaviour policy's actions
    /// (no off-policy correction, as in those methods). Each sampled transition
    /// carries N_h + n frames; the terminal pool keeps the n transitions before every
    /// goal (so |B_T| grows n-fold, as Algorithm 2 counts done transitions). Range: 1 ..= 64.
    pub n_step: usize,
    /// Weight λ_c of the temporal contrastive auxiliary loss (0: off, as the paper). A
    /// self-supervised loss that needs nothing privileged: ATC's augmented temporal
    /// contrast (Stooke et al., 2021) on the two views the update already has — the
    /// online critic encoder's features of o_t (the anchor) and the features of
    /// o_{t+n} the TD target reads (the positive, computed for it anyway: the Polyak
    /// target encoder's, or the online one's with `target_encoder = "online"`). A
    /// linear map of the anchor and the positive are L2-normalised; the InfoNCE loss
    /// over the batch (each anchor's positive against the batch's other
    /// positives, temperature 0.1) is added as λ_c·ℓ_c to the critic loss, so its
    /// gradient teaches the encoder to tell states apart — what the pixel critic's
    /// features were measured to lack. The map steps with its own optimiser. Range: [0, 100].
    pub contrast_weight: f64,
    /// Start a new run's networks from the online networks and temperature of this
    /// checkpoint folder — a run's `checkpoints/learner`, or a results folder's copy of
    /// it — instead of a fresh initialisation: a warm start, e.g. from a run without
    /// traffic before training with it. The Polyak targets start as copies of the loaded
    /// critics; the optimisers, the auxiliary heads, the counters and the replay start
    /// fresh; the architecture (`[nets]`, `twin_critics`) must match the folder's. A
    /// relative path is read from where `pednav-run` starts. Ignored when a run resumes
    /// from its own checkpoint. Absent (the default): a fresh initialisation, as the paper.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub init_from: Option<PathBuf>,
    /// Which encoder reads o_{t+n} for the TD target (and for the contrastive loss's
    /// positives). `"polyak"` (the default, as the paper's DSAC): the target quantile
    /// net's own Polyak-averaged copy of the encoder, one more forward pass over the
    /// batch's frames per update. `"online"`: the online encoder's o_{t+n} features,
    /// detached — the one-pass encoding of each transition's N_h + n frames computes
    /// them anyway — with only the heads after it Polyak-averaged, as DrQ-v2 (Yarats et
    /// al., 2021) does; it saves that forward pass (by its FLOPs ≈ a quarter of the
    /// encoder's convolution work; 13–15 % of the CPU preset's update, measured). The
    /// target net keeps its encoder's weights (Polyak-averaged, unread), so checkpoints
    /// have one layout for both modes. Needs `nets.shared_encoder = true`.
    pub target_encoder: TargetEncoder,
}

/// Which encoder computes the TD target's features ([`DsacConfig::target_encoder`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TargetEncoder {
    /// The target quantile net's own Polyak-averaged encoder (the paper's DSAC).
    #[default]
    Polyak,
    /// The online (shared) encoder's detached features; the target heads stay Polyak.
    Online,
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
            init_from: None,
            target_encoder: TargetEncoder::Polyak,
        }
    }
}

impl DsacConfig {
    /// The env steps taken in by the time the learner may have done `updates` updates at
    /// this replay ratio (`warmup` + `train_interval` × (`updates` − 1); 0 before the
    /// first): how an actor reads the run's progress off the weights version (the
    /// learner's update count) it acts with.
    pub fn env_steps_at_update(&self, updates: u64) -> u64 {
        match updates {
            0 => 0,
            u => self.warmup.saturating_add(self.train_interval.saturating_mul(u - 1)),
        }
    }

    /// The largest `n_step` accepted (each sample carries N_h + n frames; beyond a few
    /// dozen steps γⁿ no longer bootstraps much anyway).
    pub const MAX_N_STEP: usize = 64;
    /// The largest `batch_size` accepted (a pixel batch holds N_h + n frames per sample).
    pub const MAX_BATCH_SIZE: usize = 1 << 16;

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

    /// Reject values outside each field's documented range, naming the field, the value
    /// and the range. Every float comparison is false for NaN, so NaN is refused too.
    pub fn validate(&self) -> Result<()> {
        let lr = |v: f64| v > 0.0 && v <= 1.0;
        let weight = |v: f64| (0.0..=100.0).contains(&v);
        let positive = |v: f64, max: f64| v > 0.0 && v <= max;
        for (field, v, ok, range) in [
            ("gamma", self.gamma, (0.0..1.0).contains(&self.gamma), "[0, 1)"),
            ("target_entropy", self.target_entropy, (-100.0..=100.0).contains(&self.target_entropy), "[-100, 100]"),
            ("initial_alpha", self.initial_alpha, positive(self.initial_alpha, 100.0), "(0, 100]"),
            ("lr_alpha", self.lr_alpha, lr(self.lr_alpha), "(0, 1] (a learning rate)"),
            ("lr_policy", self.lr_policy, lr(self.lr_policy), "(0, 1] (a learning rate)"),
            ("lr_quantile", self.lr_quantile, lr(self.lr_quantile), "(0, 1] (a learning rate)"),
            ("lr_fraction", self.lr_fraction, lr(self.lr_fraction), "(0, 1] (a learning rate)"),
            ("soft_update", self.soft_update, positive(self.soft_update, 1.0), "(0, 1]"),
            ("huber_kappa", self.huber_kappa, positive(self.huber_kappa, 100.0), "(0, 100]"),
            ("fraction_entropy", self.fraction_entropy, weight(self.fraction_entropy), "[0, 100] (0: off)"),
            ("state_aux_weight", self.state_aux_weight, weight(self.state_aux_weight), "[0, 100] (0: off)"),
            ("contrast_weight", self.contrast_weight, weight(self.contrast_weight), "[0, 100] (0: off)"),
        ] {
            if !ok {
                return Err(ConfigError::learner(field, v, format!("must be in {range}")));
            }
        }
        if let Some(m) = self.max_grad_norm
            && !positive(m, 1e6)
        {
            return Err(ConfigError::learner("max_grad_norm", m, "must be in (0, 1e6] (omit it to disable clipping)"));
        }
        for (field, value, min, max, what) in [
            ("n_step", self.n_step as u64, 1, Self::MAX_N_STEP as u64, " (1: the paper's one-step target)"),
            ("batch_size", self.batch_size as u64, 2, Self::MAX_BATCH_SIZE as u64, " samples"),
            ("train_interval", self.train_interval, 1, 1_000_000, " env steps"),
            ("rate_slack", self.rate_slack, 1, 1_000_000, " updates"),
        ] {
            if !(min..=max).contains(&value) {
                return Err(ConfigError::learner(field, value, format!("must be in {min}..={max}{what}")));
            }
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

    /// The rule across `[dsac]` and `[nets]`: `target_encoder = "online"` reads the
    /// shared encoder's features, so it needs `nets.shared_encoder = true` (the launcher's
    /// check and the learner both ask here).
    pub fn validate_with_encoder(&self, shared_encoder: bool) -> Result<()> {
        if self.target_encoder == TargetEncoder::Online && !shared_encoder {
            return Err(ConfigError::learner(
                "target_encoder",
                "\"online\"",
                "reads the shared encoder's features: needs nets.shared_encoder = true (or target_encoder = \"polyak\")",
            ));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each out-of-range value alone is refused naming its field; each boundary value
    /// alone is accepted.
    #[test]
    fn values_outside_the_documented_ranges_are_refused_naming_the_field() {
        let refused: [(&str, fn(&mut DsacConfig)); 22] = [
            ("gamma", |c| c.gamma = 1.0),
            ("gamma", |c| c.gamma = f64::NAN),
            ("target_entropy", |c| c.target_entropy = -1e15),
            ("initial_alpha", |c| c.initial_alpha = 0.0),
            ("lr_alpha", |c| c.lr_alpha = f64::NAN),
            ("lr_policy", |c| c.lr_policy = 0.0),
            ("lr_policy", |c| c.lr_policy = 1e15),
            ("lr_quantile", |c| c.lr_quantile = 0.0),
            ("lr_quantile", |c| c.lr_quantile = 1e15),
            ("lr_fraction", |c| c.lr_fraction = 0.0),
            ("lr_fraction", |c| c.lr_fraction = 1e15),
            ("soft_update", |c| c.soft_update = f64::NAN),
            ("huber_kappa", |c| c.huber_kappa = 1e15),
            ("fraction_entropy", |c| c.fraction_entropy = -1.0),
            ("state_aux_weight", |c| c.state_aux_weight = 1e15),
            ("contrast_weight", |c| c.contrast_weight = 1e15),
            ("contrast_weight", |c| c.contrast_weight = f64::NAN),
            ("max_grad_norm", |c| c.max_grad_norm = Some(0.0)),
            ("batch_size", |c| c.batch_size = 1 << 20),
            ("train_interval", |c| c.train_interval = 0),
            ("rate_slack", |c| c.rate_slack = u64::MAX),
            ("n_step", |c| c.n_step = 65),
        ];
        for (field, set) in refused {
            let mut cfg = DsacConfig::default();
            set(&mut cfg);
            let e = cfg.validate().expect_err(field);
            assert_eq!(e.field, field, "{e}");
            assert!(e.message.contains("must be in"), "{e}");
        }
        let accepted: [fn(&mut DsacConfig); 8] = [
            |c| c.gamma = 0.0,
            |c| c.lr_policy = 1.0,
            |c| c.lr_fraction = 2.5e-9,
            |c| c.contrast_weight = 100.0,
            |c| c.target_entropy = -100.0,
            |c| c.max_grad_norm = Some(1e6),
            |c| c.rate_slack = 1_000_000,
            |c| c.n_step = DsacConfig::MAX_N_STEP,
        ];
        for set in accepted {
            let mut cfg = DsacConfig::default();
            set(&mut cfg);
            cfg.validate().unwrap();
        }
    }
}
