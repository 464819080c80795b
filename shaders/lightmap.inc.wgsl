// The shown light map on the GPU (gpu::lightmap): pages of 16×16 pixels in a pool texture,
// a page table per layer and LOD, one shown LOD per layer and world cell. The layers (0: the
// bundles' light, 1: punctual lights' direct light) add up. `shown_irradiance` is the WGSL
// twin of the CPU's ShownLightmap::irradiance (a test holds them equal).

const PAGE_SIDE: i32 = 16;
const NO_PAGE: u32 = 0xffffffffu;
const MAX_LODS: u32 = 8u;

struct LodLevel {
    pages_x: u32,
    pages_y: u32,
    // First entry of this LOD in `page_table`.
    table_offset: u32,
    _pad: u32,
}

struct LightmapParams {
    grid_origin: vec3<f32>,
    cell_size: f32,
    grid_dims: vec3<u32>,
    lod_count: u32,
    // LOD-0 atlas size in pixels.
    atlas_size: vec2<u32>,
    // Metres over which a cell blends towards a neighbour at LOD 0 (toward LOD k: over 2^k).
    blend_band: f32,
    // Pages per row of the pool texture.
    pool_columns: u32,
    // Layers to sample: 1 (the bundles' light) or 2 (and the punctual layer, once it has
    // anything published).
    layer_count: u32,
    // Cells of the grid: layer l's cell LODs start at l · cell_count in `cell_lod`.
    cell_count: u32,
    _pad0: u32,
    _pad1: u32,
    // Per layer, per LOD (layer · MAX_LODS + LOD).
    levels: array<LodLevel, 16>,
}

@group(1) @binding(0) var<uniform> lm: LightmapParams;
@group(1) @binding(1) var<storage, read> cell_lod: array<u32>;
@group(1) @binding(2) var<storage, read> page_table: array<u32>;
@group(1) @binding(3) var lm_pool: texture_2d<f32>;

// One pixel of LOD k of a layer: (E, 1) when published, 0 outside the page table, in a
// missing page or where nothing was published.
fn lm_tap(layer: u32, k: u32, px: vec2<i32>) -> vec4<f32> {
    if any(px < vec2<i32>(0)) {
        return vec4<f32>(0.0);
    }
    let page = px / PAGE_SIDE;
    let level = lm.levels[layer * MAX_LODS + k];
    if u32(page.x) >= level.pages_x || u32(page.y) >= level.pages_y {
        return vec4<f32>(0.0);
    }
    let slot = page_table[level.table_offset + u32(page.y) * level.pages_x + u32(page.x)];
    if slot == NO_PAGE {
        return vec4<f32>(0.0);
    }
    let origin = vec2<i32>(i32(slot % lm.pool_columns), i32(slot / lm.pool_columns)) * PAGE_SIDE;
    let t = textureLoad(lm_pool, origin + px % PAGE_SIDE, 0);
    if t.a > 0.0 {
        return vec4<f32>(t.rgb, 1.0);
    }
    return vec4<f32>(0.0);
}

// Bilinear at uv·2^k − 0.5 over a layer's valid taps; where none is valid, the next coarser
// LOD.
fn lm_value(layer: u32, lod: u32, uv: vec2<f32>) -> vec3<f32> {
    var k = i32(min(lod, lm.lod_count - 1u));
    loop {
        if k < 0 {
            break;
        }
        let p = uv * f32(1u << u32(k)) - vec2<f32>(0.5);
        let p0 = floor(p);
        let f = p - p0;
        let i0 = vec2<i32>(p0);
        let t00 = lm_tap(layer, u32(k), i0);
        let t10 = lm_tap(layer, u32(k), i0 + vec2<i32>(1, 0));
        let t01 = lm_tap(layer, u32(k), i0 + vec2<i32>(0, 1));
        let t11 = lm_tap(layer, u32(k), i0 + vec2<i32>(1, 1));
        let w00 = (1.0 - f.x) * (1.0 - f.y) * t00.a;
        let w10 = f.x * (1.0 - f.y) * t10.a;
        let w01 = (1.0 - f.x) * f.y * t01.a;
        let w11 = f.x * f.y * t11.a;
        let wsum = w00 + w10 + w01 + w11;
        if wsum > 0.0 {
            return (t00.rgb * w00 + t10.rgb * w10 + t01.rgb * w01 + t11.rgb * w11) / wsum;
        }
        k -= 1;
    }
    return vec3<f32>(0.0);
}

fn lm_cell_coords(p: vec3<f32>) -> vec3<u32> {
    let q = floor((p - lm.grid_origin) / lm.cell_size);
    return vec3<u32>(clamp(q, vec3<f32>(0.0), vec3<f32>(lm.grid_dims - vec3<u32>(1u))));
}

fn lm_cell_index(c: vec3<u32>) -> u32 {
    return c.x + lm.grid_dims.x * (c.y + lm.grid_dims.y * c.z);
}

// Shown LOD of the cell holding p (the bundles' layer).
fn lm_shown_lod(p: vec3<f32>) -> u32 {
    return cell_lod[lm_cell_index(lm_cell_coords(p))];
}

// One layer's irradiance at world position p with LOD-0 atlas UV uv, in cell c: the cell's
// LOD in that layer, blended near faces shared with coarser neighbours (in that layer).
fn lm_layer_irradiance(layer: u32, c: vec3<u32>, p: vec3<f32>, uv: vec2<f32>) -> vec3<f32> {
    let lods = layer * lm.cell_count;
    let k = cell_lod[lods + lm_cell_index(c)];
    let base = lm_value(layer, k, uv);
    let lo = lm.grid_origin + vec3<f32>(c) * lm.cell_size;
    if k == 0u || lm.blend_band <= 0.0 {
        return base;
    }
    var w = 0.0;
    var k_low = k;
    var near_coarser = false;
    for (var axis = 0u; axis < 3u; axis++) {
        for (var side = 0u; side < 2u; side++) {
            var n = c;
            var d = 0.0;
            if side == 0u {
                if c[axis] == 0u {
                    continue;
                }
                n[axis] = c[axis] - 1u;
                d = p[axis] - lo[axis];
            } else {
                if c[axis] + 1u >= lm.grid_dims[axis] {
                    continue;
                }
                n[axis] = c[axis] + 1u;
                d = lo[axis] + lm.cell_size - p[axis];
            }
            if d >= lm.blend_band {
                continue;
            }
            let kn = cell_lod[lods + lm_cell_index(n)];
            // A couple of the coarser side's texels wide (ShownLightmap::band_toward).
            let band = lm.blend_band / f32(1u << kn);
            if kn >= k || d >= band {
                continue;
            }
            w = max(w, clamp(1.0 - max(d, 0.0) / band, 0.0, 1.0));
            k_low = min(k_low, kn);
            near_coarser = true;
        }
    }
    if near_coarser {
        return base * (1.0 - w) + lm_value(layer, k_low, uv) * w;
    }
    return base;
}

// Irradiance (W/m²) shown at world position p with LOD-0 atlas UV uv: the layers summed.
fn shown_irradiance(p: vec3<f32>, uv: vec2<f32>) -> vec3<f32> {
    return shown_irradiance_in(lm_cell_coords(p), p, uv);
}

// `shown_irradiance` in cell c (the cell holding p: a pass that must pick the CPU's cell
// where p lies within rounding of a cell face computes c with the CPU's exact division).
fn shown_irradiance_in(c: vec3<u32>, p: vec3<f32>, uv: vec2<f32>) -> vec3<f32> {
    var e = lm_layer_irradiance(0u, c, p, uv);
    if lm.layer_count > 1u {
        e += lm_layer_irradiance(1u, c, p, uv);
    }
    return e;
}
