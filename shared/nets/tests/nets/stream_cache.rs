//! The streaming cache of the acting encoder against full recompute of each window.

use candle_core::{Device, IndexOp, Tensor};
use pednav_nets::{DsacNets, EncoderKind, NetsConfig, Obs, PolicyStream};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Build the expected window at step t of an episode independently: frames
/// f_{t−N+1..t} padded with f_0, actions/rewards a_{t−N+1..t−1} padded with zeros.
fn expected_window(frames: &[Vec<u8>], actions: &[[f32; 3]], rewards: &[f32], n: usize, s: usize) -> Obs {
    let t = frames.len() - 1;
    let mut fr = Vec::new();
    let mut ac = Vec::new();
    let mut rw = Vec::new();
    for k in 0..n {
        let idx = (t + k + 1).saturating_sub(n);
        fr.extend(frames[idx].iter().map(|&p| p as f32 / 255.0));
    }
    for k in 0..n - 1 {
        let j = (t + k + 1) as isize - n as isize;
        if j < 0 {
            ac.extend([0.0; 3]);
            rw.push(0.0);
        } else {
            ac.extend(actions[j as usize]);
            rw.push(rewards[j as usize]);
        }
    }
    Obs::Pixels {
        frames: Tensor::from_vec(fr, (1, n, s, s), &Device::Cpu).unwrap(),
        actions: Tensor::from_vec(ac, (1, n - 1, 3), &Device::Cpu).unwrap(),
        rewards: Tensor::from_vec(rw, (1, n - 1), &Device::Cpu).unwrap(),
    }
}

/// Frames, actions and rewards of one scripted episode so far.
type Episode = (Vec<Vec<u8>>, Vec<[f32; 3]>, Vec<f32>);

fn max_abs(t: &Tensor) -> f32 {
    t.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar().unwrap()
}

#[test]
fn streaming_cache_equals_full_recompute_over_an_episode_with_a_reset() {
    for (kind, history, size) in
        [(EncoderKind::Tcn, 16, 42), (EncoderKind::Tcn, 8, 42), (EncoderKind::FrameStack, 4, 42)]
    {
        let cfg = NetsConfig { encoder: kind, history, image_size: size, ..Default::default() };
        let nets = DsacNets::new(&cfg, &Device::Cpu, 9).unwrap();
        let enc = nets.acting_encoder();
        let mut rng = ChaCha8Rng::seed_from_u64(10);
        let envs = 2;
        let mut stream = PolicyStream::new(&cfg, envs, &Device::Cpu);
        let frame = |rng: &mut ChaCha8Rng| (0..size * size).map(|_| rng.random::<u8>()).collect::<Vec<u8>>();
        let mut eps: Vec<Episode> = vec![Default::default(); envs];
        for step in 0..40 {
            for (e, ep) in eps.iter_mut().enumerate() {
                let f = frame(&mut rng);
                // Env 0 resets at step 23 (mid-episode); env 1 runs one 40-step episode.
                if step == 0 || (e == 0 && step == 23) {
                    stream.reset(e, &f).unwrap();
                    *ep = (vec![f], vec![], vec![]);
                } else {
                    let a = [rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0)];
                    let r = rng.random_range(-3.0..1.0);
                    stream.push(e, a, r, &f).unwrap();
                    ep.0.push(f);
                    ep.1.push(a);
                    ep.2.push(r);
                }
            }
            if step == 30 {
                stream.invalidate();
            }
            let cached = stream.features(enc, &[0, 1]).unwrap();
            for (e, ep) in eps.iter().enumerate() {
                let want = enc.encode(&expected_window(&ep.0, &ep.1, &ep.2, history, size)).unwrap();
                let got = cached.i(e..e + 1).unwrap();
                let diff = max_abs(&(got - &want).unwrap());
                let scale = max_abs(&want);
                assert!(
                    diff <= 1e-5 * (1.0 + scale),
                    "{kind:?} N_h {history}: step {step} env {e}: max |Δ| {diff} (scale {scale})"
                );
            }
        }
    }
}
