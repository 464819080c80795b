// The viewer's surface pass: each fragment's radiance (albedo × E/π + emission, or a debug
// view), depth-tested, written as `OUTPUT` says. A scene with see-through sheets (`BLEND`,
// transmission) is drawn as exposed linear radiance into an HDR target that `tone_map.wgsl`
// then puts on screen: a sheet shows its own light plus what lies behind it through its
// `pass` (the bake's `Sheet` model), a sum the tone curve would not keep. Any other scene is
// drawn straight on screen, tone-mapped here. `MASK` materials' cut-out fragments (alpha below
// the cutoff) are discarded (`fs_cut_out`).

#include "common.inc.wgsl"
#include "lightmap.inc.wgsl"

struct MaterialUniforms {
    // Linear base-colour factor (rgb; a: alpha, multiplied by the texture's).
    base_color: vec4<f32>,
    // Emitted radiance W/(sr·m²).
    emission: vec3<f32>,
    // `MASK`'s cutoff: a fragment whose alpha is below it is cut out (`Material::alpha`,
    // `AlphaMode::Mask`; 0 for the other modes).
    alpha_cutoff: f32,
    // 1 for `BLEND` (alpha is the fraction of light the surface meets, `Material::coverage`).
    blend: u32,
    // `KHR_materials_transmission` factor, multiplied by the texture's red channel.
    transmission: f32,
    _pad0: u32,
    _pad1: u32,
}
// What a fragment writes, per pipeline (`gpu::surface::SurfacePass`): 0, exposed linear
// radiance (the HDR target); 1, the tone-mapped colour (an sRGB target, which encodes it);
// 2, that colour sRGB-encoded (any other target).
override OUTPUT: u32 = 0u;

@group(0) @binding(0) var<uniform> frame: FrameUniforms;

@group(2) @binding(0) var<uniform> material: MaterialUniforms;
@group(2) @binding(1) var base_color_texture: texture_2d<f32>;
@group(2) @binding(2) var emissive_texture: texture_2d<f32>;
@group(2) @binding(3) var material_sampler: sampler;
@group(2) @binding(4) var transmission_texture: texture_2d<f32>;

// The sky where no surface is (`scene::SkyPicture`: radiance, equirectangular, row 0 up).
@group(3) @binding(0) var sky_picture: texture_2d<f32>;

struct VertexInput {
    @location(0) position: vec3<f32>,
    @location(1) uv0: vec2<f32>,
    // Atlas UV (LOD-0 texels) of the triangle's front and back face; negative: no face.
    @location(2) lightmap_front: vec2<f32>,
    @location(3) lightmap_back: vec2<f32>,
    // Vertex colour (COLOR_0; white where the mesh has none): multiplies the base colour.
    @location(4) color: vec4<f32>,
}

struct VertexOutput {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
    @location(1) uv0: vec2<f32>,
    @location(2) lightmap_front: vec2<f32>,
    @location(3) lightmap_back: vec2<f32>,
    @location(4) color: vec4<f32>,
}

@vertex
fn vs_main(v: VertexInput) -> VertexOutput {
    var out: VertexOutput;
    out.clip = frame.view_proj * vec4<f32>(v.position, 1.0);
    out.world = v.position;
    out.uv0 = v.uv0;
    out.lightmap_front = v.lightmap_front;
    out.lightmap_back = v.lightmap_back;
    out.color = v.color;
    return out;
}

fn lod_colour(k: u32) -> vec3<f32> {
    let palette = array<vec3<f32>, 8>(
        vec3<f32>(0.2, 0.3, 1.0), vec3<f32>(0.1, 0.8, 0.9), vec3<f32>(0.2, 0.9, 0.2), vec3<f32>(0.9, 0.9, 0.1),
        vec3<f32>(1.0, 0.5, 0.1), vec3<f32>(1.0, 0.1, 0.1), vec3<f32>(0.9, 0.2, 0.9), vec3<f32>(1.0, 1.0, 1.0),
    );
    return palette[min(k, 7u)];
}

@fragment
fn fs_main(in: VertexOutput, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    return opaque(in, front, base_colour(in));
}

// `MASK` materials, in a pipeline of their own: a discard anywhere in a pipeline's shader
// costs every fragment its early depth test.
@fragment
fn fs_cut_out(in: VertexOutput, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    let base = base_colour(in);
    if base.a < material.alpha_cutoff {
        discard;
    }
    return opaque(in, front, base);
}

fn opaque(in: VertexOutput, front: bool, base: vec4<f32>) -> vec4<f32> {
    return output(shown(in, front, albedo(base)));
}

// A see-through sheet is drawn twice, after everything opaque and with no depth writes:
// `fs_sheet_filter` multiplies what lies behind by the light the sheet lets through
// (blend: dst × src), then `fs_sheet_light` adds the sheet's own (blend: dst + src).
@fragment
fn fs_sheet_filter(in: VertexOutput) -> @location(0) vec4<f32> {
    return vec4<f32>(sheet(in).passes, 1.0);
}

@fragment
fn fs_sheet_light(in: VertexOutput, @builtin(front_facing) front: bool) -> @location(0) vec4<f32> {
    return output(shown(in, front, sheet(in).reflect));
}

fn output(radiance: vec3<f32>) -> vec4<f32> {
    if OUTPUT == 0u {
        return vec4<f32>(radiance * frame.exposure, 1.0);
    }
    var colour = tone_map(radiance, frame.exposure);
    if OUTPUT == 2u {
        colour = srgb_encode(colour);
    }
    return vec4<f32>(colour, 1.0);
}

// The sky: one triangle over the viewport at the far plane, drawn after the opaque surfaces
// with depth tested (≤) and not written, so it shows only where none is.
struct SkyVertex {
    @builtin(position) clip: vec4<f32>,
    @location(0) ndc: vec2<f32>,
}

@vertex
fn vs_sky(@builtin(vertex_index) i: u32) -> SkyVertex {
    let p = vec2<f32>(f32((i << 1u) & 2u), f32(i & 2u)) * 2.0 - 1.0;
    return SkyVertex(vec4<f32>(p, 1.0, 1.0), p);
}

@fragment
fn fs_sky(in: SkyVertex) -> @location(0) vec4<f32> {
    // Two points on the pixel's line of sight (clip depths 0.25 and 0.75): its direction.
    let near = frame.inv_view_proj * vec4<f32>(in.ndc, 0.25, 1.0);
    let far = frame.inv_view_proj * vec4<f32>(in.ndc, 0.75, 1.0);
    return output(sky_radiance(normalize(far.xyz / far.w - near.xyz / near.w)));
}

// The sky picture toward `d`: bilinear between pixel centres, periodic in u, clamped in v.
fn sky_radiance(d: vec3<f32>) -> vec3<f32> {
    let size = vec2<i32>(textureDimensions(sky_picture));
    let uv = vec2<f32>(0.5 + atan2(d.x, -d.z) / TAU, acos(clamp(d.y, -1.0, 1.0)) / PI);
    let p = uv * vec2<f32>(size) - 0.5;
    let p0 = floor(p);
    let f = p - p0;
    let i0 = vec2<i32>(p0);
    let x0 = ((i0.x % size.x) + size.x) % size.x;
    let x1 = (x0 + 1) % size.x;
    let y0 = clamp(i0.y, 0, size.y - 1);
    let y1 = clamp(i0.y + 1, 0, size.y - 1);
    let top = mix(textureLoad(sky_picture, vec2<i32>(x0, y0), 0).rgb, textureLoad(sky_picture, vec2<i32>(x1, y0), 0).rgb, f.x);
    let bottom = mix(textureLoad(sky_picture, vec2<i32>(x0, y1), 0).rgb, textureLoad(sky_picture, vec2<i32>(x1, y1), 0).rgb, f.x);
    return mix(top, bottom, f.y);
}

// The base colour (rgb) and alpha: factor × texture × vertex colour, sampled once per
// fragment.
fn base_colour(in: VertexOutput) -> vec4<f32> {
    return material.base_color * textureSample(base_color_texture, material_sampler, in.uv0) * in.color;
}

fn albedo(base: vec4<f32>) -> vec3<f32> {
    return clamp(base.rgb, vec3<f32>(0.0), vec3<f32>(1.0));
}

// What a thin sheet does with light meeting it (`Material::sheet`, whose `pass` is `passes`
// here: `pass` is a WGSL keyword): with coverage c, transmission t and albedo a,
// `pass = (1 − c) + c·t·a`, `reflect = c·(1 − t)·a`.
struct Sheet {
    passes: vec3<f32>,
    reflect: vec3<f32>,
}

fn sheet(in: VertexOutput) -> Sheet {
    let base = base_colour(in);
    let a = albedo(base);
    let alpha = base.a;
    // `BLEND`: alpha; `MASK`: whole where alpha reaches the cutoff; `OPAQUE` (cutoff 0): whole.
    let c = select(select(0.0, 1.0, alpha >= material.alpha_cutoff), clamp(alpha, 0.0, 1.0), material.blend == 1u);
    let t = clamp(material.transmission * textureSample(transmission_texture, material_sampler, in.uv0).r, 0.0, 1.0);
    return Sheet(vec3<f32>(1.0 - c) + a * (c * t), a * (c * (1.0 - t)));
}

// The radiance a fragment shows in the frame's view mode (before exposure): `reflectance` × E/π
// + emission when lit.
fn shown(in: VertexOutput, front: bool, reflectance: vec3<f32>) -> vec3<f32> {
    let emission = material.emission * textureSample(emissive_texture, material_sampler, in.uv0).rgb;
    let uv = select(in.lightmap_back, in.lightmap_front, front);
    var irradiance = vec3<f32>(0.0);
    if uv.x >= 0.0 {
        irradiance = shown_irradiance(in.world, uv);
    }
    var radiance = reflectance * irradiance / PI + emission;
    let k = lm_shown_lod(in.world);
    switch frame.view_mode {
        case VIEW_CELL_GRID: {
            // Dark lines where the fragment is within a pixel of a cell face. An axis along
            // which the surface does not move across the pixel (a wall lying in a cell face)
            // draws no line: the whole surface would be one.
            let q = (in.world - lm.grid_origin) / lm.cell_size;
            let w = fwidth(q);
            let edge = select(vec3<f32>(1e9), min(fract(q), vec3<f32>(1.0) - fract(q)) / max(w, vec3<f32>(1e-9)), w > vec3<f32>(1e-4));
            if min(edge.x, min(edge.y, edge.z)) < 1.0 {
                radiance = vec3<f32>(0.0, 0.0, 0.0);
            }
        }
        case VIEW_IRRADIANCE: {
            radiance = irradiance / PI;
        }
        case VIEW_TEXEL_CHECKER: {
            // Squares of one texel of the shown LOD: their size on screen is the texel density.
            let t = vec2<i32>(floor(uv * f32(1u << k)));
            let odd = ((t.x + t.y) & 1) == 1;
            radiance = radiance * select(1.0, 0.35, odd) + select(vec3<f32>(0.0), vec3<f32>(0.02), odd);
        }
        case VIEW_CELL_LOD: {
            // The LOD's colour, shaded by the lit picture's brightness on screen: a displayed
            // colour, given as the radiance the tone curve turns into it.
            let lit = tone_map(radiance, frame.exposure);
            let colour = lod_colour(k) * (0.3 + 0.7 * dot(lit, vec3<f32>(0.2126, 0.7152, 0.0722)));
            radiance = untone_map(colour) / frame.exposure;
        }
        default: {}
    }
    return radiance;
}
