// Resolve of one built tile rectangle (bundle::estimator): one thread per bundle pixel walks
// its linked list, recomputes each fragment the CPU's way from its triangle (snapped corners
// in the tile's grid → depth and UV planes at the pixel centre → texel table), orders the
// fragments along ω with the coincident-surface rule, and exchanges radiance between
// neighbours with the sidedness rules of `estimator::exchange`. Hits are summed per texel in
// 64-bit fixed point (two u32 words, carry by hand): no float atomics, an exact sum in any
// order; a carry out of the top word saturates the texel and raises a flag.
//
// Scope: a whole-LOD target with one whole-LOD texel table and no foreign radiance (a lit
// face the table misses is black and counted lost), global bundles only.

struct ResolveParams {
    t: vec3<f32>,
    pixel: f32,
    b: vec3<f32>,
    width: u32,
    dir: vec3<f32>,
    height: u32,
    origin: vec2<f32>,
    offset: vec2<u32>,
    sky: vec3<f32>,
    // Bundle pixel area a_px (m²) and the fixed-point scales of Σ a·L and of Σ a.
    a_px: f32,
    // Texel table: covered rect [x0, x1) × [y0, y1) in LOD pixels, 8×8 blocks per row.
    rect: vec4<i32>,
    blocks_x: i32,
    // UV scale 2^lod, depth tolerance of coincident surfaces, radiance scale.
    uv_scale: f32,
    coincident: f32,
    radiance_scale: f32,
    area_scale: f32,
    // 1.0, read at run time: products scaled by it are rounded before any add (see `mul`).
    one: f32,
    _pad1: u32,
    _pad2: u32,
}

// One triangle's atlas faces: corner UVs (LOD-0 texels) of front and back; `faces` bit 0:
// has a front face, bit 1: a back face.
struct TriangleFaces {
    front: array<vec2<f32>, 3>,
    back: array<vec2<f32>, 3>,
    faces: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> params: ResolveParams;
@group(0) @binding(1) var<storage, read> corners: array<vec4<f32>>;
@group(0) @binding(2) var<storage, read> normals: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> faces: array<TriangleFaces>;
@group(0) @binding(4) var<storage, read> table: array<u32>;
// Per target texel: outgoing radiance toward the bundles (rgb).
@group(0) @binding(5) var<storage, read> own: array<vec4<f32>>;
@group(0) @binding(6) var<storage, read> heads: array<u32>;
@group(0) @binding(7) var<storage, read> nodes: array<vec2<u32>>;
@group(0) @binding(8) var<storage, read> links: array<u32>;
// Per texel 8 words: (low, high) of Σ a·L r, g, b and Σ a.
@group(0) @binding(9) var<storage, read_write> sums: array<atomic<u32>>;
// [saturated texels, lost lookups, pixels with more fragments than MAX_FRAGMENTS, covered pixels].
@group(0) @binding(10) var<storage, read_write> flags: array<atomic<u32>, 4>;

const NO_SIDE: u32 = 0x7FFFFFFFu;
const FOREIGN: u32 = 0x40000000u;
const FRONT_LOOKS_PLUS: u32 = 0x80000000u;
const CODE_MASK: u32 = 0x7FFFFFFFu;
const NO_TEXEL: u32 = 0xFFFFFFFFu;
const MAX_FRAGMENTS: u32 = 48u;

// a·b rounded to f32 before whatever adds it: the driver may fuse a·b + c into one fma
// (rounded once), the CPU rounds the product first. Scaled by the run-time 1.0 the product is
// a separate multiply, and an fma of (a·b)·1 + c rounds like the CPU's two operations.
fn mul(a: f32, b: f32) -> f32 {
    return (a * b) * params.one;
}

fn dot3(a: vec3<f32>, b: vec3<f32>) -> f32 {
    return mul(a.x, b.x) + mul(a.y, b.y) + mul(a.z, b.z);
}

fn grid_of(p: vec3<f32>) -> vec2<f32> {
    let c = vec2<f32>(dot3(p, params.t), dot3(p, params.b));
    return (c - params.origin) / params.pixel;
}

fn round_away(v: vec2<f32>) -> vec2<f32> {
    return sign(v) * floor(abs(v) + vec2<f32>(0.5));
}

// An affine function of grid coordinates: c.x·x + c.y·y + c.z.
fn eval(c: vec3<f32>, x: f32, y: f32) -> f32 {
    return mul(c.x, x) + mul(c.y, y) + c.z;
}

// `ScreenTriangle::planes` of the snapped corners `p` for corner values `v`.
fn plane(p0: vec2<f32>, e1: vec2<f32>, e2: vec2<f32>, inv: f32, v: vec3<f32>) -> vec3<f32> {
    let d1 = v.y - v.x;
    let d2 = v.z - v.x;
    let cx = (mul(d1, e2.y) - mul(d2, e1.y)) * inv;
    let cy = (mul(d2, e1.x) - mul(d1, e2.x)) * inv;
    return vec3<f32>(cx, cy, v.x - mul(cx, p0.x) - mul(cy, p0.y));
}

// `texel_at`: the texel under UV `uv` (LOD pixels), or `miss`.
fn texel_at(uv: vec2<f32>, miss: u32) -> u32 {
    if !(uv.x >= 0.0 && uv.y >= 0.0 && uv.x < 1.6e7 && uv.y < 1.6e7) {
        return miss;
    }
    let x = i32(uv.x);
    let y = i32(uv.y);
    let r = params.rect;
    if x < r.x || y < r.y || x >= r.z || y >= r.w {
        return miss;
    }
    let lx = x - r.x;
    let ly = y - r.y;
    let i = (((ly >> 3u) * params.blocks_x + (lx >> 3u)) << 6u) | ((ly & 7) << 3u) | (lx & 7);
    let t = table[u32(i)];
    return select(t, miss, t == NO_TEXEL);
}

var<private> frag_depth: array<f32, MAX_FRAGMENTS>;
var<private> frag_plus: array<u32, MAX_FRAGMENTS>;
var<private> frag_minus: array<u32, MAX_FRAGMENTS>;
var<private> frag_tri: array<u32, MAX_FRAGMENTS>;

// `estimator::before`.
fn before(a: u32, b: u32) -> bool {
    if abs(frag_depth[a] - frag_depth[b]) <= params.coincident {
        return (frag_minus[a] >> 31u) < (frag_minus[b] >> 31u);
    }
    return frag_depth[a] < frag_depth[b];
}

fn swap_fragments(i: u32, j: u32) {
    let d = frag_depth[i]; frag_depth[i] = frag_depth[j]; frag_depth[j] = d;
    let p = frag_plus[i]; frag_plus[i] = frag_plus[j]; frag_plus[j] = p;
    let m = frag_minus[i]; frag_minus[i] = frag_minus[j]; frag_minus[j] = m;
    let t = frag_tri[i]; frag_tri[i] = frag_tri[j]; frag_tri[j] = t;
}

// Adds `value` (≥ 0) × `scale` to the 64-bit word pair at `at`.
fn add_fixed(at: u32, value: f32, scale: f32) {
    let q = value * scale;
    let hi = floor(q / 4294967296.0);
    let lo = u32(q - hi * 4294967296.0);
    let old = atomicAdd(&sums[at], lo);
    let carry = select(0u, 1u, old > 0xFFFFFFFFu - lo);
    let add = u32(hi) + carry;
    if add != 0u {
        let old_hi = atomicAdd(&sums[at + 1u], add);
        if old_hi > 0xFFFFFFFFu - add {
            atomicAdd(&flags[0], 1u);
            atomicStore(&sums[at + 1u], 0xFFFFFFFFu);
            atomicStore(&sums[at], 0xFFFFFFFFu);
        }
    }
}

fn hit(texel: u32, l: vec3<f32>) {
    let a = params.a_px;
    let at = 8u * texel;
    let la = l * a;
    add_fixed(at, la.x, params.radiance_scale);
    add_fixed(at + 2u, la.y, params.radiance_scale);
    add_fixed(at + 4u, la.z, params.radiance_scale);
    add_fixed(at + 6u, a, params.area_scale);
}

// What a side with code `side` (flags allowed) sends toward the bundle.
fn look(side: u32) -> vec3<f32> {
    let code = side & CODE_MASK;
    if code == NO_SIDE {
        return vec3<f32>(0.0);
    }
    if code < FOREIGN {
        return own[code].xyz;
    }
    atomicAdd(&flags[1], 1u);
    return vec3<f32>(0.0);
}

@compute @workgroup_size(8, 8)
fn resolve(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= params.width || id.y >= params.height {
        return;
    }
    var next = heads[id.y * params.width + id.x];
    if next == 0u {
        return;
    }
    let cx = f32(id.x + params.offset.x) + 0.5;
    let cy = f32(id.y + params.offset.y) + 0.5;
    var m = 0u;
    loop {
        if next == 0u {
            break;
        }
        if m == MAX_FRAGMENTS {
            atomicAdd(&flags[2], 1u);
            break;
        }
        let node = nodes[next - 1u];
        frag_tri[m] = node.y;
        m++;
        next = links[next - 1u];
    }
    atomicAdd(&flags[3], 1u);
    // Build order as the CPU's (ascending triangle), then its stable insertion sort.
    for (var i = 1u; i < m; i++) {
        var j = i;
        while j > 0u && frag_tri[j] < frag_tri[j - 1u] {
            let t = frag_tri[j]; frag_tri[j] = frag_tri[j - 1u]; frag_tri[j - 1u] = t;
            j--;
        }
    }
    for (var i = 0u; i < m; i++) {
        let k = frag_tri[i];
        let q0 = round_away(grid_of(corners[3u * k].xyz) * 256.0) / 256.0;
        let q1 = round_away(grid_of(corners[3u * k + 1u].xyz) * 256.0) / 256.0;
        let q2 = round_away(grid_of(corners[3u * k + 2u].xyz) * 256.0) / 256.0;
        let e1 = q1 - q0;
        let e2 = q2 - q0;
        let inv = 1.0 / (mul(e1.x, e2.y) - mul(e1.y, e2.x));
        let dir = params.dir;
        let d = vec3<f32>(dot3(corners[3u * k].xyz, dir), dot3(corners[3u * k + 1u].xyz, dir), dot3(corners[3u * k + 2u].xyz, dir));
        frag_depth[i] = eval(plane(q0, e1, e2, inv, d), cx, cy);
        let front_plus = dot3(normals[k].xyz, dir) > 0.0;
        let f = faces[k];
        // Plus side: the front when it looks along +ω.
        let plus_front = front_plus;
        let foreign = FOREIGN + 2u * min(k, 0x0FFFFFFFu);
        frag_plus[i] = side_code(f, plus_front, q0, e1, e2, inv, cx, cy, foreign);
        frag_minus[i] = side_code(f, !plus_front, q0, e1, e2, inv, cx, cy, foreign + 1u) | select(0u, FRONT_LOOKS_PLUS, front_plus);
    }
    for (var i = 1u; i < m; i++) {
        var j = i;
        while j > 0u && before(j, j - 1u) {
            swap_fragments(j, j - 1u);
            j--;
        }
    }
    for (var i = 0u; i < m; i++) {
        let p = frag_plus[i] & CODE_MASK;
        if p < FOREIGN {
            var l = params.sky;
            if i + 1u < m {
                l = look(frag_minus[i + 1u]);
            }
            hit(p, l);
        }
        let n = frag_minus[i] & CODE_MASK;
        if n < FOREIGN {
            var l = params.sky;
            if i > 0u {
                l = look(frag_plus[i - 1u]);
            }
            hit(n, l);
        }
    }
}

// The code of a triangle's front (`front`) or back side at grid centre (cx, cy).
fn side_code(f: TriangleFaces, front: bool, q0: vec2<f32>, e1: vec2<f32>, e2: vec2<f32>, inv: f32, cx: f32, cy: f32, foreign: u32) -> u32 {
    let bit = select(2u, 1u, front);
    if (f.faces & bit) == 0u {
        return NO_SIDE;
    }
    var uv = f.back;
    if front {
        uv = f.front;
    }
    // `Planes::gradient` of the barycentric planes, as `side_uv` on the CPU.
    let s = params.uv_scale;
    let bu = plane(q0, e1, e2, inv, vec3<f32>(0.0, 1.0, 0.0));
    let bv = plane(q0, e1, e2, inv, vec3<f32>(0.0, 0.0, 1.0));
    let u = gradient(bu, bv, vec3<f32>(uv[0].x, uv[1].x, uv[2].x) * s);
    let v = gradient(bu, bv, vec3<f32>(uv[0].y, uv[1].y, uv[2].y) * s);
    return texel_at(vec2<f32>(eval(u, cx, cy), eval(v, cx, cy)), foreign);
}

// `Planes::gradient`: the affine function of the values at the three corners.
fn gradient(bu: vec3<f32>, bv: vec3<f32>, v: vec3<f32>) -> vec3<f32> {
    let d1 = v.y - v.x;
    let d2 = v.z - v.x;
    return vec3<f32>(mul(v.x, 0.0) + mul(d1, bu.x) + mul(d2, bv.x), mul(v.x, 0.0) + mul(d1, bu.y) + mul(d2, bv.y),
                     v.x + mul(d1, bu.z) + mul(d2, bv.z));
}
