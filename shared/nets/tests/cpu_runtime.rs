//! The process-wide CPU settings: subnormal floats flushed to zero in the thread that
//! set them, in threads it starts afterwards, and in the rayon pool the kernels use.

use std::hint::black_box;

fn half_of_the_smallest_normal() -> f32 {
    black_box(f32::MIN_POSITIVE) * black_box(0.5)
}

#[test]
fn subnormals_are_flushed_in_every_compute_thread() {
    // Without the setting, half the smallest normal float is a subnormal.
    let before = std::thread::spawn(half_of_the_smallest_normal).join().unwrap();
    assert!(before > 0.0 && !before.is_normal(), "a subnormal before the setting: {before:e}");

    pednav_nets::init_cpu_runtime(Some(2));
    assert!(pednav_nets::cpu::denormals_flushed());
    assert_eq!(half_of_the_smallest_normal(), 0.0, "main thread");
    assert_eq!(std::thread::spawn(half_of_the_smallest_normal).join().unwrap(), 0.0, "a thread started afterwards");
    let in_pool: Vec<f32> = rayon::broadcast(|_| half_of_the_smallest_normal());
    assert!(in_pool.iter().all(|v| *v == 0.0), "rayon workers: {in_pool:?}");
}
