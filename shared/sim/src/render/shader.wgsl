// pednav first-person renderer: one pipeline for everything. Ground quads sample
// the baked ground texture; buildings, poles, trees and the sky box carry a baked
// per-face shade. Output: one greyscale channel (R8Unorm target).

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
    out.clip = view.view_proj * vec4<f32>(pos, 1.0);
    out.uv = uv;
    out.shade = shade;
    out.textured = textured;
    out.world = pos;
    return out;
}

@fragment
fn fs_main(in: VsOut) -> @location(0) vec4<f32> {
    // Sample unconditionally: implicit-derivative sampling must stay in uniform control flow.
    let tex = textureSample(ground_tex, ground_smp, in.uv).r;
    var g = in.shade * mix(1.0, tex, in.textured);
    let d = distance(in.world, view.eye.xyz);
    let haze = 1.0 - exp(-d * view.eye.w);
    g = mix(g, view.look.z, haze);
    g = (g - 0.5) * view.look.y + 0.5 + view.look.x;
    return vec4<f32>(clamp(g, 0.0, 1.0), 0.0, 0.0, 1.0);
}
