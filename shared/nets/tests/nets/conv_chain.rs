//! The convolution chain op (`ops::conv_chain`: the 3D-TCN's frame layers as one op
//! with its own backward pass) against the same layers applied one by one with
//! `ops::conv` (bit for bit: the same drivers in the same order) and against central
//! finite differences, on every instruction-set path of this CPU (the binary re-runs
//! itself per path, `main.rs`).

use candle_core::{Device, Tensor, Var};
use pednav_nets::encoder::{SPATIAL_STAGES, temporal_plan};
use pednav_nets::ops::conv::ConvPrecision;
use pednav_nets::ops::{ConvSpec, conv, conv_chain};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random(rng: &mut ChaCha8Rng, shape: &[usize], scale: f32) -> Tensor {
    let n: usize = shape.iter().product();
    let data: Vec<f32> = (0..n).map(|_| rng.random_range(-scale..scale)).collect();
    Tensor::from_vec(data, shape, &Device::Cpu).unwrap()
}

fn to_vec(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1().unwrap()
}

/// The 3D-TCN's frame layers for N_h `history` (the encoder's own plan), in `precision`.
fn frame_layer_specs(history: usize, precision: ConvPrecision) -> Vec<(ConvSpec, usize, usize)> {
    let plan = temporal_plan(history);
    let mut layers = Vec::new();
    let mut c_in = 1;
    for (&(kt, dt), &(k, s, p, c)) in plan.iter().zip(&SPATIAL_STAGES) {
        layers.push((ConvSpec::spatiotemporal(kt, dt, k, s, p).with_precision(precision), c_in, c));
        c_in = c;
    }
    let (kt, _) = plan[SPATIAL_STAGES.len()];
    layers.push((ConvSpec::temporal(kt, 1).with_precision(precision), c_in, c_in));
    layers
}

/// Weights and biases for `specs`, scaled as the layers initialise them.
fn parameters(rng: &mut ChaCha8Rng, specs: &[(ConvSpec, usize, usize)]) -> Vec<(Var, Var, ConvSpec)> {
    specs
        .iter()
        .map(|&(spec, ci, co)| {
            let bound = 1.0 / (spec.weight_rows(ci) as f32).sqrt();
            let w = Var::from_tensor(&random(rng, &[spec.weight_rows(ci), co], bound)).unwrap();
            let b = Var::from_tensor(&random(rng, &[co], bound)).unwrap();
            (w, b, spec)
        })
        .collect()
}

fn links(params: &[(Var, Var, ConvSpec)]) -> Vec<(&Tensor, &Tensor, ConvSpec)> {
    params.iter().map(|(w, b, s)| (w.as_tensor(), b.as_tensor(), *s)).collect()
}

fn one_by_one(x: &Tensor, params: &[(Var, Var, ConvSpec)]) -> Tensor {
    params.iter().fold(x.clone(), |x, (w, b, s)| conv(&x, w, b, *s).unwrap())
}

/// Output and every gradient (input where it is a variable, each weight and bias) of
/// the chain op equal those of the layers one by one, bit for bit: the frame layers
/// at the CPU preset's size (42², N_h 8, the transition's N_h + 1 frames) and at the
/// paper's N_h 16 on smaller frames, in f32 and in the preset's `auto` precision (bf16
/// where this path has it), with frames as data (the encoder) and as a variable.
#[test]
fn the_chain_equals_its_layers_one_by_one_bit_for_bit() {
    for (history, frames, size) in [(8, 9, 42), (16, 17, 24)] {
        for precision in [ConvPrecision::F32, ConvPrecision::Auto] {
            for input_grad in [false, true] {
                let what = format!("N_h {history}, {size}², {precision:?}, input gradient {input_grad}");
                let mut rng = ChaCha8Rng::seed_from_u64(history as u64 * 10 + input_grad as u64);
                let params = parameters(&mut rng, &frame_layer_specs(history, precision));
                let x = Var::from_tensor(&random(&mut rng, &[3, frames, size, size, 1], 1.0)).unwrap();
                let x_in = if input_grad { x.as_tensor().clone() } else { x.as_tensor().detach() };
                let fused = conv_chain(&x_in, &links(&params)).unwrap();
                let reference = one_by_one(&x_in, &params);
                assert_eq!(fused.dims(), reference.dims(), "{what}");
                assert_eq!(to_vec(&fused), to_vec(&reference), "{what}: outputs");
                let r = random(&mut rng, fused.dims(), 1.0);
                let g1 = (&fused * &r).unwrap().sum_all().unwrap().backward().unwrap();
                let g2 = (&reference * &r).unwrap().sum_all().unwrap().backward().unwrap();
                for (i, (w, b, _)) in params.iter().enumerate() {
                    assert_eq!(to_vec(g1.get(w).unwrap()), to_vec(g2.get(w).unwrap()), "{what}: layer {i} weight");
                    assert_eq!(to_vec(g1.get(b).unwrap()), to_vec(g2.get(b).unwrap()), "{what}: layer {i} bias");
                }
                assert_eq!(g1.get(&x_in).is_some(), input_grad, "{what}: input gradient present iff asked");
                if input_grad {
                    assert_eq!(to_vec(g1.get(&x).unwrap()), to_vec(g2.get(&x).unwrap()), "{what}: input gradient");
                }
            }
        }
    }
}

/// ∂/∂θ of L = Σ y ⊙ R for a three-layer chain without ReLUs (so L is linear in each
/// single parameter and input value, and the central difference with step 0.5 is
/// exact up to rounding), against the chain op's gradients: 25 entries of the input,
/// every layer's weight and every bias.
#[test]
fn chain_gradients_match_finite_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let specs = vec![
        (ConvSpec::spatiotemporal(2, 1, 4, 2, 1).linear(), 1, 8),
        (ConvSpec::spatiotemporal(2, 2, 3, 2, 1).linear(), 8, 16),
        (ConvSpec::temporal(2, 1).linear(), 16, 16),
    ];
    let params = parameters(&mut rng, &specs);
    let x = Var::from_tensor(&random(&mut rng, &[2, 6, 10, 9, 1], 1.0)).unwrap();
    let y = conv_chain(&x, &links(&params)).unwrap();
    let r = random(&mut rng, y.dims(), 1.0);
    let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
    // L with one tensor replaced: index 0 the input, then weight and bias per layer.
    let loss = |replace: usize, with: &Tensor| -> f64 {
        let mut tensors: Vec<Tensor> = vec![x.as_tensor().clone()];
        for (w, b, _) in &params {
            tensors.push(w.as_tensor().clone());
            tensors.push(b.as_tensor().clone());
        }
        tensors[replace] = with.clone();
        let chain: Vec<_> =
            params.iter().enumerate().map(|(i, (_, _, s))| (&tensors[1 + 2 * i], &tensors[2 + 2 * i], *s)).collect();
        let y = to_vec(&conv_chain(&tensors[0], &chain).unwrap());
        y.iter().zip(to_vec(&r)).map(|(a, b)| *a as f64 * b as f64).sum()
    };
    let mut checked: Vec<(String, usize, &Var)> = vec![("input".into(), 0, &x)];
    for (i, (w, b, _)) in params.iter().enumerate() {
        checked.push((format!("layer {i} weight"), 1 + 2 * i, w));
        checked.push((format!("layer {i} bias"), 2 + 2 * i, b));
    }
    let h = 0.5f32;
    for (what, slot, var) in checked {
        let analytic = to_vec(grads.get(var).unwrap_or_else(|| panic!("no gradient for the {what}")));
        let base = to_vec(var.as_tensor());
        let picks: Vec<usize> = if base.len() <= 25 {
            (0..base.len()).collect()
        } else {
            (0..25).map(|_| rng.random_range(0..base.len())).collect()
        };
        for i in picks {
            let shifted = |d: f32| {
                let mut v = base.clone();
                v[i] += d;
                Tensor::from_vec(v, var.dims(), &Device::Cpu).unwrap()
            };
            let numeric = (loss(slot, &shifted(h)) - loss(slot, &shifted(-h))) / (2.0 * h as f64);
            let a = analytic[i] as f64;
            assert!((a - numeric).abs() <= 1e-3 * (1.0 + numeric.abs()), "d/d({what})[{i}]: analytic {a} vs {numeric}");
        }
    }
}

/// A chain whose bias does not match its weight is refused, naming the bias; one
/// layer is the plain convolution.
#[test]
fn chain_shape_errors_name_the_tensor() {
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let spec = ConvSpec::temporal(2, 1);
    let x = random(&mut rng, &[1, 4, 3, 3, 2], 1.0);
    let (w, b, bad_b) = (random(&mut rng, &[4, 3], 1.0), random(&mut rng, &[3], 1.0), random(&mut rng, &[2], 1.0));
    let w2 = random(&mut rng, &[6, 3], 1.0);
    let err = conv_chain(&x, &[(&w, &b, spec), (&w2, &bad_b, spec)]).unwrap_err().to_string();
    assert!(err.contains("bias"), "{err}");
    let single = conv_chain(&x, &[(&w, &b, spec)]).unwrap();
    assert_eq!(to_vec(&single), to_vec(&conv(&x, &w, &b, spec).unwrap()));
}
