// Tile subdivision of one bundle direction: Program 1 of Tokuyoshi et al. 2013 (Appendix
// A) in one compute pass, the twin of `TilePlanner::plan_adaptive_per_pixel`. One thread per
// finest analysis pixel descends from the top level carrying the running minimum of Eq. 3's
// αN/F; only the thread at a tile's corner appends the tile (atomic counter) or counts a
// split. Tiles come out in no particular order (the host sorts them by Morton key when an
// order matters).
//
// `real` is f64 when the device has SHADER_F64 (the Rust side rewrites the alias line): the
// decisions are then made in the CPU planner's own f64 arithmetic and agree bit for bit.
// With f32 they can differ only where C_I and C_max are within f32 rounding of each other.

alias real = f32;

struct TilePassParams {
    // Side R of level 0 and L = log2 R.
    side: u32,
    top_level: u32,
    // Capacity of `tiles` in entries; beyond it tiles are counted but not written.
    capacity: u32,
    _pad: u32,
}

struct PlannedTile {
    level: u32,
    x: u32,
    y: u32,
    res: u32,
}

@group(0) @binding(0) var<uniform> params: TilePassParams;
// [pixel area A(0), node budget αN, head-buffer pixels W²], in `real`.
@group(0) @binding(1) var<storage, read> reals: array<real>;
// Mip chains (every level, level 0 first) as f32 bits: max-mipped importance, average-mipped
// fragment counts.
@group(0) @binding(2) var<storage, read> importance: array<u32>;
@group(0) @binding(3) var<storage, read> fragments: array<u32>;
@group(0) @binding(4) var<storage, read_write> tiles: array<PlannedTile>;
// [tiles, splits for importance, splits for memory, undersampled tiles].
@group(0) @binding(5) var<storage, read_write> counters: array<atomic<u32>, 4>;

// Element offset of `level` in a mip buffer.
fn level_offset(level: u32) -> u32 {
    var offset = 0u;
    for (var i = 0u; i < level; i++) {
        let s = params.side >> i;
        offset += s * s;
    }
    return offset;
}

// ⌈√min(C_I, C_max)⌉, capped at ⌊√C_max⌋, at least 1 (`tiles::bundle_resolution`).
fn bundle_resolution(rays: real, bound: real) -> u32 {
    let wanted = ceil(sqrt(min(rays, bound)));
    let allowed = floor(sqrt(bound));
    return u32(max(min(wanted, allowed), real(1.0)));
}

@compute @workgroup_size(8, 8)
fn plan(@builtin(global_invocation_id) id: vec3<u32>) {
    let px = id.x;
    let py = id.y;
    if px >= params.side || py >= params.side {
        return;
    }
    let pixel_area = reals[0];
    let node_budget = reals[1];
    let head = reals[2];
    // Running minimum of αN/F over the levels seen; none while every F was 0 (+∞ on the CPU).
    var memory = head;
    var has_memory = false;
    for (var level = i32(params.top_level); level >= 0; level--) {
        let l = u32(level);
        let x = px >> l;
        let y = py >> l;
        let at_corner = (x << l) == px && (y << l) == py;
        let i = level_offset(l) + y * (params.side >> l) + x;
        let f = bitcast<f32>(fragments[i]);
        if f > 0.0 {
            let m = node_budget / real(f);
            memory = select(m, min(memory, m), has_memory);
            has_memory = true;
        }
        // Eq. 1: C_I = A(i)·I(i, x), A(i) = A(0)·4^i (exact: a power of two).
        let rays = pixel_area * real(1u << (2u * l)) * real(bitcast<f32>(importance[i]));
        if !(rays > real(0.0)) {
            return;
        }
        let bound = select(head, min(head, memory), has_memory);
        if rays > bound && l > 0u {
            if at_corner {
                let memory_binds = has_memory && memory < head;
                atomicAdd(&counters[select(1u, 2u, memory_binds)], 1u);
            }
            continue;
        }
        if at_corner {
            let slot = atomicAdd(&counters[0], 1u);
            if slot < params.capacity {
                tiles[slot] = PlannedTile(l, x, y, bundle_resolution(rays, bound));
            }
            if rays > bound {
                atomicAdd(&counters[3], 1u);
            }
        }
        return;
    }
}
