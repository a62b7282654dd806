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
