//! What a trained agent has learned, measured along its own evaluation episodes
//! (`pednav-diagnose`, issue 15 item 5: why pixels learn slower than the state).
//!
//! - **Linear probe of the encoder.** Ridge regression from the policy encoder's
//!   features to the agent's pose (x, y, cos ψ, sin ψ of its body heading) and to its
//!   soft return-to-go, split by episode ([`split_of`]): fitted on 3/5 of the
//!   protocol's (point, yaw) starts, the ridge strength chosen per target on 1/5, and
//!   scored by R² on the episodes of the remaining 1/5. The same probe on an
//!   **untrained** encoder of the same architecture, fed the same windows, is the
//!   baseline: what the features carry beyond that was learned.
//! - **The critic against Monte-Carlo returns.** Q(s, a) = Σᵢ (τᵢ₊₁ − τᵢ)·Z(s, a, τ̂ᵢ)
//!   with the fraction net's τ (the smaller of the two critics' with twin critics,
//!   as the policy sees it) against the soft discounted return the sampled episode
//!   actually obtained, Gₜ = rₜ + Σₖ≥₁ γᵏ (rₜ₊ₖ − α log π(aₜ₊ₖ|sₜ₊ₖ)) — what the
//!   critic's target estimates. Only steps whose return is known are compared: the
//!   episode terminated, or at least H steps remained before the T_max cut with
//!   γᴴ ≤ 1 % ([`known_return_horizon`]).
//!
//! Invariants: the observer does not change what the evaluator does (its episodes
//! and results are those of `pednav-eval` with the same tasks); every recorded
//! sample belongs to one counted episode and carries that episode's own rewards.

mod probe;
mod value;

use std::fmt::Write as _;

use candle_core::{D, DType, Tensor};
use pednav_nets::{DsacNets, Obs, OnlineFeatures};
use serde::Serialize;

use crate::error::{ExperimentError, Result};
use crate::evaluate::{ActingStep, EpisodeObserver};
use crate::protocol::{EvalTask, YAWS_DEG};

pub use probe::{RIDGE_GRID, RidgeProbe, Samples, solve_spd};
pub use value::{ValueAgreement, soft_returns};

/// The probe's targets, in column order.
pub const PROBE_TARGETS: [&str; 5] = ["x (m)", "y (m)", "cos yaw", "sin yaw", "soft return-to-go"];
const POSE_TARGETS: usize = 4;

/// Steps H after which γᴴ ≤ 1 %: a truncated episode's return is known (to 1 % of
/// the tail's scale) at the steps that had at least H steps left.
pub fn known_return_horizon(gamma: f32) -> usize {
    if gamma <= 0.0 {
        return 1;
    }
    if gamma >= 1.0 {
        // γ = 1 never forgets the tail: only terminated episodes have known returns.
        return usize::MAX;
    }
    ((0.01f64).ln() / f64::from(gamma).ln()).ceil() as usize
}

/// Which part of the probe data the episode of `task` belongs to — 0 = fit,
/// 1 = validate, 2 = test — by its start (point, yaw) combination k = 8·point + yaw
/// index: k mod 5 ∈ {0, 1, 2} fit, 3 validate, 4 test. Every run of a start lands
/// in the same part, so a tested episode's start combination was never fitted,
/// while its point and its yaw each were, with other partners (a split by yaw alone
/// would make the heading an extrapolation).
pub fn split_of(task: &EvalTask) -> usize {
    let yaw = YAWS_DEG.iter().position(|&y| y == task.yaw_deg).unwrap_or(0);
    match (task.point as usize * YAWS_DEG.len() + yaw) % 5 {
        0..=2 => 0,
        3 => 1,
        _ => 2,
    }
}

/// One decision of a counted episode.
#[derive(Debug, Clone)]
struct StepRecord {
    reward: f32,
    log_prob: f32,
    q: f32,
    /// Pose targets and (trained, untrained) encoder features, every `stride` steps.
    probe: Option<([f32; POSE_TARGETS], Vec<f32>, Vec<f32>)>,
}

/// A finished episode.
#[derive(Debug, Clone)]
struct EpisodeRecord {
    task: EvalTask,
    terminated: bool,
    steps: Vec<StepRecord>,
}

/// Records features, critic values and rewards of a learned policy's evaluation
/// episodes (an [`EpisodeObserver`]); [`DiagnosisRecorder::report`] analyses them.
pub struct DiagnosisRecorder {
    nets: DsacNets,
    untrained: DsacNets,
    alpha: f64,
    gamma: f32,
    stride: usize,
    open: Vec<Option<(EvalTask, Vec<StepRecord>)>>,
    done: Vec<EpisodeRecord>,
}

impl DiagnosisRecorder {
    /// Watch `envs` environments acting with `nets` (every network loaded, see
    /// `pednav_learner::load_agent`) at temperature `alpha`; `untrained` is the
    /// same architecture freshly initialised; features are kept every `stride` steps.
    pub fn new(nets: DsacNets, untrained: DsacNets, alpha: f64, gamma: f32, envs: usize, stride: usize) -> Self {
        assert!(stride > 0, "stride must be positive");
        DiagnosisRecorder { nets, untrained, alpha, gamma, stride, open: vec![None; envs], done: Vec::new() }
    }

    /// Episodes recorded so far.
    pub fn episodes(&self) -> usize {
        self.done.len()
    }

    /// Q(s, a) per row as the policy sees it (min over twin critics), from the
    /// online features `f` of `obs`.
    fn q_values(&self, obs: &Obs, f: &OnlineFeatures, actions: &Tensor) -> Result<Vec<f32>> {
        let nets = &self.nets;
        let fr = nets.fraction.fractions(&f.fraction, actions)?;
        let mean = |z: Tensor| -> Result<Tensor> { Ok((z * &fr.widths)?.sum(D::Minus1)?) };
        let mut q = mean(nets.quantile.grid(&f.quantile, actions)?.at(&fr.hats)?)?;
        if let Some(twin) = &nets.twin {
            let f2 = match &twin.quantile.encoder {
                Some(e) => e.encode(obs)?,
                None => f.quantile.clone(),
            };
            q = q.minimum(&mean(twin.quantile.grid(&f2, actions)?.at(&fr.hats)?)?)?;
        }
        Ok(q.to_vec1::<f32>()?)
    }
}

impl EpisodeObserver for DiagnosisRecorder {
    fn decision(&mut self, d: &ActingStep<'_>) -> Result<()> {
        let log_probs: Vec<f32> = d
            .log_probs
            .ok_or_else(|| ExperimentError::Diagnosis("needs sampled actions (log π), not the mode".into()))?
            .to_vec1()?;
        let f = self.nets.online_features(d.obs)?;
        let q = self.q_values(d.obs, &f, d.actions)?;
        let wants_probe: Vec<bool> = (0..d.tasks.len())
            .map(|e| {
                d.tasks[e].is_some() && self.open[e].as_ref().is_none_or(|(_, s)| s.len().is_multiple_of(self.stride))
            })
            .collect();
        let (trained, untrained) = if wants_probe.iter().any(|&w| w) {
            let rows = |t: Tensor| -> Result<Vec<Vec<f32>>> { Ok(t.to_dtype(DType::F32)?.to_vec2::<f32>()?) };
            (rows(f.policy)?, rows(self.untrained.policy_features(d.obs)?)?)
        } else {
            (Vec::new(), Vec::new())
        };
        for (e, task) in d.tasks.iter().enumerate() {
            let Some(task) = task else {
                self.open[e] = None;
                continue;
            };
            let open = self.open[e].get_or_insert_with(|| (*task, Vec::new()));
            let p = d.poses[e];
            let probe = wants_probe[e]
                .then(|| ([p.x, p.y, p.yaw.cos(), p.yaw.sin()], trained[e].clone(), untrained[e].clone()));
            open.1.push(StepRecord { reward: 0.0, log_prob: log_probs[e], q: q[e], probe });
        }
        Ok(())
    }

    fn transition(&mut self, env: usize, reward: f32, ended: Option<bool>) -> Result<()> {
        let Some((_, steps)) = self.open[env].as_mut() else { return Ok(()) };
        steps.last_mut().expect("a transition follows a decision").reward = reward;
        if let Some(terminated) = ended {
            let (task, steps) = self.open[env].take().expect("open");
            self.done.push(EpisodeRecord { task, terminated, steps });
        }
        Ok(())
    }
}

/// One probe target: R² on the held-out episodes for the trained and the untrained
/// encoder (`None` when there were no samples to fit, validate or test).
#[derive(Debug, Clone, Serialize)]
pub struct ProbeRow {
    /// What is regressed ([`PROBE_TARGETS`]).
    pub target: &'static str,
    /// R² of the trained policy encoder's features.
    pub trained: Option<f64>,
    /// R² of the untrained encoder's features (same architecture and windows).
    pub untrained: Option<f64>,
    /// Samples fitted (the fit and validation starts, 4/5) and tested (1/5).
    pub samples: (usize, usize),
}

/// Everything `pednav-diagnose` measured.
#[derive(Debug, Clone, Serialize)]
pub struct Diagnosis {
    /// Episodes recorded.
    pub episodes: usize,
    /// Episodes that ended at the goal (terminated).
    pub terminated: usize,
    /// Decisions recorded.
    pub decisions: usize,
    /// Temperature α of the checkpoint.
    pub alpha: f64,
    /// Mean −log π(a|s) of the sampled actions (an entropy estimate).
    pub mean_neg_log_prob: f64,
    /// The linear probe, one row per [`PROBE_TARGETS`] entry. The pose is probed at
    /// every kept decision, the return-to-go only where the return is known.
    pub probe: Vec<ProbeRow>,
    /// Q against the soft return at every step whose return is known.
    pub all_steps: ValueAgreement,
    /// The same at the first step of each episode whose return is known.
    pub episode_starts: ValueAgreement,
    /// (Q, G) of up to 4,000 known-return steps, evenly spread, for the scatter plot.
    #[serde(skip)]
    pub scatter: Vec<(f64, f64)>,
}

/// Probe samples of one group of targets, split by episode ([`split_of`]),
/// for the trained and the untrained encoder.
struct ProbeSplit {
    /// [fit, validate, test] × [trained, untrained].
    parts: [[Samples; 2]; 3],
}

impl ProbeSplit {
    fn new(d: usize, k: usize) -> ProbeSplit {
        let s = || Samples::new(d, k);
        ProbeSplit { parts: [[s(), s()], [s(), s()], [s(), s()]] }
    }

    fn push(&mut self, part: usize, trained: &[f32], untrained: &[f32], y: &[f64]) {
        self.parts[part][0].push(trained, y);
        self.parts[part][1].push(untrained, y);
    }

    /// R² per target for (trained, untrained); `None`s when a part is empty.
    fn scores(&self) -> Result<Vec<(Option<f64>, Option<f64>)>> {
        let k = self.parts[0][0].k;
        let mut out = vec![(None, None); k];
        if self.parts.iter().any(|p| p[0].is_empty()) {
            return Ok(out);
        }
        for which in 0..2 {
            let [fit, val, test] = [&self.parts[0][which], &self.parts[1][which], &self.parts[2][which]];
            let (probe, _) = RidgeProbe::fit(fit, val)?;
            for (c, r2) in probe.r_squared(test).into_iter().enumerate() {
                if which == 0 {
                    out[c].0 = Some(r2);
                } else {
                    out[c].1 = Some(r2);
                }
            }
        }
        Ok(out)
    }

    fn sizes(&self) -> (usize, usize) {
        (self.parts[0][0].len() + self.parts[1][0].len(), self.parts[2][0].len())
    }
}

impl DiagnosisRecorder {
    /// Analyse the recorded episodes.
    pub fn report(&self) -> Result<Diagnosis> {
        let horizon = known_return_horizon(self.gamma);
        let dim = pednav_nets::encoder::feature_dim(&self.nets.cfg);
        let mut pose = ProbeSplit::new(dim, POSE_TARGETS);
        let mut value = ProbeSplit::new(dim, 1);
        let (mut pairs, mut starts) = (Vec::new(), Vec::new());
        let (mut decisions, mut neg_log_prob, mut terminated) = (0usize, 0.0f64, 0usize);
        for ep in &self.done {
            let rewards: Vec<f32> = ep.steps.iter().map(|s| s.reward).collect();
            let lps: Vec<f32> = ep.steps.iter().map(|s| s.log_prob).collect();
            let g = soft_returns(&rewards, &lps, f64::from(self.gamma), self.alpha);
            let len = ep.steps.len();
            terminated += ep.terminated as usize;
            decisions += len;
            neg_log_prob -= lps.iter().map(|&v| f64::from(v)).sum::<f64>();
            let part = split_of(&ep.task);
            for (t, s) in ep.steps.iter().enumerate() {
                let known = ep.terminated || len - t >= horizon;
                if known {
                    pairs.push((f64::from(s.q), g[t]));
                    if t == 0 {
                        starts.push((f64::from(s.q), g[t]));
                    }
                }
                if let Some((p, ft, fu)) = &s.probe {
                    let y: Vec<f64> = p.iter().map(|&v| f64::from(v)).collect();
                    pose.push(part, ft, fu, &y);
                    if known {
                        value.push(part, ft, fu, &[g[t]]);
                    }
                }
            }
        }
        let scores: Vec<_> = pose.scores()?.into_iter().chain(value.scores()?).collect();
        let probe = PROBE_TARGETS
            .iter()
            .zip(scores)
            .enumerate()
            .map(|(i, (&target, (trained, untrained)))| ProbeRow {
                target,
                trained,
                untrained,
                samples: if i < POSE_TARGETS { pose.sizes() } else { value.sizes() },
            })
            .collect();
        let every = pairs.len().div_ceil(4000).max(1);
        Ok(Diagnosis {
            episodes: self.done.len(),
            terminated,
            decisions,
            alpha: self.alpha,
            mean_neg_log_prob: neg_log_prob / decisions.max(1) as f64,
            probe,
            all_steps: ValueAgreement::of(&pairs),
            episode_starts: ValueAgreement::of(&starts),
            scatter: pairs.iter().step_by(every).copied().collect(),
        })
    }
}

impl Diagnosis {
    /// The report as text.
    pub fn to_text(&self, title: &str) -> String {
        let num = |v: Option<f64>| v.map_or("n/a".to_string(), |v| format!("{v:.3}"));
        let mut s = String::new();
        let _ = writeln!(s, "{title}");
        let _ = writeln!(
            s,
            "{} episodes ({} reached the goal), {} decisions; α = {:.4}, mean −log π(a|s) = {:.3}",
            self.episodes, self.terminated, self.decisions, self.alpha, self.mean_neg_log_prob
        );
        let _ = writeln!(
            s,
            "\nLinear probe: ridge regression on standardised features, fitted on the episodes of 3/5 of the\n\
             (point, yaw) starts, strength chosen on 1/5, R² on the episodes of the other 1/5"
        );
        let _ = writeln!(
            s,
            "{:<18} | {:>15} | {:>17} | {:>13}",
            "target", "trained encoder", "untrained encoder", "fit / test"
        );
        let _ = writeln!(s, "{}", "-".repeat(72));
        for r in &self.probe {
            let _ = writeln!(
                s,
                "{:<18} | {:>15} | {:>17} | {:>13}",
                r.target,
                num(r.trained),
                num(r.untrained),
                format!("{} / {}", r.samples.0, r.samples.1)
            );
        }
        let _ = writeln!(
            s,
            "\nCritic Q(s,a) against the soft Monte-Carlo return G of the sampled episode (steps whose return is known)"
        );
        let _ = writeln!(
            s,
            "{:<16} | {:>7} | {:>8} | {:>8} | {:>8} | {:>7} | {:>5}",
            "steps", "n", "mean Q", "mean G", "Q − G", "RMSE", "corr"
        );
        let _ = writeln!(s, "{}", "-".repeat(75));
        for (name, v) in [("all known", &self.all_steps), ("episode starts", &self.episode_starts)] {
            let _ = writeln!(
                s,
                "{:<16} | {:>7} | {:>8.2} | {:>8.2} | {:>8.2} | {:>7.2} | {:>5.2}",
                name, v.n, v.mean_q, v.mean_return, v.bias, v.rmse, v.correlation
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn soft_returns_match_the_hand_computed_sums() {
        // r = (1, 2, 3), log π = (−1, −2, −3), γ = 0.5, α = 0.1:
        // G₂ = 3; G₁ = 2 + 0.5·(3 + 0.3) = 3.65; G₀ = 1 + 0.5·(3.65 + 0.2) = 2.925.
        let g = soft_returns(&[1.0, 2.0, 3.0], &[-1.0, -2.0, -3.0], 0.5, 0.1);
        for (got, want) in g.iter().zip([2.925, 3.65, 3.0]) {
            assert!((got - want).abs() < 1e-6, "{g:?}");
        }
        // Without temperature: plain discounted returns.
        let g = soft_returns(&[1.0, 1.0, 1.0], &[5.0, 5.0, 5.0], 0.9, 0.0);
        assert!((g[0] - (1.0 + 0.9 + 0.81)).abs() < 1e-9);
    }

    #[test]
    fn the_known_return_horizon_leaves_at_most_one_percent() {
        let h = known_return_horizon(0.99);
        assert_eq!(h, 459);
        assert!(0.99f64.powi(h as i32) <= 0.01 && 0.99f64.powi(h as i32 - 1) > 0.01);
    }

    #[test]
    fn the_probe_split_puts_each_start_in_one_part_in_proportion() {
        let tasks = crate::protocol::validation_tasks(&pednav_sim::Scene::reference(), 2, 0);
        let mut count = [0usize; 3];
        for t in &tasks {
            count[split_of(t)] += 1;
            let same_start = tasks.iter().filter(|u| u.point == t.point && u.yaw_deg == t.yaw_deg);
            assert!(same_start.clone().all(|u| split_of(u) == split_of(t)), "both runs of a start in one part");
        }
        // 14 points × 8 yaws = 112 starts, k = 0..111: k mod 5 → 68 / 22 / 22 starts.
        assert_eq!(count, [2 * 68, 2 * 22, 2 * 22]);
        assert_eq!((known_return_horizon(1.0), known_return_horizon(0.0)), (usize::MAX, 1));
    }

    #[test]
    fn cholesky_solves_a_hand_made_system() {
        // A = [[4, 2], [2, 3]], b = [[2, 0], [1, 1]] (two right-hand sides):
        // A⁻¹ = 1/8 [[3, −2], [−2, 4]] → x₁ = (0.5, 0), x₂ = (−0.25, 0.5).
        let x = solve_spd(&[4.0, 2.0, 2.0, 3.0], &[2.0, 0.0, 1.0, 1.0], 2, 2).unwrap();
        for (got, want) in x.iter().zip([0.5, -0.25, 0.0, 0.5]) {
            assert!((got - want).abs() < 1e-12, "{x:?}");
        }
        assert!(solve_spd(&[1.0, 2.0, 2.0, 1.0], &[1.0, 1.0], 2, 1).is_err(), "indefinite refused");
    }

    /// Samples of y = 2·x₀ − x₁ + 0.5 (+ an irrelevant feature), and pure noise.
    fn linear_samples(n: usize, seed: u64) -> Samples {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut s = Samples::new(3, 2);
        for _ in 0..n {
            let x: [f32; 3] = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
            let y = 2.0 * f64::from(x[0]) - f64::from(x[1]) + 0.5;
            s.push(&x, &[y, rng.random_range(-1.0..1.0)]);
        }
        s
    }

    #[test]
    fn the_probe_recovers_a_linear_target_and_not_noise() {
        let (probe, lambda) = RidgeProbe::fit(&linear_samples(400, 1), &linear_samples(200, 2)).unwrap();
        let r2 = probe.r_squared(&linear_samples(300, 3));
        assert!(r2[0] > 0.999, "linear target: R² {r2:?} (λ {lambda:?})");
        assert!(r2[1] < 0.05, "noise cannot be predicted: R² {r2:?}");
        let p = probe.predict(&Samples { x: vec![0.5, 0.25, 0.9], y: vec![0.0, 0.0], d: 3, k: 2 });
        assert!((p[0] - 1.25).abs() < 0.01, "2·0.5 − 0.25 + 0.5 = 1.25, got {}", p[0]);
    }

    #[test]
    fn value_agreement_by_hand() {
        let v = ValueAgreement::of(&[(1.0, 0.0), (3.0, 2.0)]);
        assert_eq!((v.n, v.mean_q, v.mean_return, v.bias, v.rmse), (2, 2.0, 1.0, 1.0, 1.0));
        assert!((v.correlation - 1.0).abs() < 1e-12);
    }
}
