//! TEXCOORD_1 as light-map UVs: validation and the block chart it becomes.
//!
//! A mesh's TEXCOORD_1 is kept only if, at the resolution the atlas would give it —
//! `s = ⌈√(world area / UV area) / texel_size⌉` LOD-0 texels for the unit square — it is a
//! layout the atlas can use as is:
//! - every used coordinate is finite and inside [0, 1], every UV triangle has area;
//! - its UV islands (triangles connected by shared UV edges that are also shared in 3-D)
//!   do not overlap and stay apart by the same gutter the packer leaves between charts:
//!   each island's conservative coverage plus a one-texel ring must not meet another's;
//! - no two triangles contain the same texel centre (folds, overlaps inside an island).
//!
//! The kept layout becomes one block per side, cropped to the pixels it uses and placed
//! by the packer at an integer offset, so the validated pixel grid is the atlas's LOD-0 grid.

use glam::DVec2;

use super::charts::{LocalChart, weld};
use super::raster::{PixelRect, area2, centres_inside, conservative};
use crate::scene::{Mesh, SceneGeometry, TriangleId};

const NONE: u32 = u32::MAX;

/// A validated TEXCOORD_1 layout, ready to become a block chart.
#[derive(Clone, Debug)]
pub struct Uv1Block {
    /// LOD-0 texels per unit of TEXCOORD_1.
    pub scale: u32,
    /// First pixel (at `scale`) of the crop the layout uses, and its size.
    pub crop_min: (u32, u32),
    pub crop_size: (u32, u32),
    /// Number of UV islands found.
    pub islands: usize,
}

impl Uv1Block {
    /// The block as a chart: local UVs `uv1 · scale − crop_min`, in LOD-0 texels.
    pub fn chart(&self, mesh: &Mesh, geom: &SceneGeometry, tris: &[TriangleId]) -> LocalChart {
        let uv1 = mesh.uv1.as_deref().unwrap_or(&[]);
        let s = self.scale as f64;
        let o = DVec2::new(self.crop_min.0 as f64, self.crop_min.1 as f64);
        let uv = tris
            .iter()
            .map(|&t| mesh.triangles[geom.local[t as usize] as usize].map(|v| uv1[v as usize].as_dvec2() * s - o))
            .collect();
        LocalChart {
            tris: tris.to_vec(),
            uv,
            extent: DVec2::new(self.crop_size.0 as f64, self.crop_size.1 as f64),
            fixed_interior: Some(self.crop_size),
        }
    }
}

/// Checks `mesh`'s TEXCOORD_1 over its lit triangles `tris` (global ids) for an atlas of
/// `texel_size` metres per LOD-0 texel. `Err` carries the reason, for the warning and the
/// report.
pub fn validate(mesh: &Mesh, geom: &SceneGeometry, tris: &[TriangleId], texel_size: f64, max_size: u32) -> Result<Uv1Block, String> {
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
        if !(a2 > 1e-7 * e2) {
            return Err(format!("TEXCOORD_1 triangle {k} is degenerate (zero UV area)"));
        }
        world_area += geom.areas[t as usize] as f64;
        uv_area += 0.5 * a2;
    }
    let s = ((world_area / uv_area).sqrt() / texel_size).ceil().max(1.0);
    if s > max_size as f64 {
        return Err(format!("TEXCOORD_1 would need {s}×{s} texels for the unit square, above the limit of {max_size}"));
    }
    let s_u = s as u32;
    let scaled: Vec<[DVec2; 3]> = tris.iter().map(|&t| corners(t).map(|v| uv1[v as usize].as_dvec2() * s)).collect();

    // The crop: every pixel any triangle can touch.
    let (mut lo, mut hi) = (DVec2::INFINITY, DVec2::NEG_INFINITY);
    for t in &scaled {
        for p in t {
            lo = lo.min(*p);
            hi = hi.max(*p);
        }
    }
    let clamp = |v: f64| (v as i64).clamp(0, s_u as i64);
    let (mut x0, mut y0, mut x1, mut y1) = (clamp(lo.x.floor()), clamp(lo.y.floor()), clamp(hi.x.ceil()), clamp(hi.y.ceil()));
    if x1 <= x0 {
        (x0, x1) = if x0 > 0 { (x0 - 1, x0) } else { (0, 1) };
    }
    if y1 <= y0 {
        (y0, y1) = if y0 > 0 { (y0 - 1, y0) } else { (0, 1) };
    }
    let crop = PixelRect::new(x0, y0, x1, y1);
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
    let (wid, _) = weld(&mesh.positions);
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

    // Conservative coverage per island; islands must not share a pixel, and their
    // coverage + one-texel rings must not meet (Chebyshev distance ≥ 3 between coverages).
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
    for y in crop.y0..crop.y1 {
        for x in crop.x0..crop.x1 {
            let i = owner[idx(x, y)];
            if i == NONE {
                continue;
            }
            for yy in (y - 2).max(crop.y0)..(y + 3).min(crop.y1) {
                for xx in (x - 2).max(crop.x0)..(x + 3).min(crop.x1) {
                    let j = owner[idx(xx, yy)];
                    if j != NONE && j != i {
                        return Err(format!(
                            "TEXCOORD_1 islands {} and {} are closer than the 2-texel gutter at {s_u}×{s_u} (texels ({x}, {y}) and ({xx}, {yy}))",
                            i.min(j),
                            i.max(j)
                        ));
                    }
                }
            }
        }
    }
    Ok(Uv1Block {
        scale: s_u,
        crop_min: (x0 as u32, y0 as u32),
        crop_size: (cw as u32, ch as u32),
        islands: islands as usize,
    })
}
