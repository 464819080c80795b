// Per-pixel linked lists of one bundle tile (Tokuyoshi et al. 2013, Sect. 4.4): an
// orthographic raster of the tile's pixel rectangle whose fragment stage appends a node
// (depth along ω, triangle) to the node buffer with an atomic counter and links it in front
// of its pixel's list in the head buffer. The counter keeps counting past the node buffer's
// capacity N (those fragments are not stored): a count above N is the overflow the host sees,
// and the tile is then split and redone (`Viewport::split`), so no sample is lost.
//
// Nodes are 8 bytes (depth bits, triangle) with the links in a second binding: N is capped
// by the binding limit on 8 bytes, not on a whole node.
//
// Vertices are snapped and placed as in bundle_analysis.wgsl (1/256 pixel in the tile's own
// grid, then moved by the rectangle's whole-pixel offset): the same coverage as
// `bundle::raster`.

struct ListParams {
    t: vec3<f32>,
    pixel: f32,
    b: vec3<f32>,
    // Node buffer capacity N.
    capacity: u32,
    dir: vec3<f32>,
    // The rectangle's size (pixels) and its offset in the tile's grid.
    width: u32,
    origin: vec2<f32>,
    offset: vec2<u32>,
    height: u32,
    // Side V of the viewport (as in bundle_analysis.wgsl).
    view_side: u32,
    drawn_count: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> params: ListParams;
@group(0) @binding(1) var<storage, read> corners: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> drawn: array<u32>;
// Per pixel of the rectangle (row-major, width × height): 1 + its first node, 0 for none.
@group(0) @binding(3) var<storage, read_write> heads: array<atomic<u32>>;
// Per node: (depth bits, triangle); and 1 + the next node of its pixel, 0 at the end.
@group(0) @binding(4) var<storage, read_write> nodes: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read_write> links: array<u32>;
@group(0) @binding(6) var<storage, read_write> counter: atomic<u32>;

fn grid_of(p: vec3<f32>) -> vec2<f32> {
    let c = vec2<f32>(p.x * params.t.x + p.y * params.t.y + p.z * params.t.z,
                      p.x * params.b.x + p.y * params.b.y + p.z * params.b.z);
    return (c - params.origin) / params.pixel;
}

fn round_away(v: vec2<f32>) -> vec2<f32> {
    return sign(v) * floor(abs(v) + vec2<f32>(0.5));
}

struct VertexOut {
    @builtin(position) position: vec4<f32>,
    @location(0) depth: f32,
    @location(1) @interpolate(flat) tri: u32,
}

@vertex
fn vs_main(@builtin(vertex_index) vertex: u32) -> VertexOut {
    let tri = drawn[vertex / 3u];
    let p = corners[3u * tri + vertex % 3u].xyz;
    let s = round_away(grid_of(p) * 256.0) / 256.0 - vec2<f32>(params.offset);
    let k = 2.0 / f32(params.view_side);
    var out: VertexOut;
    out.position = vec4<f32>(s.x * k, -s.y * k, 0.5, 1.0);
    out.depth = p.x * params.dir.x + p.y * params.dir.y + p.z * params.dir.z;
    out.tri = tri;
    return out;
}

@fragment
fn fs_main(in: VertexOut) -> @location(0) vec4<f32> {
    // The scissor keeps fragments inside the rectangle.
    let pixel = u32(in.position.y) * params.width + u32(in.position.x);
    let node = atomicAdd(&counter, 1u);
    if node < params.capacity {
        nodes[node] = vec2<u32>(bitcast<u32>(in.depth), in.tri);
        links[node] = atomicExchange(&heads[pixel], node + 1u);
    }
    return vec4<f32>(0.0);
}
