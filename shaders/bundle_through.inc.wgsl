// Light through surfaces along one bundle line, for scenes with BLEND, transmission or MASK
// materials (bundle_resolve.wgsl's `PASSING` pipelines): the GPU twin of `cpu::through`
// (each fragment's transmittance T where the line crosses it; cut-outs dropped from the
// list) and of `bundle::through::exchange_through` (every side sees the layers ahead of it
// front to back, weighed by the running product of their T, and the sky behind the last;
// a layer passes its most opaque member's T; the buried rule looks past see-through
// layers). docs/ARCHITECTURE.md "Light through surfaces" gives the semantics.
//
// The including resolve provides the fragments (`frags`), `seen`, `hit`, `layer_end`,
// `layer_face`, `blind`, the rectangle's `params` and the pixel's `centre`;
// surface_radiance.inc.wgsl the materials and textures. Every product goes through `mul`,
// so T and the walk's sums round as the CPU's f32 arithmetic does.

// Per fragment of the list once cut-outs are dropped: its transmittance.
var<private> pass_of: array<vec3<f32>, MAX_DEPTH>;
// Per layer: its fragments (layer_first..layer_last), its transmittance, and its faces
// once looked up (bit 0: seen from before it, looking +ω; bit 1: from after it).
var<private> layer_first: array<u32, MAX_DEPTH>;
var<private> layer_last: array<u32, MAX_DEPTH>;
var<private> layer_pass: array<vec3<f32>, MAX_DEPTH>;
var<private> face_minus: array<vec3<f32>, MAX_DEPTH>;
var<private> face_plus: array<vec3<f32>, MAX_DEPTH>;
var<private> face_known: array<u32, MAX_DEPTH>;

// `cpu::through::transmittance`: rgb the transmittance of material `m` (`Sheet::pass`,
// T = (1 − c) + c·t·a), w 0 where it is cut out (MASK below its cutoff), from its textures'
// values at the point.
fn material_transmittance(m: SurfaceMaterial, x: MaterialTexels) -> vec4<f32> {
    if m.alpha_mode == ALPHA_MASK && material_alpha(m, x.base) < m.alpha_cutoff {
        return vec4<f32>(1.0, 1.0, 1.0, 0.0);
    }
    let cover = material_cover(m, x.base, x.transmitted);
    let a = material_albedo(m, x.base);
    let ct = mul(cover.x, cover.y);
    return vec4<f32>(vec3<f32>(1.0 - cover.x) + vec3<f32>(mul(a.x, ct), mul(a.y, ct), mul(a.z, ct)), 1.0);
}

// `cpu::through::projected_barycentrics`: of the pixel centre in the plane of triangle
// `tri` projected along ω (not clamped: a texel's square reaches over its chart's
// neighbours, whose fragments read the texture where the face's parametrisation extends).
fn projected_barycentrics(tri: u32) -> vec2<f32> {
    let p = params.origin + vec2<f32>(mul(centre.x, params.pixel), mul(centre.y, params.pixel));
    var q: array<vec2<f32>, 3>;
    for (var k = 0u; k < 3u; k++) {
        q[k] = frame_coords(corners[3u * tri + k].xyz).xy;
    }
    let e1 = q[1] - q[0];
    let e2 = q[2] - q[0];
    let d = p - q[0];
    let det = mul(e1.x, e2.y) - mul(e1.y, e2.x);
    if det == 0.0 {
        return vec2<f32>(0.0);
    }
    return vec2<f32>(div(mul(d.x, e2.y) - mul(d.y, e2.x), det), div(mul(e1.x, d.y) - mul(e1.y, d.x), det));
}

// `Passing::pass`: the transmittance of fragment `f` at the pixel centre (w 0: cut out).
// Its surface is the triangle of its side's code (the plus side's, else the minus side's):
// a target texel's face's triangle, read at the centre projected onto it, or a foreign
// side's triangle, at the centre's clamped barycentrics; a fragment with no lit side is
// opaque.
fn fragment_transmittance(f: Fragment) -> vec4<f32> {
    var code = f.plus & CODE_MASK;
    if code == NO_SIDE {
        code = f.minus & CODE_MASK;
    }
    let opaque = vec4<f32>(0.0, 0.0, 0.0, 1.0);
    if code == NO_SIDE {
        return opaque;
    }
    let own_side = code < FOREIGN;
    var tri = 0u;
    if own_side {
        tri = texel_triangles[code];
    } else {
        tri = (code - FOREIGN) >> 1u;
    }
    let st = surface_triangles[tri];
    let m = surface_materials[st.material];
    if m.passing == 0u {
        return opaque;
    }
    var x = MaterialTexels(vec4<f32>(1.0), vec4<f32>(1.0));
    if material_textured(m) || st.colors != NO_COLOR {
        var bary: vec2<f32>;
        if own_side {
            bary = projected_barycentrics(tri);
        } else {
            bary = located_barycentrics(tri);
        }
        x = surface_texels(st, m, bary.x, bary.y);
    }
    return material_transmittance(m, x);
}

// `Passing::collect`: each fragment's transmittance into `pass_of`, cut-outs dropped from
// frags[0..n] (the order kept). Returns how many remain.
fn drop_cut_outs(n: u32) -> u32 {
    var kept = 0u;
    for (var i = 0u; i < n; i++) {
        let t = fragment_transmittance(frags[i]);
        if t.w == 0.0 {
            continue;
        }
        frags[kept] = frags[i];
        pass_of[kept] = t.rgb;
        kept += 1u;
    }
    return kept;
}

// `through::layers`: frags[0..n] in layers; returns how many.
fn build_layers(n: u32) -> u32 {
    var count = 0u;
    var start = 0u;
    while start < n {
        let end = layer_end(n, start);
        var t = vec3<f32>(1.0);
        for (var i = start; i < end; i++) {
            t = min(t, pass_of[i]);
        }
        layer_first[count] = start;
        layer_last[count] = end;
        layer_pass[count] = max(t, vec3<f32>(0.0));
        face_known[count] = 0u;
        count += 1u;
        start = end;
    }
    return count;
}

fn max_element(v: vec3<f32>) -> f32 {
    return max(v.x, max(v.y, v.z));
}

fn layer_opaque(k: u32) -> bool {
    return max_element(layer_pass[k]) <= 0.0;
}

// `through::buried`: the nearest opaque layers on both sides of layer `k` show it backs.
fn buried_through(k: u32, count: u32) -> bool {
    var behind_blind = false;
    for (var j = k; j > 0u; j--) {
        if layer_opaque(j - 1u) {
            behind_blind = blind(layer_first[j - 1u], layer_last[j - 1u], false);
            break;
        }
    }
    if !behind_blind {
        return false;
    }
    for (var j = k + 1u; j < count; j++) {
        if layer_opaque(j) {
            return blind(layer_first[j], layer_last[j], true);
        }
    }
    return false;
}

// Layer `j`'s face seen looking +ω (`ahead`: its sides looking −ω) or −ω, looked up once.
fn cached_face(j: u32, ahead: bool) -> vec3<f32> {
    let bit = select(2u, 1u, ahead);
    if (face_known[j] & bit) == 0u {
        let face = layer_face(layer_first[j], layer_last[j], ahead);
        if ahead {
            face_minus[j] = face;
        } else {
            face_plus[j] = face;
        }
        face_known[j] |= bit;
    }
    return select(face_plus[j], face_minus[j], ahead);
}

// `through::seen_along`: what a side of layer `k` looking +ω (`ahead`) or −ω sees.
fn seen_along(k: u32, count: u32, ahead: bool) -> vec3<f32> {
    var l = vec3<f32>(0.0);
    var t = vec3<f32>(1.0);
    var j = k;
    loop {
        if ahead {
            j += 1u;
            if j >= count {
                break;
            }
        } else {
            if j == 0u {
                break;
            }
            j -= 1u;
        }
        l = l + mul3(t, cached_face(j, ahead));
        t = mul3(t, layer_pass[j]);
        if max_element(t) <= 0.0 {
            return l;
        }
    }
    return l + mul3(t, select(params.sky_behind, params.sky_ahead, ahead));
}

// `through::exchange_through` over frags[0..n] with transmittances pass_of[0..n].
fn exchange_through(n: u32) {
    let count = build_layers(n);
    for (var k = 0u; k < count; k++) {
        if buried_through(k, count) {
            continue;
        }
        var l_ahead = vec3<f32>(0.0);
        var l_behind = vec3<f32>(0.0);
        var have_ahead = false;
        var have_behind = false;
        for (var i = layer_first[k]; i < layer_last[k]; i++) {
            let plus = frags[i].plus & CODE_MASK;
            if plus < FOREIGN {
                if !have_ahead {
                    l_ahead = seen_along(k, count, true);
                    have_ahead = true;
                }
                hit(plus, l_ahead);
            }
            let minus = frags[i].minus & CODE_MASK;
            if minus < FOREIGN {
                if !have_behind {
                    l_behind = seen_along(k, count, false);
                    have_behind = true;
                }
                hit(minus, l_behind);
            }
        }
    }
}
