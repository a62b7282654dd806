//! The agent as a whole: acting (seeded; the deterministic mode repeats itself), and one
//! update compared across devices weight by weight.

mod common;
use common::small;

use candle_core::{Device, Tensor};
use pednav_learner::{Dsac, FrameKind};
use pednav_nets::Obs;

#[test]
fn acting_is_seeded_and_deterministic_mode_is_tanh_of_the_mean() {
    let (cfg, nets) = small();
    let obs = Obs::State(Tensor::new(&[[0.1f32, -0.2, 0.3, 0.0]], &Device::Cpu).unwrap());
    let mut a = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
    let mut b = Dsac::new(&cfg, &nets, &Device::Cpu, 1).unwrap();
    let (x, _) = a.act(&obs, false).unwrap();
    let (y, _) = b.act(&obs, false).unwrap();
    assert_eq!(x.to_vec2::<f32>().unwrap(), y.to_vec2::<f32>().unwrap());
    let (m1, _) = a.act(&obs, true).unwrap();
    let (m2, _) = a.act(&obs, true).unwrap();
    assert_eq!(m1.to_vec2::<f32>().unwrap(), m2.to_vec2::<f32>().unwrap());
}

/// The device check's comparison: the same device twice gives identical losses and
/// weights and passes; each tolerance fails just beyond its bound (lr 3e-4 → two Adam
/// steps 6e-4 + 1e-5).
#[test]
fn one_update_on_two_devices_is_compared_weight_by_weight() {
    let (mut cfg, nets) = small();
    (cfg.lr_policy, cfg.lr_quantile, cfg.lr_fraction, cfg.lr_alpha) = (3e-4, 3e-4, 1e-4, 3e-4);
    let same = pednav_learner::compare_update(&cfg, &nets, FrameKind::State { dim: 4 }, &Device::Cpu, &Device::Cpu, 3)
        .unwrap();
    assert!(same.passes() && same.weights > 1000, "{same:?}");
    assert_eq!((same.loss_rel_diff, same.weight_max_diff, same.weight_p999_diff), (0.0, 0.0, 0.0));
    assert_eq!(same.a.critic_loss, same.b.critic_loss);
    assert_eq!(same.max_lr, 3e-4);
    for (field, ok, bad) in [("losses", 0.9e-3, 1.1e-3), ("p999", 0.9e-5, 1.1e-5), ("max", 6.09e-4, 6.11e-4)] {
        for (value, passes) in [(ok, true), (bad, false)] {
            let mut c = same.clone();
            match field {
                "losses" => c.loss_rel_diff = value,
                "p999" => c.weight_p999_diff = value,
                _ => c.weight_max_diff = value,
            }
            assert_eq!(c.passes(), passes, "{field} = {value}");
        }
    }
}
