//! Direction shards' light maps compared (tests/shards.rs, tests/slurm.rs): the bounds of
//! docs/SHARDS.md, for bakes of 64 directions in 32 batches.

use std::path::Path;

/// The scene the shard tests bake: the Cornell box.
pub const CORNELL: &str = "assets/cornell_box/cornellBox-2.79-Cycles-gltf.gltf";

pub fn scene() -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(CORNELL)
}

/// A small bake: 64 directions in 32 batches of 2 (`BundleConfig::batch_size`, the bounds'
/// B), the box's lamp through the light pass, a sky and a sun (a punctual light: share 0 of
/// direction shards holds it, each region shard its own texels' part).
pub const OPTIONS: [&str; 8] = ["--texel-budget", "20000", "--samples", "64", "--sky", "0.2,0.3,0.4", "--sun", "35,20"];

/// `livebake -q bake` of the shard tests' scene with [`OPTIONS`] and `extra`, in `dir`.
pub fn bake(dir: &Path, extra: &[&str]) -> String {
    let scene = scene();
    let mut args = vec!["-q", "bake", scene.to_str().expect("UTF-8 path")];
    args.extend(OPTIONS);
    args.extend(extra);
    super::ok(dir, &args)
}

/// Batches of the bakes compared: 64 directions in batches of 2.
pub const BATCHES: f64 = 32.0;

pub fn exr(path: &Path) -> Vec<[f32; 3]> {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).into_rgb32f();
    img.pixels().map(|p| p.0).collect()
}

/// f32's unit roundoff.
pub const U: f64 = f32::EPSILON as f64 / 2.0;

/// The bound of round 1, relative, per texel. Each texel's global-bundle sums (S rgb, A)
/// and light-pass sum are f32 sums of one non-negative term per batch, the terms the same
/// bits in both bakes (a shard traces whole batches of the same directions from the same
/// source). One machine adds the B terms in batch order; the shards add theirs, then the
/// merge adds the N partial sums: either way every term passes through at most B−1
/// additions, so each total is within (B−1)u of the exact sum, and the two within 2(B−1)u
/// of each other. E = π·S/A doubles that (4(B−1)u), its division and product add 2u on
/// each side, and adding the light-pass and punctual parts (non-negative, the punctual
/// part the same bits) two more: 4(B−1)u + 8u ≤ 4(B+2)u.
pub fn round_one_bound() -> f64 {
    4.0 * (BATCHES + 2.0) * U
}

/// Round 2 reads round 1 as its source, which differs by at most `round_one_bound` (+2u
/// for `albedo/π·E + Le`); the transport is linear and positive, so exact sums differ by
/// no more than that relative. A batch's sum of a texel's hits then rounds differently in
/// the two bakes (its inputs differ): at most 2(m−1)u for m hits of the texel in one lane
/// of one batch. At oversampling 2 a texel takes ~4|cos θ| bundle pixels a direction and
/// a lane here holds one direction of a batch of 2; tiles planned finer than importance
/// asks can raise that, and MAX_OVERSAMPLING (16) caps it: m ≤ 16² = 256. Then the
/// batches' totals as in round 1.
pub fn round_two_bound() -> f64 {
    round_one_bound() + 2.0 * U + 2.0 * 255.0 * U + round_one_bound()
}

/// Largest relative difference per pixel of two light maps (both zero: none), and that
/// the maps are lit at all.
pub fn worst_relative(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    assert_eq!(a.len(), b.len());
    assert!(a.iter().filter(|p| p.iter().any(|&c| c > 0.0)).count() * 2 > a.len() / 4, "the maps are mostly dark");
    let mut worst = 0.0f64;
    for (p, q) in a.iter().zip(b) {
        for c in 0..3 {
            let (x, y) = (p[c] as f64, q[c] as f64);
            let scale = x.abs().max(y.abs());
            if scale > 0.0 {
                worst = worst.max((x - y).abs() / scale);
            }
        }
    }
    worst
}

/// The bound of region shards merged against one machine's bake, relative, per texel
/// (docs/SHARDS.md). A region shard lays its bundles out as the whole LOD's (the whole
/// LOD's importance and lane count, a whole-LOD-shaped table), so each texel's hits come
/// in the same order (a foreign side reads the texel at the pixel the whole bake's table
/// lookup computes, from the same float operations), its batch sums are added in the same
/// batch order, and the merge puts them in place without arithmetic.
///
/// Round 1: none. Every hit reads the single bake's value (its own texels' source, the
/// sending texels' carried emission, f32 both), so every sum is the same bits.
///
/// Round 2: a foreign side reads the source of another share's texel in half floats
/// (`bake::half_source`), rounded to nearest: relative 2⁻¹¹ at most while the value is
/// over 2⁻²⁸ of the LOD's brightest source (in the box, with these options, the dimmest
/// lit texel's round-1 irradiance is 2⁻¹⁷ of the brightest's). Each hit's term `w·L` is then within 2⁻¹¹ + 2u of the single bake's (its own
/// texels' hits, the light pass and the weights the same bits), a batch's sum of m ≤ 256
/// hits of a texel in a lane rounds differently by at most 2(m−1)u, and the batches'
/// totals, E = π·S/A and the same light-pass and punctual parts added as in
/// `round_one_bound`. (Textured translucent surfaces are the exception the docs state; the
/// box has none.)
pub fn region_bound(round: u32) -> f64 {
    if round <= 1 { 0.0 } else { (-11f64).exp2() + 2.0 * U + 2.0 * 255.0 * U + round_one_bound() }
}
