//! TEXCOORD_1 as light-map UVs: validation and the charts it becomes.
//!
//! A mesh's TEXCOORD_1 is kept only if, at the resolution the atlas would give it —
//! `s = ⌈√(world area / UV area) / texel_size⌉` LOD-0 texels for the unit square — it is a
//! valid light-map layout:
//! - every used coordinate is finite and inside [0, 1], every UV triangle has area;
//! - its UV islands (triangles connected by shared UV edges that are also shared in 3-D)
//!   do not overlap at that resolution (no pixel touched by two islands);
//! - no two triangles contain the same texel centre (folds, overlaps inside an island).
//!
//! Each island of a kept layout becomes one chart, cropped to the pixels it touches and
//! placed by the packer at an integer offset: its shape, scale and pixel grid are the
//! layout's, its place in the atlas is the packer's. Islands therefore get the packer's
//! gutters whatever spacing the layout had (exporters size gutters for their own
//! resolution), and the empty space between them in the [0, 1] square is not kept.

use glam::DVec2;

use super::charts::{LocalChart, weld, weld_tolerance};
use super::raster::{PixelRect, area2, centres_inside, conservative};
use crate::scene::{Mesh, SceneGeometry, TriangleId};

const NONE: u32 = u32::MAX;

/// A validated TEXCOORD_1 layout, ready to become one chart per island.
#[derive(Clone, Debug)]
pub struct Uv1Block {
    /// LOD-0 texels per unit of TEXCOORD_1.
    pub scale: u32,
    /// Per triangle (in the order validated): its island.
    pub island_of: Vec<u32>,
    /// Per island: the pixels (at `scale`) it touches.
    pub crops: Vec<PixelRect>,
}

impl Uv1Block {
    pub fn islands(&self) -> usize {
        self.crops.len()
    }

    /// One chart per island: local UVs `uv1 · scale − crop corner`, in LOD-0 texels.
    pub fn charts(&self, mesh: &Mesh, geom: &SceneGeometry, tris: &[TriangleId]) -> Vec<LocalChart> {
        let uv1 = mesh.uv1.as_deref().unwrap_or(&[]);
        let s = self.scale as f64;
        self.crops
            .iter()
            .enumerate()
            .map(|(i, crop)| {
                let o = DVec2::new(crop.x0 as f64, crop.y0 as f64);
                let mine: Vec<TriangleId> =
                    tris.iter().zip(&self.island_of).filter(|&(_, &k)| k == i as u32).map(|(&t, _)| t).collect();
                let uv = mine
                    .iter()
                    .map(|&t| {
                        mesh.triangles[geom.local[t as usize] as usize].map(|v| uv1[v as usize].as_dvec2() * s - o)
                    })
                    .collect();
                let size = (crop.width() as u32, crop.height() as u32);
                LocalChart {
                    tris: mine,
                    uv,
                    extent: DVec2::new(size.0 as f64, size.1 as f64),
                    fixed_interior: Some(size),
                }
            })
            .collect()
    }
}

/// The pixels (at scale `s`) that triangles with corners `scaled` can touch: their bounding
/// box rounded out, at least one pixel wide, clamped to the unit square's `s × s`.
fn crop_of<'a>(scaled: impl Iterator<Item = &'a [DVec2; 3]>, s: u32) -> PixelRect {
    let (mut lo, mut hi) = (DVec2::INFINITY, DVec2::NEG_INFINITY);
    for t in scaled {
        for p in t {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let clamp = |v: f64| (v as i64).clamp(0, s as i64);
    let (mut x0, mut y0, mut x1, mut y1) =
        (clamp(lo.x.floor()), clamp(lo.y.floor()), clamp(hi.x.ceil()), clamp(hi.y.ceil()));
    if x1 <= x0 {
        (x0, x1) = if x0 > 0 { (x0 - 1, x0) } else { (0, 1) };
    }
    if y1 <= y0 {
        (y0, y1) = if y0 > 0 { (y0 - 1, y0) } else { (0, 1) };
    }
    PixelRect::new(x0, y0, x1, y1)
}

/// Checks `mesh`'s TEXCOORD_1 over its lit triangles `tris` (global ids) for an atlas of
/// `texel_size` metres per LOD-0 texel. `Err` carries the reason, for the warning and the
/// report.
pub fn validate(
    mesh: &Mesh,
    geom: &SceneGeometry,
    tris: &[TriangleId],
    texel_size: f64,
    max_size: u32,
) -> Result<Uv1Block, String> {
    let Some(uv1) = mesh.uv1.as_deref() else {
        return Err("no TEXCOORD_1".into());
    };
    if uv1.len() != mesh.positions.len() {
        return Err(format!("TEXCOORD_1 has {} values for {} vertices", uv1.len(), mesh.positions.len()));
    }
    let corners = |t: TriangleId| mesh.triangles[geom.local[t as usize] as usize];
    let mut world_area = 0.0f64;
    let mut uv_area = 0.0f64;
    for (k, &t) in tris.iter().enumerate() {
        let c = corners(t);
        for v in c {
            let p = uv1[v as usize];
            if !p.is_finite() {
                return Err(format!("TEXCOORD_1 of vertex {v} is not finite ({p})"));
            }
            if !(0.0..=1.0).contains(&p.x) || !(0.0..=1.0).contains(&p.y) {
                return Err(format!("TEXCOORD_1 of vertex {v} is outside [0,1]: ({}, {})", p.x, p.y));
            }
        }
        let q = c.map(|v| uv1[v as usize].as_dvec2());
        let a2 = area2(&q).abs();
        let e2 = (q[1] - q[0]).length_squared().max((q[2] - q[1]).length_squared()).max((q[0] - q[2]).length_squared());
        if a2 <= 1e-7 * e2 || a2.is_nan() {
            return Err(format!("TEXCOORD_1 triangle {k} is degenerate (zero UV area)"));
        }
        world_area += geom.areas[t as usize] as f64;
        uv_area += 0.5 * a2;
    }
    let s = ((world_area / uv_area).sqrt() / texel_size).ceil().max(1.0);
    if s.is_nan() || s >= (1u64 << 30) as f64 {
        return Err(format!("TEXCOORD_1 would need {s}×{s} texels for the unit square"));
    }
    let s_u = s as u32;
    let scaled: Vec<[DVec2; 3]> = tris.iter().map(|&t| corners(t).map(|v| uv1[v as usize].as_dvec2() * s)).collect();

    // The crop: every pixel any triangle can touch.
    let crop = crop_of(scaled.iter(), s_u);
    if crop.width() > max_size as i64 || crop.height() > max_size as i64 {
        return Err(format!(
            "TEXCOORD_1 layout would be {}×{} texels ({s_u}×{s_u} for the unit square), above the limit of {max_size}",
            crop.width(),
            crop.height()
        ));
    }
    let (cw, ch) = (crop.width() as usize, crop.height() as usize);
    let idx = |x: i64, y: i64| (y - crop.y0) as usize * cw + (x - crop.x0) as usize;

    // Folds and overlaps: every texel centre in at most one triangle.
    let mut owner = vec![NONE; cw * ch];
    let mut fold: Option<(usize, u32, (i64, i64))> = None;
    for (k, t) in scaled.iter().enumerate() {
        centres_inside(t, crop, |x, y| {
            let o = &mut owner[idx(x, y)];
            if *o != NONE && fold.is_none() {
                fold = Some((k, *o, (x, y)));
            }
            *o = k as u32;
        });
        if let Some((a, b, (x, y))) = fold {
            return Err(format!("TEXCOORD_1 triangles {b} and {a} overlap (texel ({x}, {y}) at {s_u}×{s_u})"));
        }
    }

    // Islands: union of triangles sharing a UV edge that is also a 3-D edge.
    let (wid, _) = weld(&mesh.positions, weld_tolerance(&mesh.positions, texel_size));
    let mut keys: Vec<(u32, u32, u32, u32)> = Vec::with_capacity(tris.len() * 3);
    for (k, &t) in tris.iter().enumerate() {
        for v in corners(t) {
            let p = uv1[v as usize] + glam::Vec2::ZERO; // −0 → +0
            keys.push((wid[v as usize], p.x.to_bits(), p.y.to_bits(), k as u32));
        }
    }
    let mut sorted: Vec<u32> = (0..keys.len() as u32).collect();
    sorted.sort_unstable_by_key(|&i| keys[i as usize]);
    let mut vid = vec![0u32; keys.len()];
    let mut next = 0u32;
    for (n, &i) in sorted.iter().enumerate() {
        if n > 0 {
            let (a, b) = (keys[i as usize], keys[sorted[n - 1] as usize]);
            if (a.0, a.1, a.2) != (b.0, b.1, b.2) {
                next += 1;
            }
        }
        vid[i as usize] = next;
    }
    let tri_v: Vec<[u32; 3]> = (0..tris.len()).map(|k| [vid[3 * k], vid[3 * k + 1], vid[3 * k + 2]]).collect();
    let (start, adj) = super::charts::edge_adjacency(&tri_v);
    let mut island = vec![NONE; tris.len()];
    let mut islands = 0u32;
    let mut stack = Vec::new();
    for k in 0..tris.len() {
        if island[k] != NONE {
            continue;
        }
        island[k] = islands;
        stack.push(k as u32);
        while let Some(f) = stack.pop() {
            for &g in &adj[start[f as usize] as usize..start[f as usize + 1] as usize] {
                if island[g as usize] == NONE {
                    island[g as usize] = islands;
                    stack.push(g);
                }
            }
        }
        islands += 1;
    }

    // Conservative coverage per island: islands must not share a pixel (the packer gives each
    // its own gutter, so how close they are does not matter).
    owner.fill(NONE);
    for (k, t) in scaled.iter().enumerate() {
        let i = island[k];
        let mut clash = None;
        conservative(t, crop, (i64::MIN, i64::MAX), |x, y| {
            let o = &mut owner[idx(x, y)];
            if *o != NONE && *o != i {
                clash = Some((*o, x, y));
            }
            *o = i;
        });
        if let Some((j, x, y)) = clash {
            return Err(format!("TEXCOORD_1 islands {j} and {i} overlap (texel ({x}, {y}) at {s_u}×{s_u})"));
        }
    }
    let crops = (0..islands)
        .map(|i| crop_of(scaled.iter().zip(&island).filter(|&(_, &k)| k == i).map(|(t, _)| t), s_u))
        .collect();
    Ok(Uv1Block { scale: s_u, island_of: island, crops })
}

#[cfg(test)]
mod tests {
    use glam::{Vec2, Vec3};

    use crate::atlas::tests::config;
    use crate::atlas::{Atlas, AtlasConfig, ChartSource, Side, TexelMap};
    use crate::scene::builder::{diffuse, white};
    use crate::scene::{Scene, SceneBuilder, SceneGeometry};

    /// Two islands in one mesh: a 2 m × 1 m quad and a 1 m × 1 m quad, TEXCOORD_1 given by
    /// `a` (x0, y0, per-metre scale) and `b`.
    fn two_islands(a: (f32, f32, f32), b: (f32, f32, f32), double_sided: bool) -> Scene {
        let mut sb = SceneBuilder::new();
        let m = sb.material(if double_sided { diffuse(Vec3::ONE, Vec3::ZERO, true) } else { white() });
        let p = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
            Vec3::new(5.0, 0.0, 0.0),
            Vec3::new(6.0, 0.0, 0.0),
            Vec3::new(6.0, 1.0, 0.0),
            Vec3::new(5.0, 1.0, 0.0),
        ];
        sb.mesh("islands", p.clone(), vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], m);
        let mut s = sb.build();
        let uv = |(x0, y0, k): (f32, f32, f32), q: Vec3, ox: f32| Vec2::new(x0 + (q.x - ox) * k, y0 + (1.0 - q.y) * k);
        s.meshes[0].uv1 =
            Some(p.iter().enumerate().map(|(i, &q)| if i < 4 { uv(a, q, 0.0) } else { uv(b, q, 5.0) }).collect());
        s
    }

    fn build(s: &Scene, cfg: &AtlasConfig) -> Atlas {
        Atlas::build(s, &SceneGeometry::new(s), cfg).unwrap()
    }

    /// Every chart is its island's TEXCOORD_1 under one map `p ↦ origin + s·R·p`, with `s`
    /// the block's texels per unit and `R` a quarter turn or none (the packer may turn a
    /// block): the layout's shape and pixel grid are kept.
    fn assert_affine_image_of_uv1(s: &Scene, a: &Atlas) {
        let g = SceneGeometry::new(s);
        let uv1 = s.meshes[0].uv1.as_ref().unwrap();
        for c in &a.charts {
            assert_eq!(c.source, ChartSource::Uv1);
            let f0 = &a.faces[c.faces[0] as usize];
            let tri0 = s.meshes[0].triangles[g.local[f0.tri as usize] as usize];
            // Scale and turn from the first edge, origin from the first corner.
            let (p0, p1) = (uv1[tri0[0] as usize], uv1[tri0[1] as usize]);
            let (d_uv1, d_atlas) = (p1 - p0, f0.uv[1] - f0.uv[0]);
            let scale = d_atlas.length() / d_uv1.length();
            let turn = [Vec2::X, Vec2::Y, -Vec2::X, -Vec2::Y]
                .into_iter()
                .find(|r| (r.rotate(d_uv1) * scale - d_atlas).length() < 1e-3)
                .unwrap_or_else(|| panic!("chart is not a quarter turn of its TEXCOORD_1: {d_uv1} ↦ {d_atlas}"));
            let origin = f0.uv[0] - turn.rotate(p0) * scale;
            for &f in &c.faces {
                let face = &a.faces[f as usize];
                let tri = s.meshes[0].triangles[g.local[face.tri as usize] as usize];
                for k in 0..3 {
                    let want = origin + turn.rotate(uv1[tri[k] as usize]) * scale;
                    assert!((face.uv[k] - want).length() < 1e-3, "{:?} vs {want:?}", face.uv[k]);
                }
            }
            // The pixel grid is kept: the image of a whole texel of the block is a whole
            // texel of the atlas.
            assert!((origin.x - origin.x.round()).abs() < 1e-3 && (origin.y - origin.y.round()).abs() < 1e-3);
        }
    }

    #[test]
    fn valid_layout_is_kept() {
        for double_sided in [false, true] {
            let s = two_islands((0.05, 0.05, 0.3), (0.7, 0.05, 0.3), double_sided);
            let a = build(&s, &config(0.05));
            assert_eq!((a.stats.meshes_from_uv1, a.stats.meshes_unwrapped), (1, 0));
            assert!(a.stats.uv1_rejected.is_empty());
            // One chart per island (and per side).
            assert_eq!(a.charts.len(), if double_sided { 4 } else { 2 });
            if double_sided {
                assert_eq!(a.charts.iter().filter(|c| c.side == Side::Back).count(), 2);
            }
            assert_affine_image_of_uv1(&s, &a);
            // s = ⌈√(3 m² / 0.27) / 0.05⌉ = 67 texels for the unit square: island a spans
            // 0.05..0.65 × 0.05..0.35 (pixels 3..44 × 3..24), island b 0.7..1.0 × 0.05..0.35
            // (pixels 46..67 × 3..24); each is cropped and gets a 1-texel border.
            let mut sizes: Vec<(u32, u32)> = a
                .charts
                .iter()
                .map(|c| (c.rect_size.0.max(c.rect_size.1) - 2, c.rect_size.0.min(c.rect_size.1) - 2))
                .collect();
            sizes.sort_unstable();
            sizes.dedup();
            assert_eq!(sizes, vec![(21, 21), (41, 21)]);
            crate::atlas::tests::check_pub(&s, &a, 2, true);
        }
        // Islands closer than the packer's gutter are fine: each gets its own.
        let s = two_islands((0.05, 0.05, 0.3), (0.66, 0.05, 0.3), false);
        let a = build(&s, &config(0.05));
        assert_eq!(a.stats.meshes_from_uv1, 1, "{:?}", a.stats.uv1_rejected);
        assert_affine_image_of_uv1(&s, &a);
        crate::atlas::tests::check_pub(&s, &a, 2, true);
    }

    #[test]
    fn invalid_layouts_are_unwrapped_with_a_reason() {
        let cases = [
            ("overlap", two_islands((0.05, 0.05, 0.3), (0.5, 0.05, 0.3), false)),
            ("outside [0,1]", two_islands((0.05, 0.05, 0.3), (0.8, 0.05, 0.3), false)),
        ];
        for (why, s) in cases {
            let a = build(&s, &config(0.05));
            assert_eq!((a.stats.meshes_from_uv1, a.stats.meshes_unwrapped), (0, 1), "{why}");
            assert_eq!(a.stats.uv1_rejected.len(), 1);
            let (name, reason) = &a.stats.uv1_rejected[0];
            assert_eq!(name, "islands");
            assert!(reason.contains(why), "expected '{why}' in '{reason}'");
            assert!(a.charts.iter().all(|c| c.source == ChartSource::Unwrapped));
            crate::atlas::tests::check_pub(&s, &a, 1, true);
        }
    }

    #[test]
    fn folds_and_degenerate_uvs_are_refused() {
        let mut sb = SceneBuilder::new();
        let m = sb.material(white());
        sb.grid_quad("fold", [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y], 2, m);
        sb.quad("flat", [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 1.0, 0.0), Vec3::Y].map(|p| p + Vec3::Z), m);
        let mut s = sb.build();
        // 3×3 vertices over [0.1, 0.9]²; the middle one pulled past the right column.
        let mut uv: Vec<Vec2> =
            (0..9).map(|i| Vec2::new(0.1 + 0.4 * (i % 3) as f32, 0.9 - 0.4 * (i / 3) as f32)).collect();
        uv[4] = Vec2::new(0.97, 0.5);
        s.meshes[0].uv1 = Some(uv);
        s.meshes[1].uv1 = Some(vec![Vec2::splat(0.5); 4]);
        let a = build(&s, &config(0.02));
        assert_eq!(a.stats.uv1_rejected.len(), 2);
        assert!(a.stats.uv1_rejected[0].1.contains("overlap"), "{:?}", a.stats.uv1_rejected[0]);
        assert!(a.stats.uv1_rejected[1].1.contains("degenerate"), "{:?}", a.stats.uv1_rejected[1]);
        // Not asked for: TEXCOORD_1 ignored, nothing reported.
        let a = build(&s, &AtlasConfig { use_uv1: false, ..config(0.02) });
        assert!(a.stats.uv1_rejected.is_empty());
        assert_eq!(a.stats.meshes_unwrapped, 2);
        let g = SceneGeometry::new(&s);
        assert!(!TexelMap::build(&s, &g, &a, 0).is_empty());
    }
}
