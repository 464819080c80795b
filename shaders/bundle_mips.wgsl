// Mip chains of the analysis maps (bundle::mips): the importance map reduced by max, the
// fragment-count map by average, one dispatch per level. Both maps hold every level in one
// buffer (level 0 first, then each coarser level), as f32 bits.

struct MipLevel {
    // Element offsets of the finer (source) and coarser (destination) level, and the
    // destination's side.
    src: u32,
    dst: u32,
    dst_side: u32,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> level: MipLevel;
@group(0) @binding(1) var<storage, read_write> importance: array<u32>;
@group(0) @binding(2) var<storage, read_write> fragments: array<u32>;

// Level 0 of the fragment map as the analysis left it (u32 counts, at `dst`) to f32, in place.
@compute @workgroup_size(8, 8)
fn finest(@builtin(global_invocation_id) id: vec3<u32>) {
    if id.x >= level.dst_side || id.y >= level.dst_side {
        return;
    }
    let i = level.dst + id.y * level.dst_side + id.x;
    fragments[i] = bitcast<u32>(f32(fragments[i]));
}

// One reduction step of both maps: max of four importances (non-negative f32 bits compare
// as u32), ((a + b) + (c + d)) / 4 of four fragment counts (the CPU's order).
@compute @workgroup_size(8, 8)
fn reduce(@builtin(global_invocation_id) id: vec3<u32>) {
    let side = level.dst_side;
    if id.x >= side || id.y >= side {
        return;
    }
    let finer = 2u * side;
    let i0 = level.src + 2u * id.y * finer + 2u * id.x;
    let i1 = i0 + finer;
    let dst = level.dst + id.y * side + id.x;
    importance[dst] = max(max(importance[i0], importance[i0 + 1u]), max(importance[i1], importance[i1 + 1u]));
    let a = bitcast<f32>(fragments[i0]);
    let b = bitcast<f32>(fragments[i0 + 1u]);
    let c = bitcast<f32>(fragments[i1]);
    let d = bitcast<f32>(fragments[i1 + 1u]);
    fragments[dst] = bitcast<u32>(((a + b) + (c + d)) * 0.25);
}
