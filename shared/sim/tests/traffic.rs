//! Traffic: the signal plan's conflict monitor and range checks, the traffic model
//! measured as traffic engineers would, determinism per episode seed, and what
//! traffic does to the agent (hits, don't-walk entries, bumps).

use std::sync::Arc;

use pednav_sim::traffic::measure::{Bench, measure};
use pednav_sim::traffic::{PedestrianSignal, TrafficSettings};
use pednav_sim::{
    BackendChoice, GroundSignals, ObsMode, Pose, Scene, SimConfig, SimError, SimWorld, TrafficLevel, VecEnv,
};

fn world(level: TrafficLevel, obs: ObsMode) -> Arc<SimWorld> {
    let cfg = SimConfig { traffic: level, obs_mode: obs, image_size: 42, ..SimConfig::default() };
    Arc::new(SimWorld::new(Scene::reference(), cfg).expect("reference world with traffic"))
}

/// The reference scene's text with one replacement made in its traffic section.
fn edited(from: &str, to: &str) -> Result<Scene, SimError> {
    let text = pednav_sim::scene::REFERENCE_SCENE_TOML;
    let at = text.find("[traffic]").expect("the reference scene has traffic");
    let (head, tail) = text.split_at(at);
    assert!(tail.contains(from), "{from:?} not in the traffic section");
    Scene::from_toml_str(&format!("{head}{}", tail.replacen(from, to, 1)), "edited")
}

fn invalid_field(r: Result<Scene, SimError>) -> (String, String) {
    match r {
        Err(SimError::SceneInvalid { field, message, .. }) => (field, message),
        Err(e) => panic!("expected SceneInvalid, got {e}"),
        Ok(_) => panic!("expected the edit to be refused"),
    }
}

#[test]
fn the_conflict_monitor_refuses_conflicting_greens_and_walks_beside_a_crossing_green() {
    let (f, m) = invalid_field(edited("green = [\"ns\"]", "green = [\"ns\", \"ew\"]"));
    assert_eq!(f, "traffic.signal.phases[0]");
    assert!(m.contains("conflicting") && m.contains("\"ns\"") && m.contains("\"ew\""), "{m}");
    let (f, m) = invalid_field(edited("walk = [0, 1]", "walk = [0, 2]"));
    assert_eq!(f, "traffic.signal.phases[0]");
    assert!(m.contains("zebra 2") && m.contains("\"ns\""), "{m}");
}

#[test]
fn every_traffic_field_is_range_checked_with_its_name() {
    let cases = [
        ("walk_s = 12.0", "walk_s = 5.0", "traffic.signal.phases[0].walk_s"),
        ("clearance_s = 10.0", "clearance_s = 8.0", "traffic.signal.phases[0].clearance_s"),
        ("green_s = 32.0", "green_s = 0.0", "traffic.signal.phases[0].green_s"),
        ("amber_s = 4.0", "amber_s = -1.0", "traffic.signal.amber_s"),
        ("flow = 450.0", "flow = -10.0", "traffic.levels.medium.flow"),
        ("stop_line = [-16.0, -2.5]", "stop_line = [-16.0, -12.5]", "traffic.lanes[0].stop_line"),
        (
            "from = [-200.0, -2.5]\nto = [250.0, -2.5]\nstop_line = [-16.0, -2.5]",
            "from = [-200.0, -7.0]\nto = [250.0, -7.0]\nstop_line = [-16.0, -7.0]",
            "traffic.lanes[0]",
        ),
        ("time_headway = 1.1", "time_headway = 0.0", "traffic.driver.time_headway"),
        ("non_yielding_share = 0.05", "non_yielding_share = 1.5", "traffic.driver.non_yielding_share"),
        ("radius = 0.3\nspeed", "radius = 3.0\nspeed", "traffic.walkers.radius"),
        ("{ a = 4, b = 5, crossing = 0 }", "{ a = 4, b = 5, crossing = 9 }", "traffic.walkers.edges[16].crossing"),
        ("{ a = 4, b = 5, crossing = 0 }", "{ a = 4, b = 13, crossing = 0 }", "traffic.walkers.edges[16]"),
        ("[7.0, -7.0], [7.0, 7.0]", "[7.0, -2.0], [7.0, 7.0]", "traffic.walkers.nodes[0]"),
        ("vehicle_hit = -300.0", "vehicle_hit = 5.0", "traffic.rewards.vehicle_hit"),
        ("vehicle_hit = -300.0", "vehicle_hit = -300.0\ndont_walk_entry = 1.0", "traffic.rewards.dont_walk_entry"),
        ("vehicle_hit = -300.0", "vehicle_hit = -300.0\ndont_walk_entry = nan", "traffic.rewards.dont_walk_entry"),
        ("facing_deg = 90.0, zebra = 0", "facing_deg = 45.0, zebra = 0", "traffic.heads[0].facing_deg"),
        ("pole = [10.4, -5.6], facing_deg = 90.0", "pole = [11.4, -5.6], facing_deg = 90.0", "traffic.heads[0].pole"),
        ("substeps = 2", "substeps = 0", "traffic.substeps"),
    ];
    for (from, to, field) in cases {
        let (f, m) = invalid_field(edited(from, to));
        assert_eq!(f, field, "{to}: {m}");
    }
    // A malformed section is a parse error naming the key, never a panic.
    match edited("amber_s = 4.0", "amber = 4.0") {
        Err(SimError::SceneParse { message, .. }) => assert!(message.contains("amber"), "{message}"),
        other => panic!("expected a parse error, got {:?}", other.map(|_| ())),
    }
    // Run-level overrides are checked too.
    let bad = SimConfig { traffic: TrafficLevel::Medium, traffic_flow: Some(-1.0), ..SimConfig::default() };
    assert!(matches!(bad.validate(), Err(SimError::Config { field: "traffic_flow", .. })));
    // Traffic on a scene without a traffic section is refused with the reason.
    let plain = pednav_sim::scene::REFERENCE_SCENE_TOML;
    let cut = &plain[..plain.find("\n# ---- traffic").expect("traffic section")];
    let scene = Scene::from_toml_str(cut, "no-traffic").unwrap();
    let err = SimWorld::new(scene, SimConfig { traffic: TrafficLevel::Light, ..SimConfig::default() }).err().unwrap();
    assert!(err.to_string().contains("[traffic] section"), "{err}");
}

#[test]
fn measured_flow_is_the_set_flow_below_saturation_and_queues_discharge_at_a_saturation_flow() {
    let w = world(TrafficLevel::Medium, ObsMode::State);
    let (traffic, medium) = w.traffic.clone().unwrap();
    let bench = Bench { ground: &w.physics, far: [-1e4, -1e4], agent_radius: w.config.agent_radius, dt: w.config.dt };
    for flow in [200.0, 450.0] {
        let r = measure(bench, &traffic, TrafficSettings { flow, walkers: 0, ..medium }, 3600.0, 3);
        assert!((r.mean_flow / flow as f64 - 1.0).abs() < 0.10, "flow {flow}: measured {:.1} veh/h/lane", r.mean_flow);
        assert!(r.backlog < 4, "below capacity the entries keep up: backlog {}", r.backlog);
    }
    let r = measure(bench, &traffic, TrafficSettings { flow: 1800.0, walkers: 0, ..medium }, 1800.0, 3);
    assert!(r.headways > 50, "{r:?}");
    assert!((1400.0..=2100.0).contains(&r.saturation_flow), "saturation flow {:.0} veh/h of green", r.saturation_flow);
}

#[test]
fn vehicles_never_overlap_and_walkers_never_stand_in_the_agent() {
    let w = world(TrafficLevel::Heavy, ObsMode::State);
    let mut env = VecEnv::new(w.clone(), 1, BackendChoice::Auto).unwrap();
    // Standing on the south kerb of the east zebra, where walkers pass and wait.
    let start = Pose::from_degrees(13.0, -6.2, 90.0);
    let (traffic, _) = w.traffic.clone().unwrap();
    for step in 0..4800 {
        if step % 1200 == 0 {
            env.reset(0, start, 5 + step / 1200).unwrap();
        }
        let t = env.step(&[[-1.0, 0.0, 0.0]]).unwrap()[0];
        assert!(!t.safety.vehicle_hit && !t.terminated);
        let state = env.traffic(0).unwrap();
        for lt in &state.lanes {
            for pair in lt.vehicles.iter().collect::<Vec<_>>().windows(2) {
                assert!(pair[1].s <= pair[0].s - pair[0].length - 0.09, "overlap {:?}", pair);
            }
            assert!(lt.vehicles.iter().all(|v| v.v >= 0.0));
        }
        // Nor across lanes: no two vehicles of crossing lanes cover their crossing point at once.
        for (i, lane) in traffic.lanes.iter().enumerate() {
            for &(j, si, sj) in &lane.conflicts {
                for a in &state.lanes[i].vehicles {
                    for b in &state.lanes[j].vehicles {
                        let a_covers = a.s >= si - 0.5 * b.width && a.s - a.length <= si + 0.5 * b.width;
                        let b_covers = b.s >= sj - 0.5 * a.width && b.s - b.length <= sj + 0.5 * a.width;
                        assert!(
                            !(a_covers && b_covers),
                            "lanes {i} and {j} overlap in the crossing box at t = {:.2}: {a:?} at {si} / {b:?} at {sj}; signals {:?} {:?}",
                            state.t,
                            traffic.plan.vehicle(lane.road, state.t),
                            traffic.plan.vehicle(traffic.lanes[j].road, state.t)
                        );
                    }
                }
            }
        }
        for wk in &state.walkers {
            let d = (wk.pos[0] - start.x).hypot(wk.pos[1] - start.y);
            assert!(d >= traffic.walkers.radius + w.config.agent_radius - 1e-4, "walker at {d} m");
        }
    }
}

#[test]
fn the_same_seed_replays_the_same_traffic_and_another_seed_does_not() {
    let w = world(TrafficLevel::Medium, ObsMode::State);
    let run = |seed: u64| {
        let mut env = VecEnv::new(w.clone(), 1, BackendChoice::Auto).unwrap();
        env.reset(0, Pose::from_degrees(14.0, -7.0, 180.0), seed).unwrap();
        let mut trace = Vec::new();
        for k in 0..200 {
            let t = env.step(&[[0.3 * ((k % 7) as f32 - 3.0) / 3.0, 0.2, 0.0]]).unwrap()[0];
            let s = env.traffic(0).unwrap();
            let cars: Vec<(u32, u32)> =
                s.lanes.iter().flat_map(|l| l.vehicles.iter().map(|v| (v.s.to_bits(), v.v.to_bits()))).collect();
            let walkers: Vec<[u32; 2]> = s.walkers.iter().map(|w| w.pos.map(f32::to_bits)).collect();
            trace.push((t.reward.to_bits(), t.pose.x.to_bits(), cars, walkers));
            if t.terminated || t.truncated {
                break;
            }
        }
        trace
    };
    assert_eq!(run(11), run(11));
    assert_ne!(run(11), run(12));
}

/// A task may set the start's position in the signal cycle (the curriculum's
/// `signal_phase = "task"`): the episode starts there, the same seed and position give
/// the same traffic, and a position without traffic or outside [0, 1) is refused.
#[test]
fn a_task_sets_the_start_s_position_in_the_cycle() {
    let w = world(TrafficLevel::Medium, ObsMode::State);
    let cycle_s = w.traffic.as_ref().unwrap().0.plan.cycle_s;
    let pose = Pose::from_degrees(14.0, -7.0, 180.0);
    let mut env = VecEnv::new(w.clone(), 1, BackendChoice::Auto).unwrap();
    for c in [0.0f32, 0.25, 0.6, 0.999] {
        env.reset_in_cycle(0, pose, 5, Some(c)).unwrap();
        let t = env.traffic(0).unwrap().t;
        assert!((t - c as f64 * cycle_s).abs() < 1e-9, "cycle {c}: t = {t}");
    }
    let traffic = |env: &VecEnv| {
        let s = env.traffic(0).unwrap();
        let cars: Vec<[u32; 2]> =
            s.lanes.iter().flat_map(|l| l.vehicles.iter().map(|v| [v.s.to_bits(), v.v.to_bits()])).collect();
        (cars, s.walkers.iter().map(|w| w.pos.map(f32::to_bits)).collect::<Vec<_>>())
    };
    env.reset_in_cycle(0, pose, 5, Some(0.3)).unwrap();
    let first = traffic(&env);
    env.reset(0, pose, 6).unwrap();
    env.reset_in_cycle(0, pose, 5, Some(0.3)).unwrap();
    assert_eq!(first, traffic(&env), "the same seed and position, the same traffic");
    for bad in [1.0f32, -0.1, f32::NAN] {
        assert!(matches!(env.reset_in_cycle(0, pose, 5, Some(bad)), Err(SimError::CyclePosition { .. })), "{bad}");
    }
    let mut off = VecEnv::new(world(TrafficLevel::Off, ObsMode::State), 1, BackendChoice::Auto).unwrap();
    let err = off.reset_in_cycle(0, pose, 5, Some(0.5)).unwrap_err().to_string();
    assert!(err.contains("sim.traffic"), "{err}");
}

/// Reset environment 0 at `pose` with the first seed (from 0) whose start shows
/// `want` on the east zebra; that seed.
fn reset_showing(env: &mut VecEnv, pose: Pose, want: PedestrianSignal) -> u64 {
    for seed in 0..200 {
        env.reset(0, pose, seed).unwrap();
        let s = env.traffic(0).unwrap();
        if env.world().traffic.as_ref().unwrap().0.plan.pedestrian(0, s.t) == want {
            return seed;
        }
    }
    panic!("no seed under 200 starts with {want:?}");
}

#[test]
fn stepping_onto_a_zebra_outside_walk_is_paid_as_the_road_and_counted() {
    let w = world(TrafficLevel::Light, ObsMode::State);
    let mut env = VecEnv::new(w.clone(), 1, BackendChoice::Auto).unwrap();
    let kerb = Pose::from_degrees(13.0, -5.3, 90.0);
    let rewards = w.scene.rewards().clone();
    // One step at 2 m/s goes 0.5 m north: onto the zebra (y > −5).
    reset_showing(&mut env, kerb, PedestrianSignal::DontWalk);
    let t = env.step(&[[1.0, 0.0, 0.0]]).unwrap()[0];
    assert_eq!(t.region, pednav_sim::RegionKind::Zebra);
    assert!(t.safety.dont_walk_entry);
    assert_eq!(t.reward, rewards.step_reward(pednav_sim::RegionKind::Road, 2.0, t.collided));
    reset_showing(&mut env, kerb, PedestrianSignal::Walk);
    let t = env.step(&[[1.0, 0.0, 0.0]]).unwrap()[0];
    assert!(!t.safety.dont_walk_entry);
    assert_eq!(t.reward, rewards.step_reward(pednav_sim::RegionKind::Zebra, 2.0, t.collided));
}

/// Light traffic, state observations, −100 for entering a zebra outside WALK.
fn light_world_paying_100_per_entry() -> Arc<SimWorld> {
    let cfg = SimConfig {
        traffic: TrafficLevel::Light,
        traffic_dont_walk_entry: Some(-100.0),
        obs_mode: ObsMode::State,
        ..SimConfig::default()
    };
    Arc::new(SimWorld::new(Scene::reference(), cfg).unwrap())
}

#[test]
fn the_dont_walk_entry_reward_is_paid_once_on_the_step_onto_the_zebra() {
    let w = light_world_paying_100_per_entry();
    assert_eq!(w.traffic.as_ref().unwrap().0.dont_walk_entry, 0.0, "the built-in scene's own reward is 0");
    let rewards = w.scene.rewards().clone();
    let road = |t: &pednav_sim::Transition| rewards.step_reward(pednav_sim::RegionKind::Road, 2.0, t.collided);
    let mut env = VecEnv::new(w.clone(), 1, BackendChoice::Auto).unwrap();
    let kerb = Pose::from_degrees(13.0, -5.3, 90.0);
    reset_showing(&mut env, kerb, PedestrianSignal::DontWalk);
    let onto = env.step(&[[1.0, 0.0, 0.0]]).unwrap()[0];
    assert!(onto.safety.dont_walk_entry);
    assert_eq!(onto.reward, road(&onto) - 100.0, "the road's pay and the entry reward");
    let on = env.step(&[[1.0, 0.0, 0.0]]).unwrap()[0];
    assert_eq!(on.region, pednav_sim::RegionKind::Zebra);
    assert!(!on.safety.dont_walk_entry && on.safety.against_signal);
    assert_eq!(on.reward, road(&on), "the next step on the zebra pays the road alone");
    reset_showing(&mut env, kerb, PedestrianSignal::Walk);
    let lawful = env.step(&[[1.0, 0.0, 0.0]]).unwrap()[0];
    assert_eq!(lawful.reward, rewards.step_reward(pednav_sim::RegionKind::Zebra, 2.0, lawful.collided));
}

#[test]
fn a_set_entry_reward_applies_from_the_next_reset_and_is_range_checked() {
    let w = light_world_paying_100_per_entry();
    let rewards = w.scene.rewards().clone();
    let road = |t: &pednav_sim::Transition| rewards.step_reward(pednav_sim::RegionKind::Road, 2.0, t.collided);
    let mut env = VecEnv::new(w.clone(), 1, BackendChoice::Auto).unwrap();
    assert_eq!(env.world_dont_walk_entry(), Some(-100.0));
    let kerb = Pose::from_degrees(13.0, -5.3, 90.0);
    let seed = reset_showing(&mut env, kerb, PedestrianSignal::DontWalk);
    env.set_dont_walk_entry(-25.0).unwrap();
    let under_way = env.step(&[[1.0, 0.0, 0.0]]).unwrap()[0];
    assert!(under_way.safety.dont_walk_entry);
    assert_eq!(under_way.reward, road(&under_way) - 100.0, "the episode under way keeps its reward");
    env.reset(0, kerb, seed).unwrap();
    let next = env.step(&[[1.0, 0.0, 0.0]]).unwrap()[0];
    assert!(next.safety.dont_walk_entry);
    assert_eq!(next.reward, road(&next) - 25.0, "the next episode pays the set reward");
    for bad in [1.0, -1001.0, f32::NAN] {
        let e = env.set_dont_walk_entry(bad).unwrap_err().to_string();
        assert!(e.contains("dont_walk_entry") && e.contains("[-1000, 0]"), "{e}");
    }
    let mut off = VecEnv::new(world(TrafficLevel::Off, ObsMode::State), 1, BackendChoice::Auto).unwrap();
    assert_eq!(off.world_dont_walk_entry(), None);
    let e = off.set_dont_walk_entry(-10.0).unwrap_err().to_string();
    assert!(e.contains("dont_walk_entry") && e.contains("traffic"), "{e}");
}

#[test]
fn a_vehicle_that_drives_into_the_agent_ends_the_episode_with_the_hit_penalty() {
    // Nobody yields, heavy flow; the agent stands in the eastbound lane inside the crossing box.
    let cfg = SimConfig {
        traffic: TrafficLevel::Heavy,
        traffic_non_yielding: Some(1.0),
        obs_mode: ObsMode::State,
        ..SimConfig::default()
    };
    let w = Arc::new(SimWorld::new(Scene::reference(), cfg).unwrap());
    let hit = w.traffic.as_ref().unwrap().0.vehicle_hit;
    let mut env = VecEnv::new(w.clone(), 1, BackendChoice::Auto).unwrap();
    env.reset(0, Pose::from_degrees(0.0, -2.5, 90.0), 1).unwrap();
    for _ in 0..2000 {
        let t = env.step(&[[-1.0, 0.0, 0.0]]).unwrap()[0];
        if t.terminated {
            assert!(t.safety.vehicle_hit && !t.reached_goal());
            assert_eq!(t.reward, w.scene.rewards().step_reward(t.region, 0.0, t.collided) + hit);
            return;
        }
    }
    panic!("no vehicle reached an agent standing in its lane for 500 s");
}

#[test]
fn vehicles_walkers_and_lamps_are_drawn() {
    let w = world(TrafficLevel::Heavy, ObsMode::Pixels);
    let off = world(TrafficLevel::Off, ObsMode::Pixels);
    // On the south-east kerb looking west along the east-west road, where queues form.
    let pose = Pose::from_degrees(8.0, -6.0, 170.0);
    let mut with = VecEnv::new(w, 1, BackendChoice::Auto).unwrap();
    let mut without = VecEnv::new(off, 1, BackendChoice::Auto).unwrap();
    with.reset(0, pose, 3).unwrap();
    without.reset(0, pose, 3).unwrap();
    for _ in 0..40 {
        with.step(&[[-1.0, 0.0, 0.0]]).unwrap();
        without.step(&[[-1.0, 0.0, 0.0]]).unwrap();
    }
    let a = with.render().unwrap().frame(0);
    let b = without.render().unwrap().frame(0);
    let differ = a.iter().zip(&b).filter(|(x, y)| x != y).count();
    assert!(differ > 20, "traffic changed only {differ} pixels of the view");
}

#[test]
fn ground_signals_light_up_on_walk_and_show_dim_with_the_hand() {
    let pixels = |ground_signals: GroundSignals| {
        let cfg = SimConfig {
            traffic: TrafficLevel::Light,
            traffic_ground_signals: ground_signals,
            image_size: 42,
            ..SimConfig::default()
        };
        VecEnv::new(Arc::new(SimWorld::new(Scene::reference(), cfg).unwrap()), 1, BackendChoice::Auto).unwrap()
    };
    let mut without = pixels(GroundSignals::Off);
    // Facing along the east zebra from its south end: 1.3–1.8 m short of the kerb band
    // (y from −5.7 to −5.2); 0.6 m short of the kerb, where the edge lines begin (they
    // run from y = −5 to the far kerb).
    let kinds = [(GroundSignals::Kerb, -7.0), (GroundSignals::Edges, -5.6)];
    for (kind, y) in kinds {
        let pose = Pose::from_degrees(13.0, y, 90.0);
        let mut with = pixels(kind);
        for (signal, lit) in [(PedestrianSignal::Walk, true), (PedestrianSignal::DontWalk, false)] {
            let seed = reset_showing(&mut with, pose, signal);
            without.reset(0, pose, seed).unwrap();
            let a = with.render().unwrap().frame(0).to_vec();
            let b = without.render().unwrap().frame(0).to_vec();
            // The band's pixels: those the option changed.
            let band: Vec<u8> = a.iter().zip(&b).filter(|(x, y)| x != y).map(|(x, _)| *x).collect();
            assert!(band.len() >= 20, "{kind:?}, {signal:?}: the band covers only {} pixels", band.len());
            let mean = band.iter().map(|&g| g as f32).sum::<f32>() / band.len() as f32;
            if lit {
                assert!(mean > 230.0, "{kind:?}, WALK: the band's mean grey is {mean:.0}, not lit");
            } else {
                assert!((70.0..110.0).contains(&mean), "{kind:?}, DON'T WALK: mean grey {mean:.0}, not the dim hand");
            }
        }
    }
}

#[test]
fn the_oracle_waits_for_walk_and_crosses_without_a_hit_or_a_violation() {
    use pednav_sim::oracle::{Oracle, OracleConfig};
    use pednav_sim::policy::{OraclePolicy, Policy};
    let w = world(TrafficLevel::Medium, ObsMode::State);
    let mut policy = OraclePolicy::new(Oracle::plan(&w, OracleConfig::default()));
    let mut env = VecEnv::new(w.clone(), 1, BackendChoice::Auto).unwrap();
    let (mut waited, mut reached) = (0, 0);
    for seed in 0..6 {
        // Validation point 3: the south-east sidewalk, facing the east zebra.
        env.reset(0, Pose::from_degrees(14.0, -7.0, 180.0), seed).unwrap();
        let mut a = [[0.0f32; 3]];
        for k in 0..2000 {
            if k == 1999 {
                let s = env.traffic(0).unwrap();
                eprintln!(
                    "seed {seed}: still at {:?}, action {a:?}, clock {:.1}, walkers {:?}",
                    env.pedestrian(0).pose,
                    s.t,
                    s.walkers.iter().map(|w| w.pos).collect::<Vec<_>>()
                );
            }
            policy.act(&env, &mut a).unwrap();
            let t = env.step(&a).unwrap()[0];
            assert!(!t.safety.dont_walk_entry && !t.safety.vehicle_hit, "seed {seed}: {:?}", t.safety);
            waited += t.safety.kerb_wait as u32;
            if t.terminated || t.truncated {
                reached += t.reached_goal() as u32;
                if !t.reached_goal() {
                    eprintln!("seed {seed}: ended at {:?} after {} steps", t.pose, t.step);
                }
                break;
            }
        }
    }
    assert_eq!(reached, 6, "the oracle reaches the goal from every phase");
    assert!(waited > 0, "over six phases it waits at the kerb at least once");
}

/// The state preset knows the traffic: with traffic on the observation has 28
/// entries more, its first 22 exactly those of the same pose without traffic, its
/// signal entries the plan's, its vehicle slots the nearest vehicles, nearest first,
/// where they are and as fast as they drive.
#[test]
fn the_state_observation_carries_the_signal_and_the_nearest_vehicles() {
    use pednav_sim::state_obs::{NEAREST_VEHICLES, POSITION_SCALE_M, VEHICLE_RANGE, VEHICLE_SPEED_SCALE};
    let on = world(TrafficLevel::Heavy, ObsMode::State);
    let off = world(TrafficLevel::Off, ObsMode::State);
    let (traffic, _) = on.traffic.as_ref().unwrap();
    let mut a = VecEnv::new(on.clone(), 1, BackendChoice::Auto).unwrap();
    let mut b = VecEnv::new(off.clone(), 1, BackendChoice::Auto).unwrap();
    assert_eq!((a.state_dim(), b.state_dim()), (50, 22));
    let pose = Pose::from_degrees(13.0, -6.6, 90.0); // at the south kerb of zebra 0, facing across
    let mut seen_walk = false;
    for seed in 0..40u64 {
        a.reset(0, pose, seed).unwrap();
        b.reset(0, pose, seed).unwrap();
        for _ in 0..(seed % 5) {
            a.step(&[[-1.0, 0.0, 0.0]]).unwrap();
            b.step(&[[-1.0, 0.0, 0.0]]).unwrap();
        }
        let (o, plain) = (a.state_obs(0), b.state_obs(0));
        assert_eq!(o[..22], plain[..22], "seed {seed}: the scene's part changed with traffic");
        assert!(plain[22..].iter().all(|&v| v == 0.0));
        let state = a.traffic(0).unwrap();
        // The nearest zebra (by distance to its bounding rectangle): its signal, times left.
        let gap = |z: &pednav_sim::traffic::Zebra| {
            let r = z.bounds;
            (r.min[0] - pose.x)
                .max(pose.x - r.max[0])
                .max(0.0)
                .hypot((r.min[1] - pose.y).max(pose.y - r.max[1]).max(0.0))
        };
        let zi = (0..traffic.zebras.len())
            .min_by(|&i, &j| gap(&traffic.zebras[i]).total_cmp(&gap(&traffic.zebras[j])))
            .unwrap();
        let near = [o[22], o[23]].map(|v| v * POSITION_SCALE_M);
        assert!(near[0].hypot(near[1]) < 3.0, "seed {seed}: nearer end {near:?}");
        let shown = traffic.plan.pedestrian(zi, state.t);
        assert_eq!(o[26] == 1.0, shown == PedestrianSignal::Walk, "seed {seed}");
        assert_eq!(o[27] == 1.0, shown == PedestrianSignal::Clearance, "seed {seed}");
        let until = (traffic.plan.until_walk(zi, state.t) / traffic.plan.cycle_s) as f32;
        assert!((o[28] - until).abs() < 1e-6 && (0.0..=1.0).contains(&o[29]), "seed {seed}: {:?}", &o[22..30]);
        assert_eq!(o[29] > 0.0, shown != PedestrianSignal::DontWalk, "seed {seed}");
        seen_walk |= shown == PedestrianSignal::Walk;
        // Vehicle slots: present ones first, nearest first, matching real vehicles.
        let mut all: Vec<(f32, [f32; 2], f32)> = traffic
            .lanes
            .iter()
            .zip(&state.lanes)
            .flat_map(|(lane, lt)| lt.vehicles.iter().map(move |v| (v.center(lane), v.v)))
            .map(|(c, v)| ((c[0] - pose.x).hypot(c[1] - pose.y), c, v))
            .filter(|(d, _, _)| *d <= VEHICLE_RANGE)
            .collect();
        all.sort_by(|x, y| x.0.total_cmp(&y.0));
        for (k, slot) in o[30..].chunks(5).enumerate() {
            assert_eq!(NEAREST_VEHICLES, 4);
            match all.get(k) {
                None => assert!(slot.iter().all(|&v| v == 0.0), "seed {seed}: slot {k} {slot:?}"),
                Some((d, _, v)) => {
                    assert_eq!(slot[0], 1.0);
                    let dist = slot[1].hypot(slot[2]) * POSITION_SCALE_M;
                    assert!((dist - d).abs() < 1e-3, "seed {seed}: slot {k} at {dist}, vehicle at {d}");
                    let speed = slot[3].hypot(slot[4]) * VEHICLE_SPEED_SCALE;
                    assert!((speed - v).abs() < 1e-3, "seed {seed}: slot {k} speed {speed}, vehicle {v}");
                }
            }
        }
    }
    assert!(seen_walk, "40 starts never saw WALK at the nearest zebra");
}
