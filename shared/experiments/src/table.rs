//! Episode results and the Table III aggregation.
//!
//! Per start point: mean ± std of the discounted return over all its episodes
//! (8 yaws × runs; std is the sample standard deviation, n − 1 in the
//! denominator, as everywhere in pednav's tables: [`mean_and_sample_std`]),
//! the success rate, and the oracle's optimal return averaged over the same start
//! yaws. Avg.Int and Avg.Ext are the means of the per-point means over points
//! 0–7 and 8–13, as in the paper's Table III. For a start list of the user's
//! (`pednav-eval --starts`) the rows are the file's starts instead, and the table
//! gives the mean over them ([`Rows::StartList`]): Avg.Int/Ext would mean nothing.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{ExperimentError, Result};
use crate::protocol::INTERIOR;

/// The outcome of one evaluation episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeResult {
    /// Start point index.
    pub point: u32,
    /// Start yaw, degrees.
    pub yaw_deg: f32,
    /// Repetition.
    pub run: u32,
    /// Discounted return Σ γ^t r_{t+1}.
    pub discounted_return: f32,
    /// The goal was reached.
    pub success: bool,
    /// Decision steps taken.
    pub steps: u32,
    /// Positions visited (x, y), start first.
    pub trajectory: Vec<[f32; 2]>,
    /// Safety counts of the episode; `None` with traffic off.
    pub safety: Option<pednav_sim::traffic::SafetyCounts>,
}

/// One row of the table.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PointRow {
    /// Start point index.
    pub point: u32,
    /// Episodes.
    pub episodes: usize,
    /// Mean discounted return.
    pub mean: f64,
    /// Sample standard deviation (n − 1 in the denominator, [`mean_and_sample_std`]) of
    /// the discounted return; 0 for a single episode.
    pub std: f64,
    /// Fraction of episodes that reached the goal.
    pub success_rate: f64,
    /// Oracle's optimal discounted return from the same starts (mean over yaws), if known.
    pub oracle: Option<f64>,
}

/// What a table's rows are.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Rows {
    /// The paper's 14 validation points (Avg.Int over 0–7, Avg.Ext over 8–13).
    ValidationPoints,
    /// The starts of a `--starts` file, by their row in the file (0-based).
    StartList,
}

/// The aggregated table.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Table {
    /// What the rows are.
    pub kind: Rows,
    /// Rows by point.
    pub rows: Vec<PointRow>,
    /// Mean of the per-row means (every row).
    pub mean_all: Option<f64>,
    /// Mean of the per-point means of points 0–7 (None without such points).
    pub avg_int: Option<f64>,
    /// Mean of the per-point means of points ≥ 8.
    pub avg_ext: Option<f64>,
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

/// Aggregate results; `oracle` maps point → optimal return for its starts.
pub fn aggregate(results: &[EpisodeResult], oracle: &BTreeMap<u32, f64>, kind: Rows) -> Table {
    let mut by_point: BTreeMap<u32, Vec<&EpisodeResult>> = BTreeMap::new();
    for r in results {
        by_point.entry(r.point).or_default().push(r);
    }
    let rows: Vec<PointRow> = by_point
        .into_iter()
        .map(|(point, rs)| {
            let g: Vec<f64> = rs.iter().map(|r| r.discounted_return as f64).collect();
            let (m, std) = mean_and_sample_std(&g);
            PointRow {
                point,
                episodes: rs.len(),
                mean: m,
                std,
                success_rate: rs.iter().filter(|r| r.success).count() as f64 / rs.len() as f64,
                oracle: oracle.get(&point).copied(),
            }
        })
        .collect();
    let avg = |f: &dyn Fn(u32) -> bool| {
        let v: Vec<f64> = rows.iter().filter(|r| f(r.point)).map(|r| r.mean).collect();
        (!v.is_empty()).then(|| mean(&v))
    };
    let (avg_int, avg_ext) = match kind {
        Rows::ValidationPoints => (avg(&|p| INTERIOR.contains(&p)), avg(&|p| !INTERIOR.contains(&p))),
        Rows::StartList => (None, None),
    };
    Table { kind, mean_all: avg(&|_| true), avg_int, avg_ext, rows }
}

impl Table {
    /// The table as text: one line per point in the paper's "mean ± std" form,
    /// with success rate and oracle, then Avg.Int and Avg.Ext.
    pub fn render(&self, title: &str) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "{title}");
        let row_name = match self.kind {
            Rows::ValidationPoints => "point",
            Rows::StartList => "start",
        };
        let _ = writeln!(
            s,
            "{:>5} | {:>16} | {:>7} | {:>7} | {:>8}",
            row_name, "return mean ± std", "success", "oracle", "episodes"
        );
        let _ = writeln!(s, "{}", "-".repeat(56));
        for r in &self.rows {
            let oracle = r.oracle.map_or("—".to_string(), |o| format!("{o:.1}"));
            let _ = writeln!(
                s,
                "{:>5} | {:>16} | {:>6.0}% | {:>7} | {:>8}",
                r.point,
                format!("{:.1} ± {:.1}", r.mean, r.std),
                100.0 * r.success_rate,
                oracle,
                r.episodes
            );
        }
        let _ = writeln!(s, "{}", "-".repeat(56));
        let f = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.1}"));
        match self.kind {
            Rows::ValidationPoints => {
                let _ = writeln!(
                    s,
                    "Avg.Int (points 0–7): {}   Avg.Ext (points 8–13): {}",
                    f(self.avg_int),
                    f(self.avg_ext)
                );
            }
            Rows::StartList => {
                let _ = writeln!(
                    s,
                    "rows: the starts of the --starts file by row (0-based); mean over them: {}",
                    f(self.mean_all)
                );
            }
        }
        s
    }

    /// Write the table as CSV (one row per point, then Avg.Int and Avg.Ext rows).
    pub fn write_csv(&self, path: &Path) -> Result<()> {
        let mut s = match self.kind {
            Rows::ValidationPoints => String::from("point,episodes,mean,std,success_rate,oracle\n"),
            Rows::StartList => String::from("start,episodes,mean,std,success_rate,oracle\n"),
        };
        for r in &self.rows {
            let oracle = r.oracle.map_or(String::new(), |o| format!("{o:.4}"));
            let _ = writeln!(s, "{},{},{:.4},{:.4},{:.4},{oracle}", r.point, r.episodes, r.mean, r.std, r.success_rate);
        }
        let f = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.4}"));
        match self.kind {
            Rows::ValidationPoints => {
                let _ = writeln!(s, "avg_int,,{},,,", f(self.avg_int));
                let _ = writeln!(s, "avg_ext,,{},,,", f(self.avg_ext));
            }
            Rows::StartList => {
                let _ = writeln!(s, "mean,,{},,,", f(self.mean_all));
            }
        }
        std::fs::write(path, s).map_err(|e| ExperimentError::file(path, e))
    }
}

/// Write every episode as CSV; with traffic, each episode's safety counts follow
/// (`vehicle_hits,dont_walk_entries,pedestrian_bumps,vehicle_bumps,kerb_wait_steps`).
pub fn write_results_csv(results: &[EpisodeResult], path: &Path) -> Result<()> {
    let traffic = results.iter().any(|r| r.safety.is_some());
    let mut s = String::from("point,yaw_deg,run,discounted_return,success,steps");
    s.push_str(if traffic {
        ",vehicle_hits,dont_walk_entries,pedestrian_bumps,vehicle_bumps,kerb_wait_steps\n"
    } else {
        "\n"
    });
    for r in results {
        let _ = write!(s, "{},{},{},{:.4},{},{}", r.point, r.yaw_deg, r.run, r.discounted_return, r.success, r.steps);
        if traffic {
            let c = r.safety.unwrap_or_default();
            let _ = write!(
                s,
                ",{},{},{},{},{}",
                c.vehicle_hits, c.dont_walk_entries, c.pedestrian_bumps, c.vehicle_bumps, c.kerb_wait_steps
            );
        }
        s.push('\n');
    }
    std::fs::write(path, s).map_err(|e| ExperimentError::file(path, e))
}

/// What a Table III row needs from one evaluation (`table.csv` of `pednav-eval`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalSummary {
    /// Avg.Int: mean of the per-point means over points 0–7.
    pub avg_int: f64,
    /// Avg.Ext: mean of the per-point means over points 8–13.
    pub avg_ext: f64,
    /// Fraction of all episodes that reached the goal.
    pub success: f64,
    /// Episodes evaluated.
    pub episodes: usize,
    /// The oracle's Avg.Int and Avg.Ext from the same starts, when the table has them.
    pub oracle: Option<(f64, f64)>,
}

impl EvalSummary {
    /// Read the `table.csv` a validation-point evaluation wrote.
    pub fn read(path: &Path) -> Result<EvalSummary> {
        let text = std::fs::read_to_string(path).map_err(|e| ExperimentError::file(path, e))?;
        let bad = |m: String| ExperimentError::file(path, m);
        let mut lines = text.lines();
        if lines.next() != Some("point,episodes,mean,std,success_rate,oracle") {
            return Err(
                bad("not the table.csv of a validation-point evaluation (pednav-eval without --starts)".into()),
            );
        }
        let (mut avg_int, mut avg_ext, mut episodes, mut successes) = (None, None, 0usize, 0.0);
        let mut oracle: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
        let mut points = 0;
        for line in lines {
            let f: Vec<&str> = line.split(',').collect();
            let num = |i: usize| -> Result<f64> {
                f.get(i).and_then(|v| v.parse().ok()).ok_or_else(|| bad(format!("bad value in column {i} of `{line}`")))
            };
            match f[0] {
                "avg_int" => avg_int = Some(num(2)?),
                "avg_ext" => avg_ext = Some(num(2)?),
                point => {
                    let point: u32 = point.parse().map_err(|_| bad(format!("bad point in `{line}`")))?;
                    let n = num(1)? as usize;
                    episodes += n;
                    successes += num(4)? * n as f64;
                    if let Ok(o) = num(5) {
                        oracle[usize::from(!INTERIOR.contains(&point))].push(o);
                    }
                    points += 1;
                }
            }
        }
        let (Some(avg_int), Some(avg_ext)) = (avg_int, avg_ext) else {
            return Err(bad("no avg_int / avg_ext rows".into()));
        };
        let mean_of = |v: &Vec<f64>| v.iter().sum::<f64>() / v.len() as f64;
        let oracle = (oracle[0].len() + oracle[1].len() == points && !oracle[0].is_empty() && !oracle[1].is_empty())
            .then(|| (mean_of(&oracle[0]), mean_of(&oracle[1])));
        Ok(EvalSummary { avg_int, avg_ext, success: successes / episodes.max(1) as f64, episodes, oracle })
    }
}

/// Mean and sample standard deviation (n − 1 in the denominator; 0 for fewer than
/// two values, where it is undefined — tables then show the mean alone with n = 1).
pub fn mean_and_sample_std(v: &[f64]) -> (f64, f64) {
    let m = v.iter().sum::<f64>() / v.len().max(1) as f64;
    if v.len() < 2 {
        return (m, 0.0);
    }
    (m, (v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64).sqrt())
}

/// The share of the gap between a random walk and the oracle that `value` closes:
/// 0 at the random walk's return, 1 at the oracle's.
pub fn gap_closed(value: f64, random: f64, oracle: f64) -> f64 {
    (value - random) / (oracle - random)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn r(point: u32, g: f32, success: bool) -> EpisodeResult {
        EpisodeResult {
            point,
            yaw_deg: 0.0,
            run: 0,
            discounted_return: g,
            success,
            steps: 10,
            trajectory: vec![],
            safety: None,
        }
    }

    #[test]
    fn aggregation_matches_hand_computed_values() {
        // Point 0: returns 2, 4, 9 → mean 5, sample var (9 + 1 + 16)/2 = 13, std 3.6056.
        // Point 1: returns −10, −20 → mean −15, sample var 50, std 7.0711.
        // Point 9: return −30 → mean −30, std 0 (one value).
        let results = vec![
            r(0, 2.0, true),
            r(0, 4.0, true),
            r(0, 9.0, false),
            r(1, -10.0, false),
            r(1, -20.0, true),
            r(9, -30.0, false),
        ];
        let oracle = BTreeMap::from([(0, 4.5), (1, -3.0)]);
        let t = aggregate(&results, &oracle, Rows::ValidationPoints);
        assert_eq!(t.rows.len(), 3);
        let p0 = &t.rows[0];
        assert_eq!((p0.point, p0.episodes), (0, 3));
        assert!((p0.mean - 5.0).abs() < 1e-12);
        assert!((p0.std - 13.0f64.sqrt()).abs() < 1e-12);
        assert!((p0.success_rate - 2.0 / 3.0).abs() < 1e-12);
        assert_eq!(p0.oracle, Some(4.5));
        assert!((t.rows[1].std - 50.0f64.sqrt()).abs() < 1e-12 && t.rows[1].success_rate == 0.5);
        assert_eq!(t.rows[2].std, 0.0);
        assert_eq!(t.rows[2].oracle, None);
        // Avg.Int = mean(5, −15) = −5; Avg.Ext = −30.
        assert_eq!(t.avg_int, Some(-5.0));
        assert_eq!(t.avg_ext, Some(-30.0));
        let text = t.render("test");
        assert!(text.contains("5.0 ± 3.6") && text.contains("Avg.Int (points 0–7): -5.0"), "{text}");
        // The same episodes as a start list: no Avg.Int/Ext; mean of the rows (5 − 15 − 30)/3.
        let t = aggregate(&results, &oracle, Rows::StartList);
        assert_eq!((t.avg_int, t.avg_ext), (None, None));
        assert!((t.mean_all.unwrap() + 40.0 / 3.0).abs() < 1e-12);
        let text = t.render("test");
        assert!(
            !text.contains("Avg.Int") && text.contains("start |") && text.contains("mean over them: -13.3"),
            "{text}"
        );
    }

    #[test]
    fn summaries_read_back_what_the_table_wrote() {
        let results = vec![r(0, -10.0, true), r(0, -20.0, false), r(3, -30.0, true), r(9, -50.0, false)];
        let oracle = BTreeMap::from([(0, 4.0), (3, -2.0), (9, -6.0)]);
        let dir = std::env::temp_dir().join(format!("pednav-summary-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("table.csv");
        aggregate(&results, &oracle, Rows::ValidationPoints).write_csv(&path).unwrap();
        let s = EvalSummary::read(&path).unwrap();
        // Avg.Int = mean(−15, −30) = −22.5; Avg.Ext = −50; 2 of 4 reached the goal;
        // the oracle's Avg.Int = mean(4, −2) = 1, Avg.Ext = −6.
        assert_eq!((s.avg_int, s.avg_ext, s.success, s.episodes), (-22.5, -50.0, 0.5, 4));
        assert_eq!(s.oracle, Some((1.0, -6.0)));
        // Halfway between a random walk at −45 and that oracle.
        assert!((gap_closed(-22.0, -45.0, 1.0) - 0.5).abs() < 1e-12);
        aggregate(&results, &oracle, Rows::StartList).write_csv(&path).unwrap();
        assert!(EvalSummary::read(&path).unwrap_err().to_string().contains("without --starts"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
