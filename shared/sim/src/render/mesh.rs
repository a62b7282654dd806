//! Static indexed triangle geometry of a scene, in world coordinates, built once.
//!
//! Invariant: every obstacle's drawn volume equals its collider (boxes and
//! prisms approximating the cylinders, same footprint and height), except the
//! purely visual additions documented here: tree crowns (above head height,
//! 2.3 m up, so never in the agent's way). Building windows are not geometry: wall
//! vertices carry a facade code and the fragment shader paints an anti-aliased
//! window grid (3 m × 3.5 m bays, 1.2 m × 1.5 m windows from 3 m up to 0.8 m below
//! the roof). Faces carry a baked shade: base shade × `0.55 + 0.45·max(0, n·sun)`.
//!
//! Cost model (llvmpipe shades every vertex of every view): the mesh is indexed
//! (4 vertices per quad), and faces no camera can see are left out — roofs and
//! caps of anything taller than [`MAX_EYE_HEIGHT`], and the ground under buildings
//! is a single quad anyway.

use bytemuck::{Pod, Zeroable};

use crate::region_map::RegionMap;
use crate::scene::{Footprint, ObstacleKind, Scene};

/// One vertex: world position, ground-texture uv or facade data, baked shade, textured flag.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct Vertex {
    /// World position (x east, y north, z up), metres.
    pub pos: [f32; 3],
    /// Ground: texture coordinate. Walls of buildings: `[facade axis, window top]`
    /// with axis 1 = wall runs along x, 2 = along y; `[0, 0]` elsewhere.
    pub uv: [f32; 2],
    /// Grey level, or a multiplier of the texture when textured.
    pub shade: f32,
    /// 1 for ground, 0 for everything else.
    pub textured: f32,
}

/// Shade of the sky (the clear colour, also the haze colour).
pub const SKY_SHADE: f32 = 0.82;

pub use crate::config::MAX_EYE_HEIGHT;

/// Direction towards the sun (unnormalised); lights west- and south-facing walls.
const SUN: [f32; 3] = [-0.6, -0.45, 0.66];

fn lit(base: f32, n: [f32; 3]) -> f32 {
    let l = (SUN[0] * SUN[0] + SUN[1] * SUN[1] + SUN[2] * SUN[2]).sqrt();
    let d = (n[0] * SUN[0] + n[1] * SUN[1] + n[2] * SUN[2]) / l;
    base * (0.55 + 0.45 * d.max(0.0))
}

/// Indexed triangle list builder.
#[derive(Default)]
pub struct MeshBuilder {
    /// Vertices.
    pub vertices: Vec<Vertex>,
    /// Triangle indices.
    pub indices: Vec<u32>,
}

impl MeshBuilder {
    fn vertex(&mut self, pos: [f32; 3], uv: [f32; 2], shade: f32, textured: f32) -> u32 {
        self.vertices.push(Vertex { pos, uv, shade, textured });
        self.vertices.len() as u32 - 1
    }

    /// A planar quad a-b-c-d (either winding; culling is off) with facade data `uv`.
    fn quad_uv(&mut self, corners: [[f32; 3]; 4], uv: [f32; 2], shade: f32) {
        let k = corners.map(|p| self.vertex(p, uv, shade, 0.0));
        self.indices.extend_from_slice(&[k[0], k[1], k[2], k[0], k[2], k[3]]);
    }

    fn quad(&mut self, corners: [[f32; 3]; 4], shade: f32) {
        self.quad_uv(corners, [0.0, 0.0], shade);
    }

    /// Axis-aligned box from the ground to `z1`; `window_top > 0` paints windows on its walls.
    fn cuboid(&mut self, min: [f32; 2], max: [f32; 2], z1: f32, base: f32, window_top: f32) {
        let [x0, y0] = min;
        let [x1, y1] = max;
        let along_x = [if window_top > 0.0 { 1.0 } else { 0.0 }, window_top];
        let along_y = [if window_top > 0.0 { 2.0 } else { 0.0 }, window_top];
        self.quad_uv([[x0, y0, 0.0], [x1, y0, 0.0], [x1, y0, z1], [x0, y0, z1]], along_x, lit(base, [0.0, -1.0, 0.0]));
        self.quad_uv([[x1, y1, 0.0], [x0, y1, 0.0], [x0, y1, z1], [x1, y1, z1]], along_x, lit(base, [0.0, 1.0, 0.0]));
        self.quad_uv([[x0, y1, 0.0], [x0, y0, 0.0], [x0, y0, z1], [x0, y1, z1]], along_y, lit(base, [-1.0, 0.0, 0.0]));
        self.quad_uv([[x1, y0, 0.0], [x1, y1, 0.0], [x1, y1, z1], [x1, y0, z1]], along_y, lit(base, [1.0, 0.0, 0.0]));
        if z1 <= MAX_EYE_HEIGHT {
            self.quad([[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], lit(base, [0.0, 0.0, 1.0]));
        }
    }

    /// Vertical prism with `segments` sides approximating a cylinder.
    fn cylinder(&mut self, c: [f32; 2], r: f32, z0: f32, z1: f32, base: f32, segments: usize) {
        let pt = |k: usize| {
            let a = k as f32 / segments as f32 * std::f32::consts::TAU;
            [c[0] + r * a.cos(), c[1] + r * a.sin()]
        };
        for k in 0..segments {
            let (a, b) = (pt(k), pt(k + 1));
            let mid = (k as f32 + 0.5) / segments as f32 * std::f32::consts::TAU;
            let shade = lit(base, [mid.cos(), mid.sin(), 0.0]);
            self.quad([[a[0], a[1], z0], [b[0], b[1], z0], [b[0], b[1], z1], [a[0], a[1], z1]], shade);
        }
        if z1 <= MAX_EYE_HEIGHT {
            let top = self.vertex([c[0], c[1], z1], [0.0; 2], lit(base, [0.0, 0.0, 1.0]), 0.0);
            let rim: Vec<u32> = (0..segments)
                .map(|k| {
                    let p = pt(k);
                    self.vertex([p[0], p[1], z1], [0.0; 2], lit(base, [0.0, 0.0, 1.0]), 0.0)
                })
                .collect();
            for k in 0..segments {
                self.indices.extend_from_slice(&[top, rim[k], rim[(k + 1) % segments]]);
            }
        }
        if z0 > 0.0 {
            // Underside (tree crowns are seen from below).
            let bottom = self.vertex([c[0], c[1], z0], [0.0; 2], base * 0.5, 0.0);
            let rim: Vec<u32> = (0..segments)
                .map(|k| {
                    let p = pt(k);
                    self.vertex([p[0], p[1], z0], [0.0; 2], base * 0.5, 0.0)
                })
                .collect();
            for k in 0..segments {
                self.indices.extend_from_slice(&[bottom, rim[k], rim[(k + 1) % segments]]);
            }
        }
    }
}

/// A contiguous index range of one object, with its bounding circle on the ground
/// (for per-view culling).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Part {
    /// First index.
    pub start: u32,
    /// One past the last index.
    pub end: u32,
    /// Centre of the bounding circle.
    pub center: [f32; 2],
    /// Radius of the bounding circle (infinite for the ground: never culled).
    pub radius: f32,
}

/// The static mesh of a scene.
pub struct SceneMesh {
    /// Vertices.
    pub vertices: Vec<Vertex>,
    /// Triangle indices.
    pub indices: Vec<u32>,
    /// One part per obstacle, then the ground; together they cover `indices` in order.
    pub parts: Vec<Part>,
}

/// Build the full static mesh of a scene.
pub fn build(scene: &Scene, map: &RegionMap) -> SceneMesh {
    let mut m = MeshBuilder::default();
    let mut parts = Vec::with_capacity(scene.obstacles.len() + 1);
    for o in &scene.obstacles {
        let start = m.indices.len() as u32;
        match (o.kind, o.footprint) {
            (ObstacleKind::Building, Footprint::Box(r)) => m.cuboid(r.min, r.max, o.height, o.shade, o.height - 0.8),
            (ObstacleKind::Tree, Footprint::Cylinder { center, radius }) => {
                m.cylinder(center, radius, 0.0, o.height, o.shade, 6);
                m.cylinder(center, 1.4, 2.3, o.height, (o.shade + 0.15).min(1.0), 8);
            }
            (_, Footprint::Box(r)) => m.cuboid(r.min, r.max, o.height, o.shade, 0.0),
            (_, Footprint::Cylinder { center, radius }) => m.cylinder(center, radius, 0.0, o.height, o.shade, 6),
        }
        let (center, radius) = match o.footprint {
            Footprint::Box(r) => {
                ([(r.min[0] + r.max[0]) * 0.5, (r.min[1] + r.max[1]) * 0.5], 0.5 * r.width().hypot(r.height()))
            }
            Footprint::Cylinder { center, radius } => (center, if o.kind == ObstacleKind::Tree { 1.4 } else { radius }),
        };
        parts.push(Part { start, end: m.indices.len() as u32, center, radius });
    }
    let ground_start = m.indices.len() as u32;
    // Ground, drawn last so that early depth testing skips its (textured, costly)
    // fragments behind obstacles. One quad far beyond the world; uv maps the region map's cells, clamped at its edge.
    let (gw, gh) = (map.nx as f32 * map.cell, map.ny as f32 * map.cell);
    let far = 600.0;
    let corners = [
        [scene.extent.min[0] - far, scene.extent.min[1] - far],
        [scene.extent.max[0] + far, scene.extent.min[1] - far],
        [scene.extent.max[0] + far, scene.extent.max[1] + far],
        [scene.extent.min[0] - far, scene.extent.max[1] + far],
    ];
    let k = corners.map(|p| m.vertex([p[0], p[1], 0.0], [(p[0] - map.x0) / gw, (p[1] - map.y0) / gh], 1.0, 1.0));
    m.indices.extend_from_slice(&[k[0], k[1], k[2], k[0], k[2], k[3]]);

    parts.push(Part { start: ground_start, end: m.indices.len() as u32, center: [0.0; 2], radius: f32::INFINITY });
    SceneMesh { vertices: m.vertices, indices: m.indices, parts }
}

/// Can a camera at `(x, y)` looking along `yaw` with horizontal field of view
/// `fov` see any of the part's bounding cylinder? Conservative: a part counts as
/// visible when its bounding circle touches the view wedge widened by 5°, or the
/// camera stands within its circle (1 m of slack against the near plane).
pub fn part_visible(part: &Part, x: f32, y: f32, yaw: f32, fov: f32) -> bool {
    if !part.radius.is_finite() {
        return true;
    }
    let (dx, dy) = (part.center[0] - x, part.center[1] - y);
    let d = dx.hypot(dy);
    if d <= part.radius + 1.0 {
        return true;
    }
    let bearing = crate::scene::wrap_angle(dy.atan2(dx) - yaw).abs();
    let spread = (part.radius / d).min(1.0).asin();
    bearing <= 0.5 * fov + spread + 5f32.to_radians()
}

/// A full-view quad at the far plane in clip space, drawn (for domain-randomised
/// views only) so that the sky takes the view's brightness and contrast.
pub fn sky_quad() -> [Vertex; 4] {
    let v = |x: f32, y: f32| Vertex { pos: [x, y, 2.0], uv: [0.0; 2], shade: SKY_SHADE, textured: -1.0 };
    [v(-1.0, -1.0), v(1.0, -1.0), v(1.0, 1.0), v(-1.0, 1.0)]
}
