//! AdamW against hand-computed steps: the first step, the non-finite guard, global-norm
//! clipping, and moments that hold no autograd graph.

use candle_core::{Device, Tensor, Var};
use pednav_nets::{AdamW, AdamWConfig, OptimStep, ParamStore};

#[test]
fn adamw_first_step_is_lr_times_sign_and_nonfinite_gradients_change_nothing() {
    let mut store = ParamStore::new("p", &Device::Cpu);
    let v = store.insert("x", Tensor::new(&[1f32, -2.0, 3.0], &Device::Cpu).unwrap()).unwrap();
    let mut opt = AdamW::new(&store, AdamWConfig::with_lr(0.1)).unwrap();
    // loss = Σ c·x with c = (2, −0.5, 0): first bias-corrected step is −lr·g/(|g| + ε).
    let c = Tensor::new(&[2f32, -0.5, 0.0], &Device::Cpu).unwrap();
    let grads = (v.as_tensor() * &c).unwrap().sum_all().unwrap().backward().unwrap();
    assert!(
        matches!(opt.step(&grads).unwrap(), OptimStep::Applied { grad_norm } if (grad_norm - 4.25f64.sqrt()).abs() < 1e-6)
    );
    let x: Vec<f32> = v.to_vec1().unwrap();
    assert!((x[0] - 0.9).abs() < 1e-6 && (x[1] + 1.9).abs() < 1e-6 && (x[2] - 3.0).abs() < 1e-6, "{x:?}");
    let bad = (v.as_tensor() * Tensor::new(&[f32::NAN, 1.0, 1.0], &Device::Cpu).unwrap())
        .unwrap()
        .sum_all()
        .unwrap()
        .backward()
        .unwrap();
    assert_eq!(opt.step(&bad).unwrap(), OptimStep::SkippedNonFinite);
    assert_eq!(v.to_vec1::<f32>().unwrap(), x);
    assert_eq!(opt.steps(), 1);
}

#[test]
fn gradient_clipping_scales_the_global_norm() {
    let mut store = ParamStore::new("p", &Device::Cpu);
    let v: Var = store.insert("x", Tensor::new(&[0f32, 0.0], &Device::Cpu).unwrap()).unwrap();
    let cfg = AdamWConfig { max_grad_norm: Some(1.0), beta1: 0.0, beta2: 0.0, eps: 0.0, ..AdamWConfig::with_lr(1.0) };
    let mut opt = AdamW::new(&store, cfg).unwrap();
    // With β₁ = β₂ = 0 and ε = 0 the step is g/|g| elementwise, so clipping must not
    // change it; the reported norm is the unclipped one.
    let grads = (v.as_tensor() * Tensor::new(&[30f32, 40.0], &Device::Cpu).unwrap())
        .unwrap()
        .sum_all()
        .unwrap()
        .backward()
        .unwrap();
    assert_eq!(opt.step(&grads).unwrap(), OptimStep::Applied { grad_norm: 50.0 });
    assert_eq!(v.to_vec1::<f32>().unwrap(), vec![-1.0, -1.0]);
    let clipped = grads.get(&v).unwrap();
    assert_eq!(clipped.to_vec1::<f32>().unwrap(), vec![30.0, 40.0], "the caller's gradients are not modified");
}

#[test]
fn adamw_moments_hold_values_not_the_update_graph() {
    // For a loss non-linear in the parameters, the gradients `backward` returns are
    // themselves built from tracked tensors. Moments computed from them without
    // detaching would keep every previous step's graph alive (the learner's memory
    // grew by one update's graph — ≈15 MB on the CPU preset — per update).
    let mut store = ParamStore::new("p", &Device::Cpu);
    let v = store.insert("x", Tensor::new(&[1f32, -2.0, 3.0], &Device::Cpu).unwrap()).unwrap();
    let mut opt = AdamW::new(&store, AdamWConfig::with_lr(0.1)).unwrap();
    for _ in 0..3 {
        let grads = v.as_tensor().sqr().unwrap().sum_all().unwrap().backward().unwrap();
        assert!(grads.get(&v).unwrap().track_op(), "the premise: a gradient of Σx² carries a graph");
        opt.step(&grads).unwrap();
        for (name, t) in opt.state_tensors() {
            assert!(!t.track_op(), "moment {name} still tracks the update's graph");
        }
    }
}

#[test]
fn soft_update_is_the_polyak_average_and_refuses_other_shapes() {
    let dev = Device::Cpu;
    let mut target = ParamStore::new("target", &dev);
    let mut online = ParamStore::new("online", &dev);
    // Above the fused kernel's parallel threshold, so both of its paths run.
    let n = pednav_nets::ops::fused::PARALLEL_MIN + 5;
    let t: Var = target.insert("w", Tensor::new(&[1f32, -2.0], &dev).unwrap()).unwrap();
    online.insert("w", Tensor::new(&[3f32, 4.0], &dev).unwrap()).unwrap();
    let big: Var = target.insert("big", Tensor::ones(n, candle_core::DType::F32, &dev).unwrap()).unwrap();
    online.insert("big", Tensor::zeros(n, candle_core::DType::F32, &dev).unwrap()).unwrap();
    target.soft_update(&online, 0.25).unwrap();
    // 0.75·(1, −2) + 0.25·(3, 4) = (1.5, −0.5); 0.75·1 + 0.25·0 = 0.75.
    assert_eq!(t.to_vec1::<f32>().unwrap(), vec![1.5, -0.5]);
    assert!(big.to_vec1::<f32>().unwrap().iter().all(|&x| x == 0.75));
    let mut other = ParamStore::new("other", &dev);
    other.insert("w", Tensor::new(&[3f32, 4.0, 5.0], &dev).unwrap()).unwrap();
    other.insert("big", Tensor::zeros(n, candle_core::DType::F32, &dev).unwrap()).unwrap();
    let err = target.soft_update(&other, 0.25).unwrap_err().to_string();
    assert!(err.contains("`w`"), "{err}");
    assert_eq!(t.to_vec1::<f32>().unwrap(), vec![1.5, -0.5], "a refused update changes nothing");
}
