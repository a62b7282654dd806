//! The linear probe: ridge regression from encoder features to targets, on
//! standardised features, the ridge strength chosen per target on held-out
//! samples, the linear systems solved by Cholesky factorisation.
//!
//! Invariants: the standardisation, Gram matrix and target means are those of the
//! samples fitted (never of those scored); a strength too weak for a nearly
//! singular system is skipped, never fatal; the Gram matrix is formed in f64, so
//! correlated features do not lose positive definiteness to rounding.

use candle_core::{Device, Tensor};

use crate::error::{ExperimentError, Result};

/// Ridge strengths tried, as multiples of the number of fitted samples (the
/// features are standardised, so the Gram matrix / n is their correlation matrix).
pub const RIDGE_GRID: [f64; 6] = [1e-5, 1e-4, 1e-3, 1e-2, 1e-1, 1.0];

/// A fitted ridge regression on standardised features.
#[derive(Debug, Clone)]
pub struct RidgeProbe {
    mean: Vec<f64>,
    scale: Vec<f64>,
    /// (d, k), row-major.
    weights: Vec<f64>,
    intercept: Vec<f64>,
}

/// Row-major samples: `x` (n, d), `y` (n, k).
#[derive(Debug, Clone, Default)]
pub struct Samples {
    /// Features, n × d.
    pub x: Vec<f32>,
    /// Targets, n × k.
    pub y: Vec<f64>,
    /// d.
    pub d: usize,
    /// k.
    pub k: usize,
}

impl Samples {
    /// Empty samples of `d` features and `k` targets.
    pub fn new(d: usize, k: usize) -> Samples {
        Samples { x: Vec::new(), y: Vec::new(), d, k }
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.y.len() / self.k.max(1)
    }

    /// No samples.
    pub fn is_empty(&self) -> bool {
        self.y.is_empty()
    }

    /// Append one sample.
    pub fn push(&mut self, x: &[f32], y: &[f64]) {
        assert_eq!((x.len(), y.len()), (self.d, self.k), "sample width");
        self.x.extend_from_slice(x);
        self.y.extend_from_slice(y);
    }

    /// The samples of both.
    fn concat(&self, other: &Samples) -> Samples {
        Samples {
            x: [self.x.as_slice(), &other.x].concat(),
            y: [self.y.as_slice(), &other.y].concat(),
            d: self.d,
            k: self.k,
        }
    }
}

/// Solve A X = B for symmetric positive-definite A (d × d) and B (d × k), both
/// row-major, by Cholesky factorisation.
pub fn solve_spd(a: &[f64], b: &[f64], d: usize, k: usize) -> Result<Vec<f64>> {
    let mut l = vec![0.0; d * d];
    for i in 0..d {
        for j in 0..=i {
            let s = a[i * d + j] - (0..j).map(|m| l[i * d + m] * l[j * d + m]).sum::<f64>();
            if i == j {
                if s <= 0.0 || !s.is_finite() {
                    return Err(ExperimentError::Diagnosis(format!("ridge system not positive definite at row {i}")));
                }
                l[i * d + i] = s.sqrt();
            } else {
                l[i * d + j] = s / l[j * d + j];
            }
        }
    }
    let mut x = b.to_vec();
    for c in 0..k {
        for i in 0..d {
            let s = x[i * k + c] - (0..i).map(|m| l[i * d + m] * x[m * k + c]).sum::<f64>();
            x[i * k + c] = s / l[i * d + i];
        }
        for i in (0..d).rev() {
            let s = x[i * k + c] - (i + 1..d).map(|m| l[m * d + i] * x[m * k + c]).sum::<f64>();
            x[i * k + c] = s / l[i * d + i];
        }
    }
    Ok(x)
}

/// The standardisation of `train`'s features, and its Gram matrix ZᵀZ and ZᵀY
/// (Y centred) in the standardised coordinates.
struct Normal {
    mean: Vec<f64>,
    scale: Vec<f64>,
    y_mean: Vec<f64>,
}

impl Normal {
    fn of(s: &Samples) -> Normal {
        let n = s.len() as f64;
        let mut mean = vec![0.0; s.d];
        let mut sq = vec![0.0; s.d];
        for row in s.x.chunks(s.d) {
            for (j, &v) in row.iter().enumerate() {
                mean[j] += f64::from(v);
                sq[j] += f64::from(v) * f64::from(v);
            }
        }
        let mean: Vec<f64> = mean.iter().map(|m| m / n).collect();
        // A constant feature gets scale 1 (it standardises to 0 and carries nothing).
        let scale = sq
            .iter()
            .zip(&mean)
            .map(|(q, m)| (q / n - m * m).max(0.0).sqrt())
            .map(|v| if v > 1e-8 { v } else { 1.0 })
            .collect();
        let mut y_mean = vec![0.0; s.k];
        for row in s.y.chunks(s.k) {
            for (c, &v) in row.iter().enumerate() {
                y_mean[c] += v / n;
            }
        }
        Normal { mean, scale, y_mean }
    }

    /// The features standardised, in f64 (an f32 Gram matrix of correlated features
    /// can lose positive definiteness to rounding).
    fn standardised(&self, s: &Samples) -> Vec<f64> {
        s.x.chunks(s.d)
            .flat_map(|row| row.iter().enumerate().map(|(j, &v)| (f64::from(v) - self.mean[j]) / self.scale[j]))
            .collect()
    }

    /// (ZᵀZ, Zᵀ(Y − ȳ)) of `s`, with the products on the tensor library.
    fn gram(&self, s: &Samples) -> Result<(Vec<f64>, Vec<f64>)> {
        let n = s.len();
        let z = Tensor::from_vec(self.standardised(s), (n, s.d), &Device::Cpu)?;
        let yc: Vec<f64> = s.y.chunks(s.k).flat_map(|row| row.iter().zip(&self.y_mean).map(|(v, m)| v - m)).collect();
        let y = Tensor::from_vec(yc, (n, s.k), &Device::Cpu)?;
        let zt = z.t()?;
        let flat = |t: Tensor| -> Result<Vec<f64>> { Ok(t.flatten_all()?.to_vec1::<f64>()?) };
        Ok((flat(zt.matmul(&z)?)?, flat(zt.matmul(&y)?)?))
    }
}

impl RidgeProbe {
    /// Fit on `train` with ridge strength `lambda` per target (each a multiple of
    /// the sample count).
    fn fit_with(
        norm: &Normal,
        gram: &(Vec<f64>, Vec<f64>),
        d: usize,
        k: usize,
        n: usize,
        lambdas: &[f64],
    ) -> Result<RidgeProbe> {
        let mut weights = vec![0.0; d * k];
        let mut todo: Vec<usize> = (0..k).collect();
        // One factorisation per distinct strength, solving all its targets at once.
        while let Some(&first) = todo.first() {
            let lambda = lambdas[first];
            let cols: Vec<usize> = todo.iter().copied().filter(|&c| lambdas[c] == lambda).collect();
            todo.retain(|c| !cols.contains(c));
            let mut a = gram.0.clone();
            for i in 0..d {
                a[i * d + i] += lambda * n as f64;
            }
            let b: Vec<f64> = (0..d).flat_map(|i| cols.iter().map(move |&c| gram.1[i * k + c])).collect();
            let w = solve_spd(&a, &b, d, cols.len())?;
            for i in 0..d {
                for (j, &c) in cols.iter().enumerate() {
                    weights[i * k + c] = w[i * cols.len() + j];
                }
            }
        }
        Ok(RidgeProbe { mean: norm.mean.clone(), scale: norm.scale.clone(), weights, intercept: norm.y_mean.clone() })
    }

    /// Fit on `fit`, choose each target's strength from [`RIDGE_GRID`] by R² on
    /// `validate`, then refit on both with the chosen strengths.
    pub fn fit(fit: &Samples, validate: &Samples) -> Result<(RidgeProbe, Vec<f64>)> {
        let (d, k) = (fit.d, fit.k);
        if fit.is_empty() || validate.is_empty() {
            return Err(ExperimentError::Diagnosis("the probe needs samples to fit and to validate".into()));
        }
        let norm = Normal::of(fit);
        let gram = norm.gram(fit)?;
        let mut best = vec![(f64::NEG_INFINITY, RIDGE_GRID[0]); k];
        for &lambda in &RIDGE_GRID {
            // A strength too weak for a nearly singular system is skipped, not fatal.
            let Ok(probe) = RidgeProbe::fit_with(&norm, &gram, d, k, fit.len(), &vec![lambda; k]) else { continue };
            for (c, r2) in probe.r_squared(validate).into_iter().enumerate() {
                if r2 > best[c].0 {
                    best[c] = (r2, lambda);
                }
            }
        }
        let lambdas: Vec<f64> = best.iter().map(|b| b.1).collect();
        let all = fit.concat(validate);
        let norm = Normal::of(&all);
        let gram = norm.gram(&all)?;
        Ok((RidgeProbe::fit_with(&norm, &gram, d, k, all.len(), &lambdas)?, lambdas))
    }

    /// Predictions (n, k) for `s`.
    pub fn predict(&self, s: &Samples) -> Vec<f64> {
        let (d, k) = (s.d, s.k);
        let mut out = Vec::with_capacity(s.len() * k);
        for row in s.x.chunks(d) {
            for c in 0..k {
                let dot: f64 =
                    (0..d).map(|j| (f64::from(row[j]) - self.mean[j]) / self.scale[j] * self.weights[j * k + c]).sum();
                out.push(self.intercept[c] + dot);
            }
        }
        out
    }

    /// R² per target on `s`: 1 − Σ(y − ŷ)² / Σ(y − ȳ)², ȳ the mean over `s`.
    pub fn r_squared(&self, s: &Samples) -> Vec<f64> {
        let pred = self.predict(s);
        let n = s.len() as f64;
        (0..s.k)
            .map(|c| {
                let ys = s.y.iter().skip(c).step_by(s.k);
                let mean = ys.clone().sum::<f64>() / n;
                let sst: f64 = ys.clone().map(|y| (y - mean).powi(2)).sum();
                let sse: f64 = ys.zip(pred.iter().skip(c).step_by(s.k)).map(|(y, p)| (y - p).powi(2)).sum();
                if sst > 0.0 { 1.0 - sse / sst } else { f64::NAN }
            })
            .collect()
    }
}
