//! Confidence intervals for the difference between two variants' Avg.Int or Avg.Ext,
//! from their per-episode results (`results.csv` of `pednav-eval`).
//!
//! Two sources of noise make a variant's average: which runs (seeds) were trained, and
//! which episodes each run's evaluation happened to sample. Three seeds alone make a
//! degenerate interval, and the episodes alone ignore the spread between runs, so the
//! bootstrap is hierarchical: each replicate draws the variant's runs with
//! replacement, then, within every drawn run, each validation point's episodes with
//! replacement (as many as it has); a run's average is the mean of its per-point means
//! over the points of the class (0–7 interpolated, 8–13 extrapolated, as Table III),
//! and the variant's average is the mean over its drawn runs. The interval is the
//! percentile interval of the replicates' differences A − B.
//!
//! Invariant: the replicates are a pure function of the inputs and the seed.

use std::collections::BTreeMap;
use std::path::Path;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

use crate::error::{ExperimentError, Result};

/// Which average of Table III.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Average {
    /// Points 0–7 (inside the curriculum region).
    Int,
    /// Points 8–13 (outside it).
    Ext,
}

impl Average {
    fn contains(self, point: u32) -> bool {
        match self {
            Average::Int => point < 8,
            Average::Ext => (8..14).contains(&point),
        }
    }
}

/// One run's evaluation: each validation point's episode returns.
#[derive(Debug, Clone, PartialEq)]
pub struct RunReturns(pub BTreeMap<u32, Vec<f64>>);

impl RunReturns {
    /// Read a `results.csv` (`point,yaw_deg,run,discounted_return,success,steps`).
    pub fn read(path: &Path) -> Result<RunReturns> {
        let text = std::fs::read_to_string(path).map_err(|e| ExperimentError::file(path, e))?;
        let mut lines = text.lines();
        let header = lines.next().unwrap_or_default();
        let cols: Vec<&str> = header.split(',').collect();
        let (Some(p), Some(g)) =
            (cols.iter().position(|c| *c == "point"), cols.iter().position(|c| *c == "discounted_return"))
        else {
            return Err(ExperimentError::file(path, "not a results.csv of pednav-eval (no point / discounted_return)"));
        };
        let mut by_point: BTreeMap<u32, Vec<f64>> = BTreeMap::new();
        for (n, line) in lines.enumerate() {
            let f: Vec<&str> = line.split(',').collect();
            let parsed = f.get(p).and_then(|v| v.parse::<u32>().ok()).zip(f.get(g).and_then(|v| v.parse::<f64>().ok()));
            let Some((point, ret)) = parsed else {
                return Err(ExperimentError::file(path, format!("line {}: cannot read `{line}`", n + 2)));
            };
            by_point.entry(point).or_default().push(ret);
        }
        Ok(RunReturns(by_point))
    }

    /// The run's average over the points of `which` (mean of the per-point means);
    /// `None` when it has no such point.
    pub fn average(&self, which: Average) -> Option<f64> {
        let means: Vec<f64> = self
            .0
            .iter()
            .filter(|(p, _)| which.contains(**p))
            .map(|(_, g)| g.iter().sum::<f64>() / g.len() as f64)
            .collect();
        (!means.is_empty()).then(|| means.iter().sum::<f64>() / means.len() as f64)
    }

    /// A bootstrap replicate of this run: every point's episodes drawn with replacement.
    fn resampled_average(&self, which: Average, rng: &mut ChaCha8Rng) -> f64 {
        let mut sum = 0.0;
        let mut n = 0;
        for (_, g) in self.0.iter().filter(|(p, _)| which.contains(**p)) {
            let mean = (0..g.len()).map(|_| g[rng.random_range(0..g.len())]).sum::<f64>() / g.len() as f64;
            sum += mean;
            n += 1;
        }
        sum / n.max(1) as f64
    }
}

/// A bootstrap interval of A − B.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Interval {
    /// Which average.
    pub average: Average,
    /// A − B on the data itself (means over each variant's runs).
    pub estimate: f64,
    /// Lower end of the interval.
    pub low: f64,
    /// Upper end.
    pub high: f64,
    /// Coverage, e.g. 0.95.
    pub level: f64,
    /// Replicates drawn.
    pub replicates: usize,
    /// Share of replicates with A − B > 0.
    pub share_above_zero: f64,
}

fn variant_average(runs: &[RunReturns], which: Average) -> Result<f64> {
    let avgs: Vec<f64> = runs.iter().filter_map(|r| r.average(which)).collect();
    if avgs.len() != runs.len() || avgs.is_empty() {
        return Err(ExperimentError::Diagnosis(format!(
            "every run needs episodes of the {which:?} points (got {} of {})",
            avgs.len(),
            runs.len()
        )));
    }
    Ok(avgs.iter().sum::<f64>() / avgs.len() as f64)
}

/// The hierarchical bootstrap interval (module docs) of `a` − `b` on `which`.
pub fn difference(
    a: &[RunReturns],
    b: &[RunReturns],
    which: Average,
    replicates: usize,
    level: f64,
    seed: u64,
) -> Result<Interval> {
    let estimate = variant_average(a, which)? - variant_average(b, which)?;
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let draw = |runs: &[RunReturns], rng: &mut ChaCha8Rng| {
        (0..runs.len()).map(|_| runs[rng.random_range(0..runs.len())].resampled_average(which, rng)).sum::<f64>()
            / runs.len() as f64
    };
    let mut diffs: Vec<f64> = (0..replicates.max(1)).map(|_| draw(a, &mut rng) - draw(b, &mut rng)).collect();
    diffs.sort_by(f64::total_cmp);
    let q = |p: f64| diffs[((p * (diffs.len() - 1) as f64).round() as usize).min(diffs.len() - 1)];
    let tail = (1.0 - level) / 2.0;
    Ok(Interval {
        average: which,
        estimate,
        low: q(tail),
        high: q(1.0 - tail),
        level,
        replicates: diffs.len(),
        share_above_zero: diffs.iter().filter(|d| **d > 0.0).count() as f64 / diffs.len() as f64,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(base: f64, spread: f64) -> RunReturns {
        // 14 points × 80 episodes: returns base ± spread around a per-point offset.
        RunReturns(
            (0..14u32)
                .map(|p| (p, (0..80).map(|k| base - p as f64 + spread * ((k % 5) as f64 - 2.0)).collect()))
                .collect(),
        )
    }

    #[test]
    fn averages_are_means_of_per_point_means() {
        let r = RunReturns(BTreeMap::from([(0, vec![1.0, 3.0]), (1, vec![10.0]), (9, vec![-4.0, -6.0])]));
        assert_eq!(r.average(Average::Int), Some(6.0)); // (2 + 10) / 2
        assert_eq!(r.average(Average::Ext), Some(-5.0));
    }

    #[test]
    fn a_clear_difference_excludes_zero_and_no_difference_covers_it() {
        let a = [run(-20.0, 5.0), run(-22.0, 5.0), run(-21.0, 5.0)];
        let b = [run(-40.0, 5.0), run(-38.0, 5.0), run(-41.0, 5.0)];
        let i = difference(&a, &b, Average::Int, 2000, 0.95, 1).unwrap();
        assert!((i.estimate - 18.666_666).abs() < 1e-3, "{i:?}");
        assert!(i.low > 0.0 && i.high > i.low && i.share_above_zero == 1.0, "{i:?}");
        let same = difference(&a, &a, Average::Ext, 2000, 0.95, 1).unwrap();
        assert!(same.estimate == 0.0 && same.low < 0.0 && same.high > 0.0, "{same:?}");
        // Seeded: the same call gives the same interval.
        assert_eq!(
            difference(&a, &b, Average::Int, 500, 0.9, 7).unwrap(),
            difference(&a, &b, Average::Int, 500, 0.9, 7).unwrap()
        );
    }

    #[test]
    fn seeds_that_disagree_widen_the_interval() {
        // The same mean difference, but B's runs disagree strongly: a wider interval.
        let a = [run(-20.0, 1.0), run(-20.0, 1.0), run(-20.0, 1.0)];
        let tight = [run(-30.0, 1.0), run(-30.0, 1.0), run(-30.0, 1.0)];
        let loose = [run(-10.0, 1.0), run(-30.0, 1.0), run(-50.0, 1.0)];
        let t = difference(&a, &tight, Average::Int, 2000, 0.95, 3).unwrap();
        let l = difference(&a, &loose, Average::Int, 2000, 0.95, 3).unwrap();
        assert!((t.estimate - l.estimate).abs() < 1e-9);
        assert!(l.high - l.low > 5.0 * (t.high - t.low), "{t:?} {l:?}");
    }
}
