//! Network settings (a section of every run's config file).

use serde::{Deserialize, Serialize};

use crate::error::{Result, config_error};

/// Dimension of the pedestrian's action (speed, turn rate, head yaw).
pub const ACTION_DIM: usize = 3;

/// How observations are encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EncoderKind {
    /// 3D temporal convolutions over the last N_h frames plus dilated 1-D
    /// convolutions over the past actions and rewards (the paper's 3D-TCN).
    Tcn,
    /// The N_h frames stacked as channels of 2D convolutions (the paper's baseline).
    FrameStack,
    /// A two-layer MLP over the simulator's state-debug observation.
    Mlp,
}

pub use crate::ops::conv::ConvPrecision;

/// Architecture of the policy, fraction-proposal and quantile networks.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetsConfig {
    /// Observation encoder: `tcn` (paper), `frame_stack` (baseline) or `mlp` (state observations).
    pub encoder: EncoderKind,
    /// Side of the square greyscale frames in pixels (84 in the paper; 42 in the CPU preset).
    /// Range: 21 ..= 1024 (`tcn`, `frame_stack`); 1 ..= 1024 (`mlp`, unused).
    pub image_size: usize,
    /// N_h: frames per observation (16 in the paper, 8 in the CPU preset, 4 for Non-ACL-FR-4).
    /// Range: 2 ..= 64 (`tcn`); 1 ..= 64 (`frame_stack`); exactly 1 with state observations.
    pub history: usize,
    /// Length of the state-debug observation (used by the `mlp` encoder only). Range: 1 ..= 4096.
    pub state_dim: usize,
    /// Width of the fully connected layer after the encoder (256 in the paper). Range: 1 ..= 8192.
    pub hidden: usize,
    /// Output width of each history branch (actions, rewards): 8 in the paper. Range: 1 ..= 1024.
    pub history_features: usize,
    /// N: quantile fractions proposed per state-action (Table IV: 32). Range: 2 ..= 1024.
    pub quantiles: usize,
    /// Intervals of the NDQFN fixed fraction grid on which monotone quantile values are
    /// produced (then linearly interpolated at the proposed fractions). Not in the
    /// paper; 32 matches N so every proposed fraction sees a distinct grid interval on average.
    /// Range: 1 ..= 1024.
    pub quantile_grid: usize,
    /// `false` (paper): policy, fraction-proposal and quantile networks each have their
    /// own encoder. `true`: one encoder, trained by the critic loss; the policy and
    /// fraction heads use its features detached (≈ 3× less encoder compute).
    pub shared_encoder: bool,
    /// Arithmetic of the encoders' convolutions: `f32` (default), `bf16` (mixed
    /// precision on CPUs with AVX-512 BF16; beyond the paper, see docs/performance.md)
    /// or `auto` (bf16 where the CPU has it, f32 elsewhere).
    pub conv_precision: ConvPrecision,
}

impl Default for NetsConfig {
    fn default() -> Self {
        NetsConfig {
            encoder: EncoderKind::Tcn,
            image_size: 84,
            history: 16,
            state_dim: 22,
            hidden: 256,
            history_features: 8,
            quantiles: 32,
            quantile_grid: 32,
            shared_encoder: false,
            conv_precision: ConvPrecision::F32,
        }
    }
}

impl NetsConfig {
    /// Whether networks built from `self` and `other` have the same parameters (every
    /// field but `conv_precision`, which changes the arithmetic, not the weights): a
    /// checkpoint trained with bf16 convolutions loads into f32 networks and back.
    pub fn same_architecture(&self, other: &NetsConfig) -> bool {
        let normalised = |c: &NetsConfig| NetsConfig { conv_precision: ConvPrecision::F32, ..c.clone() };
        normalised(self) == normalised(other)
    }

    /// Reject settings no network can be built from, naming the field.
    pub fn validate(&self) -> Result<()> {
        if self.encoder != EncoderKind::Mlp {
            if self.image_size < 21 {
                return Err(config_error(
                    "image_size",
                    self.image_size,
                    "must be at least 21 pixels (three strided stages)",
                ));
            }
            let min_history = if self.encoder == EncoderKind::Tcn { 2 } else { 1 };
            if self.history < min_history || self.history > 64 {
                return Err(config_error("history", self.history, format!("must be in {min_history}..=64")));
            }
        } else if self.state_dim == 0 {
            return Err(config_error("state_dim", self.state_dim, "must be positive"));
        }
        let needs_bf16 = self.encoder != EncoderKind::Mlp && self.conv_precision == ConvPrecision::Bf16;
        if needs_bf16 && !crate::ops::conv::bf16_available() {
            return Err(config_error(
                "conv_precision",
                self.conv_precision.name(),
                format!(
                    "needs AVX-512 BF16 on the `avx512` path (this CPU: AVX-512 BF16 {}, path `{}`); \
                     set it to \"f32\", or to \"auto\" (bf16 where the CPU has it)",
                    if crate::ops::conv::cpu_has_bf16() { "present" } else { "absent" },
                    crate::ops::Isa::active()
                ),
            ));
        }
        // Upper bounds far above any published setting (256 / 8 / 32 / 32): a larger
        // value is a typo, and `pednav-run check` builds the networks to estimate memory.
        for (field, value, min, max) in [
            ("image_size", self.image_size, 1, 1024),
            ("history", self.history, 1, 64),
            ("state_dim", self.state_dim, 1, 4096),
            ("hidden", self.hidden, 1, 8192),
            ("history_features", self.history_features, 1, 1024),
            ("quantiles", self.quantiles, 2, 1024),
            ("quantile_grid", self.quantile_grid, 1, 1024),
        ] {
            if !(min..=max).contains(&value) {
                return Err(config_error(field, value, format!("must be in {min}..={max}")));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The precision is not part of the architecture (checkpoints load across it),
    /// every other field is; asking for bf16 where it cannot run names the field.
    #[test]
    fn precision_is_not_architecture_and_bf16_is_refused_where_it_cannot_run() {
        let f32_cfg = NetsConfig::default();
        let bf16_cfg = NetsConfig { conv_precision: ConvPrecision::Bf16, ..f32_cfg.clone() };
        assert!(f32_cfg.same_architecture(&bf16_cfg));
        assert!(!f32_cfg.same_architecture(&NetsConfig { history: 8, ..bf16_cfg.clone() }));
        match bf16_cfg.validate() {
            Ok(()) => assert!(crate::ops::conv::bf16_available()),
            Err(e) => {
                assert!(!crate::ops::conv::bf16_available());
                let msg = e.to_string();
                assert!(msg.contains("conv_precision") && msg.contains("f32"), "{msg}");
            }
        }
        // The MLP encoder has no convolution: any precision is fine.
        let mlp = NetsConfig { encoder: EncoderKind::Mlp, ..bf16_cfg };
        assert!(mlp.validate().is_ok());
    }

    /// `auto` runs everywhere and becomes bf16 exactly where bf16 may be asked for.
    #[test]
    fn auto_precision_is_bf16_where_the_cpu_has_it_and_f32_elsewhere() {
        let auto = NetsConfig { conv_precision: ConvPrecision::Auto, ..NetsConfig::default() };
        assert!(auto.validate().is_ok());
        assert!(auto.same_architecture(&NetsConfig::default()));
        let expected = if crate::ops::conv::bf16_available() { ConvPrecision::Bf16 } else { ConvPrecision::F32 };
        assert_eq!(ConvPrecision::Auto.resolved(), expected);
        assert_eq!(ConvPrecision::F32.resolved(), ConvPrecision::F32);
        assert_eq!(ConvPrecision::Bf16.resolved(), ConvPrecision::Bf16);
    }

    /// Each out-of-range size alone is refused naming its field; each boundary alone is
    /// accepted.
    #[test]
    fn sizes_outside_the_documented_ranges_are_refused_naming_the_field() {
        let mlp = || NetsConfig { encoder: EncoderKind::Mlp, history: 1, ..NetsConfig::default() };
        let cases = [
            (NetsConfig { image_size: 20, ..NetsConfig::default() }, Some("image_size")),
            (NetsConfig { image_size: 1025, ..NetsConfig::default() }, Some("image_size")),
            (NetsConfig { history: 1, ..NetsConfig::default() }, Some("history")),
            (NetsConfig { history: 65, ..NetsConfig::default() }, Some("history")),
            (NetsConfig { history: 1 << 40, ..mlp() }, Some("history")),
            (NetsConfig { state_dim: 0, ..mlp() }, Some("state_dim")),
            (NetsConfig { hidden: 0, ..NetsConfig::default() }, Some("hidden")),
            (NetsConfig { hidden: 1 << 20, ..NetsConfig::default() }, Some("hidden")),
            (NetsConfig { quantiles: 1, ..NetsConfig::default() }, Some("quantiles")),
            (NetsConfig { quantile_grid: 0, ..NetsConfig::default() }, Some("quantile_grid")),
            (NetsConfig { history_features: 0, ..NetsConfig::default() }, Some("history_features")),
            (NetsConfig { image_size: 21, history: 64, ..NetsConfig::default() }, None),
            (NetsConfig { hidden: 8192, quantiles: 1024, ..mlp() }, None),
        ];
        for (cfg, refused) in cases {
            match (cfg.validate(), refused) {
                (Ok(()), None) => {}
                (Err(e), Some(field)) => assert!(e.to_string().contains(&format!("`{field}`")), "{e}"),
                (got, want) => panic!("{cfg:?}: got {got:?}, want {want:?}"),
            }
        }
    }
}
