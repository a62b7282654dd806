// pednav first-person renderer: two pipelines over one vertex format. The ground
// (fs_ground) samples the baked ground texture; walls, poles and trees (fs_flat)
// carry a baked per-face shade, and building walls get a procedural,
// anti-aliased window grid. Output: one greyscale
// channel (R8Unorm target).

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
};

@vertex
fn vs_main(
    @location(0) pos: vec3<f32>,
    @location(1) uv: vec2<f32>,
    @location(2) shade: f32,
    @location(3) textured: f32,
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

// Everything else: flat baked shade; building walls get the window grid.
@fragment
fn fs_flat(in: VsOut) -> @location(0) vec4<f32> {
    // Differentiate unconditionally: derivatives need uniform control flow.
    let along = select(in.world.y, in.world.x, in.uv.x < 1.5);
    let u = along / 3.0;
    let v = (in.world.z - 3.0) / 3.5;
    let du = fwidth(u);
    let dv = fwidth(v);
    let in_band = select(0.0, 1.0, in.uv.x > 0.5 && in.world.z >= 3.0 && in.world.z <= in.uv.y);
    let window = box_coverage(u, du, 0.3, 0.7) * box_coverage(v, dv, 0.0, 0.43) * in_band;
    return finish(in.shade * mix(1.0, 0.45, window), in.world);
}
