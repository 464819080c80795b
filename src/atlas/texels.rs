//! Inverse mapping (2017 thesis, 3.2.3): for every texel of a LOD, the surface point it stands
//! for.

use crate::parallel::par_for_each;
use glam::{DVec2, Vec3};

use super::lookup::TexelTable;
use super::raster;
use super::{Atlas, FaceId};
use crate::scene::{Rgb, Scene, SceneGeometry};

/// Marks an atlas pixel that holds no texel (not covered by any face, or gutter).
pub const NO_TEXEL: u32 = u32::MAX;

/// What [`TexelMap::restore_geometry`] recomputes of what a bake gave up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Restore {
    /// Positions, normals and albedo: the map as [`TexelMap::build`] made it.
    All,
    /// The albedo alone (what light maps and their previews read): positions and normals
    /// stay given up, 24 B a texel less in the output.
    Albedo,
}

/// What [`TexelMap::build_parts`] makes beside the pixels, faces, areas and gutters.
#[derive(Clone, Copy)]
struct Parts {
    /// Positions and normals.
    geometry: bool,
    /// Albedo and emission (and with them the surface point's texture reads).
    attributes: bool,
}

/// Every valid texel of one LOD, stored compactly (covered texels only, in `block_order`),
/// plus the gutter pixels that copy a texel. The pixel → texel lookup is not kept: the
/// bundles read a [`TexelTable`], tests [`TexelMap::slots`].
#[derive(Clone, Debug, Default)]
pub struct TexelMap {
    pub lod: u32,
    pub width: u32,
    pub height: u32,
    /// Per texel: its pixel index (`y · width + x`).
    pub pixel: Vec<u32>,
    /// Per texel: the face whose surface point it holds.
    pub face: Vec<FaceId>,
    /// Per texel: world position on the face (the texel centre mapped to the face, clamped
    /// onto it when the centre lies outside: conservative coverage keeps thin triangles).
    pub position: Vec<Vec3>,
    /// Per texel: unit geometric normal of the face's side.
    pub normal: Vec<Vec3>,
    /// Per texel: diffuse albedo (material factor × base-colour texture at the point).
    pub albedo: Vec<Rgb>,
    /// Per texel: emitted radiance of that side, W/(sr·m²) (zero when that side emits nothing).
    pub emission: Vec<Rgb>,
    /// Per texel: world area (m²) of the surface that maps into the texel's square.
    pub area: Vec<f32>,
    /// Gutter pixels (empty pixels next to a chart) and the texel each copies, so bilinear
    /// sampling near a chart edge never reads an empty or foreign texel.
    pub gutter: Vec<(u32, u32)>,
}

impl TexelMap {
    /// Inverse mapping at LOD `lod` (resolution `(width, height) · 2^lod` over the atlas
    /// layout). Every face is rasterised conservatively (see [`super::raster`]) inside its
    /// chart's interior; a pixel touched by several faces of its chart takes the face that
    /// contains the pixel centre, else the nearest one, ties to the lower face id. The texel
    /// holds the centre mapped onto that face (barycentrics of the closest point of the UV
    /// triangle). Empty pixels in the 8-neighbourhood of a texel become gutter pixels copying
    /// a 4-neighbour if any (left, right, up, down), else a diagonal one.
    ///
    /// Rows are split into bands built in parallel (scoped threads); the result does not
    /// depend on the number of threads.
    ///
    /// # Panics
    /// When the LOD's pixel count does not fit in `u32` (`width · height · 4^lod ≥ 2³²`).
    pub fn build(scene: &Scene, geom: &SceneGeometry, atlas: &Atlas, lod: u32) -> TexelMap {
        Self::build_with(scene, geom, atlas, lod, Restore::All)
    }

    /// [`build`](Self::build) making what `made` says: with [`Restore::Albedo`] the map has
    /// no positions and normals (as if [`drop_geometry`](Self::drop_geometry) had given
    /// them up; 24 B a texel less while it is built, for a bake that reads neither).
    ///
    /// # Panics
    /// As [`build`](Self::build).
    pub fn build_with(scene: &Scene, geom: &SceneGeometry, atlas: &Atlas, lod: u32, made: Restore) -> TexelMap {
        Self::build_parts(scene, geom, atlas, lod, Parts { geometry: made == Restore::All, attributes: true })
    }

    /// [`build`](Self::build) without any attribute of the surface (positions, normals,
    /// albedo, emission): which texel is where (pixels, faces, gutters) and its area, 16 B a
    /// texel less than [`Restore::Albedo`]'s and none of its texture reads. What a region
    /// shard holds of the whole LOD while it sets up; it asks the attributes of a texel
    /// when it needs them ([`TexelMap::attributes_of`]).
    ///
    /// # Panics
    /// As [`build`](Self::build).
    pub fn build_lookup(scene: &Scene, geom: &SceneGeometry, atlas: &Atlas, lod: u32) -> TexelMap {
        Self::build_parts(scene, geom, atlas, lod, Parts { geometry: false, attributes: false })
    }

    /// The attributes of texel `i` (its surface point, normal, albedo and emission), as
    /// [`build`](Self::build) makes them: from its face and pixel alone.
    pub(crate) fn attributes_of(
        &self,
        scene: &Scene,
        geom: &SceneGeometry,
        atlas: &Atlas,
        i: usize,
    ) -> TexelAttributes {
        let (face, pixel) = (self.face[i], self.pixel[i]);
        let uv = atlas.faces[face as usize].uv_lod(self.lod);
        TexelAttributes::at(scene, geom, atlas, face, &uv, (pixel % self.width) as i64, (pixel / self.width) as i64)
    }

    fn build_parts(scene: &Scene, geom: &SceneGeometry, atlas: &Atlas, lod: u32, made: Parts) -> TexelMap {
        let width =
            atlas.width.checked_shl(lod).filter(|w| w >> lod == atlas.width).expect("LOD too fine for u32 pixels");
        let height =
            atlas.height.checked_shl(lod).filter(|h| h >> lod == atlas.height).expect("LOD too fine for u32 pixels");
        let (w, h) = (width as usize, height as usize);
        assert!(w.checked_mul(h).is_some_and(|n| n < u32::MAX as usize), "LOD {lod} has too many pixels for u32 ids");

        // Per face: the pixels it may use and its LOD-k UV triangle, made where they are
        // read (held for every face, they were 80 B a face through the build: 150 MB on a
        // scene of two million faces).
        let pre = |fi: u32| {
            let f = &atlas.faces[fi as usize];
            (atlas.charts[f.chart as usize].interior(lod), f.uv_lod(lod))
        };

        let threads = if w * h < 1 << 16 { 1 } else { crate::parallel::available_threads().min(8) };
        // Whole texel blocks per band, so texel ids can follow the blocks (see [`block_order`]).
        let band_rows = if threads == 1 { h.max(1) } else { h.div_ceil(threads * 8).max(4) }.next_multiple_of(BLOCK);
        let bands = h.div_ceil(band_rows);

        // Faces per band, in increasing id order.
        let mut per_band: Vec<Vec<u32>> = vec![Vec::new(); bands];
        for fi in 0..atlas.faces.len() as u32 {
            // The rows the face may touch.
            let (b, t) = pre(fi);
            let lo = raster::floor_i64(t[0].y.min(t[1].y).min(t[2].y)) - 1;
            let hi = raster::ceil_i64(t[0].y.max(t[1].y).max(t[2].y)) + 1;
            let (r0, r1) = (lo.max(b.y0), hi.min(b.y1));
            if r1 > r0 {
                for band in per_band.iter_mut().take((r1 as usize - 1) / band_rows + 1).skip(r0 as usize / band_rows) {
                    band.push(fi);
                }
            }
        }

        // Phase 1: which face each pixel takes (NO_TEXEL where none). Per pixel the best
        // (squared distance from the centre as f32 bits, face id) packed in a u64: the
        // smallest wins, so a face containing the centre (distance 0) beats any other and
        // ties go to the lower face id.
        let mut slot = vec![0u32; w * h]; // every entry is written below
        let mut counts = vec![0usize; bands];
        // Per band, per pixel: world area of all faces inside the pixel square (m²).
        let mut band_areas: Vec<Vec<f32>> = vec![Vec::new(); bands];
        par_for_each(
            slot.chunks_mut(band_rows * w).zip(counts.iter_mut()).zip(band_areas.iter_mut()).enumerate().collect(),
            threads,
            |(b, ((owner, count), areas))| {
                let (y0, y1) = ((b * band_rows) as i64, ((b * band_rows) as i64 + (owner.len() / w.max(1)) as i64));
                let mut best = vec![u64::MAX; owner.len()];
                let mut area = vec![0f64; owner.len()];
                for &fi in &per_band[b] {
                    let (bounds, tri) = pre(fi);
                    // World m² per LOD-k pixel² of the face's parametrisation.
                    let ratio = world_per_pixel(geom, atlas, fi, &tri);
                    raster::conservative(&tri, bounds, (y0, y1), |x, y| {
                        let i = (y - y0) as usize * w + x as usize;
                        area[i] += raster::clipped_area(&tri, x, y) * ratio;
                        if best[i] >> 32 == 0 {
                            return; // the centre lies in a face with a lower id
                        }
                        let c = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
                        let (_, _, d2) = raster::closest_barycentric(&tri, c);
                        best[i] = best[i].min(((d2 as f32).to_bits() as u64) << 32 | fi as u64);
                    });
                }
                // A new buffer: collected in place, the f32s would keep the f64s' 8 B a pixel.
                *areas = area.iter().map(|&a| a as f32).collect();
                let mut n = 0;
                for (o, &k) in owner.iter_mut().zip(&best) {
                    *o = if k == u64::MAX { NO_TEXEL } else { k as u32 };
                    n += usize::from(k != u64::MAX);
                }
                *count = n;
            },
        );

        // Phase 2: texels, in block order ([`block_order`]); `slot` turns from face into texel ids.
        let total: usize = counts.iter().sum();
        let geometry = if made.geometry { total } else { 0 };
        let attributes = if made.attributes { total } else { 0 };
        let mut map = TexelMap {
            lod,
            width,
            height,
            pixel: vec![0; total],
            face: vec![0; total],
            position: vec![Vec3::ZERO; geometry],
            normal: vec![Vec3::ZERO; geometry],
            albedo: vec![Vec3::ZERO; attributes],
            emission: vec![Vec3::ZERO; attributes],
            area: vec![0.0; total],
            gutter: Vec::new(),
        };
        {
            let mut items = Vec::with_capacity(bands);
            let (mut pixel, mut face, mut position) = (&mut map.pixel[..], &mut map.face[..], &mut map.position[..]);
            let (mut normal, mut albedo, mut emission) =
                (&mut map.normal[..], &mut map.albedo[..], &mut map.emission[..]);
            let mut area = &mut map.area[..];
            let mut first = 0usize;
            for (b, chunk) in slot.chunks_mut(band_rows * w).enumerate() {
                let n = counts[b];
                items.push((
                    b,
                    first,
                    chunk,
                    take_front(&mut pixel, n),
                    take_front(&mut face, n),
                    take_front(&mut position, n.min(geometry)),
                    take_front(&mut normal, n.min(geometry)),
                    take_front(&mut albedo, n.min(attributes)),
                    take_front(&mut emission, n.min(attributes)),
                    take_front(&mut area, n),
                    &band_areas[b],
                ));
                first += n;
            }
            par_for_each(
                items,
                threads,
                |(b, first, chunk, pixel, face, position, normal, albedo, emission, area, band_area)| {
                    let y0 = b * band_rows;
                    let mut k = 0;
                    for i in block_order(w, chunk.len() / w.max(1)) {
                        let s = &mut chunk[i];
                        if *s == NO_TEXEL {
                            continue;
                        }
                        let fid = *s;
                        let (x, y) = (i % w, y0 + i / w);
                        pixel[k] = (y * w + x) as u32;
                        area[k] = band_area[i];
                        face[k] = fid;
                        if let (Some(albedo), Some(emission)) = (albedo.get_mut(k), emission.get_mut(k)) {
                            let uv = atlas.faces[fid as usize].uv_lod(lod);
                            let a = TexelAttributes::at(scene, geom, atlas, fid, &uv, x as i64, y as i64);
                            if let (Some(p), Some(n)) = (position.get_mut(k), normal.get_mut(k)) {
                                (*p, *n) = (a.position, a.normal);
                            }
                            (*albedo, *emission) = (a.albedo, a.emission);
                        }
                        *s = (first + k) as u32;
                        k += 1;
                    }
                },
            );
        }

        // Phase 3: gutters.
        let mut gutters: Vec<Vec<(u32, u32)>> = vec![Vec::new(); bands];
        {
            let slot = &slot;
            par_for_each(gutters.iter_mut().enumerate().collect(), threads, |(b, out)| {
                let at = |x: i64, y: i64| {
                    if x < 0 || y < 0 || x >= w as i64 || y >= h as i64 {
                        NO_TEXEL
                    } else {
                        slot[y as usize * w + x as usize]
                    }
                };
                // In block order, as the texels (a ranked lookup table gives them back so).
                let y0 = b * band_rows;
                for i in block_order(w, (((b + 1) * band_rows).min(h)).saturating_sub(y0)) {
                    let (x, y) = (i % w, y0 + i / w);
                    let (xi, yi) = (x as i64, y as i64);
                    if at(xi, yi) != NO_TEXEL {
                        continue;
                    }
                    if let Some((dx, dy)) = gutter_source(|dx, dy| at(xi + dx, yi + dy) != NO_TEXEL) {
                        out.push(((y * w + x) as u32, at(xi + dx, yi + dy)));
                    }
                }
            });
        }
        map.gutter = gutters.concat();
        map
    }

    pub fn len(&self) -> usize {
        self.face.len()
    }

    /// Gives up the texels' pixels and the gutter pixels (4 B a texel and 8 B a gutter
    /// pixel) while `table`, a ranked table of this map ([`TexelTable::of_map`]), holds
    /// them; `false` (nothing given up) when `table` cannot give them back (a dense one).
    /// [`restore_pixels`](Self::restore_pixels) puts them back.
    pub fn drop_pixels(&mut self, table: &TexelTable) -> bool {
        if table.chart.is_some() || !table.holds_map_pixels() {
            return false;
        }
        self.pixel = Vec::new();
        self.gutter = Vec::new();
        true
    }

    /// Puts back the pixels [`drop_pixels`](Self::drop_pixels) gave up to `table`, value
    /// for value (the gutter pixels in block order, as [`build`](Self::build) lists them).
    pub fn restore_pixels(&mut self, table: &TexelTable) {
        if let Some(given) = table.map_pixels() {
            self.pixel = given.pixel;
            self.gutter = given.gutter;
        }
    }

    /// Gives up the texels' areas (4 B a texel), read by the light pass alone and by
    /// nothing that reads a finished map's light.
    pub fn drop_area(&mut self) {
        self.area = Vec::new();
    }

    /// Gives up the texels' positions and normals (24 B a texel) while a bake that no longer
    /// reads them runs; [`restore_geometry`](Self::restore_geometry) recomputes them.
    pub fn drop_geometry(&mut self) {
        self.position = Vec::new();
        self.normal = Vec::new();
    }

    /// Gives up the texels' albedo (12 B a texel) while a bake that no longer reads it runs (one
    /// whose source radiance is already made); [`restore_geometry`](Self::restore_geometry)
    /// recomputes it.
    pub fn drop_albedo(&mut self) {
        self.albedo = Vec::new();
    }

    /// Gives up the dense emission (12 B a texel) for that of the emitting texels alone,
    /// returned; [`restore_emission`](Self::restore_emission) puts it back. `None` (the
    /// dense emission kept) when so many texels emit that the sparse form would be larger.
    pub fn take_emission(&mut self) -> Option<TexelSubset> {
        let e = TexelSubset::from_dense(&self.emission);
        if e.bytes() >= self.emission.len() * 12 {
            return None;
        }
        self.emission = Vec::new();
        Some(e)
    }

    /// Puts back the emission [`take_emission`](Self::take_emission) gave up, value for value.
    pub fn restore_emission(&mut self, emitting: &TexelSubset) {
        self.emission = emitting.dense();
    }

    /// Gives up the albedo (12 B a texel) of the texels whose material has no texture (their
    /// face's [`UniformAlbedos::of_face`]), returning the others'; [`restore_albedo`](Self::restore_albedo)
    /// puts it back. `None` (the dense albedo kept) when so many texels are textured that the
    /// sparse form would be larger.
    pub fn take_albedo(&mut self, scene: &Scene, geom: &SceneGeometry, atlas: &Atlas) -> Option<TexelSubset> {
        let uniform = UniformAlbedos::new(scene);
        let textured = |i: usize| uniform.of_face(geom, atlas, self.face[i]).is_none();
        let t = TexelSubset::from_dense_where(&self.albedo, textured);
        if t.bytes() >= self.albedo.len() * 12 {
            return None;
        }
        self.albedo = Vec::new();
        Some(t)
    }

    /// Puts back the albedo [`take_albedo`](Self::take_albedo) gave up, value for value.
    pub fn restore_albedo(&mut self, textured: &TexelSubset, scene: &Scene, geom: &SceneGeometry, atlas: &Atlas) {
        let (view, uniform) = (TexelAlbedo::Textured(textured), UniformAlbedos::new(scene));
        self.albedo = (0..self.face.len()).map(|i| view.at(i, self.face[i], &uniform, geom, atlas)).collect();
    }

    /// Recomputes the albedo when [`drop_albedo`](Self::drop_albedo) gave it up, and with
    /// [`Restore::All`] the positions and normals [`drop_geometry`](Self::drop_geometry) gave
    /// up: the same function of each texel's face and pixel as [`build`](Self::build), so the
    /// same values bit for bit.
    pub fn restore_geometry(
        &mut self,
        scene: &Scene,
        geom: &SceneGeometry,
        atlas: &Atlas,
        threads: usize,
        restore: Restore,
    ) {
        let n = self.len();
        // Each empty unless recomputed.
        let geometry = if restore == Restore::All { n } else { 0 };
        let mut position = vec![Vec3::ZERO; geometry];
        let mut normal = vec![Vec3::ZERO; geometry];
        // Empty unless given up (a map of no texels has nothing to restore either way).
        let mut albedo = if self.albedo.len() == n { Vec::new() } else { vec![Rgb::ZERO; n] };
        let chunk = n.div_ceil(threads.max(1) * 4).max(4096);
        if geometry == 0 && albedo.is_empty() {
            return;
        }
        // Chunks of the arrays recomputed, empty ones for the others.
        fn chunks<T>(v: &mut [T], chunk: usize, count: usize) -> Vec<&mut [T]> {
            let mut c: Vec<&mut [T]> = v.chunks_mut(chunk).collect();
            c.resize_with(count, Default::default);
            c
        }
        let count = n.div_ceil(chunk);
        let items: Vec<_> = chunks(&mut position, chunk, count)
            .into_iter()
            .zip(chunks(&mut normal, chunk, count))
            .zip(chunks(&mut albedo, chunk, count))
            .zip((0..n).step_by(chunk))
            .collect();
        let map = &*self;
        par_for_each(items, threads, |(((position, normal), albedo), first)| {
            for k in 0..chunk.min(n - first) {
                let a = map.attributes_of(scene, geom, atlas, first + k);
                if let (Some(p), Some(n)) = (position.get_mut(k), normal.get_mut(k)) {
                    (*p, *n) = (a.position, a.normal);
                }
                if let Some(albedo) = albedo.get_mut(k) {
                    *albedo = a.albedo;
                }
            }
        });
        if geometry > 0 {
            self.position = position;
            self.normal = normal;
        }
        if !albedo.is_empty() {
            self.albedo = albedo;
        }
    }

    pub fn is_empty(&self) -> bool {
        self.face.is_empty()
    }

    /// Per atlas pixel (row-major): the index of its texel, or [`NO_TEXEL`] (as gutter pixels
    /// are). Made on demand: the map does not keep it, since nothing reads it while a
    /// bake or the runtime runs (4 B a pixel of every LOD held).
    pub fn slots(&self) -> Vec<u32> {
        let mut slot = vec![NO_TEXEL; self.width as usize * self.height as usize];
        for (t, &p) in self.pixel.iter().enumerate() {
            slot[p as usize] = t as u32;
        }
        slot
    }

    /// Spreads per-texel `values` into a full row-major image, gutters filled from their
    /// source texel and other pixels set to `empty`.
    pub fn to_image<T: Copy>(&self, values: &[T], empty: T) -> Vec<T> {
        let mut img = vec![empty; (self.width * self.height) as usize];
        for (t, &p) in self.pixel.iter().enumerate() {
            img[p as usize] = values[t];
        }
        for &(p, t) in &self.gutter {
            img[p as usize] = values[t as usize];
        }
        img
    }
}

/// What a texel holds: the centre of pixel (x, y) mapped onto face `face` (barycentrics of
/// the closest point of its LOD-k UV triangle `uv`), and the surface there. The one place
/// that computes it, for whole-LOD and per-region texel maps alike.
pub(crate) struct TexelAttributes {
    pub position: Vec3,
    pub normal: Vec3,
    pub albedo: Rgb,
    pub emission: Rgb,
}

impl TexelAttributes {
    pub(crate) fn at(
        scene: &Scene,
        geom: &SceneGeometry,
        atlas: &Atlas,
        face: FaceId,
        uv: &[DVec2; 3],
        x: i64,
        y: i64,
    ) -> TexelAttributes {
        let f = &atlas.faces[face as usize];
        let c = DVec2::new(x as f64 + 0.5, y as f64 + 0.5);
        let (u, v, _) = raster::closest_barycentric(uv, c);
        let (u, v) = (u as f32, v as f32);
        let t = f.tri;
        let m = &scene.materials[geom.material[t as usize] as usize];
        TexelAttributes {
            position: geom.point(t, u, v),
            normal: geom.normals[t as usize] * f.side.sign(),
            albedo: geom.albedo(scene, t, u, v),
            emission: if m.emits_from(f.side) { geom.emission(scene, t, u, v) } else { Rgb::ZERO },
        }
    }
}

/// World m² per LOD-`lod` pixel² of a face's parametrisation (0 for a degenerate UV triangle):
/// turns the part of the face inside a pixel square into the texel's world area.
pub(crate) fn world_per_pixel(geom: &SceneGeometry, atlas: &Atlas, face: FaceId, uv: &[DVec2; 3]) -> f64 {
    let area = 0.5 * raster::area2(uv).abs();
    if area > 0.0 { geom.areas[atlas.faces[face as usize].tri as usize] as f64 / area } else { 0.0 }
}

/// The gutter rule: an empty pixel next to a texel copies its left, right, upper or lower
/// neighbour if one is a texel, else a diagonal one, in that order. `covered(dx, dy)` says
/// whether the neighbour at that offset holds a texel; returns the offset copied.
#[inline]
pub(crate) fn gutter_source(covered: impl Fn(i64, i64) -> bool) -> Option<(i64, i64)> {
    const ORDER: [(i64, i64); 8] = [(-1, 0), (1, 0), (0, -1), (0, 1), (-1, -1), (1, -1), (-1, 1), (1, 1)];
    ORDER.into_iter().find(|&(dx, dy)| covered(dx, dy))
}

/// The per-texel attributes of a texel map (whole-LOD or per-region), borrowed.
#[derive(Clone, Copy)]
pub struct TexelView<'a> {
    pub lod: u32,
    pub face: &'a [FaceId],
    pub position: &'a [Vec3],
    pub normal: &'a [Vec3],
    pub albedo: TexelAlbedo<'a>,
    pub emission: TexelEmission<'a>,
    pub area: &'a [f32],
}

/// Per texel: emitted radiance of its side, W/(sr·m²), held densely or for the emitting
/// texels alone.
#[derive(Clone, Copy, Debug)]
pub enum TexelEmission<'a> {
    /// One value per texel ([`TexelMap::emission`]).
    Dense(&'a [Rgb]),
    /// The emitting texels only; every other texel emits nothing.
    Emitting(&'a TexelSubset),
}

impl TexelEmission<'_> {
    /// Texel `i`'s emitted radiance.
    #[inline]
    pub fn at(&self, i: usize) -> Rgb {
        match self {
            TexelEmission::Dense(e) => e[i],
            TexelEmission::Emitting(e) => e.at(i as u32),
        }
    }
}

/// Values of a few of a map's texels (the others read as zero or absent): what a bake keeps
/// of a per-texel array while its bundles run where most texels need none, such as the
/// emission of the emitting texels, or the albedo of texels of textured materials. Which
/// texels are held is a bit per texel; a held texel's value is found through the count of
/// held texels before its 64-texel word (a value a held texel, ~0.2 B a texel). The values
/// are colours, or another per-texel type such as a colour in half floats.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TexelSubset<V = Rgb> {
    texels: usize,
    /// Bit `i % 64` of word `i / 64`: whether texel `i` is held.
    held: Vec<u64>,
    /// Per word: the held texels before it.
    before: Vec<u32>,
    values: Vec<V>,
}

impl TexelSubset {
    /// The nonzero values of `dense`.
    pub fn from_dense(dense: &[Rgb]) -> Self {
        Self::from_dense_where(dense, |i| dense[i] != Rgb::ZERO)
    }

    /// The values of `dense` at the texels `keep` says.
    pub fn from_dense_where(dense: &[Rgb], keep: impl Fn(usize) -> bool) -> Self {
        Self::from_entries(dense.len(), dense.iter().enumerate().filter(|&(i, _)| keep(i)).map(|(i, &v)| (i as u32, v)))
    }

    /// Texel `i`'s value, zero when it is not held.
    #[inline]
    pub fn at(&self, i: u32) -> Rgb {
        self.get(i).unwrap_or(Rgb::ZERO)
    }

    /// The dense array these were made from where held, zero elsewhere.
    pub fn dense(&self) -> Vec<Rgb> {
        let mut e = vec![Rgb::ZERO; self.texels];
        let mut values = self.values.iter();
        for (i, v) in e.iter_mut().enumerate() {
            if self.held[i / 64] >> (i % 64) & 1 == 1 {
                *v = *values.next().expect("one value per held texel");
            }
        }
        e
    }
}

impl<V: Copy> TexelSubset<V> {
    /// The values `entries` gives (texel, value), in ascending texel order, of a map of
    /// `texels` texels.
    ///
    /// # Panics
    /// When the texels are not ascending or not below `texels`.
    pub fn from_entries(texels: usize, entries: impl IntoIterator<Item = (u32, V)>) -> Self {
        let mut held = vec![0u64; texels.div_ceil(64)];
        let mut values = Vec::new();
        let mut last = None;
        for (i, v) in entries {
            check_ascending(&mut last, i, texels);
            held[i as usize / 64] |= 1 << (i % 64);
            values.push(v);
        }
        TexelSubset { texels, before: counts_before(&held), held, values }
    }

    /// `value` of every texel of `dense` but those of `left_out` (ascending ids): a value
    /// a held texel and a bit and a word count.
    ///
    /// # Panics
    /// When `left_out` is not ascending or holds a texel past `dense`.
    pub fn all_but<T: Copy>(dense: &[T], left_out: &[u32], value: impl Fn(T) -> V) -> Self {
        let texels = dense.len();
        let mut held = vec![!0u64; texels.div_ceil(64)];
        if texels % 64 != 0
            && let Some(last) = held.last_mut()
        {
            *last = (1 << (texels % 64)) - 1;
        }
        let mut previous = None;
        for &i in left_out {
            check_ascending(&mut previous, i, texels);
            held[i as usize / 64] &= !(1 << (i % 64));
        }
        let mut values = Vec::with_capacity(texels - left_out.len());
        values.extend((0..texels).filter(|&i| held[i / 64] >> (i % 64) & 1 == 1).map(|i| value(dense[i])));
        TexelSubset { texels, before: counts_before(&held), held, values }
    }

    /// Texel `i`'s value, `None` when it is not held.
    #[inline]
    pub fn get(&self, i: u32) -> Option<V> {
        let (w, b) = (i as usize / 64, i % 64);
        let bits = *self.held.get(w)?;
        (bits >> b & 1 == 1).then(|| self.values[(self.before[w] + super::lookup::before(bits, b)) as usize])
    }

    /// Held texels.
    pub fn len(&self) -> usize {
        self.values.len()
    }

    pub fn is_empty(&self) -> bool {
        self.values.is_empty()
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.held.len() * 12 + self.values.len() * std::mem::size_of::<V>()
    }
}

/// Panics unless texel `i` comes after `last` and lies below `texels`; then `i` is the last.
fn check_ascending(last: &mut Option<u32>, i: u32, texels: usize) {
    assert!(*last < Some(i) && (i as usize) < texels, "texel {i} after {last:?} of {texels}");
    *last = Some(i);
}

/// Per word of `held` bits: the bits set in the words before it.
fn counts_before(held: &[u64]) -> Vec<u32> {
    held.iter()
        .scan(0u32, |n, bits| {
            let b = *n;
            *n += bits.count_ones();
            Some(b)
        })
        .collect()
}

/// Each mesh's albedo where neither a texture nor vertex colours vary it (the same at every
/// point: what [`TexelMap::build`] gives each of its texels;
/// [`SceneGeometry::uniform_albedo`]), worked out once: a lean bake asks it of a texel's face
/// for every texel of every batch.
pub struct UniformAlbedos(Vec<Option<Rgb>>);

impl UniformAlbedos {
    pub fn new(scene: &Scene) -> Self {
        let of_mesh = |m: &crate::scene::Mesh| {
            let material = scene.materials.get(m.material as usize)?;
            m.colors.is_none().then(|| material.uniform_albedo(&scene.textures))?
        };
        UniformAlbedos(scene.meshes.iter().map(of_mesh).collect())
    }

    /// The albedo of face `face`, `None` where a texture or vertex colours vary it.
    #[inline]
    pub fn of_face(&self, geom: &SceneGeometry, atlas: &Atlas, face: FaceId) -> Option<Rgb> {
        self.0[geom.mesh[atlas.faces[face as usize].tri as usize] as usize]
    }
}

/// Per texel: diffuse albedo, held densely or for the texels of textured materials alone.
#[derive(Clone, Copy, Debug)]
pub enum TexelAlbedo<'a> {
    /// One value per texel ([`TexelMap::albedo`]).
    Dense(&'a [Rgb]),
    /// The texels of textured materials only; every other texel's is its material's
    /// ([`UniformAlbedos::of_face`]).
    Textured(&'a TexelSubset),
}

impl TexelAlbedo<'_> {
    /// Texel `i` of face `face`'s albedo.
    #[inline]
    pub fn at(&self, i: usize, face: FaceId, uniform: &UniformAlbedos, geom: &SceneGeometry, atlas: &Atlas) -> Rgb {
        self.at_or(i, || uniform.of_face(geom, atlas, face))
    }

    /// Texel `i`'s albedo, `of_face()` being its face's ([`UniformAlbedos::of_face`]), for
    /// a caller that knows it.
    #[inline]
    pub fn at_or(&self, i: usize, of_face: impl FnOnce() -> Option<Rgb>) -> Rgb {
        match self {
            TexelAlbedo::Dense(a) => a[i],
            TexelAlbedo::Textured(t) => t.get(i as u32).or_else(of_face).unwrap_or(Rgb::ZERO),
        }
    }
}

impl TexelView<'_> {
    pub fn len(&self) -> usize {
        self.face.len()
    }

    pub fn is_empty(&self) -> bool {
        self.face.is_empty()
    }
}

impl TexelMap {
    pub fn view(&self) -> TexelView<'_> {
        TexelView {
            lod: self.lod,
            face: &self.face,
            position: &self.position,
            normal: &self.normal,
            albedo: TexelAlbedo::Dense(&self.albedo),
            emission: TexelEmission::Dense(&self.emission),
            area: &self.area,
        }
    }
}

/// Side of the square pixel blocks texel ids follow.
const BLOCK: usize = 8;

/// The pixel indices of a `w`×`rows` row-major band, block by block ([`BLOCK`]² pixels,
/// blocks in row-major order), Z-order inside a block. Texels numbered this way keep
/// surface neighbours close in memory in every direction, not only along rows: the
/// bundle resolve walks lines across the atlas in all directions, reading and
/// accumulating per-texel values as it goes.
pub(crate) fn block_order(w: usize, rows: usize) -> impl Iterator<Item = usize> {
    let blocks_x = w.div_ceil(BLOCK);
    (0..rows.div_ceil(BLOCK) * blocks_x).flat_map(move |b| {
        let (bx, by) = (b % blocks_x * BLOCK, b / blocks_x * BLOCK);
        (0..BLOCK * BLOCK).filter_map(move |m| {
            let (x, y) = (bx + deinterleave(m), by + deinterleave(m >> 1));
            (x < w && y < rows).then_some(y * w + x)
        })
    })
}

/// The even bits of `m`, packed: one coordinate of a Z-order index.
fn deinterleave(m: usize) -> usize {
    (m & 1) | (m >> 1 & 2) | (m >> 2 & 4)
}

/// Splits the first `n` elements off a mutable slice.
fn take_front<'a, T>(s: &mut &'a mut [T], n: usize) -> &'a mut [T] {
    let (front, rest) = std::mem::take(s).split_at_mut(n);
    *s = rest;
    front
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_texel_subset_reads_the_texels_it_holds() {
        // 200 texels (ragged last word), every third held, one word with none.
        let dense: Vec<Rgb> = (0..200).map(|i| Rgb::new(i as f32, 1.0, -(i as f32))).collect();
        let keep = |i: usize| i % 3 == 0 && !(64..128).contains(&i);
        let subset = TexelSubset::from_dense_where(&dense, keep);
        assert_eq!(subset.len(), (0..200).filter(|&i| keep(i)).count());
        for (i, &v) in dense.iter().enumerate() {
            assert_eq!(subset.get(i as u32), keep(i).then_some(v), "texel {i}");
        }
        assert_eq!(subset.get(200), None);
        let back = subset.dense();
        assert!((0..200).all(|i| back[i] == if keep(i) { dense[i] } else { Rgb::ZERO }));
        // From nonzero values: the zero texel 0 is not held, and nothing is lost.
        let mut emission = dense.clone();
        emission[0] = Rgb::ZERO;
        let emitting = TexelSubset::from_dense(&emission);
        assert_eq!((emitting.len(), emitting.at(0)), (199, Rgb::ZERO));
        assert_eq!(emitting.dense(), emission);
        assert_eq!(emitting.bytes(), 4 * 12 + 199 * 12);
    }

    /// All but some: the others' values; the left-out texels read nothing.
    #[test]
    fn a_texel_subset_of_all_but_some_reads_the_others() {
        let dense: Vec<Rgb> = (0..150).map(|i| Rgb::new(i as f32, 2.0, 3.0)).collect();
        let out: Vec<u32> = (0..150).filter(|i| i % 7 == 0 || (64..128).contains(i)).collect();
        let subset = TexelSubset::all_but(&dense, &out, |v| v);
        assert_eq!(subset.len(), 150 - out.len());
        for (i, &v) in dense.iter().enumerate() {
            let left_out = out.binary_search(&(i as u32)).is_ok();
            assert_eq!(subset.get(i as u32), (!left_out).then_some(v), "texel {i}");
        }
        assert_eq!(subset.get(150), None);
        assert_eq!(TexelSubset::all_but(&dense, &[], |v| v).dense(), dense);
        assert!(std::panic::catch_unwind(|| TexelSubset::all_but(&dense, &[9, 3], |v| v)).is_err());
        // Another type of value: the first channel as bits.
        let bits = TexelSubset::all_but(&dense, &out, |v: Rgb| v.x.to_bits());
        assert_eq!((bits.get(1), bits.get(0)), (Some(1f32.to_bits()), None));
        assert_eq!(bits.bytes(), 3 * 12 + (150 - out.len()) * 4);
    }

    /// Entries out of order or past the map would make a subset that reads wrong values.
    #[test]
    fn a_texel_subset_refuses_entries_out_of_order() {
        let v = Rgb::ONE;
        assert_eq!(TexelSubset::from_entries(70, [(3, v), (69, v)]).at(69), v);
        for bad in [vec![(5, v), (5, v)], vec![(7, v), (2, v)], vec![(70, v)]] {
            assert!(std::panic::catch_unwind(|| TexelSubset::from_entries(70, bad.clone())).is_err(), "{bad:?}");
        }
    }
}
