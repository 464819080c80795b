// The groups of a built rectangle that the resolve visits: runs of 8 pixels of a row
// (starting at a multiple of 8) with at least one fragment, listed in no particular order,
// and the resolve's indirect dispatch grown to cover them.
//
// llvmpipe runs a compute shader 8 invocations at a time and runs every instruction of it
// for each such group, masked, even when no invocation of the group has anything to do: a
// resolve invocation per pixel paid its whole code for the groups of pixels without a
// fragment (39% of the pixels of the Cornell box's rectangles). The resolve runs 8
// invocations per listed group instead, one SIMD group each.

// The rectangle's width and height (pixels).
@group(0) @binding(0) var<storage, read> size: vec2<u32>;
// Per pixel (row-major): 1 + its first node, 0 for none (bundle_lists.wgsl).
@group(0) @binding(1) var<storage, read> heads: array<u32>;
// 1 + the index of each listed group (row × groups per row + column); zeroed by the host
// beyond what is listed.
@group(0) @binding(2) var<storage, read_write> groups: array<u32>;
// The resolve's dispatch: (workgroups of 64 invocations = 8 groups, 1, 1) and the number
// of groups listed; the host sets (0, 1, 1, 0) first.
@group(0) @binding(3) var<storage, read_write> dispatch: array<atomic<u32>, 4>;

@compute @workgroup_size(64)
fn list_groups(@builtin(global_invocation_id) id: vec3<u32>) {
    let width = size.x;
    let per_row = (width + 7u) / 8u;
    let group = id.x;
    if group >= per_row * size.y {
        return;
    }
    let row = group / per_row;
    let x0 = (group % per_row) * 8u;
    var any = 0u;
    for (var k = 0u; k < 8u; k++) {
        let x = x0 + k;
        if x < width {
            any |= heads[row * width + x];
        }
    }
    if any != 0u {
        let slot = atomicAdd(&dispatch[3], 1u);
        groups[slot] = group + 1u;
        atomicMax(&dispatch[0], slot / 8u + 1u);
    }
}
