//! Heads against independent values: the Cholesky-Gaussian log-density against the
//! closed form, the tanh Jacobian of squashed samples, quantiles non-decreasing in τ
//! (proptest) and the quantile grid's interpolation.

use candle_core::{Device, Tensor};
use pednav_nets::heads::standard_normal;
use pednav_nets::{CholeskyGaussian, DsacNets, EncoderKind, Obs};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::support::{random, rows, tiny};

/// log N(u; μ, Σ) in f64 from Σ = LLᵀ, its determinant and adjugate inverse.
fn mvn_log_density(u: [f64; 3], mu: [f64; 3], l: [[f64; 3]; 3]) -> f64 {
    let mut s = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            s[i][j] = (0..3).map(|k| l[i][k] * l[j][k]).sum();
        }
    }
    let det = s[0][0] * (s[1][1] * s[2][2] - s[1][2] * s[2][1]) - s[0][1] * (s[1][0] * s[2][2] - s[1][2] * s[2][0])
        + s[0][2] * (s[1][0] * s[2][1] - s[1][1] * s[2][0]);
    let cof = |r: usize, c: usize| {
        let (r0, r1) = ((r + 1) % 3, (r + 2) % 3);
        let (c0, c1) = ((c + 1) % 3, (c + 2) % 3);
        s[r0][c0] * s[r1][c1] - s[r0][c1] * s[r1][c0]
    };
    let d: Vec<f64> = (0..3).map(|i| u[i] - mu[i]).collect();
    let mut quad = 0.0;
    for i in 0..3 {
        for j in 0..3 {
            quad += d[i] * cof(j, i) / det * d[j];
        }
    }
    -0.5 * quad - 0.5 * det.ln() - 1.5 * (2.0 * std::f64::consts::PI).ln()
}

fn gaussian(rng: &mut ChaCha8Rng, b: usize) -> CholeskyGaussian {
    CholeskyGaussian::from_raw(random(rng, &[b, 3], 1.0), &random(rng, &[b, 6], 1.5)).unwrap()
}

#[test]
fn cholesky_log_density_matches_the_closed_form() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let g = gaussian(&mut rng, 16);
    let u = random(&mut rng, &[16, 3], 2.0);
    let ours: Vec<f32> = g.log_density(&u).unwrap().to_vec1().unwrap();
    let (mu, us) = (rows(&g.mean), rows(&u));
    let ls: Vec<Vec<Vec<f32>>> = g.scale_tril.to_vec3().unwrap();
    for i in 0..16 {
        let l = [0, 1, 2].map(|r| [0, 1, 2].map(|c| ls[i][r][c] as f64));
        assert_eq!([l[0][1], l[0][2], l[1][2]], [0.0; 3], "factor is lower triangular");
        assert!(l[0][0] > 0.0 && l[1][1] > 0.0 && l[2][2] > 0.0);
        let expect = mvn_log_density(
            us[i].iter().map(|&v| v as f64).collect::<Vec<_>>().try_into().unwrap(),
            [0, 1, 2].map(|k| mu[i][k] as f64),
            l,
        );
        assert!((ours[i] as f64 - expect).abs() < 1e-4 * (1.0 + expect.abs()), "row {i}: {} vs {expect}", ours[i]);
    }
}

#[test]
fn squashed_sample_log_prob_includes_the_tanh_jacobian() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    let g = gaussian(&mut rng, 8);
    let eps = standard_normal(&mut rng, 8, &Device::Cpu).unwrap();
    let s = g.sample(&eps).unwrap();
    let u = g.pre_squash(&eps).unwrap();
    let lp: Vec<f32> = s.log_prob.to_vec1().unwrap();
    let dens: Vec<f32> = g.log_density(&u).unwrap().to_vec1().unwrap();
    let (us, acts) = (rows(&u), rows(&s.action));
    for i in 0..8 {
        let jac: f64 = us[i].iter().map(|&v| (1.0 - (v as f64).tanh().powi(2)).ln()).sum();
        assert!((lp[i] as f64 - (dens[i] as f64 - jac)).abs() < 1e-3, "row {i}");
        for k in 0..3 {
            assert!((acts[i][k] as f64 - (us[i][k] as f64).tanh()).abs() < 1e-6);
        }
    }
    let mode = rows(&g.mode().unwrap());
    assert!((mode[0][0] - rows(&g.mean)[0][0].tanh()).abs() < 1e-6);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(24))]
    #[test]
    fn quantiles_never_decrease_in_tau(seed in 0u64..1000, b in 1usize..5) {
        let cfg = tiny(EncoderKind::Mlp, false);
        let nets = DsacNets::new(&cfg, &Device::Cpu, seed).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let obs = Obs::State(random(&mut rng, &[b, 5], 3.0));
        let f = nets.online_features(&obs).unwrap();
        let a = random(&mut rng, &[b, 3], 1.0);
        let grid = nets.quantile.grid(&f.quantile, &a).unwrap();
        let mut taus: Vec<f32> = (0..b * 50).map(|_| rng.random_range(0.0..1.0)).collect();
        for row in taus.chunks_mut(50) { row.sort_by(|x, y| x.partial_cmp(y).unwrap()); }
        let q = rows(&grid.at(&Tensor::from_vec(taus, (b, 50), &Device::Cpu).unwrap()).unwrap());
        for row in q { for w in row.windows(2) { prop_assert!(w[1] >= w[0] - 1e-6, "{} > {}", w[0], w[1]); } }
        let fr = nets.fraction.fractions(&f.fraction, &a).unwrap();
        for row in rows(&fr.taus) {
            prop_assert_eq!(row[0], 0.0);
            prop_assert_eq!(*row.last().unwrap(), 1.0);
            for w in row.windows(2) { prop_assert!(w[1] > w[0]); }
        }
    }
}

#[test]
fn quantile_interpolation_hits_the_grid_and_midpoints() {
    let values = Tensor::new(&[[0f32, 1.0, 3.0, 6.0]], &Device::Cpu).unwrap();
    let grid = pednav_nets::QuantileGrid { values, intervals: 3 };
    let taus = Tensor::new(&[[0f32, 1.0 / 6.0, 1.0 / 3.0, 0.5, 1.0]], &Device::Cpu).unwrap();
    let q = rows(&grid.at(&taus).unwrap())[0].clone();
    for (got, want) in q.iter().zip([0.0, 0.5, 1.0, 2.0, 6.0]) {
        assert!((got - want).abs() < 1e-5, "{q:?}");
    }
}
