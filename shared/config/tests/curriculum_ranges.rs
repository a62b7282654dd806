//! The `[curriculum]` section's ranges (docs/configuration.md, *Ranges*): each value
//! outside its range alone is refused naming the field; each boundary alone is accepted.

use pednav_config::CurriculumConfig;

#[test]
fn values_outside_the_documented_ranges_are_refused_naming_the_field() {
    let refused: [(&str, fn(&mut CurriculumConfig)); 16] = [
        ("gamma", |c| c.gamma = 1.0),
        ("gamma", |c| c.gamma = f32::NAN),
        ("beta_easy", |c| c.beta_easy = 1e15),
        ("beta_frontier_high", |c| c.beta_frontier_high = -0.1),
        ("beta_hard", |c| c.beta_hard = f32::NAN),
        ("slope", |c| c.slope = 1e15),
        ("t_thre", |c| c.t_thre = 0.0),
        ("t_thre", |c| c.t_thre = 1e15),
        ("hard_max_prob", |c| c.hard_max_prob = f32::NAN),
        ("random_prob", |c| c.random_prob = 1.5),
        ("pass_threshold", |c| c.pass_threshold = -1e15),
        ("pass_threshold", |c| c.pass_threshold = f32::NAN),
        ("net.lr", |c| c.net.lr = 0.0),
        ("net.lr", |c| c.net.lr = 1e15),
        ("net.lr", |c| c.net.lr = f64::NAN),
        ("candidates", |c| c.candidates = 1),
    ];
    for (field, set) in refused {
        let mut cfg = CurriculumConfig::default();
        set(&mut cfg);
        let e = cfg.validate().expect_err(field);
        assert_eq!((e.section, e.field), ("curriculum", field), "{e}");
        assert!(e.message.contains("must be in"), "{e}");
    }
    let accepted: [fn(&mut CurriculumConfig); 6] = [
        |c| c.slope = 100.0,
        |c| c.t_thre = 1e10,
        |c| c.pass_threshold = -25.0,
        |c| c.net.lr = 1.0,
        |c| c.random_prob = 1.0,
        |c| c.beta_frontier_high = 0.0,
    ];
    for set in accepted {
        let mut cfg = CurriculumConfig::default();
        set(&mut cfg);
        cfg.validate().unwrap();
    }
}
