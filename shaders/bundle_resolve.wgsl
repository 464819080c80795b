// Resolve of one bundle rectangle's per-pixel linked lists (global bundles): the GPU twin
// of `cpu::fragments::TileFragments::resolve` followed by `bundle::estimator::exchange`.
// One invocation per pixel of the rectangle's groups of 8 pixels that have fragments
// walks the pixel's list, rebuilds each node's fragment (depth, side codes, packed normal)
// from its triangle exactly as the CPU sets it up,
// sorts the fragments along ω with the estimator's layer rules (`Coincidence`), and credits
// every target side the radiance of what it sees (in a scene that lets light through
// surfaces, through them: bundle_through.inc.wgsl, `cpu::through`'s twin).
//
// Depths are recomputed from the triangle's snapped corners the CPU's way, never taken
// from the raster's interpolation (which differs by up to 2^-16 m, more than the layer
// tolerances). The arithmetic follows the CPU's operation for operation; only fused
// multiply-adds the compiler may form can round a value differently, which moves a
// decision only where a value lies within an ulp of its threshold (see the twin test).
//
// Accumulation without float atomics: every hit adds a_px·L and a_px to its texel as
// 64-bit fixed point (two u32 words: the low word's atomicAdd returns the old value, so
// each addition sees its own carry). The host picks the scales so a batch's sums stay
// below 2^62 with room to spare; a high word reaching 2^31 is counted as a saturation and
// the host redoes the batch with smaller scales. Integer sums are exact and independent
// of order: the result does not depend on scheduling.
//
// Foreign sides (surfaces outside the target, which a runtime cell's bundles see) show what
// the runtime's `ShownSource` says they reflect: albedo/π times the shown light map's
// irradiance at their surface point (group 1, lightmap.inc.wgsl), plus their emission where
// the global bundles carry it (group 2, surface_radiance.inc.wgsl). Without a foreign
// source (a whole-LOD bake) they are black and counted lost, as on the CPU. Which of the
// two is a pipeline constant, so the pipeline without one holds none of that code: llvmpipe
// runs both sides of a branch its lanes may take, and the foreign path, never taken, made
// every whole-LOD resolve 6× slower as a branch on a parameter.
override FOREIGN_SOURCE: bool = false;
// Whether the scene has surfaces light passes (BLEND, transmission, MASK): each fragment
// then gets its transmittance and a side sees through them (bundle_through.inc.wgsl),
// reading the scene's materials (group 2) and each target texel's triangle. A pipeline
// constant too: scenes without such surfaces resolve with none of that code.
override PASSING: bool = false;

#include "lightmap.inc.wgsl"
#include "surface_radiance.inc.wgsl"
#include "bundle_through.inc.wgsl"

// Products, divisions and square roots round as the CPU's IEEE f32 arithmetic does (every
// decision is then the CPU's): Vulkan lets f32 division and sqrt be off by ulps, so they go
// through `real`, f64 where the device has it (the host rewrites this alias), correctly
// rounded to f32 after; and it lets a compiler fuse multiply-adds, which `mul` prevents.
// Without f64, a value within an ulp of a decision's threshold can decide differently.
alias real = f32;

fn div(a: f32, b: f32) -> f32 {
    return f32(real(a) / real(b));
}

fn root(a: f32) -> f32 {
    return f32(sqrt(real(a)));
}

// A product rounded to f32 before anything is added to it: the CPU rounds every product,
// and a compiler may fuse a·b + c into one rounding (lavapipe does), which moved a line's
// texel at one fragment in 30 000. Passing the product's bits through an XOR with a
// uniform that is zero (the compiler cannot know it) leaves the value as it is but gives
// the compiler nothing it could fuse.
fn mul(a: f32, b: f32) -> f32 {
    return bitcast<f32>(bitcast<u32>(a * b) ^ params.opaque_zero);
}

const NO_SIDE: u32 = 0x7FFFFFFFu;
const FOREIGN: u32 = 0x40000000u;
const FRONT_LOOKS_PLUS: u32 = 0x80000000u;
const CODE_MASK: u32 = 0x7FFFFFFFu;
const NO_CHART: u32 = 0xFFFFFFFFu;
const NO_TEXEL: u32 = 0xFFFFFFFFu;
const COPLANAR_COS: f32 = 0.9999995;
// Fragments one pixel can hold for sorting; deeper pixels are counted and skipped.
const MAX_DEPTH: u32 = 64u;
// Status words after the sums: saturated additions, lost foreign lookups, covered pixels,
// pixels deeper than MAX_DEPTH, foreign sides looked up (and resolved).
const STATUS_SATURATED: u32 = 0u;
const STATUS_LOST: u32 = 1u;
const STATUS_COVERED: u32 = 2u;
const STATUS_DEEP: u32 = 3u;
const STATUS_FOREIGN: u32 = 4u;

struct ResolveParams {
    t: vec3<f32>,
    pixel: f32,
    b: vec3<f32>,
    pixel_area: f32,
    dir: vec3<f32>,
    capacity: u32,
    // Seen looking along +ω at a line's end (the sky in direction ω), and looking along −ω at
    // its start (the sky in direction −ω).
    sky_ahead: vec3<f32>,
    rounding: f32,
    origin: vec2<f32>,
    offset: vec2<u32>,
    width: u32,
    height: u32,
    stacked: f32,
    snap: f32,
    // 2^lod: LOD-0 atlas UV to this LOD's pixels.
    lod_scale: f32,
    table_count: u32,
    // 1 when the target has one whole-LOD table serving every chart.
    whole_table: u32,
    texel_count: u32,
    // Fixed-point units per m² of weight, and per m²·(W/m²/sr) of weighted radiance.
    weight_scale: f32,
    radiance_scale: f32,
    _pad0: u32,
    _pad1: u32,
    sky_behind: vec3<f32>,
    // Always 0 (see `mul`).
    opaque_zero: u32,
}

// A triangle's sides as the resolve needs them (set once per scene).
struct ResolveTriangle {
    // Unit front normal (world).
    normal: vec3<f32>,
    // Chart of the front face, NO_CHART when the front is not a lit face.
    front_chart: u32,
    // Per corner: (front face UV, back face UV), LOD-0 atlas texels.
    corner_uv: array<vec4<f32>, 3>,
    back_chart: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// A texel table (`atlas::lookup::TexelTable`): a pixel rectangle in 8×8 blocks.
struct TableHeader {
    // Chart served (NO_CHART for the whole-LOD table).
    chart: u32,
    x0: i32,
    y0: i32,
    x1: i32,
    y1: i32,
    blocks_x: u32,
    // First entry in the entries buffer.
    first: u32,
    _pad: u32,
}

struct Fragment {
    depth: f32,
    plus: u32,
    minus: u32,
    normal: u32,
}

// The rectangle's parameters come from a storage buffer, not a uniform block: lavapipe
// compiles a variant of a shader for every set of values of the uniforms its branches and
// loops test (inlined uniforms), which here meant one compile per tile (~1.5 s each where
// Mesa's shader cache did not have it). They are copied once into `params` at the start:
// llvmpipe loads storage lane by lane, so a load at each use would be a loop each time.
@group(0) @binding(0) var<storage, read> rectangle: ResolveParams;
var<private> params: ResolveParams;
@group(0) @binding(1) var<storage, read> corners: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> triangles: array<ResolveTriangle>;
@group(0) @binding(3) var<storage, read> heads: array<u32>;
@group(0) @binding(4) var<storage, read> nodes: array<vec2<u32>>;
@group(0) @binding(5) var<storage, read> links: array<u32>;
@group(0) @binding(6) var<storage, read> counter: array<u32>;
@group(0) @binding(7) var<storage, read> tables: array<TableHeader>;
@group(0) @binding(8) var<storage, read> entries: array<u32>;
// Per target texel: outgoing radiance toward the bundles (r, g, b).
@group(0) @binding(9) var<storage, read> own: array<f32>;
// Per texel: (lo, hi) of r, g, b, weight; then the status words.
@group(0) @binding(10) var<storage, read_write> sums: array<atomic<u32>>;
// The groups of 8 pixels (a row's, from a multiple of 8) that have fragments, as
// bundle_groups.wgsl lists them: 1 + the group's index, 0 past the last.
@group(0) @binding(11) var<storage, read> groups: array<u32>;
// Per target texel: the triangle of its face (`PASSING`: where a texel's fragment reads
// its material).
@group(0) @binding(12) var<storage, read> texel_triangles: array<u32>;

// ---- fragment set-up (cpu::fragments, bundle::raster) ----

fn frame_coords(p: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot_cpu(p, params.t), dot_cpu(p, params.b), dot_cpu(p, params.dir));
}

fn round_away(v: vec2<f32>) -> vec2<f32> {
    return sign(v) * floor(abs(v) + vec2<f32>(0.5));
}

// Affine coefficients (per pixel in x, in y, and the value at the anchor p[0]) of the
// values v at the snapped grid corners p (`ScreenTriangle::planes`).
fn plane(p: array<vec2<f32>, 3>, v: vec3<f32>, inv: f32) -> vec3<f32> {
    let e1 = p[1] - p[0];
    let e2 = p[2] - p[0];
    let d1 = v.y - v.x;
    let d2 = v.z - v.x;
    let cx = (mul(d1, e2.y) - mul(d2, e1.y)) * inv;
    let cy = (mul(d2, e1.x) - mul(d1, e2.x)) * inv;
    return vec3<f32>(cx, cy, v.x);
}

fn eval(c: vec3<f32>, x: f32, y: f32) -> f32 {
    return mul(c.x, x) + mul(c.y, y) + c.z;
}

// `Planes::gradient`: coefficients of values interpolated from the three corners.
fn gradient(bu: vec3<f32>, bv: vec3<f32>, v: vec3<f32>) -> vec3<f32> {
    let d1 = v.y - v.x;
    let d2 = v.z - v.x;
    return vec3<f32>(mul(v.x, 0.0) + mul(d1, bu.x) + mul(d2, bv.x),
                     mul(v.x, 0.0) + mul(d1, bu.y) + mul(d2, bv.y),
                     v.x + mul(d1, bu.z) + mul(d2, bv.z));
}

// `estimator::pack_normal`.
fn pack_normal(n_in: vec3<f32>) -> u32 {
    let l1 = max(abs(n_in.x) + abs(n_in.y) + abs(n_in.z), 1.17549435e-38);
    let n = vec3<f32>(div(n_in.x, l1), div(n_in.y, l1), div(n_in.z, l1));
    var u = n.x;
    var v = n.y;
    if n.z < 0.0 {
        u = (1.0 - abs(n.y)) * select(-1.0, 1.0, n.x >= 0.0);
        v = (1.0 - abs(n.x)) * select(-1.0, 1.0, n.y >= 0.0);
    }
    // Non-negative: rounding half away from zero is floor(x + 0.5), as Rust's `round`.
    let qu = u32(floor(mul(clamp(u, -1.0, 1.0) * 0.5 + 0.5, 65535.0) + 0.5));
    let qv = u32(floor(mul(clamp(v, -1.0, 1.0) * 0.5 + 0.5, 65535.0) + 0.5));
    return qu | (qv << 16u);
}

// `estimator::unpack_normal`.
fn unpack_normal(packed: u32) -> vec3<f32> {
    let u = div(f32(packed & 0xFFFFu), 65535.0) * 2.0 - 1.0;
    let v = div(f32(packed >> 16u), 65535.0) * 2.0 - 1.0;
    let z = 1.0 - abs(u) - abs(v);
    let t = max(-z, 0.0);
    let x = u + select(t, -t, u >= 0.0);
    let y = v + select(t, -t, v >= 0.0);
    // glam's normalize: times the reciprocal of the length.
    let r = vec3<f32>(x, y, z);
    return r * div(1.0, root(dot_cpu(r, r)));
}

// The index of the table serving `chart`, or NO_CHART (`BakeTarget::table_index`).
fn table_of(chart: u32) -> u32 {
    if params.whole_table == 1u {
        return 0u;
    }
    var lo = 0u;
    var hi = params.table_count;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        let c = tables[mid].chart;
        if c == chart {
            return mid;
        }
        if c < chart {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    return NO_CHART;
}

// `fragments::texel_at`: the texel under UV plane (gu, gv) at (dx, dy) from the anchor.
fn texel_at(table: u32, gu: vec3<f32>, gv: vec3<f32>, dx: f32, dy: f32, foreign: u32) -> u32 {
    let px = eval(gu, dx, dy);
    let py = eval(gv, dx, dy);
    if !(px >= 0.0 && py >= 0.0 && px < 1.6e7 && py < 1.6e7) {
        return foreign;
    }
    let h = tables[table];
    let x = i32(px);
    let y = i32(py);
    if x < h.x0 || x >= h.x1 || y < h.y0 || y >= h.y1 {
        return foreign;
    }
    let rx = u32(x - h.x0);
    let ry = u32(y - h.y0);
    let index = (((ry >> 3u) * h.blocks_x + (rx >> 3u)) << 6u) | ((ry & 7u) << 3u) | (rx & 7u);
    let t = entries[h.first + index];
    return select(t, foreign, t == NO_TEXEL);
}

// The code of one side of triangle `tri` at (dx, dy) from its anchor: `front` picks the face.
fn side_code(tri: u32, front: bool, minus: bool, bu: vec3<f32>, bv: vec3<f32>, dx: f32, dy: f32) -> u32 {
    let info = triangles[tri];
    let chart = select(info.back_chart, info.front_chart, front);
    if chart == NO_CHART {
        return NO_SIDE;
    }
    let foreign = FOREIGN + 2u * tri + select(0u, 1u, minus);
    let table = table_of(chart);
    if table == NO_CHART {
        return foreign;
    }
    let s = params.lod_scale;
    var uv: array<vec2<f32>, 3>;
    for (var k = 0u; k < 3u; k++) {
        let c = info.corner_uv[k];
        uv[k] = select(c.zw, c.xy, front) * s;
    }
    let gu = gradient(bu, bv, vec3<f32>(uv[0].x, uv[1].x, uv[2].x));
    let gv = gradient(bu, bv, vec3<f32>(uv[0].y, uv[1].y, uv[2].y));
    return texel_at(table, gu, gv, dx, dy, foreign);
}

// A triangle set up on the bundle grid (`ScreenTriangle::planes`): its barycentric and
// depth planes, and the offset of the pixel centre from its anchor (the first snapped
// corner), relative to which the CPU evaluates them (exact subtractions).
struct TrianglePlanes {
    bu: vec3<f32>,
    bv: vec3<f32>,
    depth: vec3<f32>,
    dx: f32,
    dy: f32,
}

fn triangle_planes(tri: u32, cx: f32, cy: f32) -> TrianglePlanes {
    var grid: array<vec2<f32>, 3>;
    var depths: vec3<f32>;
    for (var k = 0u; k < 3u; k++) {
        let c = frame_coords(corners[3u * tri + k].xyz);
        let q = vec2<f32>(div(c.x - params.origin.x, params.pixel), div(c.y - params.origin.y, params.pixel));
        grid[k] = round_away(q * 256.0) / 256.0;
        depths[k] = c.z;
    }
    let e1 = grid[1] - grid[0];
    let e2 = grid[2] - grid[0];
    let inv = div(1.0, mul(e1.x, e2.y) - mul(e1.y, e2.x));
    var t: TrianglePlanes;
    t.bu = plane(grid, vec3<f32>(0.0, 1.0, 0.0), inv);
    t.bv = plane(grid, vec3<f32>(0.0, 0.0, 1.0), inv);
    t.depth = plane(grid, depths, inv);
    t.dx = cx - grid[0].x;
    t.dy = cy - grid[0].y;
    return t;
}

// The fragment of triangle `tri` at grid centre (cx, cy) (`TileFragments::fill`).
fn fragment(tri: u32, cx: f32, cy: f32) -> Fragment {
    let t = triangle_planes(tri, cx, cy);
    let n = triangles[tri].normal;
    let front_looks_plus = dot_cpu(n, params.dir) > 0.0;
    var f: Fragment;
    f.depth = eval(t.depth, t.dx, t.dy);
    f.plus = side_code(tri, front_looks_plus, false, t.bu, t.bv, t.dx, t.dy);
    f.minus = side_code(tri, !front_looks_plus, true, t.bu, t.bv, t.dx, t.dy) | select(0u, FRONT_LOOKS_PLUS, front_looks_plus);
    f.normal = pack_normal(frame_coords(n));
    return f;
}

// ---- layers and exchange (bundle::estimator) ----

var<private> frags: array<Fragment, MAX_DEPTH>;
var<private> tri_of: array<u32, MAX_DEPTH>;

fn coincident_rank(f: Fragment) -> u32 {
    return f.minus >> 31u;
}

fn reach() -> f32 {
    return params.rounding + mul(100.0, params.stacked + params.snap);
}

// (gap along the normal, what rounding and snapping allow there).
fn normal_gap(gap: f32, n: vec3<f32>) -> vec2<f32> {
    let c = abs(n.z);
    let s = root(max(1.0 - mul(c, c), 0.0));
    return vec2<f32>(gap * c, mul(params.rounding, c) + mul(params.snap, s));
}

fn same_place(a: Fragment, b: Fragment) -> bool {
    let gap = abs(b.depth - a.depth);
    if gap <= params.rounding {
        return true;
    }
    if gap > reach() {
        return false;
    }
    let na = unpack_normal(a.normal);
    let nb = unpack_normal(b.normal);
    let g = normal_gap(gap, na);
    return g.x <= g.y && abs(dot_cpu(na, nb)) >= COPLANAR_COS;
}

fn joins(a: Fragment, b: Fragment) -> bool {
    let gap = abs(b.depth - a.depth);
    if coincident_rank(a) != coincident_rank(b) || gap > reach() {
        return false;
    }
    let na = unpack_normal(a.normal);
    let nb = unpack_normal(b.normal);
    let g = normal_gap(gap, na);
    return g.x <= g.y + params.stacked && dot_cpu(na, nb) >= COPLANAR_COS;
}

// glam's dot product order.
fn dot_cpu(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return mul(a.x, b.x) + mul(a.y, b.y) + mul(a.z, b.z);
}

fn before(a: Fragment, b: Fragment) -> bool {
    if same_place(a, b) {
        return coincident_rank(a) < coincident_rank(b);
    }
    return a.depth < b.depth;
}

fn sort_by_depth(n: u32) {
    for (var i = 1u; i < n; i++) {
        let f = frags[i];
        var j = i;
        while j > 0u && before(f, frags[j - 1u]) {
            frags[j] = frags[j - 1u];
            j -= 1u;
        }
        frags[j] = f;
    }
}

fn layer_end(n: u32, start: u32) -> u32 {
    var end = start + 1u;
    while end < n && joins(frags[end - 1u], frags[end]) {
        end += 1u;
    }
    return end;
}

// Foreign sides this invocation looked up, and lost (added to the status words once, at
// the end: one atomic per invocation, not one per lookup).
var<private> foreign_lookups: u32;
var<private> lost_lookups: u32;

// `Grid::coords_of` with the CPU's correctly rounded division: a point within rounding of a
// cell face lands in the CPU's cell, so it reads the same shown LOD.
fn foreign_cell(p: vec3<f32>) -> vec3<u32> {
    let d = p - lm.grid_origin;
    let q = vec3<f32>(div(d.x, lm.cell_size), div(d.y, lm.cell_size), div(d.z, lm.cell_size));
    var c: vec3<u32>;
    for (var k = 0u; k < 3u; k++) {
        c[k] = select(min(u32(q[k]), lm.grid_dims[k] - 1u), 0u, !(q[k] >= 0.0));
    }
    return c;
}

// The pixel being resolved: its grid centre (where foreign sides are located).
var<private> centre: vec2<f32>;

// `ShownSource::radiance` of foreign side `code` of fragment `f`: the side's face reflects
// albedo/π of the shown irradiance at the pixel centre's surface point, plus its emission
// where the global bundles carry it. The point's barycentrics are set up again here (as
// `ForeignSides::locate` does) rather than carried by every fragment: foreign lookups are
// few beside fragments, which stay 16 bytes of each lane's private sort array.
fn foreign_radiance(f: Fragment, code: u32) -> vec3<f32> {
    let tri = (code - FOREIGN) >> 1u;
    let minus = (code & 1u) == 1u;
    let front = ((f.minus & FRONT_LOOKS_PLUS) != 0u) != minus;
    let info = triangles[tri];
    if select(info.back_chart, info.front_chart, front) == NO_CHART {
        return vec3<f32>(0.0);
    }
    let bary = located_barycentrics(tri);
    let u = bary.x;
    let v = bary.y;
    // `SceneGeometry::point` and `AtlasFace::uv_at`: a + (b − a)·u + (c − a)·v.
    let a = corners[3u * tri].xyz;
    let e1 = corners[3u * tri + 1u].xyz - a;
    let e2 = corners[3u * tri + 2u].xyz - a;
    let p = a + vec3<f32>(mul(e1.x, u), mul(e1.y, u), mul(e1.z, u))
        + vec3<f32>(mul(e2.x, v), mul(e2.y, v), mul(e2.z, v));
    var uv: array<vec2<f32>, 3>;
    for (var k = 0u; k < 3u; k++) {
        let c = info.corner_uv[k];
        uv[k] = select(c.zw, c.xy, front);
    }
    let d1 = uv[1] - uv[0];
    let d2 = uv[2] - uv[0];
    let at = uv[0] + vec2<f32>(mul(d1.x, u), mul(d1.y, u)) + vec2<f32>(mul(d2.x, v), mul(d2.y, v));
    let e = shown_irradiance_in(foreign_cell(p), p, at);
    let albedo_e = mul3(surface_albedo(tri, u, v), e);
    let reflected = vec3<f32>(mul(albedo_e.x, FRAC_1_PI), mul(albedo_e.y, FRAC_1_PI), mul(albedo_e.z, FRAC_1_PI));
    if surface_carried(tri) {
        return reflected + surface_emission(tri, front, u, v);
    }
    return reflected;
}

// `ForeignSides::locate`'s barycentrics of the pixel centre on triangle `tri`
// (`Planes::barycentrics`: clamped onto the triangle).
fn located_barycentrics(tri: u32) -> vec2<f32> {
    let t = triangle_planes(tri, centre.x, centre.y);
    let u = clamp(eval(t.bu, t.dx, t.dy), 0.0, 1.0);
    let v = clamp(eval(t.bv, t.dx, t.dy), 0.0, 1.0 - u);
    return vec2<f32>(u, v);
}

// std::f32::consts::FRAC_1_PI.
const FRAC_1_PI: f32 = 0.3183098861837907;

// The radiance side `code` of fragment `f` shows the bundles: a target texel's source, or a
// foreign side's (black, counted lost, without a foreign source).
fn seen(f: Fragment, code: u32) -> vec3<f32> {
    if code < FOREIGN {
        return vec3<f32>(own[3u * code], own[3u * code + 1u], own[3u * code + 2u]);
    }
    if FOREIGN_SOURCE {
        foreign_lookups += 1u;
        return foreign_radiance(f, code);
    }
    lost_lookups += 1u;
    return vec3<f32>(0.0);
}

fn element_sum(l: vec3<f32>) -> f32 {
    return l.x + l.y + l.z;
}

// `estimator::layer_face` over frags[start..end]: `minus_side` picks the side seen from
// before the layer.
fn layer_face(start: u32, end: u32, minus_side: bool) -> vec3<f32> {
    var best = vec3<f32>(0.0);
    var found = false;
    for (var i = start; i < end; i++) {
        let code = select(frags[i].plus, frags[i].minus, minus_side) & CODE_MASK;
        if code == NO_SIDE {
            continue;
        }
        let l = seen(frags[i], code);
        if !found || element_sum(l) > element_sum(best) {
            best = l;
            found = true;
        }
    }
    return best;
}

// Whether no fragment of frags[start..end] shows a lit face on the chosen side
// (`estimator::buried`'s `blind`).
fn blind(start: u32, end: u32, minus_side: bool) -> bool {
    for (var i = start; i < end; i++) {
        if (select(frags[i].plus, frags[i].minus, minus_side) & CODE_MASK) != NO_SIDE {
            return false;
        }
    }
    return true;
}

// Adds `value` (≥ 0, fixed-point units) to 64-bit sum `slot`.
fn add_fixed(slot: u32, value: f32) {
    if !(value > 0.0) {
        return;
    }
    let two32 = 4294967296.0;
    if value >= two32 * two32 {
        atomicAdd(&sums[8u * params.texel_count + STATUS_SATURATED], 1u);
        return;
    }
    let high = floor(value * (1.0 / two32));
    let hi = u32(high);
    let lo = u32(value - high * two32);
    let old = atomicAdd(&sums[2u * slot], lo);
    let carry = select(0u, 1u, old + lo < old);
    let add = hi + carry;
    if add != 0u {
        let before_add = atomicAdd(&sums[2u * slot + 1u], add);
        if before_add + add >= 0x80000000u || before_add + add < before_add {
            atomicAdd(&sums[8u * params.texel_count + STATUS_SATURATED], 1u);
        }
    }
}

fn hit(texel: u32, l: vec3<f32>) {
    let a = params.pixel_area;
    let la = l * a;
    add_fixed(4u * texel, la.x * params.radiance_scale);
    add_fixed(4u * texel + 1u, la.y * params.radiance_scale);
    add_fixed(4u * texel + 2u, la.z * params.radiance_scale);
    add_fixed(4u * texel + 3u, a * params.weight_scale);
}

// `estimator::exchange` over frags[0..n].
fn exchange(n: u32) {
    var start = 0u;
    var end = layer_end(n, 0u);
    var behind_start = 0u;
    var behind_end = 0u;
    var has_behind = false;
    while start < n {
        var next_end = end;
        if end < n {
            next_end = layer_end(n, end);
        }
        var l_ahead = vec3<f32>(0.0);
        var l_behind = vec3<f32>(0.0);
        var have_ahead = false;
        var have_behind = false;
        // `estimator::buried`: a layer inside closed geometry gets no hit.
        let buried = has_behind && end < n && blind(behind_start, behind_end, false) && blind(end, next_end, true);
        for (var i = start; i < select(end, start, buried); i++) {
            let f = frags[i];
            let plus = f.plus & CODE_MASK;
            if plus < FOREIGN {
                if !have_ahead {
                    if end < n {
                        l_ahead = layer_face(end, next_end, true);
                    } else {
                        l_ahead = params.sky_ahead;
                    }
                    have_ahead = true;
                }
                hit(plus, l_ahead);
            }
            let minus = f.minus & CODE_MASK;
            if minus < FOREIGN {
                if !have_behind {
                    if has_behind {
                        l_behind = layer_face(behind_start, behind_end, false);
                    } else {
                        l_behind = params.sky_behind;
                    }
                    have_behind = true;
                }
                hit(minus, l_behind);
            }
        }
        behind_start = start;
        behind_end = end;
        has_behind = true;
        start = end;
        end = next_end;
    }
}

// Eight invocations per listed group of pixels (llvmpipe's SIMD group: see
// bundle_groups.wgsl), dispatched indirectly.
@compute @workgroup_size(64)
fn resolve(@builtin(global_invocation_id) id: vec3<u32>) {
    params = rectangle;
    let group = groups[id.x / 8u];
    if group == 0u {
        return;
    }
    let per_row = (params.width + 7u) / 8u;
    let px = ((group - 1u) % per_row) * 8u + id.x % 8u;
    let py = (group - 1u) / per_row;
    if px >= params.width {
        return;
    }
    // An overflowed rectangle is split and redone by the host; a single pixel deeper than
    // the node buffer (which cannot be split) is resolved with the nodes it kept.
    let count = counter[0];
    if count > params.capacity && (params.width > 1u || params.height > 1u) {
        return;
    }
    let pixel = py * params.width + px;
    let cx = f32(px + params.offset.x) + 0.5;
    let cy = f32(py + params.offset.y) + 0.5;
    centre = vec2<f32>(cx, cy);
    var n = 0u;
    var next = heads[pixel];
    var steps = 0u;
    while next != 0u && steps <= params.capacity {
        if n == MAX_DEPTH {
            atomicAdd(&sums[8u * params.texel_count + STATUS_DEEP], 1u);
            return;
        }
        let node = next - 1u;
        let tri = nodes[node].y;
        frags[n] = fragment(tri, cx, cy);
        tri_of[n] = tri;
        n += 1u;
        next = links[node];
        steps += 1u;
    }
    if n == 0u {
        return;
    }
    atomicAdd(&sums[8u * params.texel_count + STATUS_COVERED], 1u);
    // A pixel where no fragment is a target side credits nothing (a cell's window draws
    // the occluders around it): no sort.
    var targets = false;
    for (var i = 0u; i < n; i++) {
        targets = targets || (frags[i].plus & CODE_MASK) < FOREIGN || (frags[i].minus & CODE_MASK) < FOREIGN;
    }
    if !targets {
        return;
    }
    // The list holds the nodes in reverse raster order; the CPU's pixel lists are in
    // triangle order, and the sort is stable, so order them by triangle first.
    for (var i = 1u; i < n; i++) {
        let f = frags[i];
        let t = tri_of[i];
        var j = i;
        while j > 0u && tri_of[j - 1u] > t {
            frags[j] = frags[j - 1u];
            tri_of[j] = tri_of[j - 1u];
            j -= 1u;
        }
        frags[j] = f;
        tri_of[j] = t;
    }
    if n > 1u {
        sort_by_depth(n);
    }
    foreign_lookups = 0u;
    lost_lookups = 0u;
    if PASSING {
        exchange_through(drop_cut_outs(n));
    } else {
        exchange(n);
    }
    if foreign_lookups > 0u {
        atomicAdd(&sums[8u * params.texel_count + STATUS_FOREIGN], foreign_lookups);
    }
    if lost_lookups > 0u {
        atomicAdd(&sums[8u * params.texel_count + STATUS_LOST], lost_lookups);
    }
}
