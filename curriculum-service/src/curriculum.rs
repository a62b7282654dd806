//! [`Curriculum`]: Algorithm 1 of the paper around any RL agent — propose a task,
//! take the episode's report, collect training data for the task-value net, train
//! it every Δ_ep episodes and clear the collected set.
//!
//! Data per variant:
//! - NavACL⁺: the augmented tasks of every step, `(φ(s_t), G_t)` for t < T, with
//!   G_t bootstrapped by f^r(φ(s_T)) when the episode was truncated at T_max. With
//!   the signal phase in the task, φ(s_t)'s position in the cycle is the start's
//!   advanced by t decision steps (dt / cycle length each).
//! - NavACL: the initial task only, `(φ(s_0), 1 if the goal was reached else 0)`.
//! - Fixed start: nothing (no net is kept).
//!
//! The PassFirstTask gate sees each first-task episode's plain discounted return
//! Σ γ^k r_{k+1} (what the agent collected, no bootstrap).

use pednav_sim::{Pose, Scene};

use crate::config::{CurriculumConfig, SignalPhase, Variant};
use crate::error::{CurriculumError, Result};
use crate::filter::Category;
use crate::net::{NetState, Target, TaskValueNet};
use crate::returns::{TaskFeatures, cycle_after, discounted_returns, task_features};
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
    /// The start's position in the signal cycle, [0, 1), when it is part of the task
    /// (the proposal's, as the actor started it).
    pub start_cycle: Option<f32>,
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
    pub collected: Vec<(TaskFeatures, f32)>,
    /// Episodes reported.
    pub episodes: u64,
}

/// Task proposal plus the task-value net and its training data.
pub struct Curriculum {
    cfg: CurriculumConfig,
    scene_goal: [f32; 2],
    scheduler: TaskScheduler,
    net: Option<TaskValueNet>,
    /// The cycle's share one decision step takes (dt / cycle length), when the signal
    /// phase is part of the task.
    cycle_step: Option<f32>,
    collected: Vec<(TaskFeatures, f32)>,
    episodes: u64,
}

/// A predictor that is never asked (fixed start proposes without scoring).
struct Unused;

impl ReturnPredictor for Unused {
    fn predict(&mut self, _: &[TaskFeatures]) -> Vec<f32> {
        unreachable!("the fixed-start curriculum scores no candidates")
    }
}

impl Curriculum {
    /// A curriculum for `scene`; `seed` drives task sampling, the net's
    /// initialisation and its minibatch order; `dt` is the seconds of a decision step
    /// (`sim.dt`: how far an episode's steps move through the signal cycle).
    pub fn new(cfg: CurriculumConfig, scene: Scene, dt: f32, seed: u64) -> Result<Curriculum> {
        cfg.validate()?;
        // The scheduler below refuses a phase in the task without traffic.
        let cycle_step = match (cfg.signal_phase, &scene.traffic) {
            (SignalPhase::Task, Some(t)) => Some((dt as f64 / t.plan.cycle_s) as f32),
            _ => None,
        };
        let target = match cfg.variant {
            Variant::NavAcl => Some(Target::Success),
            Variant::NavAclPlusSlope | Variant::NavAclPlusHard => Some(Target::Return),
            Variant::FixedStart => None,
        };
        let net = target
            .map(|t| {
                TaskValueNet::new(cfg.net.clone(), t, cycle_step.is_some(), pednav_config::rng::task_net_seed(seed))
            })
            .transpose()
            .map_err(|e| CurriculumError::Net(e.to_string()))?;
        Ok(Curriculum {
            scene_goal: scene.goal_center,
            scheduler: TaskScheduler::new(cfg.clone(), scene, seed)?,
            net,
            cycle_step,
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

    /// A curriculum continued from a saved state: [`Curriculum::new`], then
    /// [`Curriculum::restore`] (`dt`: seconds of a decision step).
    pub fn from_saved(
        cfg: CurriculumConfig,
        scene: Scene,
        dt: f32,
        seed: u64,
        state: &CurriculumState,
    ) -> Result<Curriculum> {
        let mut c = Curriculum::new(cfg, scene, dt, seed)?;
        c.restore(state)?;
        Ok(c)
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

    /// Whether the signal phase is part of the task (its net sees the cycle).
    pub fn has_cycle(&self) -> bool {
        self.cycle_step.is_some()
    }

    /// The scheduler (gate, t_c).
    pub fn scheduler(&self) -> &TaskScheduler {
        &self.scheduler
    }

    /// The task-value net's predictions for tasks (e.g. for plots); `None` for fixed start.
    pub fn predict(&mut self, features: &[TaskFeatures]) -> Option<Vec<f32>> {
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
        let start_cycle = match (self.cycle_step, ep.start_cycle) {
            (None, _) => None,
            (Some(_), Some(c)) if (0.0..1.0).contains(&c) => Some(c),
            (Some(_), c) => {
                return Err(CurriculumError::Report(format!(
                    "the signal phase is part of the task, but the episode reports its start's position in the cycle as {c:?} (needs one in [0, 1))"
                )));
            }
        };
        let features: Vec<TaskFeatures> = ep
            .poses
            .iter()
            .enumerate()
            .map(|(t, &p)| {
                let cycle = start_cycle.zip(self.cycle_step).map(|(c, step)| cycle_after(c, t, step));
                task_features(p, self.scene_goal, cycle)
            })
            .collect();
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
        EpisodeOutcome { category, poses, rewards, truncated, success: !truncated, start_cycle: None }
    }

    fn curriculum(variant: Variant) -> Curriculum {
        let cfg = CurriculumConfig { variant, candidates: 16, ..CurriculumConfig::default() };
        Curriculum::new(cfg, Scene::reference(), 0.25, 3).unwrap()
    }

    fn with_traffic(cfg: CurriculumConfig) -> Result<Curriculum> {
        let scene = Scene::reference().with_traffic(pednav_sim::TrafficLevel::Medium).unwrap();
        Curriculum::new(cfg, scene, 0.25, 3)
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
        assert_eq!(c.collected[0].0, [10.0, 0.0, 0.0].into());

        // Truncated: the bootstrap is f^r(φ(s_T)), the net's own prediction at the last pose.
        let ep = episode(Category::First, vec![-1.0, -1.0], true);
        let last = task_features(ep.poses[2], c.scene_goal, None);
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

    /// With the signal phase in the task, every proposal carries a position in the
    /// cycle, and an episode's states are collected with the start's advanced by
    /// dt / cycle per step (the reference plan's cycle is 76 s).
    #[test]
    fn the_signal_phase_in_the_task_travels_with_the_proposal_and_each_step() {
        let cfg = CurriculumConfig { candidates: 16, signal_phase: SignalPhase::Task, ..CurriculumConfig::default() };
        let mut c = with_traffic(cfg.clone()).unwrap();
        let p = c.propose().unwrap();
        assert_eq!(p.category, Category::First);
        assert!(p.cycle.is_some_and(|x| (0.0..1.0).contains(&x)), "{p:?}");
        let mut ep = episode(Category::First, vec![-1.0; 3], false);
        ep.start_cycle = Some(0.995);
        c.report(&ep).unwrap();
        let cycles: Vec<f32> = c.collected.iter().map(|x| x.0.cycle.unwrap()).collect();
        let step = 0.25 / 76.0;
        let want = [0.995, 0.995 + step, (0.995 + 2.0 * step) - 1.0];
        for (a, b) in cycles.iter().zip(want) {
            assert!((a - b).abs() < 1e-5, "{cycles:?} vs {want:?}");
        }
        ep.start_cycle = None;
        let err = c.report(&ep).unwrap_err().to_string();
        assert!(err.contains("position in the cycle"), "{err}");
        // Drawn (the default): no cycle anywhere, even with traffic.
        let mut d = with_traffic(CurriculumConfig { candidates: 16, ..CurriculumConfig::default() }).unwrap();
        assert_eq!(d.propose().unwrap().cycle, None);
        // The phase in the task without traffic is refused, naming the field.
        let err = Curriculum::new(cfg, Scene::reference(), 0.25, 3).err().unwrap().to_string();
        assert!(err.contains("signal_phase"), "{err}");
    }
}
