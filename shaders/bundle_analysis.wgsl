// Analysis pass of one bundle direction (Tokuyoshi et al. 2013, Sect. 4.1-4.2): an
// orthographic raster of the direction's R×R window. Per covered pixel centre the fragment
// stage takes the max of the triangle's importance (rays per m²: positive f32 bits compare
// as u32, so atomicMax on the bits is a float max) and counts the fragment. A triangle that
// covers no pixel centre still marks the pixel under its centroid (`touch`, a compute pass
// after the raster), as the CPU analysis (src/cpu/analysis.rs) does.
//
// Vertices are snapped to 1/256 pixel here, as `bundle::raster` snaps them, and placed so
// that the rasteriser's own viewport transform and fixed-point snap are exact: GPU and CPU
// then cover the same pixel centres except where the corners' f32 grid positions differ by
// rounding right at a snap boundary (see `gpu::bundle_analysis`).

struct AnalysisParams {
    // Frame axes (screen x along t, y along b) and the grid's corner in frame coordinates.
    t: vec3<f32>,
    pixel: f32,
    b: vec3<f32>,
    res: u32,
    origin: vec2<f32>,
    // Triangles drawn (entries of `drawn`).
    drawn_count: u32,
    // Side V of the viewport (a power of two, centred on the attachment's corner; see vs_main).
    view_side: u32,
}

@group(0) @binding(0) var<uniform> params: AnalysisParams;
// Three corners per scene triangle (xyz; w unused).
@group(0) @binding(1) var<storage, read> corners: array<vec4<f32>>;
// Per scene triangle: rays needed per m² (0 for triangles holding no target texel).
@group(0) @binding(2) var<storage, read> tri_importance: array<f32>;
// The scene triangles drawn for this direction (the window's candidates).
@group(0) @binding(3) var<storage, read> drawn: array<u32>;
// R×R: max importance (f32 bits), fragment counts; per drawn triangle: covered a centre.
@group(0) @binding(4) var<storage, read_write> importance_bits: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> counts: array<atomic<u32>>;
@group(0) @binding(6) var<storage, read_write> covered: array<atomic<u32>>;

// Continuous grid pixel coordinates of a world point, as `Viewport::grid_position` of
// `BundleFrame::coords` computes them.
fn grid_of(p: vec3<f32>) -> vec2<f32> {
    let c = vec2<f32>(p.x * params.t.x + p.y * params.t.y + p.z * params.t.z,
                      p.x * params.b.x + p.y * params.b.y + p.z * params.b.z);
    return (c - params.origin) / params.pixel;
}

// Rounds half away from zero, as Rust's f32::round (WGSL's round() rounds half to even).
fn round_away(v: vec2<f32>) -> vec2<f32> {
    return sign(v) * floor(abs(v) + vec2<f32>(0.5));
}

struct VertexOut {
    @builtin(position) position: vec4<f32>,
    @location(0) @interpolate(flat) slot: u32,
}

@vertex
fn vs_main(@builtin(vertex_index) vertex: u32) -> VertexOut {
    let slot = vertex / 3u;
    let tri = drawn[slot];
    let g = grid_of(corners[3u * tri + vertex % 3u].xyz);
    // Snapped to 1/256 pixel. The viewport is V×V pixels centred on the attachment's corner
    // (V a power of two, up to the device's texture limit), so the viewport transform is
    // fb = ndc·V/2 with no offset: s·(2/V) and back are exact, and corners within V/2 pixels
    // of the window are inside the clip volume (not clipped into new, unsnapped corners).
    let s = round_away(g * 256.0) / 256.0;
    let k = 2.0 / f32(params.view_side);
    var out: VertexOut;
    out.position = vec4<f32>(s.x * k, -s.y * k, 0.5, 1.0);
    out.slot = slot;
    return out;
}

@fragment
fn fs_main(in: VertexOut) -> @location(0) vec4<f32> {
    let i = u32(in.position.y) * params.res + u32(in.position.x);
    atomicAdd(&counts[i], 1u);
    let importance = tri_importance[drawn[in.slot]];
    if importance > 0.0 {
        atomicMax(&importance_bits[i], bitcast<u32>(importance));
    }
    atomicStore(&covered[in.slot], 1u);
    return vec4<f32>(0.0);
}

// Triangles that covered no pixel centre mark the pixel under their centroid (unsnapped
// grid positions, as the CPU).
@compute @workgroup_size(64)
fn touch(@builtin(global_invocation_id) id: vec3<u32>) {
    let slot = id.x;
    if slot >= params.drawn_count || atomicLoad(&covered[slot]) != 0u {
        return;
    }
    let tri = drawn[slot];
    let importance = tri_importance[tri];
    if !(importance > 0.0) {
        return;
    }
    let c = (grid_of(corners[3u * tri].xyz) + grid_of(corners[3u * tri + 1u].xyz) + grid_of(corners[3u * tri + 2u].xyz)) / 3.0;
    let res = f32(params.res);
    if c.x >= 0.0 && c.y >= 0.0 && c.x < res && c.y < res {
        atomicMax(&importance_bits[u32(c.y) * params.res + u32(c.x)], bitcast<u32>(importance));
    }
}
