//! What moves: vehicles, walkers and the lamps of signal heads (and, as an option,
//! signal lights set in the pavement), drawn by instancing
//! a few fixed prototype meshes (one draw per prototype and view, every view in the
//! same submission as the static scene), far ones as a single box
//! ([`FAR_DISTANCE`]).
//!
//! Invariant: prototype meshes are built once and appended after the static mesh,
//! so the static scene's vertices and indices — and so every frame drawn without
//! instances — stay exactly what they were. A prototype lives in object space:
//! x forward, y left, z up, inside the unit box (−0.5..0.5 in x and y, 0..1 in z;
//! lamps and figures centred on z = 0); an [`Instance`] scales it by its size,
//! turns it by its yaw and places it. A vertex whose `uv[0]` is 1 takes the
//! instance's tint (paint, clothes, a lamp's brightness); 0 keeps its own shade
//! (glass, tyres, skin).

use bytemuck::{Pod, Zeroable};

use super::mesh::{MeshBuilder, Vertex};

/// The prototypes, in the order of their index ranges.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Prototype {
    /// A car: low body, a glazed cabin set back, dark wheels.
    Car = 0,
    /// A van, bus or truck: a tall box with a window band.
    Boxy = 1,
    /// A person.
    Walker = 2,
    /// A square lamp facing +x (vehicle heads).
    Lamp = 3,
    /// The standing figure (DON'T WALK), facing +x.
    FigureStand = 4,
    /// The walking figure (WALK), facing +x.
    FigureWalk = 5,
    /// A far vehicle or walker: one shaded box (a few pixels on screen).
    Far = 6,
    /// A lit rectangle lying on the ground, facing up (the ground-level pedestrian
    /// signals of `sim.traffic_ground_signals`).
    GroundLight = 7,
}

/// Number of prototypes.
pub const PROTOTYPES: usize = 8;

/// Beyond this distance from the camera (metres) vehicles and walkers are drawn as
/// [`Prototype::Far`]: at 84² and 135° a car there is under 10 pixels long.
pub const FAR_DISTANCE: f32 = 35.0;

/// Beyond this distance lamps are not drawn: a 0.3 m lamp there subtends under a
/// third of a pixel at 84² and 135°. Lamps seen from behind their head are never drawn.
pub const LAMP_DISTANCE: f32 = 45.0;

/// One placed prototype.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct Instance {
    /// x, y, z of the object's origin and its yaw (radians).
    pub pose: [f32; 4],
    /// Size along x, y, z, and the tint.
    pub size: [f32; 4],
}

/// The instances of every view of one render call, grouped by view, then prototype.
#[derive(Debug, Default, Clone)]
pub struct DynamicBatch {
    /// All instances.
    pub instances: Vec<Instance>,
    /// For each view, the `[start, end)` of each prototype's instances.
    pub ranges: Vec<[(u32, u32); PROTOTYPES]>,
    pending: [Vec<Instance>; PROTOTYPES],
}

impl DynamicBatch {
    /// Empty the batch, keeping its memory.
    pub fn clear(&mut self) {
        self.instances.clear();
        self.ranges.clear();
        for p in &mut self.pending {
            p.clear();
        }
    }

    /// Add an instance to the view being built.
    pub fn push(&mut self, prototype: Prototype, instance: Instance) {
        self.pending[prototype as usize].push(instance);
    }

    /// Close the view being built (views are closed in order, one per camera).
    pub fn finish_view(&mut self) {
        let mut r = [(0u32, 0u32); PROTOTYPES];
        for (k, p) in self.pending.iter_mut().enumerate() {
            let start = self.instances.len() as u32;
            self.instances.append(p);
            r[k] = (start, self.instances.len() as u32);
        }
        self.ranges.push(r);
    }
}

/// Mark the vertices from `from_vertex` on as taking the instance's tint.
fn tint_from(m: &mut MeshBuilder, from_vertex: usize) {
    for v in &mut m.vertices[from_vertex..] {
        v.uv = [1.0, 0.0];
    }
}

/// Build every prototype into `m` (appending) and return their index ranges.
pub fn build_prototypes(m: &mut MeshBuilder) -> [(u32, u32); PROTOTYPES] {
    let mut ranges = [(0, 0); PROTOTYPES];
    let mut part = |m: &mut MeshBuilder, k: Prototype, f: &dyn Fn(&mut MeshBuilder)| {
        let start = m.indices.len() as u32;
        f(m);
        ranges[k as usize] = (start, m.indices.len() as u32);
    };
    let body = |m: &mut MeshBuilder, min: [f32; 3], max: [f32; 3], shade: f32, tint: bool| {
        let v0 = m.vertices.len();
        m.shaded_box(min, max, shade);
        if tint {
            tint_from(m, v0);
        }
    };
    // Two axles, each a dark box as wide as the body: its ends are the tyres.
    let wheels = |m: &mut MeshBuilder, z: f32| {
        for x in [-0.33f32, 0.3] {
            body(m, [x - 0.09, -0.5, 0.0], [x + 0.09, 0.5, z], 0.07, false);
        }
    };
    part(m, Prototype::Car, &|m| {
        body(m, [-0.5, -0.5, 0.14], [0.5, 0.5, 0.5], 0.55, true);
        body(m, [-0.32, -0.45, 0.5], [0.16, 0.45, 0.95], 0.2, false);
        body(m, [-0.3, -0.42, 0.94], [0.14, 0.42, 1.0], 0.55, true);
        wheels(m, 0.3);
    });
    part(m, Prototype::Boxy, &|m| {
        body(m, [-0.5, -0.5, 0.1], [0.5, 0.5, 1.0], 0.6, true);
        body(m, [-0.46, -0.505, 0.58], [0.42, 0.505, 0.8], 0.18, false);
        body(m, [0.49, -0.42, 0.5], [0.505, 0.42, 0.85], 0.18, false);
        wheels(m, 0.2);
    });
    part(m, Prototype::Walker, &|m| {
        body(m, [-0.25, -0.4, 0.0], [0.25, -0.05, 0.47], 0.3, false);
        body(m, [-0.25, 0.05, 0.0], [0.25, 0.4, 0.47], 0.3, false);
        body(m, [-0.35, -0.5, 0.47], [0.35, 0.5, 0.84], 0.6, true);
        body(m, [-0.3, -0.25, 0.86], [0.3, 0.25, 1.0], 0.62, false);
    });
    part(m, Prototype::Lamp, &|m| {
        let v0 = m.vertices.len();
        m.flat_quad([[0.0, -0.5, -0.5], [0.0, 0.5, -0.5], [0.0, 0.5, 0.5], [0.0, -0.5, 0.5]], 1.0);
        tint_from(m, v0);
    });
    part(m, Prototype::FigureStand, &|m| {
        let v0 = m.vertices.len();
        let r = |m: &mut MeshBuilder, y0: f32, y1: f32, z0: f32, z1: f32| {
            m.flat_quad([[0.0, y0, z0], [0.0, y1, z0], [0.0, y1, z1], [0.0, y0, z1]], 1.0)
        };
        r(m, -0.1, 0.1, 0.3, 0.5); // head
        r(m, -0.16, 0.16, -0.12, 0.27); // body, arms at its sides
        r(m, -0.13, -0.03, -0.5, -0.12); // legs together
        r(m, 0.03, 0.13, -0.5, -0.12);
        tint_from(m, v0);
    });
    part(m, Prototype::FigureWalk, &|m| {
        let v0 = m.vertices.len();
        let q = |m: &mut MeshBuilder, c: [[f32; 2]; 4]| m.flat_quad(c.map(|p| [0.0, p[0], p[1]]), 1.0);
        q(m, [[-0.02, 0.3], [0.18, 0.3], [0.18, 0.5], [-0.02, 0.5]]); // head, leaning forward
        q(m, [[-0.1, -0.1], [0.06, -0.1], [0.14, 0.27], [-0.02, 0.27]]); // leaning body
        q(m, [[-0.1, -0.1], [0.02, -0.1], [-0.24, -0.5], [-0.38, -0.5]]); // back leg
        q(m, [[-0.04, -0.1], [0.08, -0.1], [0.34, -0.5], [0.2, -0.5]]); // front leg, in stride
        q(m, [[0.0, 0.22], [0.08, 0.18], [-0.22, -0.02], [-0.3, 0.02]]); // swinging arm
        tint_from(m, v0);
    });
    part(m, Prototype::Far, &|m| body(m, [-0.5, -0.5, 0.0], [0.5, 0.5, 1.0], 0.55, true));
    part(m, Prototype::GroundLight, &|m| {
        let v0 = m.vertices.len();
        m.flat_quad([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.5, 0.5, 0.0], [-0.5, 0.5, 0.0]], 1.0);
        tint_from(m, v0);
    });
    ranges
}

/// The vertex layout of the instance buffer (locations 6 and 7).
pub fn instance_layout() -> wgpu::VertexBufferLayout<'static> {
    const ATTRS: [wgpu::VertexAttribute; 2] = wgpu::vertex_attr_array![6 => Float32x4, 7 => Float32x4];
    wgpu::VertexBufferLayout {
        array_stride: std::mem::size_of::<Instance>() as u64,
        step_mode: wgpu::VertexStepMode::Instance,
        attributes: &ATTRS,
    }
}

/// Bytes of one vertex of the shared vertex buffer (checked against [`Vertex`]).
pub const VERTEX_BYTES: usize = std::mem::size_of::<Vertex>();
