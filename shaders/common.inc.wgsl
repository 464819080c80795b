// Shared by every viewer pass: the per-frame uniforms and the display transform.

const PI: f32 = 3.14159265358979;
const TAU: f32 = 6.28318530717959;

// View modes (FrameUniforms.view_mode); the Rust side names them in gpu::layout::ViewMode.
const VIEW_LIT: u32 = 0u;
const VIEW_CELL_LOD: u32 = 1u;
const VIEW_CELL_GRID: u32 = 2u;
const VIEW_IRRADIANCE: u32 = 3u;
const VIEW_TEXEL_CHECKER: u32 = 4u;

struct FrameUniforms {
    view_proj: mat4x4<f32>,
    // Its inverse: clip space back to the world (the sky's directions).
    inv_view_proj: mat4x4<f32>,
    eye: vec3<f32>,
    // Multiplies radiance before the tone curve.
    exposure: f32,
    view_mode: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// The same curve as the light-map previews (src/output.rs): 1 − exp(−L), then sRGB.
fn tone_map(radiance: vec3<f32>, exposure: f32) -> vec3<f32> {
    return vec3<f32>(1.0) - exp(-max(radiance * exposure, vec3<f32>(0.0)));
}

// The exposed radiance `tone_map` turns into `colour` (each channel below 1; kept a step
// short of 1, where the curve has no inverse).
fn untone_map(colour: vec3<f32>) -> vec3<f32> {
    return -log(vec3<f32>(1.0) - min(colour, vec3<f32>(0.9999)));
}

fn srgb_encode(c: vec3<f32>) -> vec3<f32> {
    let lo = c * 12.92;
    let hi = 1.055 * pow(c, vec3<f32>(1.0 / 2.4)) - 0.055;
    return select(hi, lo, c <= vec3<f32>(0.0031308));
}
