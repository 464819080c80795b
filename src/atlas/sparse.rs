//! Texel maps of a region: the texels of one LOD whose surface points lie in a box (a runtime
//! grid cell), built without the rest of the LOD. LOD k has 4^k × LOD 0's texels; the runtime
//! makes them per cell, where the viewer needs them, so memory grows with what was refined.
//!
//! The result is exactly the part of [`TexelMap::build`](super::TexelMap::build)'s texels (and gutter pixels) that the
//! region owns: same pixels, faces, positions, areas, bit for bit (a test holds them equal).
//! That follows from computing each pixel from every face that touches it:
//! * *core faces* are those whose triangle meets the region (only they can hold a texel
//!   positioned in it); the part of each inside the region, mapped to UV and grown by
//!   `REACH` pixels, bounds the pixels that matter in its chart;
//! * every face of those charts whose UV box meets that window is rasterised in it, so each
//!   pixel's owner (the face containing its centre, else the nearest, ties to the lower id),
//!   area and coverage are what the whole-LOD raster computes;
//! * a covered pixel is the region's texel when its surface point is inside the region; an
//!   empty pixel is the region's gutter pixel when the gutter rule copies one of its texels.
//!
//! Faces of other charts never touch a chart's texels or gutter pixels (charts' footprints
//! never overlap, [`super::pack`]: covered pixels of two charts are three pixels apart), so
//! charts are independent, though their rectangles may overlap.

use std::collections::BTreeMap;

use glam::{DVec2, DVec3, Vec3};

use super::lookup::TexelTable;
use super::raster::{self, PixelRect};
use super::texels::{TexelAttributes, gutter_source, world_per_pixel};
use super::{Atlas, FaceId};
use crate::scene::{Rgb, Scene, SceneGeometry};

/// Pixels around a texel whose coverage decides it (its own pixel, its gutter neighbours and
/// theirs), plus one for the distance between a surface point and its pixel centre.
const REACH: i64 = 4;

/// Window pixel states while building.
const EMPTY: u8 = 0;
const OTHERS: u8 = 1;
const OURS: u8 = 2;

/// The texels of one LOD inside a region, with their lookup tables.
#[derive(Clone, Debug, Default)]
pub struct SparseTexels {
    pub lod: u32,
    /// LOD pixel (x, y) of each texel, in block order (8×8 blocks row by row over the whole
    /// LOD, Z-order inside: the order of [`TexelMap`](super::TexelMap)'s texel ids).
    pub pixel: Vec<[u32; 2]>,
    pub face: Vec<FaceId>,
    pub position: Vec<Vec3>,
    pub normal: Vec<Vec3>,
    pub albedo: Vec<Rgb>,
    pub emission: Vec<Rgb>,
    pub area: Vec<f32>,
    /// Per texel: the index of its chart's table in [`tables`](Self::tables).
    pub table: Vec<u32>,
    /// Gutter pixels the region writes and the texel each copies.
    pub gutter: Vec<([u32; 2], u32)>,
    /// One lookup table per chart holding region texels, ascending by chart.
    pub tables: Vec<TexelTable>,
    /// A world box holding every surface point whose atlas pixel is one of the texels: the
    /// part of each face touching a texel's pixel (see [`face_in_pixel_box`]); gutter pixels
    /// touch no face. `None` without texels. Where a chart stretches a face (a face steep to
    /// the chart's plane), this reaches several texels beyond the texels' own points.
    pub footprint: Option<(Vec3, Vec3)>,
}

/// A world box holding the part of face `uv` (LOD pixels) of triangle `corners` that lies in
/// pixel (x, y): the box of the pixel square mapped through the face's affine UV-to-world map,
/// cut to the triangle's box (the part lies in both; the map alone reaches far past a face
/// whose UVs are nearly degenerate, and is not defined for one whose UVs are).
fn face_in_pixel_box(corners: &[Vec3; 3], uv: &[DVec2; 3], x: i64, y: i64) -> (Vec3, Vec3) {
    let p = corners.map(|c| c.as_dvec3());
    let (tri_lo, tri_hi) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
    let (e1, e2) = (uv[1] - uv[0], uv[2] - uv[0]);
    let det = e1.perp_dot(e2);
    let (mut lo, mut hi) = (tri_lo, tri_hi);
    if det != 0.0 {
        let (mut a, mut b) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let d = DVec2::new((x + dx) as f64, (y + dy) as f64) - uv[0];
            let (u, v) = (d.perp_dot(e2) / det, e1.perp_dot(d) / det);
            let q = p[0] + (p[1] - p[0]) * u + (p[2] - p[0]) * v;
            a = a.min(q);
            b = b.max(q);
        }
        if a.is_finite() && b.is_finite() {
            lo = lo.max(a);
            hi = hi.min(b);
        }
    }
    (lo.as_vec3(), hi.as_vec3())
}

/// A pixel's candidate from one face.
#[derive(Clone, Copy, Default)]
struct Touch {
    /// Row-major pixel index within the chart's window.
    pixel: u32,
    face: FaceId,
    area: f64,
}

impl SparseTexels {
    /// The texels of LOD `lod` whose surface points satisfy `inside`, where `core` lists the
    /// triangles that meet the region (a superset is fine: faces whose part in `[lo, hi]`
    /// is empty add nothing) and `[lo, hi]` is a box holding the region.
    #[allow(clippy::too_many_arguments)]
    pub fn build(
        scene: &Scene,
        geom: &SceneGeometry,
        atlas: &Atlas,
        lod: u32,
        core: &[u32],
        lo: Vec3,
        hi: Vec3,
        inside: impl Fn(Vec3) -> bool,
    ) -> SparseTexels {
        // Per chart: the window of pixels that matter.
        let mut windows: BTreeMap<u32, PixelRect> = BTreeMap::new();
        for &t in core {
            for f in atlas.face_of[t as usize] {
                if f == super::NO_FACE {
                    continue;
                }
                let face = &atlas.faces[f as usize];
                let Some(uv_box) = footprint(geom, face.tri, &face.uv_lod(lod), lo, hi) else { continue };
                let chart = &atlas.charts[face.chart as usize];
                let clip = chart.rect(lod);
                let grown = PixelRect::new(
                    (uv_box.0.x.floor() as i64 - REACH).max(clip.x0),
                    (uv_box.0.y.floor() as i64 - REACH).max(clip.y0),
                    (uv_box.1.x.ceil() as i64 + REACH).min(clip.x1),
                    (uv_box.1.y.ceil() as i64 + REACH).min(clip.y1),
                );
                if grown.is_empty() {
                    continue;
                }
                windows.entry(face.chart).and_modify(|w| *w = union(*w, grown)).or_insert(grown);
            }
        }

        let mut out = SparseTexels { lod, ..SparseTexels::default() };
        let (mut touches, mut sorted, mut starts): (Vec<Touch>, Vec<Touch>, Vec<u32>) = Default::default();
        // (block key, pixel, face, area, attributes)
        let mut texels: Vec<(u64, [u32; 2], FaceId, f32, TexelAttributes)> = Vec::new();
        let mut gutters: Vec<([u32; 2], [u32; 2], u32)> = Vec::new(); // (gutter pixel, copied pixel, chart)
        let mut texel_box: Option<(Vec3, Vec3)> = None;
        for (&chart_id, &window) in &windows {
            let chart = &atlas.charts[chart_id as usize];
            let interior = chart.interior(lod);
            touches.clear();
            for &f in &chart.faces {
                let uv = atlas.faces[f as usize].uv_lod(lod);
                let (a, b) = (uv[0].min(uv[1]).min(uv[2]), uv[0].max(uv[1]).max(uv[2]));
                // Faces whose box misses the window only matter through the centroid
                // fallback, which lands inside their box too.
                if b.x < window.x0 as f64 - 1.0
                    || b.y < window.y0 as f64 - 1.0
                    || a.x > window.x1 as f64 + 1.0
                    || a.y > window.y1 as f64 + 1.0
                {
                    continue;
                }
                let ratio = world_per_pixel(geom, atlas, f, &uv);
                raster::conservative_in(&uv, interior, window, |x, y| {
                    touches.push(Touch {
                        pixel: ((y - window.y0) * window.width() + (x - window.x0)) as u32,
                        face: f,
                        area: raster::clipped_area(&uv, x, y) * ratio,
                    });
                });
            }
            // Faces of a chart are in ascending id order, so a stable (counting) sort by
            // pixel keeps each pixel's touches in face order: areas add up as the whole-LOD
            // raster's do.
            let (ww, wh) = (window.width(), window.height());
            starts.clear();
            starts.resize((ww * wh) as usize + 1, 0);
            for t in &touches {
                starts[t.pixel as usize + 1] += 1;
            }
            for i in 1..starts.len() {
                starts[i] += starts[i - 1];
            }
            sorted.clear();
            sorted.resize(touches.len(), Touch::default());
            {
                let mut fill = starts.clone();
                for t in &touches {
                    let slot = &mut fill[t.pixel as usize];
                    sorted[*slot as usize] = *t;
                    *slot += 1;
                }
            }
            // Per pixel of the window: empty, covered by another region's texel, or ours.
            let mut state = vec![EMPTY; (ww * wh) as usize];
            let at = |x: i64, y: i64| ((y - window.y0) * ww + (x - window.x0)) as usize;
            for w in 0..(ww * wh) as usize {
                let group = &sorted[starts[w] as usize..starts[w + 1] as usize];
                if group.is_empty() {
                    continue;
                }
                let (x, y) = (window.x0 + w as i64 % ww, window.y0 + w as i64 / ww);
                let area: f64 = group.iter().map(|t| t.area).sum();
                // The face holding the pixel centre, else the nearest, ties to the lower id:
                // (squared distance as f32 bits, face) packed, the smallest wins. A pixel
                // touched by one face (most are) needs no distance.
                let face = if let [only] = group {
                    only.face
                } else {
                    let c = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                    let key = |t: &Touch| {
                        let (_, _, d2) = raster::closest_barycentric(&atlas.faces[t.face as usize].uv_lod(lod), c);
                        ((d2 as f32).to_bits() as u64) << 32 | t.face as u64
                    };
                    group.iter().map(key).min().unwrap_or(u64::MAX) as u32
                };
                let uv = atlas.faces[face as usize].uv_lod(lod);
                let attributes = TexelAttributes::at(scene, geom, atlas, face, &uv, x, y);
                let ours = inside(attributes.position);
                state[at(x, y)] = if ours { OURS } else { OTHERS };
                if ours {
                    texels.push((block_key(x as u32, y as u32), [x as u32, y as u32], face, area as f32, attributes));
                    // Every face touching the pixel credits the texel where a bundle line
                    // crosses it inside the pixel.
                    for t in group {
                        let f = &atlas.faces[t.face as usize];
                        let (a, b) = face_in_pixel_box(&geom.corners[f.tri as usize], &f.uv_lod(lod), x, y);
                        texel_box = Some(texel_box.map_or((a, b), |(lo, hi)| (a.min(lo), b.max(hi))));
                    }
                }
            }
            touches.clear();
            // Gutters: empty pixels next to one of our texels whose rule copies one of ours.
            let get = |x: i64, y: i64| if window.contains(x, y) { state[at(x, y)] } else { EMPTY };
            for y in window.y0..window.y1 {
                for x in window.x0..window.x1 {
                    if get(x, y) != EMPTY {
                        continue;
                    }
                    let Some((dx, dy)) = gutter_source(|dx, dy| get(x + dx, y + dy) != EMPTY) else { continue };
                    if get(x + dx, y + dy) == OURS {
                        gutters.push(([x as u32, y as u32], [(x + dx) as u32, (y + dy) as u32], chart_id));
                    }
                }
            }
        }

        // Texels in block order, then the lookup tables (per chart, over its texels and
        // gutter pixels), through which gutter pixels find the texel they copy.
        // (Sorted through their keys: the texels themselves are large to move.)
        let mut order: Vec<(u64, u32)> = texels.iter().enumerate().map(|(i, t)| (t.0, i as u32)).collect();
        order.sort_unstable();
        let mut rects: BTreeMap<u32, PixelRect> = BTreeMap::new();
        let mut grow = |chart: u32, p: [u32; 2]| {
            let r = PixelRect::new(p[0] as i64, p[1] as i64, p[0] as i64 + 1, p[1] as i64 + 1);
            rects.entry(chart).and_modify(|w| *w = union(*w, r)).or_insert(r);
        };
        for &(_, pixel, face, _, _) in &texels {
            grow(atlas.faces[face as usize].chart, pixel);
        }
        for &(g, _, chart) in &gutters {
            grow(chart, g);
        }
        let mut tables: BTreeMap<u32, TexelTable> =
            rects.into_iter().map(|(c, r)| (c, TexelTable::new(Some(c), r))).collect();
        let n = order.len();
        out.pixel.reserve_exact(n);
        out.face.reserve_exact(n);
        out.position.reserve_exact(n);
        out.normal.reserve_exact(n);
        out.albedo.reserve_exact(n);
        out.emission.reserve_exact(n);
        out.area.reserve_exact(n);
        for (k, &(_, i)) in order.iter().enumerate() {
            let (_, pixel, face, area, ref a) = texels[i as usize];
            out.pixel.push(pixel);
            out.face.push(face);
            out.position.push(a.position);
            out.normal.push(a.normal);
            out.albedo.push(a.albedo);
            out.emission.push(a.emission);
            out.area.push(area);
            if let Some(t) = tables.get_mut(&atlas.faces[face as usize].chart) {
                t.set(pixel[0] as i64, pixel[1] as i64, k as u32);
            }
        }
        for &(g, src, chart) in &gutters {
            if let Some(t) = tables.get_mut(&chart) {
                let id = t.get(src[0] as i64, src[1] as i64);
                t.set(g[0] as i64, g[1] as i64, id);
                out.gutter.push((g, id));
            }
        }
        let index: BTreeMap<u32, u32> = tables.keys().enumerate().map(|(i, &c)| (c, i as u32)).collect();
        out.table = out.face.iter().map(|&f| index[&atlas.faces[f as usize].chart]).collect();
        out.tables = tables.into_values().collect();
        out.footprint = texel_box;
        out
    }

    pub fn len(&self) -> usize {
        self.pixel.len()
    }

    pub fn view(&self) -> super::texels::TexelView<'_> {
        super::texels::TexelView {
            lod: self.lod,
            face: &self.face,
            position: &self.position,
            normal: &self.normal,
            albedo: super::texels::TexelAlbedo::Dense(&self.albedo),
            emission: super::texels::TexelEmission::Dense(&self.emission),
            area: &self.area,
        }
    }

    pub fn is_empty(&self) -> bool {
        self.pixel.is_empty()
    }

    /// The lookup table of texel `i`'s chart.
    pub fn table_of(&self, i: usize) -> &TexelTable {
        &self.tables[self.table[i] as usize]
    }

    /// The lookup table of a chart, if the region has texels in it.
    pub fn table(&self, chart: u32) -> Option<&TexelTable> {
        self.tables.binary_search_by_key(&Some(chart), |t| t.chart).ok().map(|i| &self.tables[i])
    }

    /// Bytes held (texel attributes, gutters and tables).
    pub fn bytes(&self) -> usize {
        self.len() * (8 + 4 + 12 * 4 + 4 + 4)
            + self.gutter.len() * 12
            + self.tables.iter().map(TexelTable::bytes).sum::<usize>()
    }
}

/// Sort key of a pixel in texel order: 8×8 blocks row by row, Z-order inside a block.
pub fn block_key(x: u32, y: u32) -> u64 {
    let morton = |v: u32| (v & 1) | (v & 2) << 1 | (v & 4) << 2;
    ((y as u64 >> 3) << 40) | ((x as u64 >> 3) << 8) | (morton(x & 7) | morton(y & 7) << 1) as u64
}

fn union(a: PixelRect, b: PixelRect) -> PixelRect {
    PixelRect::new(a.x0.min(b.x0), a.y0.min(b.y0), a.x1.max(b.x1), a.y1.max(b.y1))
}

/// UV box (LOD pixels) of the part of triangle `tri` inside the box `[lo, hi]`, or `None`
/// when that part is empty. Falls back to the whole triangle's UV box when the triangle is
/// too thin to locate points on it reliably.
fn footprint(geom: &SceneGeometry, tri: u32, uv: &[DVec2; 3], lo: Vec3, hi: Vec3) -> Option<(DVec2, DVec2)> {
    let c = geom.corners[tri as usize].map(|p| p.as_dvec3());
    let whole = || Some((uv[0].min(uv[1]).min(uv[2]), uv[0].max(uv[1]).max(uv[2])));
    // Sutherland–Hodgman against the box's six planes (f64).
    let mut poly: Vec<DVec3> = c.to_vec();
    let (lo, hi) = (lo.as_dvec3(), hi.as_dvec3());
    for axis in 0..3 {
        for (bound, keep_above) in [(lo[axis], true), (hi[axis], false)] {
            let dist = |p: &DVec3| if keep_above { p[axis] - bound } else { bound - p[axis] };
            let mut next = Vec::with_capacity(poly.len() + 2);
            for i in 0..poly.len() {
                let (a, b) = (poly[i], poly[(i + 1) % poly.len()]);
                let (da, db) = (dist(&a), dist(&b));
                if da >= 0.0 {
                    next.push(a);
                }
                if (da >= 0.0) != (db >= 0.0) {
                    next.push(a + (b - a) * (da / (da - db)));
                }
            }
            poly = next;
            if poly.is_empty() {
                return None;
            }
        }
    }
    // Barycentrics of the clipped points (least squares on the triangle's plane).
    let (e1, e2) = (c[1] - c[0], c[2] - c[0]);
    let (a11, a12, a22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let det = a11 * a22 - a12 * a12;
    // Written so that a NaN determinant also takes the whole-triangle path.
    #[allow(clippy::neg_cmp_op_on_partial_ord)]
    if !(det > 1e-12 * a11.max(a22).powi(2)) {
        return whole();
    }
    let (mut bmin, mut bmax) = (DVec2::splat(f64::MAX), DVec2::splat(f64::MIN));
    for p in poly {
        let d = p - c[0];
        let (r1, r2) = (d.dot(e1), d.dot(e2));
        let u = (a22 * r1 - a12 * r2) / det;
        let v = (a11 * r2 - a12 * r1) / det;
        let q = uv[0] + (uv[1] - uv[0]) * u + (uv[2] - uv[0]) * v;
        bmin = bmin.min(q);
        bmax = bmax.max(q);
    }
    (bmin.is_finite() && bmax.is_finite()).then_some((bmin, bmax)).or_else(whole)
}
