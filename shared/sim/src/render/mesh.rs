//! Static indexed triangle geometry of a scene, in world coordinates, built once.
//!
//! Invariant: every obstacle's drawn volume equals its collider (boxes and
//! prisms approximating the cylinders, same footprint and height), except the
//! purely visual additions documented here: tree crowns (two stacked frustums
//! from 2.3 m up, above head height, so never in the agent's way) and the scene's overhead details (at
//! least [`crate::appearance::MIN_OVERHEAD_BASE`] up, no collider). Facades are
//! not geometry: wall vertices carry the building's [`Facade`] as codes and lit
//! grey levels, and the fragment shader paints it anti-aliased — the windows of
//! the upper floors (from 3 m up to 0.8 m below the roof, one per bay and storey)
//! and the ground floor (shop windows under a sign band, or arcades). Faces carry
//! a baked shade: base shade × `0.55 + 0.45·max(0, n·sun)`, the facade's glass and
//! trim lit the same way.
//!
//! Cost model (llvmpipe shades every vertex of every view): the mesh is indexed
//! (4 vertices per quad), and faces no camera can see are left out — roofs and
//! caps of anything taller than [`MAX_EYE_HEIGHT`], and the ground under buildings
//! is a single quad anyway.

use bytemuck::{Pod, Zeroable};

use crate::appearance::{Facade, GroundFloor, WindowStyle};
use crate::region_map::RegionMap;
use crate::scene::{Footprint, ObstacleKind, Scene};

/// One vertex: world position, ground-texture uv, baked shade, textured flag and
/// the facade of a building's wall.
#[repr(C)]
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
pub struct Vertex {
    /// World position (x east, y north, z up), metres.
    pub pos: [f32; 3],
    /// Ground: texture coordinate; `[0, 0]` elsewhere.
    pub uv: [f32; 2],
    /// Grey level, or a multiplier of the texture when textured.
    pub shade: f32,
    /// 1 for ground, 0 for everything else (−1: the sky quad).
    pub textured: f32,
    /// Walls of buildings: `[axis, window top, window style, ground-floor style]`
    /// with axis 1 = the wall runs along x, 2 = along y, 0 = not a wall (then the
    /// rest is unused); styles as [`window_code`] and [`ground_floor_code`].
    pub facade: [f32; 4],
    /// Walls of buildings: `[bay, storey, lit glass grey, lit trim grey]`.
    pub facade_look: [f32; 4],
}

/// The shader's code of a window style.
pub fn window_code(w: WindowStyle) -> f32 {
    match w {
        WindowStyle::Grid => 0.0,
        WindowStyle::Tall => 1.0,
        WindowStyle::Ribbon => 2.0,
        WindowStyle::Curtain => 3.0,
        WindowStyle::Blank => 4.0,
    }
}

/// The shader's code of a ground floor.
pub fn ground_floor_code(g: GroundFloor) -> f32 {
    match g {
        GroundFloor::Plain => 0.0,
        GroundFloor::Shop => 1.0,
        GroundFloor::Arcade => 2.0,
    }
}

/// The facade data of one wall of a building: which way it runs, where its windows
/// stop, and its grey levels lit for the wall's normal `n`.
#[derive(Debug, Clone, Copy)]
struct Wall<'a> {
    facade: &'a Facade,
    window_top: f32,
}

impl Wall<'_> {
    fn vertex_data(&self, axis: f32, base: f32, n: [f32; 3]) -> ([f32; 4], [f32; 4]) {
        let f = self.facade;
        let glass = f.glass.unwrap_or(base * 0.45);
        (
            [axis, self.window_top, window_code(f.windows), ground_floor_code(f.ground_floor)],
            [f.bay, f.storey, lit(glass, n), lit(f.trim, n)],
        )
    }
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
        self.vertices.push(Vertex { pos, uv, shade, textured, facade: [0.0; 4], facade_look: [0.0; 4] });
        self.vertices.len() as u32 - 1
    }

    /// A planar quad a-b-c-d (either winding; culling is off) with facade data.
    fn quad_facade(&mut self, corners: [[f32; 3]; 4], shade: f32, facade: ([f32; 4], [f32; 4])) {
        let k = corners.map(|pos| {
            self.vertices.push(Vertex {
                pos,
                uv: [0.0; 2],
                shade,
                textured: 0.0,
                facade: facade.0,
                facade_look: facade.1,
            });
            self.vertices.len() as u32 - 1
        });
        self.indices.extend_from_slice(&[k[0], k[1], k[2], k[0], k[2], k[3]]);
    }

    fn quad(&mut self, corners: [[f32; 3]; 4], shade: f32) {
        self.quad_facade(corners, shade, ([0.0; 4], [0.0; 4]));
    }

    /// A planar quad of one flat shade (no lighting): lamps and figures.
    pub(crate) fn flat_quad(&mut self, corners: [[f32; 3]; 4], shade: f32) {
        self.quad(corners, shade);
    }

    /// A closed box from `min` to `max`, every face lit from the sun as it faces.
    pub(crate) fn shaded_box(&mut self, min: [f32; 3], max: [f32; 3], base: f32) {
        let ([x0, y0, z0], [x1, y1, z1]) = (min, max);
        let faces = [
            ([[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]], [0.0, -1.0, 0.0]),
            ([[x1, y1, z0], [x0, y1, z0], [x0, y1, z1], [x1, y1, z1]], [0.0, 1.0, 0.0]),
            ([[x0, y1, z0], [x0, y0, z0], [x0, y0, z1], [x0, y1, z1]], [-1.0, 0.0, 0.0]),
            ([[x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1]], [1.0, 0.0, 0.0]),
            ([[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], [0.0, 0.0, 1.0]),
        ];
        for (corners, n) in faces {
            self.quad(corners, lit(base, n));
        }
    }

    /// Axis-aligned box from `z0` to `z1`; a `wall` paints its facade on the sides.
    fn cuboid(&mut self, min: [f32; 2], max: [f32; 2], [z0, z1]: [f32; 2], base: f32, wall: Option<Wall<'_>>) {
        let [x0, y0] = min;
        let [x1, y1] = max;
        let side = |axis: f32, n: [f32; 3]| match wall {
            Some(w) => w.vertex_data(axis, base, n),
            None => ([0.0; 4], [0.0; 4]),
        };
        let sides = [
            ([[x0, y0, z0], [x1, y0, z0], [x1, y0, z1], [x0, y0, z1]], 1.0, [0.0, -1.0, 0.0]),
            ([[x1, y1, z0], [x0, y1, z0], [x0, y1, z1], [x1, y1, z1]], 1.0, [0.0, 1.0, 0.0]),
            ([[x0, y1, z0], [x0, y0, z0], [x0, y0, z1], [x0, y1, z1]], 2.0, [-1.0, 0.0, 0.0]),
            ([[x1, y0, z0], [x1, y1, z0], [x1, y1, z1], [x1, y0, z1]], 2.0, [1.0, 0.0, 0.0]),
        ];
        for (corners, axis, n) in sides {
            self.quad_facade(corners, lit(base, n), side(axis, n));
        }
        if z1 <= MAX_EYE_HEIGHT {
            self.quad([[x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], lit(base, [0.0, 0.0, 1.0]));
        }
        if z0 > 0.0 {
            // The underside of something overhead.
            self.quad([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0]], lit(base, [0.0, 0.0, -1.0]));
        }
    }

    /// Vertical prism with `segments` sides approximating a cylinder.
    fn cylinder(&mut self, c: [f32; 2], r: f32, z0: f32, z1: f32, base: f32, segments: usize) {
        self.frustum(c, [r, r], [z0, z1], base, segments);
    }

    /// Vertical frustum with `segments` sides, radius `r0` at `z0` and `r1` at `z1`;
    /// a cap on top when a camera can see it, underneath when it floats.
    fn frustum(&mut self, c: [f32; 2], [r0, r1]: [f32; 2], [z0, z1]: [f32; 2], base: f32, segments: usize) {
        let pt = |k: usize, r: f32| {
            let a = k as f32 / segments as f32 * std::f32::consts::TAU;
            [c[0] + r * a.cos(), c[1] + r * a.sin()]
        };
        // Side normals lean by the slope of the frustum (up when it narrows upwards).
        let lean = (r0 - r1) / (z1 - z0).max(1e-3);
        let norm = (1.0 + lean * lean).sqrt();
        for k in 0..segments {
            let (a0, b0, a1, b1) = (pt(k, r0), pt(k + 1, r0), pt(k, r1), pt(k + 1, r1));
            let mid = (k as f32 + 0.5) / segments as f32 * std::f32::consts::TAU;
            let shade = lit(base, [mid.cos() / norm, mid.sin() / norm, lean / norm]);
            self.quad([[a0[0], a0[1], z0], [b0[0], b0[1], z0], [b1[0], b1[1], z1], [a1[0], a1[1], z1]], shade);
        }
        if z1 <= MAX_EYE_HEIGHT {
            self.disc(c, r1, z1, segments, lit(base, [0.0, 0.0, 1.0]));
        }
        if z0 > 0.0 {
            // Underside (tree crowns are seen from below).
            self.disc(c, r0, z0, segments, base * 0.5);
        }
    }

    /// A horizontal polygon of `segments` sides at height `z`.
    fn disc(&mut self, c: [f32; 2], r: f32, z: f32, segments: usize, shade: f32) {
        let centre = self.vertex([c[0], c[1], z], [0.0; 2], shade, 0.0);
        let rim: Vec<u32> = (0..segments)
            .map(|k| {
                let a = k as f32 / segments as f32 * std::f32::consts::TAU;
                self.vertex([c[0] + r * a.cos(), c[1] + r * a.sin(), z], [0.0; 2], shade, 0.0)
            })
            .collect();
        for k in 0..segments {
            self.indices.extend_from_slice(&[centre, rim[k], rim[(k + 1) % segments]]);
        }
    }

    /// A tree's crown of radius `r` from 2.3 m up to `top`: widening to its full
    /// radius at 45 % of its height, then narrowing to a third of it.
    fn crown(&mut self, c: [f32; 2], r: f32, top: f32, base: f32) {
        let z0 = 2.3;
        let mid = z0 + 0.45 * (top - z0).max(0.0);
        self.frustum(c, [0.6 * r, r], [z0, mid], base, 8);
        self.frustum(c, [r, 0.35 * r], [mid, top.max(mid + 0.1)], base, 8);
    }
}

/// A contiguous index range of one object, with its bounding circle on the ground
/// (for per-view culling).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DrawRange {
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
    /// One part per obstacle, one per overhead detail, then the ground; together
    /// they cover `indices` in order.
    pub parts: Vec<DrawRange>,
}

/// Build the full static mesh of a scene.
pub fn build(scene: &Scene, map: &RegionMap) -> SceneMesh {
    let mut m = MeshBuilder::default();
    let mut parts = Vec::with_capacity(scene.obstacles.len() + scene.overhead.len() + 1);
    for o in &scene.obstacles {
        let start = m.indices.len() as u32;
        match (o.kind, o.footprint) {
            (ObstacleKind::Building, Footprint::Box(r)) => {
                let wall = Wall { facade: &o.facade, window_top: o.height - 0.8 };
                m.cuboid(r.min, r.max, [0.0, o.height], o.shade, Some(wall));
            }
            (ObstacleKind::Tree, Footprint::Cylinder { center, radius }) => {
                m.cylinder(center, radius, 0.0, o.height, o.shade, 6);
                m.crown(center, o.crown_radius, o.height, (o.shade + 0.15).min(1.0));
            }
            (_, Footprint::Box(r)) => m.cuboid(r.min, r.max, [0.0, o.height], o.shade, None),
            (_, Footprint::Cylinder { center, radius }) => m.cylinder(center, radius, 0.0, o.height, o.shade, 6),
        }
        let (center, radius) = match o.footprint {
            Footprint::Box(r) => {
                ([(r.min[0] + r.max[0]) * 0.5, (r.min[1] + r.max[1]) * 0.5], 0.5 * r.width().hypot(r.height()))
            }
            Footprint::Cylinder { center, radius } => (center, radius.max(o.crown_radius)),
        };
        parts.push(DrawRange { start, end: m.indices.len() as u32, center, radius });
    }
    for o in &scene.overhead {
        let start = m.indices.len() as u32;
        m.cuboid(o.rect.min, o.rect.max, [o.base, o.top], o.shade, None);
        let (r, center) = (o.rect, [(o.rect.min[0] + o.rect.max[0]) * 0.5, (o.rect.min[1] + o.rect.max[1]) * 0.5]);
        parts.push(DrawRange { start, end: m.indices.len() as u32, center, radius: 0.5 * r.width().hypot(r.height()) });
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

    parts.push(DrawRange { start: ground_start, end: m.indices.len() as u32, center: [0.0; 2], radius: f32::INFINITY });
    SceneMesh { vertices: m.vertices, indices: m.indices, parts }
}

/// Can a camera at `(x, y)` looking along `yaw` with horizontal field of view
/// `fov` see any of the part's bounding cylinder? Conservative: a part counts as
/// visible when its bounding circle touches the view wedge widened by 5°, or the
/// camera stands within its circle (1 m of slack against the near plane).
pub fn part_visible(part: &DrawRange, x: f32, y: f32, yaw: f32, fov: f32) -> bool {
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

/// [`part_visible`] for a bounding circle given by its centre and radius.
pub fn part_visible_circle(center: [f32; 2], radius: f32, x: f32, y: f32, yaw: f32, fov: f32) -> bool {
    part_visible(&DrawRange { start: 0, end: 0, center, radius }, x, y, yaw, fov)
}

/// A full-view quad at the far plane in clip space, drawn (for domain-randomised
/// views only) so that the sky takes the view's brightness and contrast.
pub fn sky_quad() -> [Vertex; 4] {
    let v = |x: f32, y: f32| Vertex {
        pos: [x, y, 2.0],
        uv: [0.0; 2],
        shade: SKY_SHADE,
        textured: -1.0,
        facade: [0.0; 4],
        facade_look: [0.0; 4],
    };
    [v(-1.0, -1.0), v(1.0, -1.0), v(1.0, 1.0), v(-1.0, 1.0)]
}
