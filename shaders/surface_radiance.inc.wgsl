// What a scene surface reflects and emits at a point of a triangle, as light transport sees
// it (gpu::surface_radiance): the WGSL twin of `SceneGeometry::albedo` and
// `SceneGeometry::emission`, with `Texture::sample`'s bilinear filtering of 8-bit texels on
// linear values. The arithmetic follows the CPU's operation for operation; the including
// pass defines `mul(a, b)`, a product the compiler cannot fuse into an addition (see
// bundle_resolve.wgsl), so texel choices and weights round as the CPU's do.

const NO_TEXTURE: u32 = 0xFFFFFFFFu;
const NO_COLOR: u32 = 0xFFFFFFFFu;
const WRAP_REPEAT: u32 = 0u;
const WRAP_MIRRORED_REPEAT: u32 = 1u;
const WRAP_CLAMP_TO_EDGE: u32 = 2u;
const ALPHA_OPAQUE: u32 = 0u;
const ALPHA_MASK: u32 = 1u;
const ALPHA_BLEND: u32 = 2u;

// Per triangle: its corners' texture coordinates (`SceneGeometry::texture_uv_corners`), its
// material, whether its emission travels with the global bundles
// (`EmitterPlan::carried_by_bundles`), and its corners' vertex colours
// (`surface_colors[colors..colors + 3]`; NO_COLOR: its mesh has none).
struct SurfaceTriangle {
    uv0: array<vec2<f32>, 3>,
    material: u32,
    carried: u32,
    colors: u32,
    _pad: u32,
}

struct SurfaceMaterial {
    // Linear base-colour factor (rgb; alpha: the coverage factor).
    base_color: vec4<f32>,
    // Emitted radiance W/(sr·m²).
    emission: vec3<f32>,
    // 1 when both sides are lit surfaces (and emit, when emissive).
    double_sided: u32,
    base_texture: u32,
    emissive_texture: u32,
    // ALPHA_* (`scene::AlphaMode`), and MASK's cutoff.
    alpha_mode: u32,
    alpha_cutoff: f32,
    // KHR_materials_transmission: factor, and the texture whose red channel scales it.
    transmission: f32,
    transmission_texture: u32,
    // 1 when light may pass the surface (`Material::lets_light_through`).
    passing: u32,
    _pad: u32,
}

struct TextureHeader {
    width: u32,
    height: u32,
    // First texel in `texture_texels` (row-major, top row first).
    first: u32,
    // 1: colour channels are sRGB-encoded.
    srgb: u32,
    wrap_s: u32,
    wrap_t: u32,
    _pad0: u32,
    _pad1: u32,
}

@group(2) @binding(0) var<storage, read> surface_triangles: array<SurfaceTriangle>;
@group(2) @binding(1) var<storage, read> surface_materials: array<SurfaceMaterial>;
@group(2) @binding(2) var<storage, read> texture_headers: array<TextureHeader>;
// RGBA8 texels, r in the low byte.
@group(2) @binding(3) var<storage, read> texture_texels: array<u32>;
// The CPU's sRGB decoding table (256 entries): the same values, not a recomputed power.
@group(2) @binding(4) var<storage, read> srgb_to_linear: array<f32>;
// Vertex colours (linear RGBA, COLOR_0), three a triangle that has them.
@group(2) @binding(5) var<storage, read> surface_colors: array<vec4<f32>>;

fn mul3(a: vec3<f32>, b: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(mul(a.x, b.x), mul(a.y, b.y), mul(a.z, b.z));
}

fn mul4s(a: vec4<f32>, s: f32) -> vec4<f32> {
    return vec4<f32>(mul(a.x, s), mul(a.y, s), mul(a.z, s), mul(a.w, s));
}

// `texture::wrap`. Coordinates are whole texels from a floor; beyond ±2^30 texels (no real
// UV) they are held there, where the CPU's i64 would wrap them on.
fn wrap_texel(x: f32, n: u32, mode: u32) -> u32 {
    let i = i32(clamp(x, -1073741824.0, 1073741824.0));
    let m = i32(n);
    if mode == WRAP_CLAMP_TO_EDGE {
        return u32(clamp(i, 0, m - 1));
    }
    if mode == WRAP_MIRRORED_REPEAT {
        let p = ((i % (2 * m)) + 2 * m) % (2 * m);
        return u32(select(2 * m - 1 - p, p, p < m));
    }
    return u32(((i % m) + m) % m);
}

// `Texture::texel`: linear value (alpha is never sRGB-encoded).
fn texture_texel(h: TextureHeader, x: u32, y: u32) -> vec4<f32> {
    let w = texture_texels[h.first + y * h.width + x];
    let r = w & 0xFFu;
    let g = (w >> 8u) & 0xFFu;
    let b = (w >> 16u) & 0xFFu;
    let a = w >> 24u;
    if h.srgb == 1u {
        return vec4<f32>(srgb_to_linear[r], srgb_to_linear[g], srgb_to_linear[b], div(f32(a), 255.0));
    }
    return vec4<f32>(div(f32(r), 255.0), div(f32(g), 255.0), div(f32(b), 255.0), div(f32(a), 255.0));
}

// `Texture::sample`: bilinear at uv with the texture's wrap modes.
fn texture_sample(index: u32, uv: vec2<f32>) -> vec4<f32> {
    let h = texture_headers[index];
    if h.width == 0u || h.height == 0u {
        return vec4<f32>(1.0);
    }
    let x = mul(uv.x, f32(h.width)) - 0.5;
    let y = mul(uv.y, f32(h.height)) - 0.5;
    // Not finite (NaN fails both comparisons).
    if !(abs(x) <= 3.4028235e38) || !(abs(y) <= 3.4028235e38) {
        return texture_texel(h, 0u, 0u);
    }
    let x0 = floor(x);
    let y0 = floor(y);
    let fx = x - x0;
    let fy = y - y0;
    let xs = vec2<u32>(wrap_texel(x0, h.width, h.wrap_s), wrap_texel(x0 + 1.0, h.width, h.wrap_s));
    let ys = vec2<u32>(wrap_texel(y0, h.height, h.wrap_t), wrap_texel(y0 + 1.0, h.height, h.wrap_t));
    let top = mul4s(texture_texel(h, xs.x, ys.x), 1.0 - fx) + mul4s(texture_texel(h, xs.y, ys.x), fx);
    let bottom = mul4s(texture_texel(h, xs.x, ys.y), 1.0 - fx) + mul4s(texture_texel(h, xs.y, ys.y), fx);
    return mul4s(top, 1.0 - fy) + mul4s(bottom, fy);
}

// TEXCOORD_0 of triangle `tri` at barycentrics (u, v) (`SceneGeometry::uv0`).
fn surface_uv0(tri: SurfaceTriangle, u: f32, v: f32) -> vec2<f32> {
    let a = tri.uv0[0];
    let d1 = tri.uv0[1] - a;
    let d2 = tri.uv0[2] - a;
    return a + vec2<f32>(mul(d1.x, u), mul(d1.y, u)) + vec2<f32>(mul(d2.x, v), mul(d2.y, v));
}

// The vertex colour of triangle `tri` (which has them: `colors` is not NO_COLOR) at
// barycentrics (u, v) (`SceneGeometry::material_point`).
fn surface_color(tri: SurfaceTriangle, u: f32, v: f32) -> vec4<f32> {
    let a = surface_colors[tri.colors];
    let d1 = surface_colors[tri.colors + 1u] - a;
    let d2 = surface_colors[tri.colors + 2u] - a;
    return a + mul4s(d1, u) + mul4s(d2, v);
}

// `Material::albedo` from what multiplies the base colour factor at the point, `base`
// (`Material::base_sample`: the texture's value times the vertex colour; 1 where there is
// neither, and a product with 1 is exact, so no test is needed), linear, clamped to [0, 1].
fn material_albedo(m: SurfaceMaterial, base: vec4<f32>) -> vec3<f32> {
    return clamp(mul3(m.base_color.rgb, base.rgb), vec3<f32>(0.0), vec3<f32>(1.0));
}

// `Material::alpha` from what multiplies the base colour factor at the point, `base`.
fn material_alpha(m: SurfaceMaterial, base: vec4<f32>) -> f32 {
    return mul(m.base_color.w, base.w);
}

// `Material::is_see_through`: BLEND or transmissive.
fn material_see_through(m: SurfaceMaterial) -> bool {
    return m.alpha_mode == ALPHA_BLEND || m.transmission > 0.0;
}

// `Material::sheet`'s coverage c (`Material::coverage`) and transmission t
// (`Material::transmission_at` where the factor is positive, else 0), from the base colour
// and transmission textures' values `base` and `transmitted`.
fn material_cover(m: SurfaceMaterial, base: vec4<f32>, transmitted: vec4<f32>) -> vec2<f32> {
    let alpha = material_alpha(m, base);
    var c = 1.0;
    if m.alpha_mode == ALPHA_MASK {
        c = select(0.0, 1.0, alpha >= m.alpha_cutoff);
    } else if m.alpha_mode == ALPHA_BLEND {
        c = clamp(alpha, 0.0, 1.0);
    }
    var t = 0.0;
    if m.transmission > 0.0 {
        t = m.transmission;
        if m.transmission_texture != NO_TEXTURE {
            t = mul(t, transmitted.x);
        }
        t = clamp(t, 0.0, 1.0);
    }
    return vec2<f32>(c, t);
}

// Whether material `m`'s textures are read at a point: its base colour texture, and its
// transmission texture where the factor is positive.
fn material_textured(m: SurfaceMaterial) -> bool {
    return m.base_texture != NO_TEXTURE || (m.transmission > 0.0 && m.transmission_texture != NO_TEXTURE);
}

// What multiplies material `m`'s base colour factor at a point (its texture's value times
// the vertex colour; 1 where there is neither), and its transmission texture's value there
// (1 where it has none, or where its transmission factor is 0).
struct MaterialTexels {
    base: vec4<f32>,
    transmitted: vec4<f32>,
}

fn material_texels(m: SurfaceMaterial, uv: vec2<f32>) -> MaterialTexels {
    var x: MaterialTexels;
    x.base = vec4<f32>(1.0);
    x.transmitted = vec4<f32>(1.0);
    if m.base_texture != NO_TEXTURE {
        x.base = texture_sample(m.base_texture, uv);
    }
    if m.transmission > 0.0 && m.transmission_texture != NO_TEXTURE {
        x.transmitted = texture_sample(m.transmission_texture, uv);
    }
    return x;
}

// `material_texels` of triangle `tri`'s material `m` at barycentrics (u, v), the vertex
// colour multiplied in after the texture as `Material::base_sample` does.
fn surface_texels(tri: SurfaceTriangle, m: SurfaceMaterial, u: f32, v: f32) -> MaterialTexels {
    var x = MaterialTexels(vec4<f32>(1.0), vec4<f32>(1.0));
    if material_textured(m) {
        x = material_texels(m, surface_uv0(tri, u, v));
    }
    if tri.colors != NO_COLOR {
        let c = surface_color(tri, u, v);
        x.base = vec4<f32>(mul(x.base.x, c.x), mul(x.base.y, c.y), mul(x.base.z, c.z), mul(x.base.w, c.w));
    }
    return x;
}

// Diffuse reflectance (linear) of triangle `t` at barycentrics (u, v): `SceneGeometry::albedo`,
// the albedo clamped to [0, 1] (`Material::albedo`), of a see-through surface the part it
// reflects, α(1 − t)·a (`Material::reflectance`).
fn surface_albedo(t: u32, u: f32, v: f32) -> vec3<f32> {
    let tri = surface_triangles[t];
    let m = surface_materials[tri.material];
    let x = surface_texels(tri, m, u, v);
    let a = material_albedo(m, x.base);
    if !material_see_through(m) {
        return a;
    }
    let ct = material_cover(m, x.base, x.transmitted);
    let r = mul(ct.x, 1.0 - ct.y);
    return vec3<f32>(mul(a.x, r), mul(a.y, r), mul(a.z, r));
}

// Emitted radiance of side `front` of triangle `t` at barycentrics (u, v): zero from the
// back of a single-sided material (`Material::emits_from`).
fn surface_emission(t: u32, front: bool, u: f32, v: f32) -> vec3<f32> {
    let tri = surface_triangles[t];
    let m = surface_materials[tri.material];
    if !(max(m.emission.x, max(m.emission.y, m.emission.z)) > 0.0) || (!front && m.double_sided == 0u) {
        return vec3<f32>(0.0);
    }
    if m.emissive_texture == NO_TEXTURE {
        return m.emission;
    }
    return mul3(m.emission, texture_sample(m.emissive_texture, surface_uv0(tri, u, v)).rgb);
}

// Whether triangle `t`'s emission travels with the global bundles.
fn surface_carried(t: u32) -> bool {
    return surface_triangles[t].carried == 1u;
}
