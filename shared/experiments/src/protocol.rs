//! The paper's validation protocol (§V-C) and custom start lists.
//!
//! Invariant: a task list is fully determined by its inputs — the full protocol
//! is 14 points × 8 yaws × `runs` in a fixed order, each task with its own seed
//! derived from (seed, point, yaw, run), so results do not depend on how the
//! list is split across worker processes.

use std::path::Path;

use pednav_sim::{Pose, Scene};
use serde::{Deserialize, Serialize};

use crate::error::{ExperimentError, Result};

/// The eight start yaws of the protocol, degrees (absolute heading: 0 = east,
/// counter-clockwise, as everywhere in pednav).
pub const YAWS_DEG: [f32; 8] = [0.0, 45.0, -45.0, 90.0, -90.0, 135.0, -135.0, 180.0];
/// Runs per (point, yaw) in the paper.
pub const RUNS: u32 = 10;
/// T_max of validation episodes in the paper.
pub const T_MAX: u32 = 2000;
/// The discount of the protocol's returns (Table IV's γ): every Avg.Int / Avg.Ext is
/// discounted by it, whatever discount a run trained with, so tables compare.
pub const GAMMA: f32 = 0.99;
/// Points 0–7 are interpolated (inside the curriculum region): Avg.Int.
pub const INTERIOR: std::ops::Range<u32> = 0..8;

/// One validation episode to run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EvalTask {
    /// Index of the start point (validation point id, or row of a CSV list).
    pub point: u32,
    /// Start yaw, degrees.
    pub yaw_deg: f32,
    /// Repetition index.
    pub run: u32,
    /// Start x, metres.
    pub x: f32,
    /// Start y, metres.
    pub y: f32,
    /// Seed of the episode (rendering look; policy noise when stochastic).
    pub seed: u64,
}

impl EvalTask {
    /// Start pose.
    pub fn pose(&self) -> Pose {
        Pose::from_degrees(self.x, self.y, self.yaw_deg)
    }
}

fn task_seed(seed: u64, point: u32, yaw_index: usize, run: u32) -> u64 {
    let mut h = seed ^ 0x9E37_79B9_7F4A_7C15;
    for v in [point as u64, yaw_index as u64, run as u64] {
        h = (h ^ v).wrapping_mul(0x0100_0000_01b3).rotate_left(17);
    }
    h
}

/// The full protocol over the scene's validation points: points × 8 yaws × `runs`.
pub fn validation_tasks(scene: &Scene, runs: u32, seed: u64) -> Vec<EvalTask> {
    let starts: Vec<(u32, f32, f32)> = scene.validation_points().iter().map(|p| (p.id, p.x, p.y)).collect();
    tasks_over(&starts, runs, seed)
}

fn tasks_over(starts: &[(u32, f32, f32)], runs: u32, seed: u64) -> Vec<EvalTask> {
    let mut out = Vec::with_capacity(starts.len() * YAWS_DEG.len() * runs as usize);
    for &(point, x, y) in starts {
        for (k, &yaw_deg) in YAWS_DEG.iter().enumerate() {
            for run in 0..runs {
                out.push(EvalTask { point, yaw_deg, run, x, y, seed: task_seed(seed, point, k, run) });
            }
        }
    }
    out
}

/// Start poses from a CSV file with columns `x,y,yaw` (metres, metres, degrees;
/// a header line is optional): each row × `runs`, at the row's own yaw.
pub fn tasks_from_csv(path: &Path, runs: u32, seed: u64) -> Result<Vec<EvalTask>> {
    let text = std::fs::read_to_string(path).map_err(|e| ExperimentError::file(path, e))?;
    let mut out = Vec::new();
    let mut point = 0;
    for (line_no, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let cols: Vec<&str> = line.split(',').map(str::trim).collect();
        let parsed: Option<Vec<f32>> = cols.iter().map(|c| c.parse::<f32>().ok()).collect();
        match parsed {
            Some(v) if v.len() == 3 && v.iter().all(|x| x.is_finite()) => {
                for run in 0..runs {
                    out.push(EvalTask {
                        point,
                        yaw_deg: v[2],
                        run,
                        x: v[0],
                        y: v[1],
                        seed: task_seed(seed, point, 0, run),
                    });
                }
                point += 1;
            }
            _ if line_no == 0 => {} // header
            _ => {
                return Err(ExperimentError::file(
                    path,
                    format!("line {}: expected `x,y,yaw` (three numbers), got `{line}`", line_no + 1),
                ));
            }
        }
    }
    if out.is_empty() {
        return Err(ExperimentError::file(path, "no start poses (expected lines `x,y,yaw`)"));
    }
    Ok(out)
}

/// Tasks of worker `shard` out of `of` (every `of`-th task).
pub fn shard(tasks: &[EvalTask], shard: usize, of: usize) -> Vec<EvalTask> {
    tasks.iter().enumerate().filter(|(i, _)| i % of.max(1) == shard).map(|(_, t)| *t).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_full_protocol_is_1120_episodes() {
        let tasks = validation_tasks(&Scene::reference(), RUNS, 0);
        assert_eq!(tasks.len(), 1120, "14 points × 8 yaws × 10 runs");
        for p in 0..14 {
            let of_point: Vec<_> = tasks.iter().filter(|t| t.point == p).collect();
            assert_eq!(of_point.len(), 80);
            for yaw in YAWS_DEG {
                assert_eq!(of_point.iter().filter(|t| t.yaw_deg == yaw).count(), 10);
            }
        }
        let mut seeds: Vec<u64> = tasks.iter().map(|t| t.seed).collect();
        seeds.sort();
        seeds.dedup();
        assert_eq!(seeds.len(), 1120, "every episode has its own seed");
        // Shards partition the list.
        let parts: usize = (0..3).map(|k| shard(&tasks, k, 3).len()).sum();
        assert_eq!(parts, 1120);
    }

    #[test]
    fn csv_lists_parse_and_errors_name_the_line() {
        let dir = std::env::temp_dir().join(format!("pednav-proto-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let f = dir.join("starts.csv");
        std::fs::write(&f, "x,y,yaw\n12,7,0\n14, -7, 180\n").unwrap();
        let t = tasks_from_csv(&f, 2, 0).unwrap();
        assert_eq!(t.len(), 4);
        assert_eq!((t[2].point, t[2].x, t[2].y, t[2].yaw_deg), (1, 14.0, -7.0, 180.0));
        std::fs::write(&f, "12,7,0\n14,oops,180\n").unwrap();
        let e = tasks_from_csv(&f, 1, 0).unwrap_err().to_string();
        assert!(e.contains("line 2") && e.contains("oops"), "{e}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
