//! Adaptive filtering (paper §III-A/B): fit μ, σ of the predicted returns of the
//! candidate tasks, classify tasks into easy / frontier / hard bands, and the
//! per-variant schedule of category probabilities.
//!
//! Invariants: the probabilities of [`category_probabilities`] are non-negative
//! and sum to 1; [`Fit::of`] is finite for finite predictions; the random
//! category accepts every task.

use serde::{Deserialize, Serialize};

pub use pednav_config::Category;

use crate::config::{CurriculumConfig, Variant};

/// Mean and standard deviation of the candidates' predicted returns.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Fit {
    /// Mean μ_f.
    pub mu: f32,
    /// Population standard deviation σ_f.
    pub sigma: f32,
}

impl Fit {
    /// Fit μ and σ (population) of the predictions; `None` for an empty slice.
    pub fn of(predictions: &[f32]) -> Option<Fit> {
        if predictions.is_empty() {
            return None;
        }
        let n = predictions.len() as f64;
        let mu = predictions.iter().map(|&p| p as f64).sum::<f64>() / n;
        let var = predictions.iter().map(|&p| (p as f64 - mu).powi(2)).sum::<f64>() / n;
        Some(Fit { mu: mu as f32, sigma: var.sqrt() as f32 })
    }
}

/// The classification thresholds at one point of training.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Bands {
    /// Easy when f > this.
    pub easy_above: f32,
    /// Frontier when f > this …
    pub frontier_low: f32,
    /// … and f < this.
    pub frontier_high: f32,
    /// Hard when f < this.
    pub hard_below: f32,
}

/// β_f^l at ACL-phase step count `t_c`: `β_f^l + S·min(t_c/t_thre, 1)` for the
/// Slope variant, the constant β_f^l otherwise.
pub fn frontier_low_beta(cfg: &CurriculumConfig, t_c: u64) -> f32 {
    match cfg.variant {
        Variant::NavAclPlusSlope => cfg.beta_frontier_low + cfg.slope * progress(cfg, t_c),
        _ => cfg.beta_frontier_low,
    }
}

/// min(t_c / t_thre, 1).
pub fn progress(cfg: &CurriculumConfig, t_c: u64) -> f32 {
    (t_c as f64 / cfg.t_thre).min(1.0) as f32
}

/// The bands for a fit at ACL-phase step count `t_c`.
pub fn bands(cfg: &CurriculumConfig, fit: Fit, t_c: u64) -> Bands {
    Bands {
        easy_above: fit.mu + cfg.beta_easy * fit.sigma,
        frontier_low: fit.mu - frontier_low_beta(cfg, t_c) * fit.sigma,
        frontier_high: fit.mu + cfg.beta_frontier_high * fit.sigma,
        hard_below: fit.mu - cfg.beta_hard * fit.sigma,
    }
}

impl Bands {
    /// Does a task with predicted return `f` belong to `category`?
    /// First and Fixed are not bands and accept nothing.
    pub fn contains(&self, category: Category, f: f32) -> bool {
        match category {
            Category::Easy => f > self.easy_above,
            Category::Frontier => f > self.frontier_low && f < self.frontier_high,
            Category::Hard => f < self.hard_below,
            Category::Random => true,
            Category::First | Category::Fixed => false,
        }
    }
}

/// Probabilities of the categories in the ACL phase at step count `t_c`.
/// - NavACL and NavACL⁺ (Slope): easy and frontier `(1 − p_r)/2` each, random `p_r`.
/// - NavACL⁺ (Hard): hard `p_h = hard_max·min(t_c/t_thre, 1)`, easy and frontier `(1 − p_h)/2` each.
/// - Fixed start: the fixed start with probability 1.
pub fn category_probabilities(cfg: &CurriculumConfig, t_c: u64) -> Vec<(Category, f32)> {
    match cfg.variant {
        Variant::NavAcl | Variant::NavAclPlusSlope => {
            let r = cfg.random_prob;
            vec![(Category::Easy, (1.0 - r) * 0.5), (Category::Frontier, (1.0 - r) * 0.5), (Category::Random, r)]
        }
        Variant::NavAclPlusHard => {
            let h = cfg.hard_max_prob * progress(cfg, t_c);
            vec![(Category::Easy, (1.0 - h) * 0.5), (Category::Frontier, (1.0 - h) * 0.5), (Category::Hard, h)]
        }
        Variant::FixedStart => vec![(Category::Fixed, 1.0)],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(variant: Variant) -> CurriculumConfig {
        CurriculumConfig { variant, ..CurriculumConfig::default() }
    }

    #[test]
    fn fit_matches_hand_computed_mean_and_std() {
        // [-10, 0, 10, 20]: μ = 5, σ² = (225 + 25 + 25 + 225)/4 = 125.
        let f = Fit::of(&[-10.0, 0.0, 10.0, 20.0]).unwrap();
        assert_eq!(f.mu, 5.0);
        assert!((f.sigma - 125f32.sqrt()).abs() < 1e-5);
        assert!(Fit::of(&[]).is_none());
    }

    #[test]
    fn thresholds_with_table_iv_values() {
        // μ = -40, σ = 10, β_e 1, β_f^h 0.1, β_f^l 1, β_h 1.
        let b = bands(&cfg(Variant::NavAclPlusHard), Fit { mu: -40.0, sigma: 10.0 }, 0);
        assert_eq!((b.easy_above, b.frontier_low, b.frontier_high, b.hard_below), (-30.0, -50.0, -39.0, -50.0));
        assert!(b.contains(Category::Easy, -29.0) && !b.contains(Category::Easy, -30.0));
        assert!(b.contains(Category::Frontier, -45.0) && !b.contains(Category::Frontier, -39.0));
        assert!(!b.contains(Category::Frontier, -50.0) && b.contains(Category::Hard, -50.5));
        assert!(b.contains(Category::Random, -1e6));
    }

    #[test]
    fn slope_schedule_widens_the_frontier() {
        let c = cfg(Variant::NavAclPlusSlope);
        // β_f^l = 1 + 5·min(t_c / 1.5e6, 1).
        assert_eq!(frontier_low_beta(&c, 0), 1.0);
        assert!((frontier_low_beta(&c, 750_000) - 3.5).abs() < 1e-6);
        assert_eq!(frontier_low_beta(&c, 1_500_000), 6.0);
        assert_eq!(frontier_low_beta(&c, 9_000_000), 6.0);
        let b = bands(&c, Fit { mu: -40.0, sigma: 10.0 }, 750_000);
        assert_eq!(b.frontier_low, -75.0);
        // Other variants keep β_f^l.
        assert_eq!(frontier_low_beta(&cfg(Variant::NavAclPlusHard), 9_000_000), 1.0);
    }

    #[test]
    fn hard_probabilities_ramp_to_twenty_percent() {
        let c = cfg(Variant::NavAclPlusHard);
        let p = |t| category_probabilities(&c, t);
        assert_eq!(p(0), vec![(Category::Easy, 0.5), (Category::Frontier, 0.5), (Category::Hard, 0.0)]);
        let mid = p(750_000);
        assert!((mid[2].1 - 0.1).abs() < 1e-6 && (mid[0].1 - 0.45).abs() < 1e-6 && (mid[1].1 - 0.45).abs() < 1e-6);
        let end = p(3_000_000);
        assert!((end[2].1 - 0.2).abs() < 1e-6 && (end[0].1 - 0.4).abs() < 1e-6);
        let s = category_probabilities(&cfg(Variant::NavAclPlusSlope), 0);
        assert_eq!(s, vec![(Category::Easy, 0.4), (Category::Frontier, 0.4), (Category::Random, 0.2)]);
    }
}
