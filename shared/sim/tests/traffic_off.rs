//! With `sim.traffic = "off"` (the default) the simulator is the one every committed
//! figure was made with, bit for bit: frames, rewards, poses and oracle returns are
//! hashed over fixed episodes and compared with the hash the simulator of e6479e7
//! (the last commit before traffic existed) gives for the same code.

use std::sync::Arc;

use pednav_sim::oracle::{Oracle, OracleConfig};
use pednav_sim::policy::{Policy, RandomPolicy};
use pednav_sim::{BackendChoice, Pose, Scene, SimConfig, SimWorld, VecEnv};

/// FNV-1a over everything the episodes produce.
struct Fnv(u64);

impl Fnv {
    fn add(&mut self, bytes: &[u8]) {
        for b in bytes {
            self.0 ^= *b as u64;
            self.0 = self.0.wrapping_mul(0x0100_0000_01b3);
        }
    }
    fn f32(&mut self, v: f32) {
        self.add(&v.to_bits().to_le_bytes());
    }
}

/// The hash e6479e7's simulator gives (computed by running this file on that commit).
const BEFORE_TRAFFIC: u64 = 0xa2ce_0768_880c_2365;

#[test]
fn traffic_off_reproduces_the_simulator_before_traffic() {
    let scene = Scene::reference();
    let starts: Vec<Pose> = scene
        .validation_points()
        .iter()
        .flat_map(|p| {
            [
                Pose::from_degrees(p.x, p.y, p.favourable_yaw_deg),
                Pose::from_degrees(p.x, p.y, p.favourable_yaw_deg + 135.0),
            ]
        })
        .collect();
    let mut h = Fnv(0xcbf2_9ce4_8422_2325);
    // Pixels: 4 environments at 42², a seeded random walk, every frame hashed.
    let world = Arc::new(SimWorld::new(scene.clone(), SimConfig { image_size: 42, ..SimConfig::default() }).unwrap());
    let mut env = VecEnv::new(world.clone(), 4, BackendChoice::Auto).unwrap();
    let mut walk = RandomPolicy::new(7);
    let mut actions = vec![[0.0f32; 3]; 4];
    for chunk in starts.chunks(4) {
        for (i, s) in chunk.iter().enumerate() {
            env.reset(i, *s, i as u64).unwrap();
        }
        for i in chunk.len()..4 {
            env.reset(i, starts[0], 99).unwrap();
        }
        for _ in 0..40 {
            walk.act(&env, &mut actions).unwrap();
            let done: Vec<bool> = env
                .step(&actions)
                .unwrap()
                .iter()
                .map(|t| {
                    h.f32(t.reward);
                    h.f32(t.pose.x);
                    h.f32(t.pose.y);
                    h.f32(t.pose.yaw);
                    h.add(&[t.collided as u8, t.terminated as u8, t.truncated as u8, t.region.label()]);
                    t.terminated || t.truncated
                })
                .collect();
            let frames = env.render().unwrap();
            for i in 0..4 {
                h.add(&frames.frame(i));
            }
            drop(frames);
            for (i, d) in done.into_iter().enumerate() {
                if d {
                    env.reset(i, starts[i], 1000 + i as u64).unwrap();
                }
            }
        }
    }
    // The oracle's returns from every start.
    let world = SimWorld::new(scene, SimConfig { t_max: 2000, ..SimConfig::default() }).unwrap();
    let oracle = Oracle::plan(&world, OracleConfig::default());
    for s in &starts {
        let r = oracle.rollout(&world, *s, 2000);
        h.f32(r.discounted_return as f32);
        h.add(&(r.steps as u64).to_le_bytes());
    }
    println!("hash {:#018x}", h.0);
    assert_eq!(h.0, BEFORE_TRAFFIC, "traffic off must reproduce the simulator of e6479e7 bit for bit");
}
