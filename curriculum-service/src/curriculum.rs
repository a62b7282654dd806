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
use crate::net::{NetState, Target, TaskValueNet};
use crate::returns::{discounted_returns, task_features};
use crate::scheduler::{Proposal, ReturnPredictor, SchedulerState, TaskScheduler};

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

/// Everything a [`Curriculum`] needs to continue after a restart.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct CurriculumState {
    /// The variant it was saved from (a resume with another variant is refused).
    pub variant: Variant,
    /// Gate, t_c, sampling RNG.
    pub scheduler: SchedulerState,
    /// The task-value net, if the variant has one.
    pub net: Option<NetState>,
    /// Training data collected since the last round.
    pub collected: Vec<([f32; 3], f32)>,
    /// Episodes reported.
    pub episodes: u64,
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
            .map(|t| TaskValueNet::new(cfg.net.clone(), t, pednav_config::rng::task_net_seed(seed)))
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

    /// Episodes reported so far.
    pub fn episodes(&self) -> u64 {
        self.episodes
    }

    /// The state to save with the run's checkpoints.
    pub fn state(&self) -> Result<CurriculumState> {
        Ok(CurriculumState {
            variant: self.cfg.variant,
            scheduler: self.scheduler.state(),
            net: self.net.as_ref().map(|n| n.state()).transpose().map_err(|e| CurriculumError::Net(e.to_string()))?,
            collected: self.collected.clone(),
            episodes: self.episodes,
        })
    }

    /// Continue from a saved state (same variant and net architecture).
    pub fn restore(&mut self, state: &CurriculumState) -> Result<()> {
        if state.variant != self.cfg.variant {
            return Err(CurriculumError::Report(format!(
                "saved curriculum is {:?}, this run is {:?}",
                state.variant, self.cfg.variant
            )));
        }
        match (self.net.as_mut(), state.net.as_ref()) {
            (Some(net), Some(saved)) => net.restore(saved).map_err(|e| CurriculumError::Net(e.to_string()))?,
            (None, None) => {}
            _ => {
                return Err(CurriculumError::Report(
                    "saved curriculum and this variant disagree on having a net".into(),
                ));
            }
        }
        self.scheduler.restore(&state.scheduler);
        self.collected = state.collected.clone();
        self.episodes = state.episodes;
        Ok(())
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

#[cfg(test)]
mod tests {
    use super::*;

    fn episode(category: Category, rewards: Vec<f32>, truncated: bool) -> EpisodeOutcome {
        let poses = (0..=rewards.len()).map(|k| Pose { x: 10.0 + k as f32, y: 7.0, yaw: 0.0 }).collect();
        EpisodeOutcome { category, poses, rewards, truncated, success: !truncated }
    }

    fn curriculum(variant: Variant) -> Curriculum {
        let cfg = CurriculumConfig { variant, candidates: 16, ..CurriculumConfig::default() };
        Curriculum::new(cfg, Scene::reference(), 3).unwrap()
    }

    #[test]
    fn navacl_plus_collects_every_step_with_its_return() {
        let mut c = curriculum(Variant::NavAclPlusSlope);
        let s = c.report(&episode(Category::First, vec![-0.35, -0.35, 15.25], false)).unwrap();
        // γ = 0.99: G2 = 15.25, G1 = -0.35 + 0.99·15.25 = 14.7475, G0 = -0.35 + 0.99·14.7475 = 14.250025.
        let g: Vec<f32> = c.collected.iter().map(|x| x.1).collect();
        assert!((g[0] - 14.250025).abs() < 1e-4 && (g[1] - 14.7475).abs() < 1e-4 && g[2] == 15.25, "{g:?}");
        assert!((s.discounted_return - 14.250025).abs() < 1e-4);
        // Features of s_0 = (10, 7): the goal centre (20, 7) is 10 m along x.
        assert_eq!(c.collected[0].0, [10.0, 0.0, 0.0]);

        // Truncated: the bootstrap is f^r(φ(s_T)), the net's own prediction at the last pose.
        let ep = episode(Category::First, vec![-1.0, -1.0], true);
        let last = task_features(ep.poses[2], c.scene_goal);
        let f_t = c.predict(&[last]).unwrap()[0];
        c.report(&ep).unwrap();
        let g1 = c.collected[4].1;
        assert!((g1 - (-1.0 + 0.99 * f_t)).abs() < 1e-4, "G1 = {g1}, f^r(h_T) = {f_t}");
        assert_eq!(c.collected.len(), 5, "both states of the truncated episode");
    }

    #[test]
    fn navacl_collects_initial_tasks_with_success_labels_and_trains_every_ten() {
        let mut c = curriculum(Variant::NavAcl);
        for k in 0..9 {
            let s = c.report(&episode(Category::Random, vec![-1.0; 4], k % 2 == 0)).unwrap();
            assert!(s.trained_loss.is_none());
        }
        assert_eq!(c.collected.len(), 9, "one sample per episode");
        assert_eq!(c.collected[0].1, 0.0, "truncated = not reached");
        assert_eq!(c.collected[1].1, 1.0);
        let s = c.report(&episode(Category::Random, vec![-1.0; 4], false)).unwrap();
        assert!(s.trained_loss.is_some_and(f32::is_finite), "Δ_ep = 10 triggers training");
        assert!(c.collected.is_empty(), "the collected set is cleared after training");
    }

    #[test]
    fn state_round_trip_continues_identically() {
        let mut a = curriculum(Variant::NavAclPlusHard);
        for k in 0..35 {
            a.report(&episode(Category::First, vec![0.5; 3 + k % 4], false)).unwrap();
        }
        assert!(a.scheduler().in_acl_phase(), "30 good first-task returns open the gate");
        let saved = a.state().unwrap();
        let json = serde_json::to_string(&saved).unwrap();
        let mut b = curriculum(Variant::NavAclPlusHard);
        b.restore(&serde_json::from_str(&json).unwrap()).unwrap();
        for _ in 0..3 {
            assert_eq!(a.propose().unwrap(), b.propose().unwrap());
        }
        assert_eq!(a.episodes(), b.episodes());
        let mut other = curriculum(Variant::NavAcl);
        assert!(other.restore(&saved).is_err(), "another variant is refused");
    }

    #[test]
    fn a_report_with_the_wrong_number_of_poses_is_rejected() {
        let mut c = curriculum(Variant::NavAclPlusHard);
        let mut ep = episode(Category::First, vec![-1.0; 3], true);
        ep.poses.pop();
        assert!(matches!(c.report(&ep), Err(CurriculumError::Report(_))));
    }
}
