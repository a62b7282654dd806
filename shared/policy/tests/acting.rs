//! The acting policy against independent computations: its actions equal the
//! networks' full forward pass on the same windows (so the streaming cache is
//! never stale, also right after new weights), sampling is reproducible from the
//! episode seed alone, and the mode is tanh(μ).

use std::sync::Arc;

use candle_core::{Device, Tensor};
use pednav_nets::{DsacNets, EncoderKind, NetsConfig, Obs};
use pednav_policy::{ActingPolicy, Sampling, action_rows};
use pednav_sim::{Action, BackendChoice, ObsMode, Policy, Pose, Scene, SimConfig, SimWorld, VecEnv};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const SIZE: usize = 42;
const HISTORY: usize = 8;

fn pixel_cfg() -> NetsConfig {
    NetsConfig { encoder: EncoderKind::Tcn, history: HISTORY, image_size: SIZE, ..Default::default() }
}

/// Environments without a renderer: the pixel policy gets its frames from the test.
fn envs(m: usize) -> VecEnv {
    let sim = SimConfig { obs_mode: ObsMode::State, ..SimConfig::default() };
    let world = Arc::new(SimWorld::new(Scene::reference(), sim).unwrap());
    let mut envs = VecEnv::new(world, m, BackendChoice::Auto).unwrap();
    let p = envs.world().scene.validation_points()[2];
    for e in 0..m {
        envs.reset(e, Pose::from_degrees(p.x, p.y, p.favourable_yaw_deg), e as u64).unwrap();
    }
    envs
}

fn random_frame(rng: &mut ChaCha8Rng) -> Vec<u8> {
    (0..SIZE * SIZE).map(|_| rng.random::<u8>()).collect()
}

/// The mode action of `nets` on an explicit window, by the full forward pass.
fn full_forward_mode(nets: &DsacNets, frames: &[Vec<u8>], actions: &[Action], rewards: &[f32]) -> Action {
    let window = &frames[frames.len() - HISTORY..];
    let pixels: Vec<f32> = window.iter().flatten().map(|&p| p as f32 / 255.0).collect();
    let acts: Vec<f32> = actions[actions.len() - (HISTORY - 1)..].iter().flatten().copied().collect();
    let rews = rewards[rewards.len() - (HISTORY - 1)..].to_vec();
    let obs = Obs::Pixels {
        frames: Tensor::from_vec(pixels, (1, HISTORY, SIZE, SIZE), &Device::Cpu).unwrap(),
        actions: Tensor::from_vec(acts, (1, HISTORY - 1, 3), &Device::Cpu).unwrap(),
        rewards: Tensor::from_vec(rews, (1, HISTORY - 1), &Device::Cpu).unwrap(),
    };
    let f = nets.acting_encoder().encode(&obs).unwrap();
    action_rows(&nets.policy.head(&f).unwrap().mode().unwrap()).unwrap()[0]
}

#[test]
fn new_weights_never_meet_a_stale_cache() {
    let cfg = pixel_cfg();
    let reference_a = DsacNets::new(&cfg, &Device::Cpu, 1).unwrap();
    let reference_b = DsacNets::new(&cfg, &Device::Cpu, 2).unwrap();
    let mut policy = ActingPolicy::new(DsacNets::new(&cfg, &Device::Cpu, 1).unwrap(), &cfg, 1, Sampling::Mode);
    assert!(policy.needs_frames());
    let envs = envs(1);
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    // The window starts as the first frame N_h times with zero actions and rewards.
    let first = random_frame(&mut rng);
    let mut frames = vec![first.clone(); HISTORY];
    let mut actions = vec![[0.0; 3]; HISTORY - 1];
    let mut rewards = vec![0.0; HISTORY - 1];
    policy.begin(0, 3, Some(&first)).unwrap();
    let mut act = [[0.0; 3]];
    for step in 0..20 {
        if step == 12 {
            // New weights mid-episode: the next action must come from B on the same window.
            policy
                .load_weights(|nets| -> pednav_nets::Result<()> {
                    for (dst, src) in nets.acting_stores().into_iter().zip(reference_b.acting_stores()) {
                        dst.copy_from(src)?;
                    }
                    Ok(())
                })
                .unwrap();
        }
        policy.act(&envs, &mut act).unwrap();
        let reference = if step < 12 { &reference_a } else { &reference_b };
        let expected = full_forward_mode(reference, &frames, &actions, &rewards);
        for (got, want) in act[0].iter().zip(expected) {
            assert!((got - want).abs() < 1e-4, "step {step}: {:?} vs {expected:?}", act[0]);
        }
        let frame = random_frame(&mut rng);
        let reward = rng.random_range(-2.0..1.0);
        policy.observe(0, act[0], reward, Some(&frame)).unwrap();
        frames.push(frame);
        actions.push(act[0]);
        rewards.push(reward);
    }
}

#[test]
fn sampling_depends_only_on_the_episode_seed() {
    let cfg = NetsConfig { encoder: EncoderKind::Mlp, ..Default::default() };
    let envs = envs(3);
    let run = |seeds: [u64; 3]| {
        let mut policy = ActingPolicy::new(DsacNets::new(&cfg, &Device::Cpu, 4).unwrap(), &cfg, 3, Sampling::Sample);
        assert!(!policy.needs_frames());
        for (e, s) in seeds.into_iter().enumerate() {
            policy.begin(e, s, None).unwrap();
        }
        let mut out = Vec::new();
        for _ in 0..5 {
            let d = policy.decide(&envs, true).unwrap();
            assert!(d.obs.is_some() && d.log_probs.is_some());
            out.push(action_rows(&d.actions).unwrap());
        }
        out
    };
    let a = run([10, 11, 12]);
    let b = run([10, 11, 12]);
    assert_eq!(a, b, "same seeds, same actions");
    // Environment 1 keeps its seed while the others change: its actions stay.
    let c = run([20, 11, 22]);
    for (x, y) in a.iter().zip(&c) {
        assert_eq!(x[1], y[1]);
        assert_ne!(x[0], y[0]);
    }
    assert!(a.iter().flatten().flatten().all(|v| v.abs() <= 1.0));
}

#[test]
fn the_mode_is_tanh_mu_of_the_state_vector() {
    let cfg = NetsConfig { encoder: EncoderKind::Mlp, ..Default::default() };
    let envs = envs(2);
    let nets = DsacNets::new(&cfg, &Device::Cpu, 6).unwrap();
    let s: Vec<f32> = (0..2).flat_map(|e| envs.state_obs(e).into_iter().take(envs.state_dim())).collect();
    let obs = Obs::State(Tensor::from_vec(s, (2, cfg.state_dim), &Device::Cpu).unwrap());
    let expected =
        action_rows(&nets.policy.head(&nets.acting_encoder().encode(&obs).unwrap()).unwrap().mode().unwrap()).unwrap();
    let mut policy = ActingPolicy::new(nets, &cfg, 2, Sampling::Mode);
    let mut got = vec![[0.0; 3]; 2];
    policy.act(&envs, &mut got).unwrap();
    assert_eq!(got, expected);
}
