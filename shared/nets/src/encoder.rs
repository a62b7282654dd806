//! Observation encoders: 3D-TCN, frame-stacking and MLP.
//!
//! Observation layout ([`Obs`]): frames (B, N_h, H, W) in [0, 1], oldest first; past
//! actions (B, N_h − 1, 3) and rewards (B, N_h − 1), where entry j belongs to the
//! step between frames j and j + 1. At an episode start the frames are padded with
//! the first frame and the actions and rewards with zeros (docs/design.md §4).
//!
//! 3D-TCN (paper Fig. 2, docs/design.md §4): spatial stages 84 → 42 → 21 → 7 (kernels 4/4/3,
//! strides 2/2/3, padding 1/1/0, 16/32/64 channels), each with temporal kernel 2 and
//! dilation 1, 2, 4, then one temporal convolution with dilation 1 over all remaining
//! steps (T: 16 → 15 → 13 → 9 → 1); the histories go through four 1-D temporal
//! convolutions of the same plan to 8 features each. When N_h is too short for a
//! dilation, [`temporal_plan`] shrinks it (documented there).

use candle_core::{D, Tensor};
use rand_chacha::ChaCha8Rng;

use crate::config::{ACTION_DIM, EncoderKind, NetsConfig};
use crate::error::Result;
use crate::layers::{Conv, Dense};
use crate::ops::ConvSpec;
use crate::params::ParamStore;

/// A batch of observations.
#[derive(Debug, Clone)]
pub enum Obs {
    /// Pixel observations with their action and reward histories.
    Pixels {
        /// (B, N_h, H, W), values in [0, 1].
        frames: Tensor,
        /// (B, N_h − 1, 3).
        actions: Tensor,
        /// (B, N_h − 1).
        rewards: Tensor,
    },
    /// State-debug observations (B, S).
    State(Tensor),
    /// Pixel frames already in the frame-stacking encoder's channel-last layout
    /// (B, 1, H, W, N_h), made once by [`Obs::stacked`] when several encoders read
    /// the same batch (the transpose was ≈ 12 % of a frame-stacking update when each
    /// encoder repeated it). Only the frame-stacking encoder accepts it.
    Stacked(Tensor),
}

impl Obs {
    /// Batch size.
    pub fn batch(&self) -> usize {
        match self {
            Obs::Pixels { frames, .. } => frames.dims()[0],
            Obs::State(s) | Obs::Stacked(s) => s.dims()[0],
        }
    }

    /// The frames in the frame-stacking encoder's channel-last layout
    /// ([`Obs::Stacked`]); the histories are dropped (frame stacking does not read
    /// them). Anything but pixels is returned as it is.
    pub fn stacked(&self) -> Result<Obs> {
        Ok(match self {
            Obs::Pixels { frames, .. } => Obs::Stacked(crate::ops::frames_to_channels_last(frames)?),
            other => other.clone(),
        })
    }
}

/// A batch of transitions (o_t, o_{t+n}) with each transition's observations held
/// once: o_t and the bootstrap observation o_{t+n} are views ([`Transitions::obs`],
/// [`Transitions::next_obs`]) of one run of N_h + n consecutive frames, so they cannot
/// disagree, and the 3D-TCN encodes both in one pass over the frames
/// ([`Encoder::encode_transition`]). n is 1 for the paper's one-step TD target.
#[derive(Debug, Clone)]
pub enum Transitions {
    /// Pixel transitions.
    Pixels {
        /// (B, N_h + n, H, W) in [0, 1]: o_t is the first N_h frames, o_{t+n} the last N_h.
        frames: Tensor,
        /// (B, N_h + n − 1, 3): the actions between the frames; o_t's history is the
        /// first N_h − 1, o_{t+n}'s the last N_h − 1 (a_t is entry N_h − 1).
        actions: Tensor,
        /// (B, N_h + n − 1): the rewards between the frames, split like `actions`.
        rewards: Tensor,
        /// n ≥ 1: the steps from o_t to the bootstrap observation.
        n_step: usize,
    },
    /// State-vector transitions.
    State {
        /// o_t (B, S).
        obs: Tensor,
        /// o_{t+n} (B, S).
        next: Tensor,
    },
}

impl Transitions {
    /// Batch size.
    pub fn batch(&self) -> usize {
        match self {
            Transitions::Pixels { frames, .. } => frames.dims()[0],
            Transitions::State { obs, .. } => obs.dims()[0],
        }
    }

    /// o_t (a view, or for pixels narrowed views of the stored tensors).
    pub fn obs(&self) -> Result<Obs> {
        self.view(false)
    }

    /// o_{t+n}, the observation the TD target bootstraps from.
    pub fn next_obs(&self) -> Result<Obs> {
        self.view(true)
    }

    fn view(&self, next: bool) -> Result<Obs> {
        Ok(match self {
            Transitions::Pixels { frames, actions, rewards, n_step } => {
                let h = frames.dims()[1] - n_step;
                let offset = if next { *n_step } else { 0 };
                Obs::Pixels {
                    frames: frames.narrow(1, offset, h)?,
                    actions: actions.narrow(1, offset, h - 1)?,
                    rewards: rewards.narrow(1, offset, h - 1)?,
                }
            }
            Transitions::State { obs, next: n } => Obs::State(if next { n.clone() } else { obs.clone() }),
        })
    }
}

/// Spatial stages of the image encoders: (kernel, stride, padding, channels).
pub const SPATIAL_STAGES: [(usize, usize, usize, usize); 3] = [(4, 2, 1, 16), (4, 2, 1, 32), (3, 3, 0, 64)];

/// Temporal dilations of the 3D-TCN's dilated layers.
pub const DILATIONS: [usize; 3] = [1, 2, 4];

/// (kernel, dilation) of each temporal layer for a sequence of length `t`: the
/// dilated layers (kernel 2, dilations 1, 2, 4), then one layer with dilation 1 over
/// everything left. A dilation that would leave no step is reduced to the largest
/// that leaves one (and a layer on a single step has kernel 1), so N_h = 8 gives
/// 8 → 7 → 5 → 1 → 1 and N_h = 4 gives 4 → 3 → 1 → 1 → 1; N_h = 16 is the paper's
/// 16 → 15 → 13 → 9 → 1.
pub fn temporal_plan(t: usize) -> Vec<(usize, usize)> {
    let mut plan = Vec::with_capacity(DILATIONS.len() + 1);
    let mut len = t;
    for d in DILATIONS {
        if len > d {
            plan.push((2, d));
            len -= d;
        } else if len > 1 {
            plan.push((2, len - 1));
            len = 1;
        } else {
            plan.push((1, 1));
        }
    }
    plan.push((len, 1));
    plan
}

/// Spatial output side after the three stages.
pub fn spatial_out(image_size: usize) -> usize {
    SPATIAL_STAGES.iter().fold(image_size, |s, &(k, st, p, _)| (s + 2 * p - k) / st + 1)
}

/// Width of the feature vector the encoder of `cfg` produces.
pub fn feature_dim(cfg: &NetsConfig) -> usize {
    let side = spatial_out(cfg.image_size);
    match cfg.encoder {
        EncoderKind::Tcn => 64 * side * side + 2 * cfg.history_features,
        EncoderKind::FrameStack => 64 * side * side,
        EncoderKind::Mlp => cfg.hidden,
    }
}

/// The 3D-TCN encoder.
#[derive(Clone)]
pub struct TcnEncoder {
    /// Frame layers: three spatio-temporal stages then the final temporal layer.
    pub(crate) frames: Vec<Conv>,
    pub(crate) actions: Vec<Conv>,
    pub(crate) rewards: Vec<Conv>,
    out_dim: usize,
}

impl TcnEncoder {
    fn new(store: &mut ParamStore, cfg: &NetsConfig, rng: &mut ChaCha8Rng) -> Result<TcnEncoder> {
        let plan = temporal_plan(cfg.history);
        let mut frames = Vec::new();
        let mut c_in = 1;
        for (i, (&(kt, dt), &(k, s, p, c))) in plan.iter().zip(&SPATIAL_STAGES).enumerate() {
            let spec = ConvSpec::spatiotemporal(kt, dt, k, s, p).with_precision(cfg.conv_precision);
            frames.push(Conv::new(store, &format!("enc.frames{i}"), spec, c_in, c, rng)?);
            c_in = c;
        }
        let (kt, _) = plan[DILATIONS.len()];
        let spec = ConvSpec::temporal(kt, 1).with_precision(cfg.conv_precision);
        frames.push(Conv::new(store, "enc.frames3", spec, c_in, c_in, rng)?);
        let hist_plan = temporal_plan(cfg.history - 1);
        let branch = |store: &mut ParamStore, name: &str, c0: usize, rng: &mut ChaCha8Rng| -> Result<Vec<Conv>> {
            let mut c_in = c0;
            let mut layers = Vec::new();
            for (i, &(kt, dt)) in hist_plan.iter().enumerate() {
                let layer = Conv::new(
                    store,
                    &format!("enc.{name}{i}"),
                    ConvSpec::temporal(kt, dt).with_precision(cfg.conv_precision),
                    c_in,
                    cfg.history_features,
                    rng,
                )?;
                layers.push(layer);
                c_in = cfg.history_features;
            }
            Ok(layers)
        };
        let actions = branch(store, "actions", ACTION_DIM, rng)?;
        let rewards = branch(store, "rewards", 1, rng)?;
        Ok(TcnEncoder { frames, actions, rewards, out_dim: feature_dim(cfg) })
    }

    /// Features of the frames alone: (B, 64·s·s).
    pub(crate) fn encode_frames(&self, frames: &Tensor) -> Result<Tensor> {
        let b = frames.dims()[0];
        Ok(self.encode_frames_steps(frames)?.reshape((b, ()))?)
    }

    /// The frame layers over (B, T, H, W): (B, T − N_h + 1, 64·s·s), one feature
    /// vector per window of N_h consecutive frames.
    fn encode_frames_steps(&self, frames: &Tensor) -> Result<Tensor> {
        let (b, t, h, w) = frames.dims4()?;
        // One op over the whole chain: its activations' gradients never pass through
        // candle's gradient store (`ops::conv_chain`).
        let links: Vec<_> = self.frames.iter().map(Conv::chain_link).collect();
        let x = crate::ops::conv_chain(&frames.reshape((b, t, h, w, 1))?, &links)?;
        let steps = x.dims()[1];
        Ok(x.reshape((b, steps, ()))?)
    }

    /// Features of the action and reward histories: (B, 2·history_features).
    pub(crate) fn encode_history(&self, actions: &Tensor, rewards: &Tensor) -> Result<Tensor> {
        let (b, t, _) = actions.dims3()?;
        let mut a = actions.reshape((b, t, 1, 1, ACTION_DIM))?;
        for layer in &self.actions {
            a = layer.forward(&a)?;
        }
        let mut r = rewards.reshape((b, t, 1, 1, 1))?;
        for layer in &self.rewards {
            r = layer.forward(&r)?;
        }
        Ok(Tensor::cat(&[a.reshape((b, ()))?, r.reshape((b, ()))?], D::Minus1)?)
    }
}

/// The frame-stacking encoder: N_h frames as channels of three 2D convolutions.
#[derive(Clone)]
pub struct FrameStackEncoder {
    convs: Vec<Conv>,
    out_dim: usize,
}

impl FrameStackEncoder {
    fn new(store: &mut ParamStore, cfg: &NetsConfig, rng: &mut ChaCha8Rng) -> Result<FrameStackEncoder> {
        let mut convs = Vec::new();
        let mut c_in = cfg.history;
        for (i, &(k, s, p, c)) in SPATIAL_STAGES.iter().enumerate() {
            let spec = ConvSpec::spatial(k, s, p).with_precision(cfg.conv_precision);
            convs.push(Conv::new(store, &format!("enc.conv{i}"), spec, c_in, c, rng)?);
            c_in = c;
        }
        Ok(FrameStackEncoder { convs, out_dim: feature_dim(cfg) })
    }
}

/// The MLP encoder for state observations: two ReLU layers of `hidden` units.
#[derive(Clone)]
pub struct MlpEncoder {
    layers: Vec<Dense>,
}

/// One of the three encoders.
#[derive(Clone)]
pub enum Encoder {
    /// 3D-TCN.
    Tcn(TcnEncoder),
    /// Frame stacking.
    FrameStack(FrameStackEncoder),
    /// MLP over state observations.
    Mlp(MlpEncoder),
}

impl Encoder {
    /// Build the encoder `cfg` asks for, registering its parameters in `store`.
    pub fn new(store: &mut ParamStore, cfg: &NetsConfig, rng: &mut ChaCha8Rng) -> Result<Encoder> {
        Ok(match cfg.encoder {
            EncoderKind::Tcn => Encoder::Tcn(TcnEncoder::new(store, cfg, rng)?),
            EncoderKind::FrameStack => Encoder::FrameStack(FrameStackEncoder::new(store, cfg, rng)?),
            EncoderKind::Mlp => Encoder::Mlp(MlpEncoder {
                layers: vec![
                    Dense::new(store, "enc.fc0", cfg.state_dim, cfg.hidden, rng)?,
                    Dense::new(store, "enc.fc1", cfg.hidden, cfg.hidden, rng)?,
                ],
            }),
        })
    }

    /// Width of the feature vector.
    pub fn out_dim(&self) -> usize {
        match self {
            Encoder::Tcn(e) => e.out_dim,
            Encoder::FrameStack(e) => e.out_dim,
            Encoder::Mlp(e) => e.layers[1].fan_out(),
        }
    }

    /// Features of o_t and o_{t+n} for a batch of transitions: (B, out_dim) each.
    ///
    /// A pixel transition's frames (B, N_h + n, H, W) are o_t's followed by the n
    /// newer ones (so o_t is the first N_h frames and o_{t+n} the last N_h, as the
    /// replay builds them). With the 3D-TCN the frame layers then run once over them
    /// instead of twice over N_h frames: with no temporal padding and temporal stride
    /// 1 every layer shortens the sequence by a fixed amount, so the last layer
    /// outputs n + 1 steps, the first o_t's features and the last o_{t+n}'s, each
    /// equal to its own [`Encoder::encode`] (the histories are encoded per
    /// observation). Other encoders encode the two observations separately.
    pub fn encode_transition(&self, t: &Transitions) -> Result<(Tensor, Tensor)> {
        match self.encode_window(t)? {
            Some(pair) => Ok(pair),
            None => Ok((self.encode(&t.obs()?)?, self.encode(&t.next_obs()?)?)),
        }
    }

    /// The one-pass encoding of [`Encoder::encode_transition`] where it applies (a
    /// 3D-TCN on pixel transitions), else `None`.
    pub(crate) fn encode_window(&self, t: &Transitions) -> Result<Option<(Tensor, Tensor)>> {
        let (Encoder::Tcn(e), Transitions::Pixels { frames, n_step, .. }) = (self, t) else { return Ok(None) };
        let (Obs::Pixels { actions, rewards, .. }, Obs::Pixels { actions: next_actions, rewards: next_rewards, .. }) =
            (t.obs()?, t.next_obs()?)
        else {
            unreachable!("pixel transitions give pixel observations")
        };
        let b = frames.dims()[0];
        let steps = e.encode_frames_steps(frames)?; // (B, n + 1, F): a window ending at each of t … t+n
        let frame_features = |i: usize| -> Result<Tensor> { Ok(steps.narrow(1, i, 1)?.reshape((b, ()))?) };
        Ok(Some((
            Tensor::cat(&[frame_features(0)?, e.encode_history(&actions, &rewards)?], D::Minus1)?,
            Tensor::cat(&[frame_features(*n_step)?, e.encode_history(&next_actions, &next_rewards)?], D::Minus1)?,
        )))
    }

    /// Features (B, out_dim) of a batch of observations.
    pub fn encode(&self, obs: &Obs) -> Result<Tensor> {
        match (self, obs) {
            (Encoder::Tcn(e), Obs::Pixels { frames, actions, rewards }) => {
                let f = e.encode_frames(frames)?;
                let h = e.encode_history(actions, rewards)?;
                Ok(Tensor::cat(&[f, h], D::Minus1)?)
            }
            (Encoder::FrameStack(e), Obs::Pixels { .. } | Obs::Stacked(_)) => {
                let b = obs.batch();
                let mut x = match obs {
                    Obs::Stacked(x) => x.clone(),
                    Obs::Pixels { frames, .. } => crate::ops::frames_to_channels_last(frames)?,
                    Obs::State(_) => unreachable!("matched pixels"),
                };
                for c in &e.convs {
                    x = c.forward(&x)?;
                }
                Ok(x.reshape((b, ()))?)
            }
            (Encoder::Mlp(e), Obs::State(s)) => {
                let mut x = s.clone();
                for l in &e.layers {
                    x = l.forward(&x)?.relu()?;
                }
                Ok(x)
            }
            _ => {
                Err(candle_core::Error::Msg("observation kind does not match the encoder (pixels vs state)".into())
                    .into())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temporal_plans_end_at_one_step() {
        assert_eq!(temporal_plan(16), vec![(2, 1), (2, 2), (2, 4), (9, 1)]);
        assert_eq!(temporal_plan(15), vec![(2, 1), (2, 2), (2, 4), (8, 1)]);
        assert_eq!(temporal_plan(8), vec![(2, 1), (2, 2), (2, 4), (1, 1)]);
        assert_eq!(temporal_plan(7), vec![(2, 1), (2, 2), (2, 3), (1, 1)]);
        assert_eq!(temporal_plan(4), vec![(2, 1), (2, 2), (1, 1), (1, 1)]);
        assert_eq!(temporal_plan(1), vec![(1, 1), (1, 1), (1, 1), (1, 1)]);
        assert_eq!(spatial_out(84), 7);
        assert_eq!(spatial_out(42), 3);
    }
}
