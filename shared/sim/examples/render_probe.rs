//! Renderer cost probe: vertex count and views per CPU-second at 16 views.
//! `cargo run --release --example render_probe`
use pednav_sim::render::mesh;
use pednav_sim::{BackendChoice, CameraView, Look, Renderer, RendererConfig, Scene, SimConfig, SimWorld};
use std::time::Instant;

fn main() -> anyhow::Result<()> {
    let w = SimWorld::new(Scene::reference(), SimConfig::default())?;
    let m = mesh::build(&w.scene, &w.map);
    println!("vertices: {}, indices: {}", m.vertices.len(), m.indices.len());
    let size = std::env::var("SIZE").ok().and_then(|s| s.parse().ok()).unwrap_or(84);
    let cfg = RendererConfig {
        image_size: size,
        ..RendererConfig::from_sim(&w.config, 16, BackendChoice::from_env().unwrap())
    };
    let mut r = Renderer::new(&w.scene, &w.map, cfg)?;
    println!("adapter: {}", r.adapter_description());
    let cams: Vec<CameraView> = (0..16)
        .map(|i| CameraView { x: 10.0 + i as f32, y: -7.0, z: 1.6, yaw: i as f32, look: Look::default() })
        .collect();
    for _ in 0..5 {
        r.render(&cams)?;
    }
    let t = Instant::now();
    let n = 100;
    for _ in 0..n {
        r.render(&cams)?;
    }
    let s = t.elapsed().as_secs_f64();
    println!("{:.3} ms per 16-view batch, {:.0} views/s", s / n as f64 * 1e3, 16.0 * n as f64 / s);
    Ok(())
}
