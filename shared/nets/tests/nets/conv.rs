//! The channel-last convolution kernel against independent values: central finite
//! differences (exact for a linear op up to rounding) and candle's own `conv2d`, on
//! every instruction-set path of this CPU (the binary re-runs itself per path, `main.rs`).

use candle_core::{Device, Tensor, Var};
use pednav_nets::ops::{ConvSpec, conv, conv_reference};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random(rng: &mut ChaCha8Rng, shape: &[usize]) -> Tensor {
    let n: usize = shape.iter().product();
    let data: Vec<f32> = (0..n).map(|_| rng.random_range(-1.0..1.0)).collect();
    Tensor::from_vec(data, shape, &Device::Cpu).unwrap()
}

fn to_vec(t: &Tensor) -> Vec<f32> {
    t.flatten_all().unwrap().to_vec1().unwrap()
}

struct Case {
    name: &'static str,
    input: [usize; 5],
    c_out: usize,
    spec: ConvSpec,
}

fn cases() -> Vec<Case> {
    let s = |kernel, stride: [usize; 2], padding: [usize; 2], dilation_t| ConvSpec {
        kernel,
        stride,
        padding,
        dilation_t,
        relu: false,
        bf16: false,
    };
    vec![
        Case { name: "3d k2x4x4 s2 p1 d1", input: [2, 5, 9, 9, 2], c_out: 3, spec: s([2, 4, 4], [2, 2], [1, 1], 1) },
        Case {
            name: "3d k2x3x3 s1 p1 d2 odd",
            input: [2, 6, 7, 8, 3],
            c_out: 4,
            spec: s([2, 3, 3], [1, 1], [1, 1], 2),
        },
        Case { name: "3d k3x3x3 s3 p0 d2", input: [1, 7, 9, 12, 2], c_out: 2, spec: s([3, 3, 3], [3, 3], [0, 0], 2) },
        Case { name: "3d k2x3x3 s2 p2 d4", input: [2, 9, 5, 5, 1], c_out: 3, spec: s([2, 3, 3], [2, 2], [2, 2], 4) },
        Case { name: "2d k4 s2 p1", input: [2, 1, 9, 9, 4], c_out: 3, spec: s([1, 4, 4], [2, 2], [1, 1], 1) },
        Case { name: "1d k2 d4", input: [3, 9, 1, 1, 3], c_out: 5, spec: s([2, 1, 1], [1, 1], [0, 0], 4) },
        Case { name: "temporal k5 over 3x3", input: [2, 5, 3, 3, 4], c_out: 3, spec: s([5, 1, 1], [1, 1], [0, 0], 1) },
        Case { name: "pointwise", input: [2, 2, 3, 3, 3], c_out: 2, spec: s([1, 1, 1], [1, 1], [0, 0], 1) },
        // One input channel with a lane-sized C_out: the direct kernel.
        Case {
            name: "direct 1ch k2x4x4 s2 p1 d2 odd",
            input: [3, 6, 9, 10, 1],
            c_out: 16,
            spec: s([2, 4, 4], [2, 2], [1, 1], 2),
        },
        Case {
            name: "direct 1ch k3x3x3 s3 p0 d1",
            input: [2, 4, 9, 12, 1],
            c_out: 8,
            spec: s([3, 3, 3], [3, 3], [0, 0], 1),
        },
        Case {
            name: "direct 1ch 2d k4 s2 p2",
            input: [2, 1, 8, 6, 1],
            c_out: 32,
            spec: s([1, 4, 4], [2, 2], [2, 2], 1),
        },
        Case {
            name: "direct 1ch k2x4x4 s2 p1 d1",
            input: [2, 3, 10, 10, 1],
            c_out: 16,
            spec: s([2, 4, 4], [2, 2], [1, 1], 1),
        },
        // Several input channels.
        Case {
            name: "16ch k2x4x4 s2 p1 d2 C_out 32 (64 KiB of weights: direct)",
            input: [2, 5, 10, 12, 16],
            c_out: 32,
            spec: s([2, 4, 4], [2, 2], [1, 1], 2),
        },
        Case {
            name: "direct 32ch k2x3x3 s3 p0 C_out 64 (channel groups; direct input gradient)",
            input: [2, 3, 7, 8, 32],
            c_out: 64,
            spec: s([2, 3, 3], [3, 3], [0, 0], 1),
        },
        Case {
            name: "16ch 2d k3 s2 p1 (input gradient: direct on AVX2, gemm on AVX-512)",
            input: [2, 1, 9, 9, 16],
            c_out: 16,
            spec: s([1, 3, 3], [2, 2], [1, 1], 1),
        },
        Case {
            name: "direct temporal k3 d2 over 3x3, 8ch C_out 16 (pointwise)",
            input: [2, 7, 3, 3, 8],
            c_out: 16,
            spec: s([3, 1, 1], [1, 1], [0, 0], 2),
        },
        Case {
            name: "12ch 2d k3 s1 p1 C_out 24 (gemm: no direct kernel for 24)",
            input: [2, 1, 6, 7, 12],
            c_out: 24,
            spec: s([1, 3, 3], [1, 1], [1, 1], 1),
        },
        Case {
            name: "direct 3ch k2x3x3 s1 p1 odd",
            input: [2, 3, 7, 9, 3],
            c_out: 16,
            spec: s([2, 3, 3], [1, 1], [1, 1], 1),
        },
        Case {
            name: "direct 4ch 2d k4 s2 p1",
            input: [2, 1, 8, 8, 4],
            c_out: 8,
            spec: s([1, 4, 4], [2, 2], [1, 1], 1),
        },
        // One sample: its output positions are split over the threads (inference),
        // with the direct kernel even beyond the training path's weight limit.
        Case {
            name: "1 sample 16ch C_out 32 (inference path)",
            input: [1, 4, 10, 10, 16],
            c_out: 32,
            spec: s([2, 4, 4], [2, 2], [1, 1], 1),
        },
        Case {
            name: "direct 1 sample 16ch",
            input: [1, 5, 9, 9, 16],
            c_out: 16,
            spec: s([2, 3, 3], [1, 1], [1, 1], 2),
        },
    ]
}

/// ∂/∂θ of L = Σ y ⊙ R by central differences with step 0.5 (L is linear in each
/// argument, so the difference quotient is exact up to rounding).
/// With `input_grad` false the input is a constant (the first layer of an encoder),
/// which takes the kernels' weight-gradient-only path.
fn fd_check(case: &Case, seed: u64, input_grad: bool) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let [_, _, _, _, ci] = case.input;
    let x = Var::from_tensor(&random(&mut rng, &case.input)).unwrap();
    let x_in = if input_grad { x.as_tensor().clone() } else { x.as_tensor().detach() };
    let w = Var::from_tensor(&random(&mut rng, &[case.spec.weight_rows(ci), case.c_out])).unwrap();
    let b = Var::from_tensor(&random(&mut rng, &[case.c_out])).unwrap();
    let y = conv(&x_in, &w, &b, case.spec).unwrap();
    let r = random(&mut rng, y.dims());
    let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
    assert_eq!(grads.get(&x).is_some(), input_grad, "{}: input gradient present iff asked", case.name);
    let loss = |x: &Tensor, w: &Tensor, b: &Tensor| -> f64 {
        let y = to_vec(&conv(x, w, b, case.spec).unwrap());
        y.iter().zip(to_vec(&r)).map(|(a, b)| *a as f64 * b as f64).sum()
    };
    let h = 0.5f32;
    let checked: &[(&str, &Var)] =
        if input_grad { &[("input", &x), ("weight", &w), ("bias", &b)] } else { &[("weight", &w), ("bias", &b)] };
    for &(which, var) in checked {
        let analytic = to_vec(grads.get(var).unwrap_or_else(|| panic!("{}: no gradient for {which}", case.name)));
        let base = to_vec(var.as_tensor());
        let n = base.len();
        let picks: Vec<usize> =
            if n <= 40 { (0..n).collect() } else { (0..40).map(|_| rng.random_range(0..n)).collect() };
        for i in picks {
            let shifted = |delta: f32| {
                let mut v = base.clone();
                v[i] += delta;
                Tensor::from_vec(v, var.dims(), &Device::Cpu).unwrap()
            };
            let (plus, minus) = (shifted(h), shifted(-h));
            let (lp, lm) = match which {
                "input" => (loss(&plus, &w, &b), loss(&minus, &w, &b)),
                "weight" => (loss(&x, &plus, &b), loss(&x, &minus, &b)),
                _ => (loss(&x, &w, &plus), loss(&x, &w, &minus)),
            };
            let numeric = (lp - lm) / (2.0 * h as f64);
            let a = analytic[i] as f64;
            assert!(
                (a - numeric).abs() <= 1e-3 * (1.0 + numeric.abs()),
                "{}: d/d{which}[{i}] analytic {a} vs finite difference {numeric}",
                case.name
            );
        }
    }
}

#[test]
fn gradients_match_finite_differences() {
    for (i, case) in cases().iter().enumerate() {
        fd_check(case, 100 + i as u64, true);
        fd_check(case, 300 + i as u64, false);
    }
}

#[test]
fn relu_gradients_match_finite_differences_away_from_the_kink() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let spec = ConvSpec { relu: true, ..ConvSpec::spatiotemporal(2, 2, 3, 2, 1) };
    let x = Var::from_tensor(&random(&mut rng, &[2, 5, 7, 7, 2])).unwrap();
    let w = random(&mut rng, &[spec.weight_rows(2), 3]);
    let b = random(&mut rng, &[3]);
    let y = conv(&x, &w, &b, spec).unwrap();
    let pre = to_vec(&conv(&x, &w, &b, spec.linear()).unwrap());
    let r = random(&mut rng, y.dims());
    let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
    let analytic = to_vec(grads.get(&x).unwrap());
    let base = to_vec(x.as_tensor());
    let h = 1e-2f32;
    let mut checked = 0;
    for i in (0..base.len()).step_by(7) {
        let eval = |d: f32| -> (f64, Vec<f32>) {
            let mut v = base.clone();
            v[i] += d;
            let xt = Tensor::from_vec(v, x.dims(), &Device::Cpu).unwrap();
            let y = to_vec(&conv(&xt, &w, &b, spec).unwrap());
            let p = to_vec(&conv(&xt, &w, &b, spec.linear()).unwrap());
            (y.iter().zip(to_vec(&r)).map(|(a, b)| *a as f64 * b as f64).sum(), p)
        };
        let ((lp, pp), (lm, pm)) = (eval(h), eval(-h));
        // Skip perturbations that move any pre-activation across zero.
        if pre.iter().zip(&pp).zip(&pm).any(|((a, b), c)| (a.signum() != b.signum()) || (a.signum() != c.signum())) {
            continue;
        }
        let numeric = (lp - lm) / (2.0 * h as f64);
        assert!(
            (analytic[i] as f64 - numeric).abs() <= 2e-2 * (1.0 + numeric.abs()),
            "relu d/dx[{i}]: {} vs {numeric}",
            analytic[i]
        );
        checked += 1;
    }
    assert!(checked > 20, "too few entries away from the ReLU kink ({checked})");
}

#[test]
fn outputs_and_gradients_equal_candles_conv2d() {
    for (i, case) in cases().iter().enumerate() {
        for relu in [false, true] {
            let spec = ConvSpec { relu, ..case.spec };
            let mut rng = ChaCha8Rng::seed_from_u64(200 + i as u64);
            let [_, _, _, _, ci] = case.input;
            let x = Var::from_tensor(&random(&mut rng, &case.input)).unwrap();
            let w = Var::from_tensor(&random(&mut rng, &[spec.weight_rows(ci), case.c_out])).unwrap();
            let b = Var::from_tensor(&random(&mut rng, &[case.c_out])).unwrap();
            let ours = conv(&x, &w, &b, spec).unwrap();
            let reference = conv_reference(&x, &w, &b, spec).unwrap();
            assert_eq!(ours.dims(), reference.dims(), "{}", case.name);
            let close = |a: &Tensor, b: &Tensor, what: &str| {
                for (u, v) in to_vec(a).iter().zip(to_vec(b)) {
                    assert!((u - v).abs() <= 1e-5 * (1.0 + v.abs()), "{} relu={relu} {what}: {u} vs {v}", case.name);
                }
            };
            close(&ours, &reference, "output");
            // candle 0.11's conv2d backward returns a wrongly sized input gradient when
            // the stride does not divide (size + 2·padding − kernel); compare gradients
            // only where its reference is well defined (the finite-difference test
            // covers the other shapes).
            let [_, _, h, wd, _] = case.input;
            let exact = [(h, 0), (wd, 1)]
                .iter()
                .all(|&(n, a)| (n + 2 * spec.padding[a] - spec.kernel[a + 1]).is_multiple_of(spec.stride[a]));
            if !exact {
                continue;
            }
            let r = random(&mut rng, ours.dims());
            let g1 = (&ours * &r).unwrap().sum_all().unwrap().backward().unwrap();
            let g2 = (&reference * &r).unwrap().sum_all().unwrap().backward().unwrap();
            for (what, var) in [("dx", &x), ("dw", &w), ("db", &b)] {
                close(g1.get(var).unwrap(), g2.get(var).unwrap(), what);
            }
            // A constant input (first layer): the weight-gradient-only path.
            let xc = x.as_tensor().detach();
            let g1 = (conv(&xc, &w, &b, spec).unwrap() * &r).unwrap().sum_all().unwrap().backward().unwrap();
            let g2 = (conv_reference(&xc, &w, &b, spec).unwrap() * &r).unwrap().sum_all().unwrap().backward().unwrap();
            for (what, var) in [("dw (constant input)", &w), ("db (constant input)", &b)] {
                close(g1.get(var).unwrap(), g2.get(var).unwrap(), what);
            }
        }
    }
}

/// Mixed precision (`ConvSpec::bf16`) on the 3D-TCN's layer shapes at 42² (and one
/// sample, the inference path), against the f32 op: the output (ReLU on) within bf16
/// rounding (relative L2 error ≤ 1 %); without the ReLU (whose mask would differ
/// wherever rounding moves an output across zero) the input and weight gradients
/// within bf16 rounding and the bias gradient, which stays f32, equal up to
/// summation order; a layer the bf16 kernels do not take gives the f32 result.
#[test]
fn bf16_convolutions_stay_within_rounding_of_f32() {
    if !pednav_nets::ops::conv::bf16_available() {
        eprintln!("skipped: no AVX-512 BF16 on this CPU's active path");
        return;
    }
    let rel_l2 = |a: &[f32], b: &[f32]| -> f64 {
        let num: f64 = a.iter().zip(b).map(|(u, v)| (*u as f64 - *v as f64).powi(2)).sum();
        let den: f64 = b.iter().map(|v| (*v as f64).powi(2)).sum();
        (num / den.max(1e-30)).sqrt()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    // The parts the bf16 kernels compute for each layer (layer 0's input gradient
    // goes through gemm: its rows of k_w·C_in = 4 inputs are narrower than a tile).
    let all: &[&str] = &["output", "dx", "dW"];
    for (name, input, c_out, spec, half_parts) in [
        ("layer 0", [3, 9, 42, 42, 1], 16, ConvSpec::spatiotemporal(2, 1, 4, 2, 1), &["output", "dW"][..]),
        ("layer 1", [3, 8, 21, 21, 16], 32, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), all),
        ("layer 2", [3, 6, 10, 10, 32], 64, ConvSpec::spatiotemporal(2, 4, 3, 3, 0), all),
        ("one sample", [1, 8, 21, 21, 16], 32, ConvSpec::spatiotemporal(2, 2, 4, 2, 1), all),
        ("actions (C_in 3, C_out 8: f32)", [3, 7, 1, 1, 3], 8, ConvSpec::temporal(2, 1), &[][..]),
    ] {
        let ci = input[4];
        let x = Var::from_tensor(&random(&mut rng, &input)).unwrap();
        let w = Var::from_tensor(&(random(&mut rng, &[spec.weight_rows(ci), c_out]) * 0.2).unwrap()).unwrap();
        let b = Var::from_tensor(&random(&mut rng, &[c_out])).unwrap();
        let linear = spec.linear();
        let r = random(&mut rng, conv(&x, &w, &b, linear).unwrap().dims());
        let run = |s: ConvSpec| {
            let y = conv(&x, &w, &b, s).unwrap();
            let grads = (&y * &r).unwrap().sum_all().unwrap().backward().unwrap();
            let g = |v: &Var| to_vec(grads.get(v).unwrap());
            [g(&x), g(&w), g(&b)]
        };
        let half = |s: ConvSpec| ConvSpec { bf16: true, ..s };
        let relu = ConvSpec { relu: true, ..spec };
        let (y, y_half) = (to_vec(&conv(&x, &w, &b, relu).unwrap()), to_vec(&conv(&x, &w, &b, half(relu)).unwrap()));
        let (exact, grads) = (run(linear), run(half(linear)));
        for (what, a, e) in [("output", &y_half, &y), ("dx", &grads[0], &exact[0]), ("dW", &grads[1], &exact[1])]
            .into_iter()
            .chain([("db", &grads[2], &exact[2])])
        {
            let err = rel_l2(a, e);
            assert!(a.iter().all(|v| v.is_finite()), "{name} {what}: not finite");
            if half_parts.contains(&what) {
                // Within rounding, and not zero: the bf16 kernel ran.
                assert!(err <= 1e-2 && err > 0.0, "{name} {what}: relative L2 error {err:.2e} (bf16: (0, 1e-2])");
            } else {
                assert!(err <= 1e-5, "{name} {what}: relative L2 error {err:.2e} (f32: ≤ 1e-5)");
            }
        }
    }
}

#[test]
fn shape_errors_name_the_problem() {
    let x = Tensor::zeros((1, 1, 4, 4, 2), candle_core::DType::F32, &Device::Cpu).unwrap();
    let w = Tensor::zeros((7, 3), candle_core::DType::F32, &Device::Cpu).unwrap();
    let b = Tensor::zeros(3, candle_core::DType::F32, &Device::Cpu).unwrap();
    let err = conv(&x, &w, &b, ConvSpec::spatial(3, 1, 0)).unwrap_err().to_string();
    assert!(err.contains("weight has 7 rows"), "{err}");
    let w = Tensor::zeros((2 * 9 * 2, 3), candle_core::DType::F32, &Device::Cpu).unwrap();
    let err = conv(&x, &w, &b, ConvSpec::spatiotemporal(2, 1, 3, 1, 0)).unwrap_err().to_string();
    assert!(err.contains("does not fit"), "{err}");
}

/// The fully connected op equals candle's matmul + bias (row-streaming kernel for
/// few rows, gemm beyond), and its gradients match finite differences.
#[test]
fn linear_equals_matmul_and_finite_differences() {
    use pednav_nets::ops::linear;
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    for m in [1, 3, 8, 9, 40] {
        let (k, n) = (37, 21);
        let x = Var::from_tensor(&random(&mut rng, &[m, k])).unwrap();
        let w = Var::from_tensor(&random(&mut rng, &[k, n])).unwrap();
        let b = Var::from_tensor(&random(&mut rng, &[n])).unwrap();
        let ours = linear(&x, &w, &b).unwrap();
        let reference = x.matmul(&w).unwrap().broadcast_add(&b).unwrap();
        for (u, v) in to_vec(&ours).iter().zip(to_vec(&reference)) {
            assert!((u - v).abs() <= 1e-5 * (1.0 + v.abs()), "M {m}: {u} vs {v}");
        }
        let r = random(&mut rng, ours.dims());
        let grads = (&ours * &r).unwrap().sum_all().unwrap().backward().unwrap();
        let loss = |x: &Tensor, w: &Tensor, b: &Tensor| -> f64 {
            to_vec(&linear(x, w, b).unwrap()).iter().zip(to_vec(&r)).map(|(a, b)| *a as f64 * b as f64).sum()
        };
        for (which, var) in [("input", &x), ("weight", &w), ("bias", &b)] {
            let analytic = to_vec(grads.get(var).unwrap());
            let base = to_vec(var.as_tensor());
            for _ in 0..15 {
                let i = rng.random_range(0..base.len());
                let shifted = |d: f32| {
                    let mut v = base.clone();
                    v[i] += d;
                    Tensor::from_vec(v, var.dims(), &Device::Cpu).unwrap()
                };
                let (lp, lm) = match which {
                    "input" => (loss(&shifted(0.5), &w, &b), loss(&shifted(-0.5), &w, &b)),
                    "weight" => (loss(&x, &shifted(0.5), &b), loss(&x, &shifted(-0.5), &b)),
                    _ => (loss(&x, &w, &shifted(0.5)), loss(&x, &w, &shifted(-0.5))),
                };
                let numeric = lp - lm;
                assert!(
                    (analytic[i] as f64 - numeric).abs() <= 1e-3 * (1.0 + numeric.abs()),
                    "M {m} d/d{which}[{i}]: {} vs {numeric}",
                    analytic[i]
                );
            }
        }
    }
}
