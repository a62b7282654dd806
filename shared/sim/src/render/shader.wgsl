// pednav first-person renderer: two pipelines over one vertex format. The ground
// (fs_ground) samples the baked ground texture; walls, poles, trees and overhead
// details (fs_flat) carry a baked per-face shade, and building walls get their
// facade painted procedurally and anti-aliased (mesh.rs documents the codes).
// Output: one greyscale channel (R8Unorm target).

struct View {
    view_proj: mat4x4<f32>,
    // xyz: camera position; w: haze density per metre.
    eye: vec4<f32>,
    // x: brightness offset, y: contrast gain, z: haze (sky) shade, w: unused.
    look: vec4<f32>,
};

@group(0) @binding(0) var<uniform> view: View;
@group(0) @binding(1) var ground_tex: texture_2d<f32>;
@group(0) @binding(2) var ground_smp: sampler;

struct VsOut {
    @builtin(position) clip: vec4<f32>,
    @location(0) uv: vec2<f32>,
    @location(1) shade: f32,
    @location(2) textured: f32,
    @location(3) world: vec3<f32>,
    @location(4) facade: vec4<f32>,
    @location(5) facade_look: vec4<f32>,
};

@vertex
fn vs_main(
    @location(0) pos: vec3<f32>,
    @location(1) uv: vec2<f32>,
    @location(2) shade: f32,
    @location(3) textured: f32,
    @location(4) facade: vec4<f32>,
    @location(5) facade_look: vec4<f32>,
) -> VsOut {
    var out: VsOut;
    if (textured < -0.5) {
        // Sky quad, given in clip space, just in front of the far plane.
        out.clip = vec4<f32>(pos.xy, 0.9999999, 1.0);
        out.world = view.eye.xyz;
    } else {
        out.clip = view.view_proj * vec4<f32>(pos, 1.0);
        out.world = pos;
    }
    out.uv = uv;
    out.shade = shade;
    out.textured = max(textured, 0.0);
    out.facade = facade;
    out.facade_look = facade_look;
    return out;
}

// Instanced prototypes (vehicles, walkers, lamps): the unit mesh scaled by the
// instance's size, turned by its yaw and placed; uv.x = 1 marks vertices that take
// the instance's tint (dynamic.rs documents the conventions).
@vertex
fn vs_instanced(
    @location(0) pos: vec3<f32>,
    @location(1) uv: vec2<f32>,
    @location(2) shade: f32,
    @location(3) textured: f32,
    @location(4) facade: vec4<f32>,
    @location(5) facade_look: vec4<f32>,
    @location(6) pose: vec4<f32>,
    @location(7) size: vec4<f32>,
) -> VsOut {
    var out: VsOut;
    let p = pos * size.xyz;
    let c = cos(pose.w);
    let s = sin(pose.w);
    let world = vec3<f32>(pose.x + c * p.x - s * p.y, pose.y + s * p.x + c * p.y, pose.z + p.z);
    out.clip = view.view_proj * vec4<f32>(world, 1.0);
    out.world = world;
    out.uv = vec2<f32>(0.0, 0.0);
    out.shade = shade * mix(1.0, size.w, uv.x);
    out.textured = 0.0;
    out.facade = vec4<f32>(0.0);
    out.facade_look = vec4<f32>(0.0);
    return out;
}

// Integral over (-inf, x] of the periodic box that is 1 on [a, b) + n (period 1).
fn box_integral(x: f32, a: f32, b: f32) -> f32 {
    return floor(x) * (b - a) + clamp(fract(x), a, b) - a;
}

// Fraction of the pixel footprint [x - w/2, x + w/2] that lies inside the box:
// an exact box-filtered pattern, so distant windows blend instead of aliasing.
fn box_coverage(x: f32, w: f32, a: f32, b: f32) -> f32 {
    let h = max(0.5 * w, 1e-4);
    return (box_integral(x + h, a, b) - box_integral(x - h, a, b)) / (2.0 * h);
}

fn finish(g0: f32, world: vec3<f32>) -> vec4<f32> {
    let d = distance(world, view.eye.xyz);
    let haze = 1.0 - exp(-d * view.eye.w);
    var g = mix(g0, view.look.z, haze);
    g = (g - 0.5) * view.look.y + 0.5 + view.look.x;
    return vec4<f32>(clamp(g, 0.0, 1.0), 0.0, 0.0, 1.0);
}

// The ground: the baked ground texture, trilinear.
@fragment
fn fs_ground(in: VsOut) -> @location(0) vec4<f32> {
    return finish(in.shade * textureSample(ground_tex, ground_smp, in.uv).r, in.world);
}

// Everything else: flat baked shade; the walls of buildings get their facade.
// facade = [axis (0: not a wall, 1: runs along x, 2: along y), window top,
//           window style (0 grid, 1 tall, 2 ribbon, 3 curtain, 4 blank),
//           ground floor (0 plain, 1 shop, 2 arcade)]
// facade_look = [bay, storey, lit glass grey, lit trim grey]
@fragment
fn fs_flat(in: VsOut) -> @location(0) vec4<f32> {
    let f = in.facade;
    let look = in.facade_look;
    // Differentiate unconditionally: derivatives need uniform control flow.
    let along = select(in.world.y, in.world.x, f.x < 1.5);
    let u = along / max(look.x, 0.5);
    let v = (in.world.z - 3.0) / max(look.y, 1.0);
    let g = in.world.z / 3.0;
    let du = fwidth(u);
    let dv = fwidth(v);
    let dg = fwidth(g);
    let wall = f.x > 0.5;
    let upper = select(0.0, 1.0, wall && in.world.z >= 3.0 && in.world.z <= f.y);
    let lower = select(0.0, 1.0, wall && in.world.z < 3.0);

    // Upper floors: one window per bay and storey, of the building's style.
    let grid = box_coverage(u, du, 0.3, 0.7) * box_coverage(v, dv, 0.0, 0.43);
    let tall = box_coverage(u, du, 0.38, 0.62) * box_coverage(v, dv, 0.08, 0.72);
    let ribbon = box_coverage(u, du, 0.04, 1.0) * box_coverage(v, dv, 0.12, 0.6);
    let curtain = box_coverage(u, du, 0.05, 1.0) * box_coverage(v, dv, 0.1, 1.0);
    let style = f.z;
    let window = select(select(select(select(0.0, curtain, style < 3.5), ribbon, style < 2.5), tall, style < 1.5), grid, style < 0.5);

    // Ground floor: shop windows under a sign band, or dark arcade openings.
    let shop_glass = box_coverage(u, du, 0.06, 0.94) * box_coverage(g, dg, 0.1, 0.8);
    let shop_sign = box_coverage(g, dg, 0.84, 0.97);
    let arcade = box_coverage(u, du, 0.15, 0.85) * box_coverage(g, dg, 0.0, 0.83);
    let ground = f.w;
    let opening = select(select(arcade, shop_glass, ground < 1.5), 0.0, ground < 0.5);
    let opening_grey = select(look.z, 0.5 * look.z, ground > 1.5);
    let sign = select(0.0, shop_sign, ground > 0.5 && ground < 1.5);

    var grey = mix(in.shade, look.z, window * upper);
    grey = mix(grey, opening_grey, opening * lower);
    grey = mix(grey, look.w, sign * lower);
    return finish(grey, in.world);
}
