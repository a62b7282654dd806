//! Static triangle geometry of a scene, in world coordinates, built once.
//!
//! Invariant: every obstacle's drawn volume equals its collider (boxes and
//! cylinders with the same footprint and height), except the purely visual
//! additions documented here: building windows (flush quads 5 cm off the wall),
//! tree crowns (above head height, 2.3–5 m, so never in the agent's way), and the
//! sky box far outside the world. Faces carry a baked shade: base shade times
//! `0.55 + 0.45·max(0, n·sun)`.

use bytemuck::{Pod, Zeroable};

use crate::region_map::RegionMap;
use crate::scene::{Footprint, ObstacleKind, Scene};

/// One vertex: world position, ground-texture uv, baked shade, textured flag.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct Vertex {
    /// World position (x east, y north, z up), metres.
    pub pos: [f32; 3],
    /// Ground texture coordinate (only used when `textured` is 1).
    pub uv: [f32; 2],
    /// Grey level, or a multiplier of the texture when textured.
    pub shade: f32,
    /// 1 for ground, 0 for everything else.
    pub textured: f32,
}

/// Shade of the sky box (also the haze colour).
pub const SKY_SHADE: f32 = 0.82;

/// Direction towards the sun (unnormalised); lights west- and south-facing walls.
const SUN: [f32; 3] = [-0.6, -0.45, 0.66];

fn lit(base: f32, n: [f32; 3]) -> f32 {
    let l = (SUN[0] * SUN[0] + SUN[1] * SUN[1] + SUN[2] * SUN[2]).sqrt();
    let d = (n[0] * SUN[0] + n[1] * SUN[1] + n[2] * SUN[2]) / l;
    base * (0.55 + 0.45 * d.max(0.0))
}

/// Triangle list builder.
#[derive(Default)]
pub struct MeshBuilder {
    /// Vertices, three per triangle.
    pub vertices: Vec<Vertex>,
}

impl MeshBuilder {
    fn tri(&mut self, a: [f32; 3], b: [f32; 3], c: [f32; 3], shade: f32) {
        for pos in [a, b, c] {
            self.vertices.push(Vertex { pos, uv: [0.0; 2], shade, textured: 0.0 });
        }
    }

    /// A planar quad a-b-c-d (either winding; culling is off).
    fn quad(&mut self, a: [f32; 3], b: [f32; 3], c: [f32; 3], d: [f32; 3], shade: f32) {
        self.tri(a, b, c, shade);
        self.tri(a, c, d, shade);
    }

    /// Axis-aligned box from `z0` to `z1` over a rectangle; `top` adds the roof.
    fn cuboid(&mut self, min: [f32; 2], max: [f32; 2], z0: f32, z1: f32, base: f32, top: bool) {
        let [x0, y0] = min;
        let [x1, y1] = max;
        self.quad([x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1], lit(base, [0.0, -1.0, 0.0]));
        self.quad([x1, y1, z0], [x0, y1, z0], [x0, y1, z1], [x1, y1, z1], lit(base, [0.0, 1.0, 0.0]));
        self.quad([x0, y1, z0], [x0, y0, z0], [x0, y0, z1], [x0, y1, z1], lit(base, [-1.0, 0.0, 0.0]));
        self.quad([x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1], lit(base, [1.0, 0.0, 0.0]));
        if top {
            self.quad([x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1], lit(base, [0.0, 0.0, 1.0]));
        }
    }

    /// Vertical prism with `segments` sides approximating a cylinder.
    fn cylinder(&mut self, c: [f32; 2], r: f32, z0: f32, z1: f32, base: f32, segments: usize) {
        let pt = |k: usize| {
            let a = k as f32 / segments as f32 * std::f32::consts::TAU;
            (c[0] + r * a.cos(), c[1] + r * a.sin(), a)
        };
        for k in 0..segments {
            let (xa, ya, aa) = pt(k);
            let (xb, yb, ab) = pt(k + 1);
            let mid = 0.5 * (aa + ab);
            let shade = lit(base, [mid.cos(), mid.sin(), 0.0]);
            self.quad([xa, ya, z0], [xb, yb, z0], [xb, yb, z1], [xa, ya, z1], shade);
            self.tri([c[0], c[1], z1], [xa, ya, z1], [xb, yb, z1], lit(base, [0.0, 0.0, 1.0]));
        }
    }

    /// Rows of dark windows on the four walls of a building.
    fn windows(&mut self, min: [f32; 2], max: [f32; 2], height: f32, base: f32) {
        let off = 0.05;
        let shade = (base * 0.45).min(0.3);
        let (w, h) = (1.2, 1.5);
        let mut z = 3.0;
        while z + h + 0.8 <= height {
            // South and north walls (run along x).
            for (y, sign) in [(min[1] - off, -1.0f32), (max[1] + off, 1.0)] {
                let mut x = min[0] + 1.5;
                while x + w <= max[0] - 1.0 {
                    let s = lit(shade, [0.0, sign, 0.0]);
                    self.quad([x, y, z], [x + w, y, z], [x + w, y, z + h], [x, y, z + h], s);
                    x += 3.0;
                }
            }
            // West and east walls (run along y).
            for (x, sign) in [(min[0] - off, -1.0f32), (max[0] + off, 1.0)] {
                let mut y = min[1] + 1.5;
                while y + w <= max[1] - 1.0 {
                    let s = lit(shade, [sign, 0.0, 0.0]);
                    self.quad([x, y, z], [x, y + w, z], [x, y + w, z + h], [x, y, z + h], s);
                    y += 3.0;
                }
            }
            z += 3.5;
        }
    }
}

/// Build the full static mesh of a scene.
pub fn build(scene: &Scene, map: &RegionMap) -> Vec<Vertex> {
    let mut m = MeshBuilder::default();
    // Ground: one quad far beyond the world; uv maps the region map's cells, clamped at its edge.
    let (gw, gh) = (map.nx as f32 * map.cell, map.ny as f32 * map.cell);
    let far = 600.0;
    let corners = [
        [scene.extent.min[0] - far, scene.extent.min[1] - far],
        [scene.extent.max[0] + far, scene.extent.min[1] - far],
        [scene.extent.max[0] + far, scene.extent.max[1] + far],
        [scene.extent.min[0] - far, scene.extent.max[1] + far],
    ];
    let gv = |p: [f32; 2]| Vertex {
        pos: [p[0], p[1], 0.0],
        uv: [(p[0] - map.x0) / gw, (p[1] - map.y0) / gh],
        shade: 1.0,
        textured: 1.0,
    };
    for k in [0, 1, 2, 0, 2, 3] {
        m.vertices.push(gv(corners[k]));
    }

    for o in &scene.obstacles {
        match (o.kind, o.footprint) {
            (ObstacleKind::Building, Footprint::Box(r)) => {
                m.cuboid(r.min, r.max, 0.0, o.height, o.shade, true);
                m.windows(r.min, r.max, o.height, o.shade);
            }
            (ObstacleKind::Tree, Footprint::Cylinder { center, radius }) => {
                m.cylinder(center, radius, 0.0, o.height, o.shade, 8);
                m.cylinder(center, 1.4, 2.3, o.height, (o.shade + 0.15).min(1.0), 8);
            }
            (_, Footprint::Box(r)) => m.cuboid(r.min, r.max, 0.0, o.height, o.shade, true),
            (_, Footprint::Cylinder { center, radius }) => m.cylinder(center, radius, 0.0, o.height, o.shade, 10),
        }
    }

    // Sky box around the world (walls and ceiling), drawn with the haze shade.
    let cx = 0.5 * (scene.extent.min[0] + scene.extent.max[0]);
    let cy = 0.5 * (scene.extent.min[1] + scene.extent.max[1]);
    let s = 400.0;
    let top = 300.0;
    let (x0, y0, x1, y1) = (cx - s, cy - s, cx + s, cy + s);
    let z0 = -1.0;
    m.quad([x0, y0, z0], [x1, y0, z0], [x1, y0, top], [x0, y0, top], SKY_SHADE);
    m.quad([x0, y1, z0], [x1, y1, z0], [x1, y1, top], [x0, y1, top], SKY_SHADE);
    m.quad([x0, y0, z0], [x0, y1, z0], [x0, y1, top], [x0, y0, top], SKY_SHADE);
    m.quad([x1, y0, z0], [x1, y1, z0], [x1, y1, top], [x1, y0, top], SKY_SHADE);
    m.quad([x0, y0, top], [x1, y0, top], [x1, y1, top], [x0, y1, top], SKY_SHADE);
    m.vertices
}
