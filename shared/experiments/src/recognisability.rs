//! Which corner from one frame: a small CNN trained to name the intersection's
//! quadrant ([`pednav_sim::recognisability::quadrant`]) from a single greyscale
//! frame, tested on held-out poses. With [`pednav_sim::recognisability::aliasing`]
//! it measures how well a scene lets a pedestrian know where it stands.
//!
//! The network is the frame-stacking encoder of `pednav-nets` with one frame (the
//! spatial stages every pixel policy of pednav has) under a 64-unit ReLU layer and
//! four logits, trained with AdamW on the softmax cross-entropy. Every weight and
//! every minibatch order comes from the seed.
//!
//! Invariant: the test poses never reach the optimiser; the reported accuracy is
//! measured once, after the last epoch.

use candle_core::{DType, Device, Tensor};
use pednav_nets::layers::Dense;
use pednav_nets::{AdamW, AdamWConfig, EncoderKind, NetsConfig, Obs, ParamStore};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::error::Result;

/// Training settings of the corner classifier.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassifierConfig {
    /// Passes over the training frames.
    pub epochs: usize,
    /// Frames per minibatch.
    pub batch: usize,
    /// AdamW learning rate.
    pub lr: f64,
    /// Seed of the weights and the minibatch order.
    pub seed: u64,
}

impl Default for ClassifierConfig {
    fn default() -> Self {
        ClassifierConfig { epochs: 20, batch: 64, lr: 1e-3, seed: 0 }
    }
}

/// Labelled frames: `size × size` greyscale, quadrant labels 0–3.
#[derive(Debug, Clone, Copy)]
pub struct Frames<'a> {
    /// One `size²` frame per example.
    pub frames: &'a [Vec<u8>],
    /// One quadrant per frame.
    pub labels: &'a [usize],
}

/// What the classifier reached.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ClassifierReport {
    /// Training frames.
    pub train_frames: usize,
    /// Held-out test frames.
    pub test_frames: usize,
    /// Accuracy on the training frames after the last epoch.
    pub train_accuracy: f64,
    /// Accuracy on the held-out frames (chance: 0.25).
    pub test_accuracy: f64,
    /// Held-out accuracy per true quadrant.
    pub test_accuracy_by_quadrant: [f64; 4],
    /// Held-out confusion counts, `[true][predicted]`.
    pub confusion: [[usize; 4]; 4],
    /// Mean training loss of each epoch.
    pub epoch_loss: Vec<f64>,
    /// The predicted quadrant of every held-out frame, in order.
    pub test_predictions: Vec<usize>,
}

struct Classifier {
    store: ParamStore,
    encoder: pednav_nets::Encoder,
    hidden: Dense,
    out: Dense,
}

impl Classifier {
    fn new(size: usize, seed: u64) -> Result<Classifier> {
        let cfg =
            NetsConfig { encoder: EncoderKind::FrameStack, image_size: size, history: 1, ..NetsConfig::default() };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut store = ParamStore::new("corner", &Device::Cpu);
        let encoder = pednav_nets::Encoder::new(&mut store, &cfg, &mut rng)?;
        let hidden = Dense::new(&mut store, "fc", encoder.out_dim(), 64, &mut rng)?;
        let out = Dense::new(&mut store, "logits", 64, 4, &mut rng)?;
        Ok(Classifier { store, encoder, hidden, out })
    }

    fn logits(&self, frames: &Tensor) -> Result<Tensor> {
        let b = frames.dims()[0];
        let obs = Obs::Pixels {
            frames: frames.clone(),
            actions: Tensor::zeros((b, 0, 3), DType::F32, &Device::Cpu)?,
            rewards: Tensor::zeros((b, 0), DType::F32, &Device::Cpu)?,
        };
        let f = self.encoder.encode(&obs)?;
        Ok(self.out.forward(&self.hidden.forward(&f)?.relu()?)?)
    }

    fn predict(&self, data: Frames<'_>, size: usize) -> Result<Vec<usize>> {
        let mut out = Vec::with_capacity(data.frames.len());
        let idx: Vec<usize> = (0..data.frames.len()).collect();
        for chunk in idx.chunks(256) {
            let logits = self.logits(&batch_tensor(data.frames, chunk, size)?)?;
            out.extend(logits.argmax(1)?.to_vec1::<u32>()?.into_iter().map(|k| k as usize));
        }
        Ok(out)
    }
}

fn batch_tensor(frames: &[Vec<u8>], idx: &[usize], size: usize) -> Result<Tensor> {
    let mut v = Vec::with_capacity(idx.len() * size * size);
    for &i in idx {
        v.extend(frames[i].iter().map(|&p| p as f32 / 255.0));
    }
    Ok(Tensor::from_vec(v, (idx.len(), 1, size, size), &Device::Cpu)?)
}

/// Mean softmax cross-entropy of `logits` (B, 4) against `labels` (B).
fn cross_entropy(logits: &Tensor, labels: &Tensor) -> Result<Tensor> {
    let picked = logits.gather(&labels.unsqueeze(1)?, 1)?.squeeze(1)?;
    Ok((logits.log_sum_exp(1)? - picked)?.mean_all()?)
}

fn accuracy(pred: &[usize], labels: &[usize]) -> f64 {
    pred.iter().zip(labels).filter(|(p, l)| p == l).count() as f64 / labels.len().max(1) as f64
}

/// Train the corner classifier on `train` and report it on `test`; frames are `size²`.
/// `progress` is called after every epoch with (epoch, mean loss).
pub fn train_and_test(
    train: Frames<'_>,
    test: Frames<'_>,
    size: usize,
    cfg: ClassifierConfig,
    mut progress: impl FnMut(usize, f64),
) -> Result<ClassifierReport> {
    assert_eq!(train.frames.len(), train.labels.len(), "one label per training frame");
    assert_eq!(test.frames.len(), test.labels.len(), "one label per test frame");
    let net = Classifier::new(size, cfg.seed)?;
    let mut opt = AdamW::new(&net.store, AdamWConfig::with_lr(cfg.lr))?;
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x00c0_ffee);
    let mut order: Vec<usize> = (0..train.frames.len()).collect();
    let mut epoch_loss = Vec::with_capacity(cfg.epochs);
    for epoch in 0..cfg.epochs {
        order.shuffle(&mut rng);
        let (mut sum, mut n) = (0.0, 0usize);
        for chunk in order.chunks(cfg.batch.max(1)) {
            let x = batch_tensor(train.frames, chunk, size)?;
            let y: Vec<u32> = chunk.iter().map(|&i| train.labels[i] as u32).collect();
            let y = Tensor::from_vec(y, chunk.len(), &Device::Cpu)?;
            let loss = cross_entropy(&net.logits(&x)?, &y)?;
            opt.step(&loss.backward()?)?;
            sum += loss.to_scalar::<f32>()? as f64 * chunk.len() as f64;
            n += chunk.len();
        }
        let mean = sum / n.max(1) as f64;
        epoch_loss.push(mean);
        progress(epoch + 1, mean);
    }
    let train_pred = net.predict(train, size)?;
    let test_pred = net.predict(test, size)?;
    let mut confusion = [[0usize; 4]; 4];
    for (&p, &l) in test_pred.iter().zip(test.labels) {
        confusion[l][p] += 1;
    }
    let by_quadrant = std::array::from_fn(|q| {
        let row = confusion[q];
        row[q] as f64 / row.iter().sum::<usize>().max(1) as f64
    });
    Ok(ClassifierReport {
        train_frames: train.frames.len(),
        test_frames: test.frames.len(),
        train_accuracy: accuracy(&train_pred, train.labels),
        test_accuracy: accuracy(&test_pred, test.labels),
        test_accuracy_by_quadrant: by_quadrant,
        confusion,
        epoch_loss,
        test_predictions: test_pred,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames whose quadrant is written in their brightness are learned; frames
    /// that carry no label information stay near chance on held-out data.
    #[test]
    fn the_classifier_learns_a_visible_label_and_not_an_invisible_one() {
        let size = 42;
        let make = |n: usize, seed: u64, visible: bool| -> (Vec<Vec<u8>>, Vec<usize>) {
            use rand::Rng;
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            (0..n)
                .map(|_| {
                    let q = rng.random_range(0..4usize);
                    let frame = (0..size * size)
                        .map(|_| {
                            let noise: f32 = rng.random_range(0.0..120.0);
                            (noise + if visible { 40.0 * q as f32 } else { 60.0 }) as u8
                        })
                        .collect();
                    (frame, q)
                })
                .unzip()
        };
        let cfg = ClassifierConfig { epochs: 6, ..ClassifierConfig::default() };
        for (visible, check) in [(true, 0.9..=1.0), (false, 0.0..=0.45)] {
            let (tf, tl) = make(400, 1, visible);
            let (hf, hl) = make(200, 2, visible);
            let r = train_and_test(
                Frames { frames: &tf, labels: &tl },
                Frames { frames: &hf, labels: &hl },
                size,
                cfg,
                |_, _| {},
            )
            .unwrap();
            assert!(check.contains(&r.test_accuracy), "visible {visible}: {r:?}");
        }
    }
}
