//! [`TaskScheduler`]: Algorithm 1's task proposal — the first task until
//! PassFirstTask, then adaptive filtering over freshly drawn candidates and a
//! category drawn from the variant's schedule.
//!
//! Usage loop (one episode per proposal):
//! ```text
//! let proposal = scheduler.propose(&mut predictor)?;       // pose + category
//! let episode = run_episode(proposal.pose);                 // actor side
//! scheduler.record_episode(proposal.category, episode.steps, episode.discounted_return);
//! ```
//!
//! Invariants: t_c only grows, and only with episodes proposed in the ACL phase;
//! a proposed pose is the first task, the fixed start, or a pose of the curriculum
//! region; a proposal carries a position in the signal cycle, in [0, 1), exactly
//! when the signal phase is part of the task (`signal_phase = "task"`: the first
//! task and the fixed start draw theirs uniformly too); all randomness comes from
//! the scheduler's seeded RNG.

use pednav_sim::{Pose, Scene};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::config::{CurriculumConfig, SignalPhase, Variant};
use crate::error::{CurriculumError, Result};
use crate::filter::{Bands, Category, Fit, bands, category_probabilities};
use crate::gate::PassFirstTask;
use crate::returns::{TaskFeatures, task_features};
use crate::sampler::TaskSampler;

/// Predicts the discounted return (NavACL⁺) or success probability (NavACL) of tasks.
pub trait ReturnPredictor {
    /// One prediction per task-feature vector φ = (dx, dy, yaw[, cycle]).
    fn predict(&mut self, features: &[TaskFeatures]) -> Vec<f32>;
}

/// A proposed task.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Proposal {
    /// Start pose.
    pub pose: Pose,
    /// Position in the signal cycle at the start, [0, 1), when it is part of the task.
    pub cycle: Option<f32>,
    /// Category it was drawn from (the one actually used, after any fallback).
    pub category: Category,
    /// The predictor's value for it, when candidates were scored.
    pub predicted: Option<f32>,
    /// The fit of that round, when candidates were scored.
    pub fit: Option<Fit>,
}

impl Proposal {
    /// A proposal made without scoring candidates (first task, fixed start).
    fn plain(pose: Pose, cycle: Option<f32>, category: Category) -> Proposal {
        Proposal { pose, cycle, category, predicted: None, fit: None }
    }
}

/// Saved state of a [`TaskScheduler`].
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct SchedulerState {
    /// The PassFirstTask gate (its window of returns and whether it opened).
    pub gate: PassFirstTask,
    /// Decision steps in the ACL phase.
    pub t_c: u64,
    /// The task-sampling RNG.
    pub rng: ChaCha8Rng,
}

/// Proposes tasks for one run.
pub struct TaskScheduler {
    cfg: CurriculumConfig,
    scene: Scene,
    sampler: TaskSampler,
    gate: PassFirstTask,
    t_c: u64,
    rng: ChaCha8Rng,
    candidates: Vec<(Pose, Option<f32>)>,
    features: Vec<TaskFeatures>,
}

impl TaskScheduler {
    /// A scheduler for `scene` driven by `seed`.
    pub fn new(cfg: CurriculumConfig, scene: Scene, seed: u64) -> Result<TaskScheduler> {
        cfg.validate()?;
        cfg.validate_for_scene(&scene.origin, !scene.enlarged_curriculum_region.is_empty())?;
        cfg.validate_for_traffic(scene.traffic_fixtures)?;
        Ok(TaskScheduler {
            sampler: TaskSampler::new(&scene, cfg.enlarged_region, cfg.max_rejections),
            gate: PassFirstTask::new(cfg.pass_window, cfg.pass_threshold),
            t_c: 0,
            rng: ChaCha8Rng::seed_from_u64(seed),
            candidates: Vec::with_capacity(cfg.candidates),
            features: Vec::with_capacity(cfg.candidates),
            scene,
            cfg,
        })
    }

    /// Is the run in the ACL phase? NavACL has no gate; NavACL⁺ enters it at
    /// PassFirstTask; the fixed start never does.
    pub fn in_acl_phase(&self) -> bool {
        match self.cfg.variant {
            Variant::NavAcl => true,
            Variant::NavAclPlusSlope | Variant::NavAclPlusHard => self.gate.passed(),
            Variant::FixedStart => false,
        }
    }

    /// Decision steps taken in the ACL phase.
    pub fn t_c(&self) -> u64 {
        self.t_c
    }

    /// The PassFirstTask gate.
    pub fn gate(&self) -> &PassFirstTask {
        &self.gate
    }

    /// What must survive a restart: the gate's window, t_c and the RNG.
    pub fn state(&self) -> SchedulerState {
        SchedulerState { gate: self.gate.clone(), t_c: self.t_c, rng: self.rng.clone() }
    }

    /// Continue from a saved [`SchedulerState`].
    pub fn restore(&mut self, state: &SchedulerState) {
        self.gate = state.gate.clone();
        self.t_c = state.t_c;
        self.rng = state.rng.clone();
    }

    /// Propose the next task.
    pub fn propose(&mut self, predictor: &mut dyn ReturnPredictor) -> Result<Proposal> {
        match self.cfg.variant {
            Variant::FixedStart => {
                let cycle = self.draw_cycle();
                return Ok(Proposal::plain(self.scene.fixed_start(), cycle, Category::Fixed));
            }
            Variant::NavAclPlusSlope | Variant::NavAclPlusHard if !self.gate.passed() => {
                let cycle = self.draw_cycle();
                return Ok(Proposal::plain(self.scene.first_task(), cycle, Category::First));
            }
            _ => {}
        }
        self.candidates.clear();
        self.features.clear();
        for _ in 0..self.cfg.candidates {
            let pose = self.sampler.sample(&self.scene, &mut self.rng)?;
            let cycle = self.draw_cycle();
            self.candidates.push((pose, cycle));
            self.features.push(task_features(pose, self.scene.goal_center, cycle));
        }
        let predictions = predictor.predict(&self.features);
        assert_eq!(predictions.len(), self.features.len(), "one prediction per candidate");
        if let Some((i, v)) = predictions.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(CurriculumError::NonFinitePrediction { value: *v, features: self.features[i] });
        }
        let fit = Fit::of(&predictions).expect("at least two candidates (validated)");
        let bands = bands(&self.cfg, fit, self.t_c);
        let category = self.draw_category();
        let (index, category) = self.pick(&bands, category, &predictions);
        let (pose, cycle) = self.candidates[index];
        Ok(Proposal { pose, cycle, category, predicted: Some(predictions[index]), fit: Some(fit) })
    }

    /// A uniform position in the signal cycle when it is part of the task (drawn after
    /// the pose, from the same RNG); `None` when the episode's seed draws it.
    fn draw_cycle(&mut self) -> Option<f32> {
        match self.cfg.signal_phase {
            SignalPhase::Drawn => None,
            SignalPhase::Task => Some(self.rng.random_range(0.0..1.0)),
        }
    }

    fn draw_category(&mut self) -> Category {
        let probs = category_probabilities(&self.cfg, self.t_c);
        let u: f32 = self.rng.random();
        let mut acc = 0.0;
        for &(c, p) in &probs {
            acc += p;
            if u < acc {
                return c;
            }
        }
        probs.last().expect("non-empty schedule").0
    }

    /// A uniformly chosen candidate of the category; when the band is empty this
    /// round (e.g. σ = 0 early on), a uniformly random candidate, reported as `Random`.
    fn pick(&mut self, bands: &Bands, category: Category, predictions: &[f32]) -> (usize, Category) {
        let members: Vec<usize> =
            (0..predictions.len()).filter(|&i| bands.contains(category, predictions[i])).collect();
        if members.is_empty() {
            (self.rng.random_range(0..predictions.len()), Category::Random)
        } else {
            (members[self.rng.random_range(0..members.len())], category)
        }
    }

    /// Record a finished episode: first-task returns feed the gate, ACL-phase
    /// episodes add their decision steps to t_c.
    pub fn record_episode(&mut self, category: Category, steps: u32, discounted_return: f32) {
        match category {
            Category::First => {
                self.gate.record(discounted_return);
            }
            Category::Fixed => {}
            Category::Easy | Category::Frontier | Category::Random | Category::Hard => self.t_c += steps as u64,
        }
    }
}
