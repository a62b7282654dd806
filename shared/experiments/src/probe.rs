//! A probe: a small CNN trained to name a label from one greyscale frame or a short
//! history of frames, tested on held-out examples. It measures what a pixel policy
//! *could* read from its input: which corner of the intersection a frame shows
//! (`pednav-recognisability`, labels from [`pednav_sim::recognisability::quadrant`],
//! with [`pednav_sim::recognisability::aliasing`]), and at the kerb whether the
//! pedestrian signal shows WALK or a vehicle is about to cross the zebra
//! (`pednav-traffic-probe`, [`crate::traffic_probe`]).
//!
//! The network is one of `pednav-nets`' encoders — frame stacking with one frame (the
//! spatial stages every pixel policy of pednav has), or the policy's own encoder over
//! `history` frames — under a 64-unit ReLU layer and one logit per class, trained
//! with AdamW on the softmax cross-entropy. Every weight and every minibatch order
//! comes from the seed.
//!
//! Invariant: the test examples never reach the optimiser; the reported accuracy is
//! measured once, after the last epoch.

use candle_core::{DType, Device, Tensor};
use pednav_nets::layers::Dense;
use pednav_nets::{AdamW, AdamWConfig, EncoderKind, NetsConfig, Obs, ParamStore};
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::error::Result;

/// Training settings of a probe.
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
    /// Weigh each training example by `N / (classes · n_its_class)`, so that every
    /// class counts alike in the loss: a rare class (WALK is 16 % of a signal cycle)
    /// is then not given up for the majority's accuracy.
    pub balance_classes: bool,
}

impl Default for ClassifierConfig {
    fn default() -> Self {
        ClassifierConfig { epochs: 20, batch: 64, lr: 1e-3, seed: 0, balance_classes: false }
    }
}

/// What a probe looks at and names.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeShape {
    /// Frame side, pixels.
    pub size: usize,
    /// Frames per example, oldest first (1: a single frame).
    pub history: usize,
    /// The encoder under the classifier: [`EncoderKind::FrameStack`] for one frame,
    /// the policy's own for a history.
    pub encoder: EncoderKind,
    /// Number of classes (labels `0..classes`).
    pub classes: usize,
}

impl ProbeShape {
    /// One `size²` frame, `classes` labels, the frame-stacking encoder's spatial stages.
    pub fn single_frame(size: usize, classes: usize) -> ProbeShape {
        ProbeShape { size, history: 1, encoder: EncoderKind::FrameStack, classes }
    }
}

/// Labelled examples: each `history × size²` greyscale bytes (frames oldest first).
#[derive(Debug, Clone, Copy)]
pub struct Frames<'a> {
    /// One example per entry.
    pub frames: &'a [Vec<u8>],
    /// One label per example.
    pub labels: &'a [usize],
}

/// What a probe reached.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ClassifierReport {
    /// Training frames.
    pub train_frames: usize,
    /// Held-out test frames.
    pub test_frames: usize,
    /// Accuracy on the training frames after the last epoch.
    pub train_accuracy: f64,
    /// Accuracy on the held-out frames.
    pub test_accuracy: f64,
    /// Share of the held-out frames in their most common class: the accuracy of
    /// always naming it (chance for balanced classes).
    pub test_majority: f64,
    /// Mean of the per-class held-out accuracies (chance: 1 / classes).
    pub test_balanced_accuracy: f64,
    /// Held-out accuracy per true class.
    pub test_accuracy_by_class: Vec<f64>,
    /// Held-out confusion counts, `[true][predicted]`.
    pub confusion: Vec<Vec<usize>>,
    /// Mean training loss of each epoch.
    pub epoch_loss: Vec<f64>,
    /// The predicted class of every held-out example, in order.
    pub test_predictions: Vec<usize>,
}

struct Classifier {
    store: ParamStore,
    encoder: pednav_nets::Encoder,
    hidden: Dense,
    out: Dense,
}

impl Classifier {
    fn new(shape: ProbeShape, seed: u64) -> Result<Classifier> {
        let cfg = NetsConfig {
            encoder: shape.encoder,
            image_size: shape.size,
            history: shape.history,
            ..NetsConfig::default()
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut store = ParamStore::new("probe", &Device::Cpu);
        let encoder = pednav_nets::Encoder::new(&mut store, &cfg, &mut rng)?;
        let hidden = Dense::new(&mut store, "fc", encoder.out_dim(), 64, &mut rng)?;
        let out = Dense::new(&mut store, "logits", 64, shape.classes, &mut rng)?;
        Ok(Classifier { store, encoder, hidden, out })
    }

    /// Logits of a batch (B, history, size, size); the action and reward histories
    /// the policy's encoder also reads are zero (the probe sees pixels only).
    fn logits(&self, frames: &Tensor) -> Result<Tensor> {
        let (b, h) = (frames.dims()[0], frames.dims()[1]);
        let obs = Obs::Pixels {
            frames: frames.clone(),
            actions: Tensor::zeros((b, h - 1, 3), DType::F32, &Device::Cpu)?,
            rewards: Tensor::zeros((b, h - 1), DType::F32, &Device::Cpu)?,
        };
        let f = self.encoder.encode(&obs)?;
        Ok(self.out.forward(&self.hidden.forward(&f)?.relu()?)?)
    }

    fn predict(&self, data: Frames<'_>, shape: ProbeShape) -> Result<Vec<usize>> {
        let mut out = Vec::with_capacity(data.frames.len());
        let idx: Vec<usize> = (0..data.frames.len()).collect();
        for chunk in idx.chunks(256) {
            let logits = self.logits(&batch_tensor(data.frames, chunk, shape)?)?;
            out.extend(logits.argmax(1)?.to_vec1::<u32>()?.into_iter().map(|k| k as usize));
        }
        Ok(out)
    }
}

fn batch_tensor(frames: &[Vec<u8>], idx: &[usize], shape: ProbeShape) -> Result<Tensor> {
    let (size, h) = (shape.size, shape.history);
    let mut v = Vec::with_capacity(idx.len() * h * size * size);
    for &i in idx {
        v.extend(frames[i].iter().map(|&p| p as f32 / 255.0));
    }
    Ok(Tensor::from_vec(v, (idx.len(), h, size, size), &Device::Cpu)?)
}

/// Softmax cross-entropy of `logits` (B, C) against `labels` (B): the mean, or the
/// `weights`-weighted mean.
fn cross_entropy(logits: &Tensor, labels: &Tensor, weights: Option<&Tensor>) -> Result<Tensor> {
    let picked = logits.gather(&labels.unsqueeze(1)?, 1)?.squeeze(1)?;
    let each = (logits.log_sum_exp(1)? - picked)?;
    Ok(match weights {
        None => each.mean_all()?,
        Some(w) => ((each * w)?.sum_all()? / w.sum_all()?.to_scalar::<f32>()? as f64)?,
    })
}

/// Per-class weights `N / (classes · n_c)` of a label set (1 for an absent class).
fn class_weights(labels: &[usize], classes: usize) -> Vec<f32> {
    let mut counts = vec![0usize; classes];
    for &l in labels {
        counts[l] += 1;
    }
    counts.iter().map(|&n| if n == 0 { 1.0 } else { labels.len() as f32 / (classes * n) as f32 }).collect()
}

fn accuracy(pred: &[usize], labels: &[usize]) -> f64 {
    pred.iter().zip(labels).filter(|(p, l)| p == l).count() as f64 / labels.len().max(1) as f64
}

/// A probe's training progress on stderr: every epoch on a terminal (one line,
/// rewritten in place), every fifth and the last otherwise.
pub struct EpochProgress {
    name: String,
    epochs: usize,
    tty: bool,
}

impl EpochProgress {
    /// Progress of probe `name` over `epochs` epochs.
    pub fn new(name: &str, epochs: usize) -> EpochProgress {
        use std::io::IsTerminal;
        EpochProgress { name: name.to_string(), epochs, tty: std::io::stderr().is_terminal() }
    }

    /// Report an epoch's mean loss.
    pub fn epoch(&self, epoch: usize, loss: f64) {
        if self.tty {
            eprint!("\r    {} epoch {epoch}/{} loss {loss:.3}", self.name, self.epochs);
        } else if epoch == self.epochs || epoch % 5 == 0 {
            eprintln!("    {} epoch {epoch}/{} loss {loss:.3}", self.name, self.epochs);
        }
    }

    /// End the progress line (on a terminal).
    pub fn done(&self) {
        if self.tty {
            eprintln!();
        }
    }
}

/// Train a probe of `shape` on `train` and report it on `test`. `progress` is
/// called after every epoch with (epoch, mean loss).
pub fn train_and_test(
    train: Frames<'_>,
    test: Frames<'_>,
    shape: ProbeShape,
    cfg: ClassifierConfig,
    mut progress: impl FnMut(usize, f64),
) -> Result<ClassifierReport> {
    let bytes = shape.history * shape.size * shape.size;
    for (name, set) in [("training", train), ("test", test)] {
        assert_eq!(set.frames.len(), set.labels.len(), "one label per {name} example");
        assert!(set.frames.iter().all(|f| f.len() == bytes), "every {name} example has history × size² bytes");
        assert!(set.labels.iter().all(|&l| l < shape.classes), "every {name} label is below {}", shape.classes);
    }
    let net = Classifier::new(shape, cfg.seed)?;
    let mut opt = AdamW::new(&net.store, AdamWConfig::with_lr(cfg.lr))?;
    let mut rng = ChaCha8Rng::seed_from_u64(pednav_config::rng::probe_order_seed(cfg.seed));
    let mut order: Vec<usize> = (0..train.frames.len()).collect();
    let mut epoch_loss = Vec::with_capacity(cfg.epochs);
    let weights = class_weights(train.labels, shape.classes);
    for epoch in 0..cfg.epochs {
        order.shuffle(&mut rng);
        let (mut sum, mut n) = (0.0, 0usize);
        for chunk in order.chunks(cfg.batch.max(1)) {
            let x = batch_tensor(train.frames, chunk, shape)?;
            let y: Vec<u32> = chunk.iter().map(|&i| train.labels[i] as u32).collect();
            let w = cfg
                .balance_classes
                .then(|| {
                    let w: Vec<f32> = chunk.iter().map(|&i| weights[train.labels[i]]).collect();
                    Tensor::from_vec(w, chunk.len(), &Device::Cpu)
                })
                .transpose()?;
            let y = Tensor::from_vec(y, chunk.len(), &Device::Cpu)?;
            let loss = cross_entropy(&net.logits(&x)?, &y, w.as_ref())?;
            opt.step(&loss.backward()?)?;
            sum += loss.to_scalar::<f32>()? as f64 * chunk.len() as f64;
            n += chunk.len();
        }
        let mean = sum / n.max(1) as f64;
        epoch_loss.push(mean);
        progress(epoch + 1, mean);
    }
    let train_pred = net.predict(train, shape)?;
    let test_pred = net.predict(test, shape)?;
    let mut confusion = vec![vec![0usize; shape.classes]; shape.classes];
    for (&p, &l) in test_pred.iter().zip(test.labels) {
        confusion[l][p] += 1;
    }
    let by_class: Vec<f64> =
        (0..shape.classes).map(|c| confusion[c][c] as f64 / confusion[c].iter().sum::<usize>().max(1) as f64).collect();
    let present: Vec<f64> =
        (0..shape.classes).filter(|&c| confusion[c].iter().sum::<usize>() > 0).map(|c| by_class[c]).collect();
    let largest = confusion.iter().map(|row| row.iter().sum::<usize>()).max().unwrap_or(0);
    Ok(ClassifierReport {
        train_frames: train.frames.len(),
        test_frames: test.frames.len(),
        train_accuracy: accuracy(&train_pred, train.labels),
        test_accuracy: accuracy(&test_pred, test.labels),
        test_majority: largest as f64 / test.labels.len().max(1) as f64,
        test_balanced_accuracy: present.iter().sum::<f64>() / present.len().max(1) as f64,
        test_accuracy_by_class: by_class,
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
                ProbeShape::single_frame(size, 4),
                cfg,
                |_, _| {},
            )
            .unwrap();
            assert!(check.contains(&r.test_accuracy), "visible {visible}: {r:?}");
        }
    }

    /// The weighted loss against hand-computed values: labels (0, 0, 0, 1) weigh
    /// 4/6 and 4/2; logits (0, 0) give ln 2 for every example whatever the weights,
    /// logits (ln 3, 0) give ln(4/3) for class 0 and ln 4 for class 1.
    #[test]
    fn the_balanced_loss_matches_hand_computed_values() {
        let w = class_weights(&[0, 0, 0, 1], 2);
        assert!((w[0] - 2.0 / 3.0).abs() < 1e-6 && (w[1] - 2.0).abs() < 1e-6, "{w:?}");
        assert_eq!(class_weights(&[0, 0], 3), vec![1.0 / 3.0, 1.0, 1.0]);
        let y = Tensor::new(&[0u32, 0, 0, 1], &Device::Cpu).unwrap();
        let wt = Tensor::new(&[w[0], w[0], w[0], w[1]], &Device::Cpu).unwrap();
        let flat = Tensor::zeros((4, 2), DType::F32, &Device::Cpu).unwrap();
        let l = cross_entropy(&flat, &y, Some(&wt)).unwrap().to_scalar::<f32>().unwrap();
        assert!((l - 2f32.ln()).abs() < 1e-6, "{l}");
        let l3 = 3f32.ln();
        let logits = Tensor::new(&[[l3, 0.0], [l3, 0.0], [l3, 0.0], [l3, 0.0]], &Device::Cpu).unwrap();
        let (a, b) = ((4.0f32 / 3.0).ln(), 4f32.ln());
        let plain = cross_entropy(&logits, &y, None).unwrap().to_scalar::<f32>().unwrap();
        assert!((plain - (3.0 * a + b) / 4.0).abs() < 1e-5, "{plain}");
        let weighted = cross_entropy(&logits, &y, Some(&wt)).unwrap().to_scalar::<f32>().unwrap();
        let want = (3.0 * w[0] * a + w[1] * b) / (3.0 * w[0] + w[1]);
        assert!((weighted - want).abs() < 1e-5, "{weighted} vs {want}");
    }

    /// A label carried only by motion (a bright bar moving left or right across
    /// the frames, at a random place) is read by the policy's temporal encoder over
    /// the history, while one frame of the same examples stays near chance.
    #[test]
    fn a_history_probe_reads_motion_that_one_frame_cannot() {
        use rand::Rng;
        let (size, history) = (42usize, 4usize);
        let make = |n: usize, seed: u64| -> (Vec<Vec<u8>>, Vec<usize>) {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            (0..n)
                .map(|_| {
                    let right = rng.random_range(0..2usize);
                    let start = rng.random_range(8..size - 8) as i64;
                    let mut ex = Vec::with_capacity(history * size * size);
                    for t in 0..history as i64 {
                        let col = start + if right == 1 { t * 2 - 3 } else { 3 - t * 2 };
                        for _row in 0..size {
                            for c in 0..size as i64 {
                                let noise: u8 = rng.random_range(0..40);
                                ex.push(if (c - col).abs() <= 1 { 200 } else { 40 + noise });
                            }
                        }
                    }
                    (ex, right)
                })
                .unzip()
        };
        let (tf, tl) = make(600, 3);
        let (hf, hl) = make(200, 4);
        let cfg = ClassifierConfig { epochs: 8, ..ClassifierConfig::default() };
        let shape = ProbeShape { size, history, encoder: EncoderKind::Tcn, classes: 2 };
        let r = train_and_test(
            Frames { frames: &tf, labels: &tl },
            Frames { frames: &hf, labels: &hl },
            shape,
            cfg,
            |_, _| {},
        )
        .unwrap();
        assert!(r.test_accuracy >= 0.9, "history: {r:?}");
        let last =
            |f: &[Vec<u8>]| -> Vec<Vec<u8>> { f.iter().map(|e| e[(history - 1) * size * size..].to_vec()).collect() };
        let (tf1, hf1) = (last(&tf), last(&hf));
        let r1 = train_and_test(
            Frames { frames: &tf1, labels: &tl },
            Frames { frames: &hf1, labels: &hl },
            ProbeShape::single_frame(size, 2),
            cfg,
            |_, _| {},
        )
        .unwrap();
        assert!(r1.test_accuracy <= 0.65, "one frame: {r1:?}");
    }
}
