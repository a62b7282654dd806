//! Streaming policy inference for actors: per-environment observation windows and,
//! for the 3D-TCN, a cache of every temporal layer's per-step outputs, so one policy
//! step convolves one new frame per layer instead of the whole window.
//!
//! Why this is exact: with no temporal padding and temporal stride 1, the output of
//! temporal layer l at window position p depends only on its input at positions
//! p − d_l·j (j < k_l). Those positions are the same absolute time steps whether the
//! window is recomputed or slid by one, so the new slice of each layer is the
//! convolution (dilation 1) of the gathered taps of the layer below, and the final
//! layer reads the last k_final slices of the third. The action/reward branch is
//! tiny and recomputed every step.
//!
//! Invariants: after any sequence of `reset`/`push` calls, [`PolicyStream::features`]
//! equals `encoder.encode(window)` of [`PolicyStream::observation`] (up to float
//! rounding; tested over 40-step episodes with a reset in the middle); new weights
//! make every cache stale, so callers must call [`PolicyStream::invalidate`] after
//! loading weights (the next step recomputes the full windows once).
//! Frame-stacking and MLP encoders have no per-layer cache: their step is the full
//! (already small) forward.

use std::collections::VecDeque;

use candle_core::{D, Device, IndexOp, Tensor};

use crate::config::{ACTION_DIM, EncoderKind, NetsConfig};
use crate::encoder::{Encoder, Obs, TcnEncoder};
use crate::error::Result;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Pending {
    /// The caches hold the current window.
    Ready,
    /// One frame was pushed since the caches were last updated.
    OneStep,
    /// The caches must be rebuilt from the window (reset, several pushes, new weights).
    Full,
}

struct EnvWindow {
    /// Last N_h frames, each (1, 1, H, W, 1) in [0, 1].
    frames: VecDeque<Tensor>,
    actions: VecDeque<[f32; ACTION_DIM]>,
    rewards: VecDeque<f32>,
    /// Per 3D-TCN layer 0..3: the last outputs the next layer needs, each (1, 1, h, w, c).
    layers: Vec<VecDeque<Tensor>>,
    pending: Pending,
    started: bool,
}

/// Observation windows and inference caches of M environments.
pub struct PolicyStream {
    cfg: NetsConfig,
    envs: Vec<EnvWindow>,
    device: Device,
}

impl PolicyStream {
    /// Windows for `envs` environments; every env must be `reset` before use.
    pub fn new(cfg: &NetsConfig, envs: usize, device: &Device) -> PolicyStream {
        let window = || EnvWindow {
            frames: VecDeque::new(),
            actions: VecDeque::new(),
            rewards: VecDeque::new(),
            layers: vec![VecDeque::new(); 3],
            pending: Pending::Full,
            started: false,
        };
        PolicyStream { cfg: cfg.clone(), envs: (0..envs).map(|_| window()).collect(), device: device.clone() }
    }

    fn frame_tensor(&self, frame: &[u8]) -> Result<Tensor> {
        let s = self.cfg.image_size;
        assert_eq!(frame.len(), s * s, "frame must be {s}×{s} greyscale");
        let data: Vec<f32> = frame.iter().map(|&p| p as f32 / 255.0).collect();
        Ok(Tensor::from_vec(data, (1, 1, s, s, 1), &self.device)?)
    }

    /// Start an episode in `env` with its first frame: the window is the first frame
    /// N_h times, with zero actions and rewards (docs/design.md §4).
    pub fn reset(&mut self, env: usize, frame: &[u8]) -> Result<()> {
        let f = self.frame_tensor(frame)?;
        let n = self.cfg.history;
        let w = &mut self.envs[env];
        w.frames = std::iter::repeat_n(f, n).collect();
        w.actions = std::iter::repeat_n([0.0; ACTION_DIM], n.saturating_sub(1)).collect();
        w.rewards = std::iter::repeat_n(0.0, n.saturating_sub(1)).collect();
        w.pending = Pending::Full;
        w.started = true;
        Ok(())
    }

    /// `env` took `action`, received `reward` and now sees `frame`.
    pub fn push(&mut self, env: usize, action: [f32; ACTION_DIM], reward: f32, frame: &[u8]) -> Result<()> {
        let f = self.frame_tensor(frame)?;
        let n = self.cfg.history;
        let w = &mut self.envs[env];
        assert!(w.started, "push before reset in env {env}");
        w.frames.push_back(f);
        if w.frames.len() > n {
            w.frames.pop_front();
        }
        if n > 1 {
            w.actions.push_back(action);
            w.rewards.push_back(reward);
            if w.actions.len() > n - 1 {
                w.actions.pop_front();
                w.rewards.pop_front();
            }
        }
        w.pending = if w.pending == Pending::Ready { Pending::OneStep } else { Pending::Full };
        Ok(())
    }

    /// New weights were loaded: every cache must be rebuilt.
    pub fn invalidate(&mut self) {
        for w in &mut self.envs {
            w.pending = Pending::Full;
        }
    }

    /// The current observation windows of `envs` as a batch (oldest frame first).
    pub fn observation(&self, envs: &[usize]) -> Result<Obs> {
        let n = self.cfg.history;
        let s = self.cfg.image_size;
        let mut frames = Vec::with_capacity(envs.len() * n);
        for &e in envs {
            let w = &self.envs[e];
            assert!(w.started, "observation of env {e} before reset");
            frames.extend(w.frames.iter().cloned());
        }
        let (actions, rewards) = self.histories(envs)?;
        Ok(Obs::Pixels { frames: Tensor::cat(&frames, 0)?.reshape((envs.len(), n, s, s))?, actions, rewards })
    }

    /// Past actions (len, N_h − 1, 3) and rewards (len, N_h − 1) of `envs`.
    fn histories(&self, envs: &[usize]) -> Result<(Tensor, Tensor)> {
        let n = self.cfg.history;
        let b = envs.len();
        let actions: Vec<f32> = envs.iter().flat_map(|&e| self.envs[e].actions.iter().flatten().copied()).collect();
        let rewards: Vec<f32> = envs.iter().flat_map(|&e| self.envs[e].rewards.iter().copied()).collect();
        Ok((
            Tensor::from_vec(actions, (b, n - 1, ACTION_DIM), &self.device)?,
            Tensor::from_vec(rewards, (b, n - 1), &self.device)?,
        ))
    }

    /// Encoder features (len, F) of the current windows of `envs`, updating caches.
    pub fn features(&mut self, encoder: &Encoder, envs: &[usize]) -> Result<Tensor> {
        match encoder {
            Encoder::Tcn(tcn) if self.cfg.encoder == EncoderKind::Tcn => self.tcn_features(tcn, envs),
            _ => encoder.encode(&self.observation(envs)?),
        }
    }

    fn tcn_features(&mut self, tcn: &TcnEncoder, envs: &[usize]) -> Result<Tensor> {
        let full: Vec<usize> = envs.iter().copied().filter(|&e| self.envs[e].pending == Pending::Full).collect();
        let step: Vec<usize> = envs.iter().copied().filter(|&e| self.envs[e].pending == Pending::OneStep).collect();
        if !full.is_empty() {
            self.rebuild(tcn, &full)?;
        }
        if !step.is_empty() {
            self.advance(tcn, &step)?;
        }
        // Final temporal layer over the cached outputs of the third layer.
        let last = &tcn.frames[3];
        let kt = last.spec().kernel[0];
        let mut taps = Vec::with_capacity(envs.len() * kt);
        for &e in envs {
            let cache = &self.envs[e].layers[2];
            taps.extend(cache.iter().skip(cache.len() - kt).cloned());
        }
        let x = Tensor::cat(&taps, 1)?;
        let (_, _, h, w, c) = x.dims5()?;
        let x = x.reshape((envs.len(), kt, h, w, c))?;
        let f = last.forward(&x)?.reshape((envs.len(), ()))?;
        let (actions, rewards) = self.histories(envs)?;
        let hist = tcn.encode_history(&actions, &rewards)?;
        Ok(Tensor::cat(&[f, hist], D::Minus1)?)
    }

    /// How many outputs of layer `l` (0..3) layer `l + 1` reads.
    fn keep(tcn: &TcnEncoder, l: usize) -> usize {
        let spec = tcn.frames[l + 1].spec();
        spec.dilation_t * (spec.kernel[0] - 1) + 1
    }

    /// Recompute the three cached layers over the whole window.
    fn rebuild(&mut self, tcn: &TcnEncoder, envs: &[usize]) -> Result<()> {
        let Obs::Pixels { frames, .. } = self.observation(envs)? else { unreachable!() };
        let (b, t, h, w) = frames.dims4()?;
        let mut x = frames.reshape((b, t, h, w, 1))?;
        for l in 0..3 {
            x = tcn.frames[l].forward(&x)?;
            let keep = Self::keep(tcn, l);
            let len = x.dims()[1];
            for (i, &e) in envs.iter().enumerate() {
                let cache = &mut self.envs[e].layers[l];
                cache.clear();
                for p in len - keep..len {
                    cache.push_back(x.i((i..i + 1, p..p + 1))?);
                }
            }
        }
        for &e in envs {
            self.envs[e].pending = Pending::Ready;
        }
        Ok(())
    }

    /// Compute one new slice per cached layer from the gathered taps of the layer below.
    fn advance(&mut self, tcn: &TcnEncoder, envs: &[usize]) -> Result<()> {
        for l in 0..3 {
            let spec = tcn.frames[l].spec();
            let (kt, d) = (spec.kernel[0], spec.dilation_t);
            let mut taps = Vec::with_capacity(envs.len() * kt);
            for &e in envs {
                let w = &self.envs[e];
                let below: &VecDeque<Tensor> = if l == 0 { &w.frames } else { &w.layers[l - 1] };
                let newest = below.len() - 1;
                for j in (0..kt).rev() {
                    taps.push(below[newest - j * d].clone());
                }
            }
            let x = Tensor::cat(&taps, 1)?;
            let (_, _, h, w, c) = x.dims5()?;
            let y = tcn.frames[l].forward_with_dilation(&x.reshape((envs.len(), kt, h, w, c))?, 1)?;
            let keep = Self::keep(tcn, l);
            for (i, &e) in envs.iter().enumerate() {
                let cache = &mut self.envs[e].layers[l];
                cache.push_back(y.i(i..i + 1)?);
                while cache.len() > keep {
                    cache.pop_front();
                }
            }
        }
        for &e in envs {
            self.envs[e].pending = Pending::Ready;
        }
        Ok(())
    }
}
