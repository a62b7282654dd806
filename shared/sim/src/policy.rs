//! Who chooses the actions: the one [`Policy`] trait every acting loop drives —
//! the actors, the evaluator and `pednav-sim record` — and the reference
//! policies that need nothing but the simulator: [`RandomPolicy`] (the random-walk
//! baseline of Table III), [`OraclePolicy`] (the planner's greedy action) and
//! [`FixedPolicy`] (one action always, for looking at the renderer). The learned
//! policy (`pednav_policy::ActingPolicy`) implements the same trait.
//!
//! The protocol, for a batch of environments in a [`VecEnv`]: after
//! `VecEnv::reset(e, …)` the loop calls [`Policy::begin`] with the episode's seed
//! (and its first frame when [`Policy::needs_frames`]); every step it calls
//! [`Policy::act`] once for all environments, steps them, and calls
//! [`Policy::observe`] for each environment whose episode goes on.
//!
//! Invariant: a policy's actions depend only on what it was shown through these
//! calls (and, for the learned policy, its weights): no policy reads hidden state
//! of the loop, so the same calls give the same actions in any loop.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::env::VecEnv;
use crate::oracle::Oracle;
use crate::pedestrian::Action;

/// The error a policy reports (a learned policy's tensor errors, for one).
pub type PolicyError = Box<dyn std::error::Error + Send + Sync>;

/// Chooses one action per environment of a [`VecEnv`].
pub trait Policy {
    /// Whether the policy reads rendered frames; the loop renders only for such
    /// a policy and passes each environment's frame to `begin` and `observe`.
    fn needs_frames(&self) -> bool {
        false
    }

    /// Environment `env` starts an episode with seed `seed` (the one passed to
    /// `VecEnv::reset`); `frame` is its first view when [`Policy::needs_frames`].
    fn begin(&mut self, env: usize, seed: u64, frame: Option<&[u8]>) -> Result<(), PolicyError> {
        let _ = (env, seed, frame);
        Ok(())
    }

    /// Environment `env` took `action`, received `reward` and its episode goes on;
    /// `frame` is its new view when [`Policy::needs_frames`].
    fn observe(&mut self, env: usize, action: Action, reward: f32, frame: Option<&[u8]>) -> Result<(), PolicyError> {
        let _ = (env, action, reward, frame);
        Ok(())
    }

    /// One action per environment of `envs` into `actions` (every environment is
    /// in an episode).
    fn act(&mut self, envs: &VecEnv, actions: &mut [Action]) -> Result<(), PolicyError>;
}

/// Every action component uniform in [−1, 1): the random walk.
pub struct RandomPolicy {
    rng: ChaCha8Rng,
}

impl RandomPolicy {
    /// A random walk drawing from its own generator seeded with `seed`.
    pub fn new(seed: u64) -> RandomPolicy {
        RandomPolicy { rng: ChaCha8Rng::seed_from_u64(seed) }
    }

    /// A random walk drawing from `rng`.
    pub fn from_rng(rng: ChaCha8Rng) -> RandomPolicy {
        RandomPolicy { rng }
    }
}

impl Policy for RandomPolicy {
    fn act(&mut self, _envs: &VecEnv, actions: &mut [Action]) -> Result<(), PolicyError> {
        for a in actions.iter_mut() {
            *a = std::array::from_fn(|_| self.rng.random_range(-1.0..1.0));
        }
        Ok(())
    }
}

/// The action of standing still: no speed, no turn, head straight ahead.
pub const STAND_STILL: Action = [-1.0, 0.0, 0.0];

/// Standing still where the episode starts ([`STAND_STILL`]): the return of never
/// crossing, a reference for what waiting for ever is worth.
pub struct StandStillPolicy;

impl Policy for StandStillPolicy {
    fn act(&mut self, _envs: &VecEnv, actions: &mut [Action]) -> Result<(), PolicyError> {
        actions.fill(STAND_STILL);
        Ok(())
    }
}

/// The oracle planner's greedy action ([`Oracle::best_action`]) in every environment.
///
/// With traffic it also knows the signal plan and sees the vehicles: from off the
/// road it does not step onto a zebra that does not show WALK, nor onto the road or
/// a zebra where a moving vehicle would be within 2 s (plus 3 m) of it — it stands
/// and waits instead ([`traffic_gate`]). The plan itself ignores traffic, so this
/// is a safe reference, not an optimal one over time in the cycle.
pub struct OraclePolicy {
    oracle: Oracle,
    gate: bool,
}

impl OraclePolicy {
    /// Acts greedily on `oracle`'s planned values (planned on the world the
    /// environments run in).
    pub fn new(oracle: Oracle) -> OraclePolicy {
        OraclePolicy { oracle, gate: true }
    }

    /// The plan of the empty crossing walked through signals and vehicles as if
    /// there were none (no [`traffic_gate`]): what running against the signal costs.
    pub fn ignoring_traffic(oracle: Oracle) -> OraclePolicy {
        OraclePolicy { oracle, gate: false }
    }
}

impl Policy for OraclePolicy {
    fn act(&mut self, envs: &VecEnv, actions: &mut [Action]) -> Result<(), PolicyError> {
        let world = envs.world();
        for (e, a) in actions.iter_mut().enumerate() {
            *a = self.oracle.best_action(world, envs.pedestrian(e));
            if let Some(state) = envs.traffic(e).filter(|_| self.gate) {
                *a = traffic_gate(world, state, envs.pedestrian(e), *a);
            }
        }
        Ok(())
    }
}

/// Stand still instead of `action` when it would step from off the road onto a
/// zebra that does not show WALK, or onto the road or a zebra in front of a moving
/// vehicle (within 2 s of travel plus 3 m, upstream along its lane, across its
/// width plus 1 m) that is not held by a red stop line between it and the agent.
pub fn traffic_gate(
    world: &crate::SimWorld,
    state: &crate::TrafficState,
    p: &crate::Pedestrian,
    action: Action,
) -> Action {
    use crate::RegionKind;
    let Some((traffic, _)) = &world.traffic else { return action };
    let here = world.map.kind_at(p.pose.x, p.pose.y);
    if matches!(here, RegionKind::Road | RegionKind::Zebra) {
        return action; // never freeze on the road
    }
    let mut q = *p;
    let t = q.step(action, world);
    let next = [t.pose.x, t.pose.y];
    let wait = [-1.0, 0.0, action[2]];
    if let Some(z) = traffic.zebra_at(next[0], next[1]) {
        if traffic.plan.pedestrian(z, state.t) != crate::traffic::PedestrianSignal::Walk {
            return wait;
        }
    }
    if matches!(t.region, RegionKind::Road | RegionKind::Zebra) {
        for (lane, lt) in traffic.lanes.iter().zip(&state.lanes) {
            let (s, off) = lane.local(next);
            let held = traffic.plan.vehicle(lane.road, state.t) != crate::traffic::VehicleSignal::Green;
            for v in lt.vehicles.iter().filter(|v| v.v > 0.5) {
                if held && v.s <= lane.stop_s && s > lane.stop_s {
                    continue;
                }
                let ahead = s - v.s;
                if off.abs() <= 0.5 * v.width + 1.0 && ahead > -v.length && ahead < 2.0 * v.v + 3.0 {
                    return wait;
                }
            }
        }
    }
    action
}

/// The same action in every environment at every step.
pub struct FixedPolicy(pub Action);

impl Policy for FixedPolicy {
    fn act(&mut self, _envs: &VecEnv, actions: &mut [Action]) -> Result<(), PolicyError> {
        actions.fill(self.0);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::oracle::OracleConfig;
    use crate::{BackendChoice, ObsMode, Pose, Scene, SimConfig, SimWorld};

    fn envs(m: usize) -> VecEnv {
        let world = SimWorld::new(Scene::reference(), SimConfig { obs_mode: ObsMode::State, ..SimConfig::default() })
            .expect("reference scene");
        let mut envs = VecEnv::new(Arc::new(world), m, BackendChoice::Auto).expect("no renderer in state mode");
        let p = envs.world().scene.validation_points()[0];
        for e in 0..m {
            envs.reset(e, Pose::from_degrees(p.x, p.y, p.favourable_yaw_deg), e as u64).unwrap();
        }
        envs
    }

    #[test]
    fn random_actions_are_in_range_and_seeded() {
        let envs = envs(3);
        let (mut a, mut b) = (RandomPolicy::new(7), RandomPolicy::new(7));
        let (mut x, mut y) = (vec![[0.0; 3]; 3], vec![[0.0; 3]; 3]);
        for _ in 0..50 {
            a.act(&envs, &mut x).unwrap();
            b.act(&envs, &mut y).unwrap();
            assert_eq!(x, y);
            assert!(x.iter().flatten().all(|v| (-1.0..1.0).contains(v)));
        }
    }

    #[test]
    fn oracle_policy_is_the_planners_greedy_action() {
        let envs = envs(2);
        let oracle = Oracle::plan(envs.world(), OracleConfig::default());
        let expected: Vec<Action> = (0..2).map(|e| oracle.best_action(envs.world(), envs.pedestrian(e))).collect();
        let mut policy = OraclePolicy::new(oracle);
        let mut got = vec![[9.0; 3]; 2];
        policy.act(&envs, &mut got).unwrap();
        assert_eq!(got, expected);
        assert!(!policy.needs_frames());
    }

    /// Standing still keeps the start pose: no speed, no turn (and the head ahead).
    #[test]
    fn standing_still_never_moves() {
        let mut envs = envs(2);
        let start = envs.pedestrian(0).pose;
        let mut actions = vec![[0.5; 3]; 2];
        for _ in 0..20 {
            StandStillPolicy.act(&envs, &mut actions).unwrap();
            assert_eq!(actions, vec![[-1.0, 0.0, 0.0]; 2]);
            envs.step(&actions).unwrap();
        }
        assert_eq!(envs.pedestrian(0).pose, start);
    }
}
