//! Networks and encoders against independent values: seeded construction, prepared
//! observations, every encoder kind forward and backward, one-pass transition features
//! and the fast frame transpose.

use candle_core::{Device, Tensor};
use pednav_nets::{DsacNets, EncoderKind, NetsConfig, Obs, Transitions};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::support::{random, rows, tiny};

fn pixel_obs(rng: &mut ChaCha8Rng, cfg: &NetsConfig, b: usize) -> Obs {
    let s = cfg.image_size;
    Obs::Pixels {
        frames: random(rng, &[b, cfg.history, s, s], 1.0).abs().unwrap(),
        actions: random(rng, &[b, cfg.history - 1, 3], 1.0),
        rewards: random(rng, &[b, cfg.history - 1], 1.0),
    }
}

#[test]
fn networks_are_reproducible_from_the_seed_and_the_target_starts_equal() {
    let cfg = tiny(EncoderKind::Tcn, false);
    let a = DsacNets::new(&cfg, &Device::Cpu, 5).unwrap();
    let b = DsacNets::new(&cfg, &Device::Cpu, 5).unwrap();
    let c = DsacNets::new(&cfg, &Device::Cpu, 6).unwrap();
    let first = |n: &DsacNets| n.policy.store.vars()[0].1.flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(first(&a), first(&b));
    assert_ne!(first(&a), first(&c));
    for ((_, q), (_, t)) in a.quantile.store.vars().iter().zip(a.target.store.vars()) {
        assert_eq!(
            q.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
            t.flatten_all().unwrap().to_vec1::<f32>().unwrap()
        );
    }
}

/// `DsacNets::prepare` (frame stacking: frames transposed once for every encoder)
/// changes no feature, for any encoder kind.
#[test]
fn prepared_observations_give_the_same_features() {
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    for kind in [EncoderKind::FrameStack, EncoderKind::Tcn] {
        let cfg = tiny(kind, false);
        let nets = DsacNets::new(&cfg, &Device::Cpu, 2).unwrap();
        let obs = pixel_obs(&mut rng, &cfg, 3);
        let prepared = nets.prepare(&obs).unwrap();
        assert_eq!(matches!(prepared, Obs::Stacked(_)), kind == EncoderKind::FrameStack);
        let (a, b) = (nets.online_features(&obs).unwrap(), nets.online_features(&prepared).unwrap());
        for (x, y) in [(&a.policy, &b.policy), (&a.fraction, &b.fraction), (&a.quantile, &b.quantile)] {
            assert_eq!(rows(x), rows(y), "{kind:?}");
        }
        assert_eq!(rows(&nets.target_features(&obs).unwrap()), rows(&nets.target_features(&prepared).unwrap()));
    }
}

#[test]
fn every_encoder_kind_runs_forward_and_backward() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for (kind, shared) in [
        (EncoderKind::Tcn, false),
        (EncoderKind::Tcn, true),
        (EncoderKind::FrameStack, false),
        (EncoderKind::Mlp, false),
    ] {
        let cfg = tiny(kind, shared);
        let nets = DsacNets::new(&cfg, &Device::Cpu, 1).unwrap();
        let obs = if kind == EncoderKind::Mlp {
            Obs::State(random(&mut rng, &[3, 5], 1.0))
        } else {
            pixel_obs(&mut rng, &cfg, 3)
        };
        let f = nets.online_features(&obs).unwrap();
        let a = random(&mut rng, &[3, 3], 1.0);
        let q = nets.quantile.grid(&f.quantile, &a).unwrap().values.sum_all().unwrap();
        let grads = q.backward().unwrap();
        let enc_grad = nets
            .quantile
            .store
            .vars()
            .iter()
            .filter(|(n, _)| n.starts_with("enc."))
            .filter(|(_, v)| grads.get(v).is_some())
            .count();
        assert!(enc_grad > 0, "{kind:?}: the critic loss must reach its encoder");
        if shared {
            // Policy features are detached: the policy loss does not reach the shared encoder.
            let p = nets.policy.head(&f.policy).unwrap().mean.sum_all().unwrap().backward().unwrap();
            assert!(nets.quantile.store.vars().iter().all(|(_, v)| p.get(v).is_none()));
        }
    }
}

/// One pass over a transition's N_h + n frames gives the same features as encoding
/// o_t and o_{t+n} separately (separate and shared encoders, several N_h, one-step
/// and n-step transitions).
#[test]
fn transition_features_equal_separate_encoding() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for (history, shared, n) in [(4, false, 1), (8, true, 1), (16, false, 1), (7, true, 1), (8, true, 3), (4, false, 2)]
    {
        let cfg = NetsConfig { history, ..tiny(EncoderKind::Tcn, shared) };
        let nets = DsacNets::new(&cfg, &Device::Cpu, 2).unwrap();
        let (b, s) = (3, cfg.image_size);
        let window = random(&mut rng, &[b, history + n, s, s], 1.0).abs().unwrap();
        let (actions, rewards) =
            (random(&mut rng, &[b, history + n - 1, 3], 1.0), random(&mut rng, &[b, history + n - 1], 1.0));
        let t = Transitions::Pixels {
            frames: window.clone(),
            actions: actions.clone(),
            rewards: rewards.clone(),
            n_step: n,
        };
        // o_t and o_{t+n} are the stored tensors' overlapping views, made contiguous
        // here so the reference encodes plain tensors.
        let part = |x: &Tensor, start: usize, len: usize| x.narrow(1, start, len).unwrap().contiguous().unwrap();
        let obs = Obs::Pixels {
            frames: part(&window, 0, history),
            actions: part(&actions, 0, history - 1),
            rewards: part(&rewards, 0, history - 1),
        };
        let next = Obs::Pixels {
            frames: part(&window, n, history),
            actions: part(&actions, n, history - 1),
            rewards: part(&rewards, n, history - 1),
        };
        let (Obs::Pixels { frames: f0, actions: a0, .. }, Obs::Pixels { frames: f1, rewards: r1, .. }) =
            (t.obs().unwrap(), t.next_obs().unwrap())
        else {
            panic!("pixel transitions give pixel observations")
        };
        let (Obs::Pixels { frames: g0, actions: b0, .. }, Obs::Pixels { frames: g1, rewards: s1, .. }) = (&obs, &next)
        else {
            unreachable!()
        };
        for (view, plain) in [(&f0, g0), (&a0, b0), (&f1, g1), (&r1, s1)] {
            assert_eq!(
                view.flatten_all().unwrap().to_vec1::<f32>().unwrap(),
                plain.flatten_all().unwrap().to_vec1::<f32>().unwrap()
            );
        }
        let together = nets.transition_features(&t).unwrap();
        let online = nets.online_features(&obs).unwrap();
        let (next_policy, next_fraction) = nets.policy_and_fraction_features(&next).unwrap();
        let close = |a: &Tensor, b: &Tensor, what: &str| {
            assert_eq!(a.dims(), b.dims(), "N_h {history} {what}");
            for (u, v) in rows(a).concat().iter().zip(rows(b).concat()) {
                assert!((u - v).abs() <= 1e-5 * (1.0 + v.abs()), "N_h {history} shared {shared} {what}: {u} vs {v}");
            }
        };
        close(&together.online.policy, &online.policy, "policy");
        close(&together.online.fraction, &online.fraction, "fraction");
        close(&together.online.quantile, &online.quantile, "quantile");
        close(&together.next_policy, &next_policy, "next policy");
        close(&together.next_fraction, &next_fraction, "next fraction");
    }
}

/// The fast frames → channel-last transpose equals candle's permute.
#[test]
fn frames_to_channels_last_equals_the_permute() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    // Frames smaller than one transpose block, and several blocks with a partial last one.
    for (b, t, h, w) in [(3, 5, 7, 6), (2, 16, 13, 11)] {
        let frames = random(&mut rng, &[b, t, h, w], 1.0);
        let fast = pednav_nets::ops::frames_to_channels_last(&frames).unwrap();
        let reference = frames.permute((0, 2, 3, 1)).unwrap().reshape((b, 1, h, w, t)).unwrap();
        assert_eq!(fast.dims(), reference.dims());
        assert_eq!(rows(&fast.flatten_from(1).unwrap()), rows(&reference.flatten_from(1).unwrap()));
    }
}
