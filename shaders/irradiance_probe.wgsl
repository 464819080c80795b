// Evaluates the shown light map's sampling function at given points (a compute pass): how
// tests hold the GPU twin equal to the CPU's ShownLightmap::irradiance.

#include "lightmap.inc.wgsl"

struct ProbePoint {
    position: vec3<f32>,
    _pad0: f32,
    uv: vec2<f32>,
    _pad1: vec2<f32>,
}

@group(0) @binding(0) var<storage, read> points: array<ProbePoint>;
@group(0) @binding(1) var<storage, read_write> results: array<vec4<f32>>;

@compute @workgroup_size(64)
fn cs_main(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if i >= arrayLength(&points) {
        return;
    }
    results[i] = vec4<f32>(shown_irradiance(points[i].position, points[i].uv), 0.0);
}
