//! [`Curriculum`]: Algorithm 1 of the paper around any RL agent — propose a task,
//! take the episode's report, collect training data for the task-value net, train
//! it every Δ_ep episodes and clear the collected set.
//!
//! Data per variant:
//! - NavACL⁺: the augmented tasks of every step, `(φ(s_t), G_t)` for t < T, with
//!   G_t bootstrapped by f^r(φ(s_T)) when the episode was truncated at T_max.
//! - NavACL: the initial task only, `(φ(s_0), 1 if the goal was reached else 0)`.
//! - Fixed start: nothing (no net is kept).
//!
//! The PassFirstTask gate sees each first-task episode's plain discounted return
//! Σ γ^k r_{k+1} (what the agent collected, no bootstrap).

use pednav_sim::{Pose, Scene};

use crate::config::{CurriculumConfig, Variant};
use crate::error::{CurriculumError, Result};
use crate::filter::Category;
use crate::net::{Target, TaskValueNet};
use crate::returns::{discounted_returns, task_features};
use crate::scheduler::{Proposal, ReturnPredictor, TaskScheduler};

/// What the actor reports at the end of an episode.
#[derive(Debug, Clone, PartialEq)]
pub struct EpisodeOutcome {
    /// The category the task was proposed from.
    pub category: Category,
    /// Poses s_0 … s_T: one more than `rewards`.
    pub poses: Vec<Pose>,
    /// Rewards r_1 … r_T.
    pub rewards: Vec<f32>,
    /// The episode hit T_max (its returns are bootstrapped).
    pub truncated: bool,
    /// The episode reached the goal.
    pub success: bool,
}

/// What [`Curriculum::report`] did with an episode.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReportSummary {
    /// The episode's plain discounted return.
    pub discounted_return: f32,
    /// Loss of the training round this report triggered, if any.
    pub trained_loss: Option<f32>,
}

/// Task proposal plus the task-value net and its training data.
pub struct Curriculum {
    cfg: CurriculumConfig,
    scene_goal: [f32; 2],
    scheduler: TaskScheduler,
    net: Option<TaskValueNet>,
    collected: Vec<([f32; 3], f32)>,
    episodes: u64,
}

/// A predictor that is never asked (fixed start proposes without scoring).
struct Unused;

impl ReturnPredictor for Unused {
    fn predict(&mut self, _: &[[f32; 3]]) -> Vec<f32> {
        unreachable!("the fixed-start curriculum scores no candidates")
    }
}

impl Curriculum {
    /// A curriculum for `scene`; `seed` drives task sampling, the net's
    /// initialisation and its minibatch order.
    pub fn new(cfg: CurriculumConfig, scene: Scene, seed: u64) -> Result<Curriculum> {
        cfg.validate()?;
        let target = match cfg.variant {
            Variant::NavAcl => Some(Target::Success),
            Variant::NavAclPlusSlope | Variant::NavAclPlusHard => Some(Target::Return),
            Variant::FixedStart => None,
        };
        let net = target
            .map(|t| TaskValueNet::new(cfg.net.clone(), t, seed ^ 0x6E65_7477))
            .transpose()
            .map_err(|e| CurriculumError::Net(e.to_string()))?;
        Ok(Curriculum {
            scene_goal: scene.goal_center,
            scheduler: TaskScheduler::new(cfg.clone(), scene, seed)?,
            net,
            collected: Vec::new(),
            episodes: 0,
            cfg,
        })
    }

    /// Propose the next task.
    pub fn propose(&mut self) -> Result<Proposal> {
        match self.net.as_mut() {
            Some(net) => self.scheduler.propose(net),
            None => self.scheduler.propose(&mut Unused),
        }
    }

    /// The scheduler (gate, t_c).
    pub fn scheduler(&self) -> &TaskScheduler {
        &self.scheduler
    }

    /// The task-value net's predictions for tasks (e.g. for plots); `None` for fixed start.
    pub fn predict(&mut self, features: &[[f32; 3]]) -> Option<Vec<f32>> {
        self.net.as_mut().map(|n| n.predict(features))
    }

    /// Take an episode's report (Algorithm 1, lines 9–16).
    pub fn report(&mut self, ep: &EpisodeOutcome) -> Result<ReportSummary> {
        if ep.poses.len() != ep.rewards.len() + 1 {
            return Err(CurriculumError::Report(format!(
                "an episode of {} rewards needs {} poses (s_0 … s_T), got {}",
                ep.rewards.len(),
                ep.rewards.len() + 1,
                ep.poses.len()
            )));
        }
        let gamma = self.cfg.gamma;
        let plain = discounted_returns(&ep.rewards, gamma, None).first().copied().unwrap_or(0.0);
        let features: Vec<[f32; 3]> = ep.poses.iter().map(|&p| task_features(p, self.scene_goal)).collect();
        match (self.cfg.variant, self.net.as_mut()) {
            (Variant::NavAclPlusSlope | Variant::NavAclPlusHard, Some(net)) => {
                let bootstrap = ep.truncated.then(|| net.predict(&features[features.len() - 1..])[0]);
                let returns = discounted_returns(&ep.rewards, gamma, bootstrap);
                self.collected.extend(features.iter().copied().zip(returns));
            }
            (Variant::NavAcl, Some(_)) => {
                self.collected.push((features[0], if ep.success { 1.0 } else { 0.0 }));
            }
            _ => {}
        }
        self.scheduler.record_episode(ep.category, ep.rewards.len() as u32, plain);
        self.episodes += 1;
        let mut trained_loss = None;
        if self.episodes.is_multiple_of(self.cfg.train_every_episodes as u64) && !self.collected.is_empty() {
            if let Some(net) = self.net.as_mut() {
                trained_loss = Some(net.train(&self.collected).map_err(|e| CurriculumError::Net(e.to_string()))?);
            }
            self.collected.clear();
        }
        Ok(ReportSummary { discounted_return: plain, trained_loss })
    }
}
