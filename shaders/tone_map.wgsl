// The viewer's last pass: the surface pass's exposed linear radiance (an HDR target of the
// frame's size) through the tone curve onto the screen, pixel for pixel. `fs_main` writes to
// an sRGB target (the hardware encodes), `fs_encode` to a linear one.

#include "common.inc.wgsl"

@group(0) @binding(0) var radiance: texture_2d<f32>;

// One triangle covering the viewport.
@vertex
fn vs_main(@builtin(vertex_index) i: u32) -> @builtin(position) vec4<f32> {
    let p = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u));
    return vec4<f32>(p * 2.0 - 1.0, 0.0, 1.0);
}

fn displayed(pixel: vec4<f32>) -> vec3<f32> {
    return tone_map(textureLoad(radiance, vec2<i32>(pixel.xy), 0).rgb, 1.0);
}

@fragment
fn fs_main(@builtin(position) pixel: vec4<f32>) -> @location(0) vec4<f32> {
    return vec4<f32>(displayed(pixel), 1.0);
}

@fragment
fn fs_encode(@builtin(position) pixel: vec4<f32>) -> @location(0) vec4<f32> {
    return vec4<f32>(srgb_encode(displayed(pixel)), 1.0);
}
