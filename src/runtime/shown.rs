//! The shown light map: what the viewer draws, what `probe` and `run --points` read, and
//! what the bundles of a cell bake see of the surfaces around them. One sampling function,
//! [`ShownLightmap::irradiance`], serves them all, so what the user sees is what the tests
//! measure.
//!
//! Storage is a sparse pyramid over the one atlas layout: LOD k is a grid of pages of
//! [`PAGE_SIDE`]² pixels of LOD k, allocated only where a cell was published at that level.
//! A snapshot is immutable and cheap to share (`Arc`): a publish builds the next snapshot,
//! copying only the page-table rows and the pages it writes (copy-on-write, each written page
//! gets a new id), so a reader sees a cell before or after its publish, never half of it, and
//! a GPU mirror uploads exactly the pages whose id changed.
//!
//! A cell shown at LOD k keeps its pages at coarser levels: sampling falls back to them
//! where LOD k has no texel yet (next to a coarser neighbour), and blends toward the coarser
//! neighbour's LOD j across a band of a couple of LOD-j texels along a border between cells
//! of different LOD ([`ShownLightmap::band_toward`]), so the border shows no step beyond the
//! noise.
//!
//! The map has two [`Layer`]s, summed by the sampling function, each with its own pages and
//! its own LOD per cell: the light the bundles carry (sky, emitters, every bounce: noisy, so
//! a finer LOD is shown once its bake has converged far enough) and the direct light of
//! punctual lights (exact per texel, one shadow ray per light: no noise, so it is baked
//! straight at the LOD the screen wants). Sharp sun shadows need fine texels, the smoother
//! rest far fewer (the split of direct and indirect light real-time light maps make): near
//! the camera the punctual layer runs ahead of the bundle layer. Bilinear interpolation is
//! linear, so where both layers are at one LOD their sum is the bilinear of the summed
//! texels.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use glam::{Vec2, Vec3};
use serde::Serialize;

use super::policy::LayerLight;
use crate::grid::{CellId, Grid};
use crate::scene::{Rgb, luminance};

/// Side of a page, in pixels of its LOD. Small: a cell's texels at a fine LOD lie in many
/// small pieces over the atlas (its charts, scattered among other cells' charts), and a page
/// holds its pixels whether published or not. On zdm2 at LODs 2 and 3, published pixels fill
/// 14% and 8% of 64×64 pages, 24% and 35% of 16×16 ones (the page tables, one entry a page
/// position, grow 16-fold: a few MB at the finest LODs of the runtime's atlas).
pub const PAGE_SIDE: u32 = 16;
const PAGE_TEXELS: usize = (PAGE_SIDE * PAGE_SIDE) as usize;

/// Unique ids for pages (a written page is a new page).
static NEXT_PAGE_ID: AtomicU64 = AtomicU64::new(1);

/// 64×64 pixels of one LOD: rgb = irradiance E (W/m²), a = 1 where a texel (or a gutter pixel
/// copying one) was published, 0 elsewhere.
#[derive(Debug)]
pub struct Page {
    pub id: u64,
    pub texels: Box<[[f32; 4]]>,
    /// Pixels with a = 1.
    pub valid: u32,
}

impl Page {
    fn empty() -> Page {
        Page { id: NEXT_PAGE_ID.fetch_add(1, Ordering::Relaxed), texels: vec![[0.0; 4]; PAGE_TEXELS].into(), valid: 0 }
    }

    fn copy(&self) -> Page {
        Page { id: NEXT_PAGE_ID.fetch_add(1, Ordering::Relaxed), texels: self.texels.clone(), valid: self.valid }
    }

    pub const BYTES: usize = PAGE_TEXELS * 16;
}

/// One LOD's page table: `pages_y` rows of `pages_x` entries (rows are shared between
/// snapshots until written).
#[derive(Clone, Debug)]
pub struct LodPages {
    pub pages_x: u32,
    pub pages_y: u32,
    /// Written only by a [`PageWriter`], which keeps [`live`](Self::live) counted.
    pub rows: Vec<Arc<Vec<Option<Arc<Page>>>>>,
    /// Pages allocated: the memory budget asks at every pick of work, and a recount walked
    /// every page-table entry of every LOD (2.4% of a run's time on zdm2).
    live: usize,
}

impl LodPages {
    fn new(width: u64, height: u64) -> LodPages {
        let pages_x = width.div_ceil(PAGE_SIDE as u64) as u32;
        let pages_y = height.div_ceil(PAGE_SIDE as u64) as u32;
        let row = Arc::new(vec![None; pages_x as usize]);
        LodPages { pages_x, pages_y, rows: vec![row; pages_y as usize], live: 0 }
    }

    #[inline]
    pub fn page(&self, px: u32, py: u32) -> Option<&Arc<Page>> {
        self.rows.get(py as usize)?.get(px as usize)?.as_ref()
    }

    /// The published value of LOD pixel (x, y), if any.
    #[inline]
    pub fn texel(&self, x: i64, y: i64) -> Option<Rgb> {
        if x < 0 || y < 0 {
            return None;
        }
        let (x, y) = (x as u64, y as u64);
        let page = self.page((x / PAGE_SIDE as u64) as u32, (y / PAGE_SIDE as u64) as u32)?;
        published(page.texels[((y % PAGE_SIDE as u64) * PAGE_SIDE as u64 + x % PAGE_SIDE as u64) as usize])
    }

    /// Pages allocated.
    pub fn live_pages(&self) -> usize {
        debug_assert_eq!(self.live, self.rows.iter().map(|r| r.iter().filter(|p| p.is_some()).count()).sum::<usize>());
        self.live
    }

    /// Published pixels (texels and gutter pixels) over the allocated pages.
    pub fn published_pixels(&self) -> usize {
        self.rows.iter().flat_map(|r| r.iter().flatten()).map(|p| p.valid as usize).sum()
    }
}

/// A stored pixel's value if it is published (its weight channel set).
#[inline(always)]
fn published(t: [f32; 4]) -> Option<Rgb> {
    (t[3] > 0.0).then(|| Rgb::new(t[0], t[1], t[2]))
}

/// Bilinear blend at fraction `f` of the taps `tap(dx, dy)` (dx, dy ∈ {0, 1}) that are
/// published, renormalised over them; `None` when none is.
#[inline(always)]
fn blend(f: Vec2, tap: impl Fn(i64, i64) -> Option<Rgb>) -> Option<Rgb> {
    let mut sum = Rgb::ZERO;
    let mut wsum = 0.0;
    for (dx, dy, w) in
        [(0, 0, (1.0 - f.x) * (1.0 - f.y)), (1, 0, f.x * (1.0 - f.y)), (0, 1, (1.0 - f.x) * f.y), (1, 1, f.x * f.y)]
    {
        if let Some(e) = tap(dx, dy) {
            sum += e * w;
            wsum += w;
        }
    }
    (wsum > 0.0).then(|| sum / wsum)
}

/// Which part of the light a layer of the shown map holds (module docs); the irradiance is
/// their sum.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Layer {
    /// What the bundles compute: the sky, emissive surfaces and every bounce, filtered within
    /// charts; a finer LOD is shown once its bake has converged far enough.
    Bundles = 0,
    /// The direct light of punctual lights (shadow rays): exact, baked at the LOD wanted.
    Punctual = 1,
}

impl Layer {
    pub const ALL: [Layer; 2] = [Layer::Bundles, Layer::Punctual];
}

/// One layer's sparse pyramid and each cell's LOD in it.
#[derive(Clone, Debug)]
pub struct LayerPages {
    /// Shown LOD of each cell (every cell starts at 0).
    pub cell_lod: Arc<Vec<u8>>,
    pub levels: Vec<LodPages>,
    /// Something was published in this layer (an unused layer adds nothing to a sample and
    /// is skipped: scenes without punctual lights pay nothing for it).
    pub used: bool,
}

impl LayerPages {
    fn new(cells: usize, atlas_width: u32, atlas_height: u32, levels: u32) -> LayerPages {
        LayerPages {
            cell_lod: Arc::new(vec![0; cells]),
            levels: (0..levels.max(1))
                .map(|k| LodPages::new((atlas_width as u64) << k, (atlas_height as u64) << k))
                .collect(),
            used: false,
        }
    }

    /// Bilinear at LOD `k` over published pixels only (missing taps weigh 0, the rest are
    /// renormalised); where LOD `k` has none of the four, the next coarser level.
    pub fn bilinear(&self, k: u32, uv_lod0: Vec2) -> Rgb {
        let mut k = k.min(self.levels.len() as u32 - 1) as i64;
        while k >= 0 {
            let q = uv_lod0 * (1u64 << k) as f32 - Vec2::splat(0.5);
            let base = q.floor();
            let f = q - base;
            let (bx, by) = (base.x as i64, base.y as i64);
            let level = &self.levels[k as usize];
            let side = PAGE_SIDE as i64;
            // The four taps lie in one page unless the footprint straddles a page border
            // (15 of 16 rows and columns): the page is then found once, not per tap (the
            // taps are the bundles' foreign lookups, a tenth of a cell bake's time on zdm2).
            let blended = if bx >= 0 && by >= 0 && bx % side != side - 1 && by % side != side - 1 {
                match level.page((bx / side) as u32, (by / side) as u32) {
                    Some(page) => {
                        let first = ((by % side) * side + bx % side) as usize;
                        blend(f, |dx, dy| published(page.texels[first + (dy * side + dx) as usize]))
                    }
                    None => None,
                }
            } else {
                blend(f, |dx, dy| level.texel(bx + dx, by + dy))
            };
            if let Some(e) = blended {
                return e;
            }
            k -= 1;
        }
        Rgb::ZERO
    }

    /// Pages allocated, over every LOD.
    pub fn live_pages(&self) -> usize {
        self.levels.iter().map(|l| l.live_pages()).sum()
    }
}

/// An immutable snapshot of the shown light map.
#[derive(Clone, Debug)]
pub struct ShownLightmap {
    pub grid: Grid,
    /// LOD-0 atlas size in texels; LOD k is `2^k` times larger.
    pub atlas_width: u32,
    pub atlas_height: u32,
    /// Width (metres) of the band along a border with a cell shown at LOD 0 over which the
    /// finer cell blends into it (toward LOD k: this over 2^k, [`ShownLightmap::band_toward`]).
    pub blend_band: f32,
    /// Indexed by [`Layer`].
    pub layers: [LayerPages; 2],
    /// Incremented by every publish or eviction.
    pub version: u64,
}

impl ShownLightmap {
    /// An empty map (nothing published: every sample is 0) for `levels` LODs.
    pub fn new(grid: Grid, atlas_width: u32, atlas_height: u32, levels: u32, blend_band: f32) -> Self {
        let layer = || LayerPages::new(grid.len(), atlas_width, atlas_height, levels);
        ShownLightmap { grid, atlas_width, atlas_height, blend_band, layers: [layer(), layer()], version: 0 }
    }

    pub fn lods(&self) -> u32 {
        self.layers[0].levels.len() as u32
    }

    pub fn layer(&self, layer: Layer) -> &LayerPages {
        &self.layers[layer as usize]
    }

    /// The LOD `cell` shows in `layer`.
    pub fn cell_lod(&self, layer: Layer, cell: CellId) -> u32 {
        self.layers[layer as usize].cell_lod[cell as usize] as u32
    }

    /// The finest LOD any cell shows in any layer.
    pub fn finest_lod(&self) -> u32 {
        self.layers.iter().flat_map(|l| l.cell_lod.iter()).copied().max().unwrap_or(0) as u32
    }

    /// Follows an atlas that grew taller (hot reload: nothing moved, rows were added below):
    /// every level gets page rows for the new height. A change of width (every pixel index
    /// moves) needs a new map instead, and is ignored here.
    pub fn resize(&mut self, atlas_width: u32, atlas_height: u32) {
        if atlas_width != self.atlas_width || atlas_height <= self.atlas_height {
            return;
        }
        for layer in self.layers.iter_mut() {
            for (k, level) in layer.levels.iter_mut().enumerate() {
                let rows = ((atlas_height as u64) << k).div_ceil(PAGE_SIDE as u64) as u32;
                let row = Arc::new(vec![None; level.pages_x as usize]);
                level.rows.resize(rows as usize, row);
                level.pages_y = rows;
            }
        }
        self.atlas_height = atlas_height;
    }

    /// Takes LOD `lod` of both layers from `other` (a map of the same shape), keeping every
    /// other level and the cells' LODs: first light's successive showings of LOD 0 replace
    /// only LOD 0, whatever finer punctual levels were published meanwhile.
    pub fn adopt_level(&mut self, other: &ShownLightmap, lod: u32) {
        for (mine, theirs) in self.layers.iter_mut().zip(&other.layers) {
            if let (Some(a), Some(b)) = (mine.levels.get_mut(lod as usize), theirs.levels.get(lod as usize)) {
                *a = b.clone();
            }
            mine.used |= theirs.used;
        }
        self.version = self.version.max(other.version) + 1;
    }

    /// Irradiance (W/m²) of the surface point at world `position` whose light-map UV (of the
    /// side being looked at, LOD-0 texel units) is `uv_lod0`: per layer, the cell of the
    /// point, its LOD in that layer, bilinear within the chart there, blended toward a
    /// coarser face-neighbour near their shared border (module docs); the layers summed.
    pub fn irradiance(&self, position: Vec3, uv_lod0: Vec2) -> Rgb {
        let cell = self.grid.cell_of(position);
        let mut e = self.layer_irradiance(Layer::Bundles, cell, position, uv_lod0);
        if self.layers[Layer::Punctual as usize].used {
            e += self.layer_irradiance(Layer::Punctual, cell, position, uv_lod0);
        }
        e
    }

    /// One layer's part of [`ShownLightmap::irradiance`].
    pub fn layer_irradiance(&self, layer: Layer, cell: CellId, position: Vec3, uv_lod0: Vec2) -> Rgb {
        let pages = &self.layers[layer as usize];
        let k = pages.cell_lod[cell as usize] as u32;
        let fine = pages.bilinear(k, uv_lod0);
        match self.border_blend(&pages.cell_lod, cell, k, position) {
            Some((w, k_low)) => fine * (1.0 - w) + pages.bilinear(k_low, uv_lod0) * w,
            None => fine,
        }
    }

    /// Both layers' [`LayerPages::bilinear`] at LOD `k`, summed.
    pub fn bilinear(&self, k: u32, uv_lod0: Vec2) -> Rgb {
        self.layers.iter().filter(|l| l.used).map(|l| l.bilinear(k, uv_lod0)).fold(Rgb::ZERO, |a, b| a + b)
    }

    /// Width (metres) of the band in which a cell blends toward a face-neighbour shown at
    /// LOD `k_low`: [`ShownLightmap::blend_band`] halved per level, so the band is a couple of
    /// the coarser side's texels wide (what its values differ by) and a cell at a fine LOD
    /// blends only near its border, whatever it borders.
    pub fn band_toward(&self, k_low: u32) -> f32 {
        self.blend_band / (1u64 << k_low) as f32
    }

    /// Near a face shared with a coarser neighbour (LODs `cell_lod` of one layer): the blend
    /// weight toward it (1 on the face, 0 at [`ShownLightmap::band_toward`] its LOD inside)
    /// and the coarsest such neighbour's LOD.
    fn border_blend(&self, cell_lod: &[u8], cell: CellId, k: u32, p: Vec3) -> Option<(f32, u32)> {
        if k == 0 || self.blend_band <= 0.0 {
            return None;
        }
        let (lo, hi) = self.grid.bounds(cell);
        let mut best: Option<(f32, u32)> = None;
        for axis in 0..3 {
            for (step, d) in [(-1, p[axis] - lo[axis]), (1, hi[axis] - p[axis])] {
                if d >= self.blend_band {
                    continue;
                }
                let Some(n) = self.grid.neighbour(cell, axis, step) else { continue };
                let kn = cell_lod[n as usize] as u32;
                let band = self.band_toward(kn);
                if kn >= k || d >= band {
                    continue;
                }
                let w = (1.0 - d.max(0.0) / band).clamp(0.0, 1.0);
                best = Some(match best {
                    Some((bw, bk)) => (bw.max(w), bk.min(kn)),
                    None => (w, kn),
                });
            }
        }
        best
    }

    /// The pixel rectangle `(x0, y0, x1, y1)` of LOD `lod` covered by allocated pages of
    /// either layer, if any.
    pub fn published_rect(&self, lod: u32) -> Option<(u64, u64, u64, u64)> {
        let (mut a, mut b) = ((u64::MAX, u64::MAX), (0u64, 0u64));
        for layer in &self.layers {
            let Some(level) = layer.levels.get(lod as usize) else { continue };
            for (py, row) in level.rows.iter().enumerate() {
                for (px, page) in row.iter().enumerate() {
                    if page.is_some() {
                        a = (a.0.min(px as u64), a.1.min(py as u64));
                        b = (b.0.max(px as u64 + 1), b.1.max(py as u64 + 1));
                    }
                }
            }
        }
        let side = PAGE_SIDE as u64;
        let (w, h) = ((self.atlas_width as u64) << lod, (self.atlas_height as u64) << lod);
        (a.0 != u64::MAX).then(|| (a.0 * side, a.1 * side, (b.0 * side).min(w), (b.1 * side).min(h)))
    }

    /// Irradiance of LOD `lod`'s pixels in the rectangle `(x0, y0, x1, y1)`, row-major: where
    /// either layer published the pixel, both layers' values there (a layer without it at
    /// this LOD read at its centre through [`LayerPages::bilinear`], from a coarser level);
    /// 0 elsewhere.
    pub fn level_pixels(&self, lod: u32, rect: (u64, u64, u64, u64)) -> Vec<Rgb> {
        let (x0, y0, x1, y1) = rect;
        let scale = 1.0 / (1u64 << lod) as f32;
        let mut out = Vec::with_capacity(((x1 - x0) * (y1 - y0)) as usize);
        for y in y0..y1 {
            for x in x0..x1 {
                let own: Vec<Option<Rgb>> = self
                    .layers
                    .iter()
                    .map(|l| l.levels.get(lod as usize).and_then(|level| level.texel(x as i64, y as i64)))
                    .collect();
                if own.iter().all(Option::is_none) {
                    out.push(Rgb::ZERO);
                    continue;
                }
                let centre = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) * scale;
                let e = self
                    .layers
                    .iter()
                    .zip(&own)
                    .filter(|(l, _)| l.used)
                    .map(|(l, t)| t.unwrap_or_else(|| l.bilinear(lod, centre)))
                    .fold(Rgb::ZERO, |a, b| a + b);
                out.push(e);
            }
        }
        out
    }

    /// Bytes of the pages held (both layers).
    pub fn page_bytes(&self) -> usize {
        self.live_pages() * Page::BYTES
    }

    /// Pages held (both layers).
    pub fn live_pages(&self) -> usize {
        self.layers.iter().map(|l| l.live_pages()).sum::<usize>()
    }

    /// The share of the held pages' pixels that are published (both layers): how much of
    /// the page memory holds light.
    pub fn page_fill(&self) -> f64 {
        let pixels: usize = self.layers.iter().flat_map(|l| l.levels.iter()).map(|l| l.published_pixels()).sum();
        match self.live_pages() {
            0 => 1.0,
            pages => pixels as f64 / (pages * PAGE_TEXELS) as f64,
        }
    }

    /// A bound on any channel of [`ShownLightmap::irradiance`] anywhere: the layers' largest
    /// published channels, summed (a sample is a convex blend of published pixels of each
    /// used layer). Reads every page.
    pub fn max_irradiance(&self) -> f32 {
        let layer_max = |l: &LayerPages| {
            let pages = l.levels.iter().flat_map(|level| level.rows.iter().flat_map(|row| row.iter().flatten()));
            pages
                .flat_map(|p| p.texels.iter())
                .filter(|t| t[3] > 0.0)
                .fold(0f32, |m, t| m.max(t[0]).max(t[1]).max(t[2]))
        };
        self.layers.iter().filter(|l| l.used).map(layer_max).sum()
    }

    /// The light `layer` shows at LOD `lod` over `pixels` (a cell's published pixels there):
    /// their mean luminance and relative detail ([`LayerLight`]), each pixel against the
    /// tent-weighted mean of its published 8-neighbours at that LOD. A gutter pixel copies
    /// the texel beside it, so pixels of other charts across a gutter never meet.
    pub fn layer_light(&self, layer: Layer, lod: u32, pixels: &[[u32; 2]]) -> LayerLight {
        let Some(level) = self.layers[layer as usize].levels.get(lod as usize) else {
            return LayerLight::default();
        };
        let lum = |x: i64, y: i64| level.texel(x, y).map(luminance);
        LayerLight::of(pixels.iter().filter_map(|&[x, y]| {
            let (x, y) = (x as i64, y as i64);
            let v = lum(x, y)?;
            let (mut sum, mut wsum) = (0.0, 0.0);
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    if (dx, dy) == (0, 0) {
                        continue;
                    }
                    if let Some(n) = lum(x + dx, y + dy) {
                        let w = ((2 - dx.abs()) * (2 - dy.abs())) as f32;
                        sum += n * w;
                        wsum += w;
                    }
                }
            }
            Some((v, if wsum > 0.0 { (v - sum / wsum).powi(2) } else { f32::NAN }))
        }))
    }

    /// Published pixels (of either layer, any LOD) holding a non-finite value.
    pub fn non_finite_pixels(&self) -> usize {
        let pages = self
            .layers
            .iter()
            .flat_map(|l| l.levels.iter().flat_map(|level| level.rows.iter().flat_map(|row| row.iter().flatten())));
        pages.flat_map(|p| p.texels.iter()).filter(|t| t[3] > 0.0 && !t[..3].iter().all(|v| v.is_finite())).count()
    }

    /// Cells shown at each LOD in `layer`.
    pub fn cells_per_lod(&self, layer: Layer) -> Vec<usize> {
        let l = &self.layers[layer as usize];
        let mut counts = vec![0; l.levels.len()];
        for &k in l.cell_lod.iter() {
            counts[k as usize] += 1;
        }
        counts
    }
}

/// Where a page of the shown map lies: its layer, LOD and page position (pixels
/// `px·PAGE_SIDE..` and `py·PAGE_SIDE..` of that LOD).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct PageKey {
    pub layer: Layer,
    pub lod: u32,
    pub px: u32,
    pub py: u32,
}

/// What became of one page position between two snapshots ([`ShownLightmap::changed_pages`]).
#[derive(Clone, Debug)]
pub enum PageChange {
    /// A page written (or allocated) since: its new content.
    Written(PageKey, Arc<Page>),
    /// A page freed since (an eviction, or a publish that emptied it).
    Dropped(PageKey),
}

impl ShownLightmap {
    /// The pages `self` holds that `before` does not (by id: a publish gives every page it
    /// writes a new id) and the ones `before` held that `self` no longer has: what a mirror of
    /// `before` must take to become `self`. A publish's change is exactly the pages its cells
    /// wrote. Rows the two snapshots share are skipped unread. `None`, or a `before` of
    /// another shape (a reload that repacked the atlas), compares with an empty map: every
    /// live page.
    pub fn changed_pages(&self, before: Option<&ShownLightmap>) -> Vec<PageChange> {
        let mut out = Vec::new();
        for layer in Layer::ALL {
            let now = &self.layers[layer as usize];
            let then = before.map(|b| &b.layers[layer as usize]);
            for (k, level) in now.levels.iter().enumerate() {
                let old = then.and_then(|t| t.levels.get(k)).filter(|o| {
                    o.pages_x == level.pages_x && before.is_some_and(|b| b.atlas_width == self.atlas_width)
                });
                for py in 0..level.pages_y {
                    let row = &level.rows[py as usize];
                    let old_row = old.and_then(|o| o.rows.get(py as usize));
                    if old_row.is_some_and(|r| Arc::ptr_eq(r, row)) {
                        continue;
                    }
                    for px in 0..level.pages_x {
                        let key = PageKey { layer, lod: k as u32, px, py };
                        let was = old_row.and_then(|r| r.get(px as usize)).and_then(|p| p.as_ref());
                        match (row.get(px as usize).and_then(|p| p.as_ref()), was) {
                            (Some(p), Some(w)) if p.id == w.id => {}
                            (Some(p), _) => out.push(PageChange::Written(key, p.clone())),
                            (None, Some(_)) => out.push(PageChange::Dropped(key)),
                            (None, None) => {}
                        }
                    }
                }
            }
        }
        out
    }
}

/// Writes LOD pixels into a copy of a snapshot: pages are copied (or made) on first write,
/// page-table rows on first change.
pub struct PageWriter<'a> {
    map: &'a mut ShownLightmap,
    /// Pages already copied by this writer (their ids), so a page is copied once.
    fresh: std::collections::HashSet<u64>,
}

impl<'a> PageWriter<'a> {
    pub fn new(map: &'a mut ShownLightmap) -> Self {
        PageWriter { map, fresh: Default::default() }
    }

    fn page_mut(&mut self, layer: Layer, lod: u32, px: u32, py: u32, create: bool) -> Option<&mut Page> {
        let level = &mut self.map.layers[layer as usize].levels[lod as usize];
        let row = Arc::make_mut(level.rows.get_mut(py as usize)?);
        let slot = row.get_mut(px as usize)?;
        match slot {
            Some(page) if self.fresh.contains(&page.id) => {}
            Some(page) => {
                let copy = Arc::new(page.copy());
                self.fresh.insert(copy.id);
                *slot = Some(copy);
            }
            None if create => {
                let page = Arc::new(Page::empty());
                self.fresh.insert(page.id);
                *slot = Some(page);
                level.live += 1;
            }
            None => return None,
        }
        // The page was made or copied by this writer: nobody else holds it.
        slot.as_mut().and_then(Arc::get_mut)
    }

    /// Publishes `e` at LOD pixel (x, y) of `layer`.
    pub fn write(&mut self, layer: Layer, lod: u32, x: u32, y: u32, e: Rgb) {
        let (px, py) = (x / PAGE_SIDE, y / PAGE_SIDE);
        self.map.layers[layer as usize].used = true;
        if let Some(page) = self.page_mut(layer, lod, px, py, true) {
            let t = &mut page.texels[((y % PAGE_SIDE) * PAGE_SIDE + x % PAGE_SIDE) as usize];
            if t[3] == 0.0 {
                page.valid += 1;
            }
            *t = [e.x, e.y, e.z, 1.0];
        }
    }

    /// Withdraws LOD pixel (x, y) of `layer`; a page left with no valid pixel is freed.
    pub fn clear(&mut self, layer: Layer, lod: u32, x: u32, y: u32) {
        let (px, py) = (x / PAGE_SIDE, y / PAGE_SIDE);
        let mut empty = false;
        if let Some(page) = self.page_mut(layer, lod, px, py, false) {
            let t = &mut page.texels[((y % PAGE_SIDE) * PAGE_SIDE + x % PAGE_SIDE) as usize];
            if t[3] != 0.0 {
                *t = [0.0; 4];
                page.valid -= 1;
            }
            empty = page.valid == 0;
        }
        if empty {
            let level = &mut self.map.layers[layer as usize].levels[lod as usize];
            Arc::make_mut(&mut level.rows[py as usize])[px as usize] = None;
            level.live -= 1;
        }
    }

    /// Shows `cell` at `lod` in `layer`.
    pub fn set_cell_lod(&mut self, layer: Layer, cell: CellId, lod: u32) {
        Arc::make_mut(&mut self.map.layers[layer as usize].cell_lod)[cell as usize] = lod as u8;
    }

    /// Ends the edit: the snapshot gets a new version.
    pub fn finish(self) {
        self.map.version += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A snapshot's change against the one before it is exactly the pages the publish
    /// wrote (new content) and the ones it freed; against nothing, every live page.
    #[test]
    fn changed_pages_are_what_a_publish_wrote() {
        let mut a = ShownLightmap::new(grid(), 4 * PAGE_SIDE, 2 * PAGE_SIDE, 2, 0.0);
        let mut w = PageWriter::new(&mut a);
        w.write(Layer::Bundles, 0, 1, 1, Rgb::ONE);
        w.write(Layer::Bundles, 0, 2 * PAGE_SIDE + 2, 1, Rgb::ONE);
        w.finish();
        assert_eq!(a.changed_pages(None).len(), 2);
        let mut b = a.clone();
        let mut w = PageWriter::new(&mut b);
        w.write(Layer::Bundles, 0, 3, PAGE_SIDE + 1, Rgb::splat(2.0));
        w.write(Layer::Punctual, 1, 5, 5, Rgb::splat(3.0));
        w.clear(Layer::Bundles, 0, 2 * PAGE_SIDE + 2, 1);
        w.finish();
        let mut written: Vec<(PageKey, f32)> = Vec::new();
        let mut dropped = Vec::new();
        for c in b.changed_pages(Some(&a)) {
            match c {
                PageChange::Written(k, p) => written.push((k, p.texels.iter().map(|t| t[0]).sum())),
                PageChange::Dropped(k) => dropped.push(k),
            }
        }
        written.sort_by_key(|(k, _)| (k.layer as u8, k.lod, k.py, k.px));
        assert_eq!(
            written,
            vec![
                (PageKey { layer: Layer::Bundles, lod: 0, px: 0, py: 1 }, 2.0),
                (PageKey { layer: Layer::Punctual, lod: 1, px: 0, py: 0 }, 3.0),
            ]
        );
        assert_eq!(dropped, vec![PageKey { layer: Layer::Bundles, lod: 0, px: 2, py: 0 }]);
        assert!(b.changed_pages(Some(&b)).is_empty());
    }

    fn grid() -> Grid {
        Grid::covering(Vec3::ZERO, Vec3::new(2.0, 1.0, 1.0), 1.0).unwrap()
    }

    /// Bilinear weights between published pixels, renormalised over the published ones, and
    /// the fall-back to the coarser level where a finer one has nothing.
    #[test]
    fn bilinear_uses_published_texels_and_falls_back_to_coarser_levels() {
        let mut map = ShownLightmap::new(grid(), 8, 8, 2, 0.0);
        let mut w = PageWriter::new(&mut map);
        w.write(Layer::Bundles, 0, 2, 2, Rgb::splat(1.0));
        w.write(Layer::Bundles, 0, 3, 2, Rgb::splat(3.0));
        w.finish();
        // Midway between the two pixel centres of LOD 0: their mean.
        assert_eq!(map.bilinear(0, Vec2::new(3.0, 2.5)), Rgb::splat(2.0));
        // A quarter of the way: 0.75·1 + 0.25·3 (rows 1 and 3 unpublished: renormalised).
        assert_eq!(map.bilinear(0, Vec2::new(2.75, 2.2)), Rgb::splat(1.5));
        // LOD 1 has nothing there: LOD 0 answers.
        assert_eq!(map.bilinear(1, Vec2::new(3.0, 2.5)), Rgb::splat(2.0));
        let mut w = PageWriter::new(&mut map);
        w.write(Layer::Bundles, 1, 5, 4, Rgb::splat(7.0));
        w.finish();
        assert_eq!(map.bilinear(1, Vec2::new(2.75, 2.25)), Rgb::splat(7.0));
        assert_eq!(map.bilinear(0, Vec2::new(100.0, 100.0)), Rgb::ZERO);
    }

    /// Wherever the taps fall (within a page, across its borders, off the map, on pages
    /// partly published), the bilinear read is, to the bit, the blend of the four pixels
    /// read one by one, renormalised over the published ones — and where none of the four
    /// is published, the coarser level's. (Footprints within one page read the page once.)
    #[test]
    fn bilinear_reads_the_same_whether_or_not_the_taps_share_a_page() {
        let side = 3 * PAGE_SIDE;
        let mut map = ShownLightmap::new(grid(), side, side, 2, 0.0);
        let mut rng = crate::sampling::Rng::new(41, 0);
        let mut w = PageWriter::new(&mut map);
        // LOD 1 is 6×6 pages: publish two thirds of its pixels, each page's own share.
        for y in 0..2 * side {
            for x in 0..2 * side {
                if rng.next_f32() < 0.67 {
                    w.write(Layer::Bundles, 1, x, y, Rgb::new(rng.next_f32(), 1.0 + rng.next_f32(), x as f32));
                }
            }
        }
        w.write(Layer::Bundles, 0, 7, 7, Rgb::splat(5.0));
        w.finish();
        let pages = &map.layers[0];
        let (mut straddling, mut fell_back) = (0, 0);
        for i in 0..20_000 {
            // Every tenth near a page border (pixel 15 of 16), the rest anywhere (and a little
            // beyond the map).
            let uv = if i % 10 == 0 {
                let border = (PAGE_SIDE * (1 + rng.next_u32() % 4) - 1) as f32 / 2.0;
                Vec2::new(border + 0.5 + 0.49 * rng.next_f32(), rng.next_f32() * side as f32)
            } else {
                Vec2::new(rng.next_f32(), rng.next_f32()) * (side as f32 + 2.0) - Vec2::splat(1.0)
            };
            let q = uv * 2.0 - Vec2::splat(0.5);
            let (base, f) = (q.floor(), q - q.floor());
            let (bx, by) = (base.x as i64, base.y as i64);
            straddling += usize::from(bx.rem_euclid(PAGE_SIDE as i64) == PAGE_SIDE as i64 - 1);
            let level = &pages.levels[1];
            let taps = [
                (level.texel(bx, by), (1.0 - f.x) * (1.0 - f.y)),
                (level.texel(bx + 1, by), f.x * (1.0 - f.y)),
                (level.texel(bx, by + 1), (1.0 - f.x) * f.y),
                (level.texel(bx + 1, by + 1), f.x * f.y),
            ];
            let (mut sum, mut wsum) = (Rgb::ZERO, 0.0);
            for (e, w) in taps {
                if let Some(e) = e {
                    sum += e * w;
                    wsum += w;
                }
            }
            let expected = if wsum > 0.0 {
                sum / wsum
            } else {
                fell_back += 1;
                pages.bilinear(0, uv)
            };
            let got = pages.bilinear(1, uv);
            assert_eq!(got.to_array().map(f32::to_bits), expected.to_array().map(f32::to_bits), "at {uv}");
        }
        assert!(straddling > 1000 && fell_back > 100, "{straddling} straddling, {fell_back} fell back");
    }

    /// The pages a layer counts are those its page tables hold, through writes that make
    /// pages, clears that empty them, and snapshots that share them.
    #[test]
    fn live_pages_count_the_allocated_pages() {
        let recount = |m: &ShownLightmap| -> usize {
            m.layers.iter().flat_map(|l| &l.levels).flat_map(|l| &l.rows).map(|r| r.iter().flatten().count()).sum()
        };
        let mut map = ShownLightmap::new(grid(), 4 * PAGE_SIDE, 4 * PAGE_SIDE, 2, 0.0);
        let mut rng = crate::sampling::Rng::new(43, 0);
        let mut snapshots = Vec::new();
        for round in 0..6 {
            let mut w = PageWriter::new(&mut map);
            for _ in 0..300 {
                let layer = if rng.next_f32() < 0.5 { Layer::Bundles } else { Layer::Punctual };
                let lod = rng.next_u32() % 2;
                let size = (4 * PAGE_SIDE) << lod;
                let (x, y) = (rng.next_u32() % size, rng.next_u32() % size);
                // More writes early, more clears late: pages fill up, then empty.
                if rng.next_f32() < 0.8 - 0.12 * round as f32 {
                    w.write(layer, lod, x, y, Rgb::ONE);
                } else {
                    w.clear(layer, lod, x, y);
                }
            }
            w.finish();
            assert_eq!(map.live_pages(), recount(&map), "round {round}");
            snapshots.push(map.clone());
        }
        for s in &snapshots {
            assert_eq!(s.live_pages(), recount(s));
        }
        assert!(snapshots.iter().any(|s| s.live_pages() > 10));
    }

    /// Copy-on-write: a publish leaves the old snapshot as it was, gives written pages new
    /// ids, shares untouched pages, and frees pages left empty.
    #[test]
    fn publishing_copies_only_what_it_writes() {
        let mut a = ShownLightmap::new(grid(), 4 * PAGE_SIDE, 2 * PAGE_SIDE, 1, 0.0);
        let mut w = PageWriter::new(&mut a);
        w.write(Layer::Bundles, 0, 1, 1, Rgb::ONE);
        w.write(Layer::Bundles, 0, 2 * PAGE_SIDE + 2, 1, Rgb::ONE);
        w.finish();
        let mut b = a.clone();
        let mut w = PageWriter::new(&mut b);
        w.write(Layer::Bundles, 0, 2, 1, Rgb::splat(2.0));
        w.write(Layer::Bundles, 0, 3, 1, Rgb::splat(2.0));
        w.set_cell_lod(Layer::Bundles, 1, 0);
        w.finish();
        let (pa, pb) = (a.layers[0].levels[0].page(0, 0).unwrap(), b.layers[0].levels[0].page(0, 0).unwrap());
        assert_ne!(pa.id, pb.id);
        assert_eq!((pa.valid, pb.valid), (1, 3));
        assert_eq!(a.layers[0].levels[0].texel(2, 1), None);
        assert!(Arc::ptr_eq(a.layers[0].levels[0].page(2, 0).unwrap(), b.layers[0].levels[0].page(2, 0).unwrap()));
        assert_eq!(b.version, a.version + 1);
        let mut c = b.clone();
        let mut w = PageWriter::new(&mut c);
        w.clear(Layer::Bundles, 0, 2 * PAGE_SIDE + 2, 1);
        w.finish();
        assert!(c.layers[0].levels[0].page(2, 0).is_none());
        assert_eq!(c.page_bytes(), Page::BYTES);
    }

    /// Across a border with a coarser neighbour the fine side blends to the coarse value on
    /// the shared face, so the two sides meet; away from the band it shows its own LOD.
    #[test]
    fn borders_with_coarser_cells_blend_continuously() {
        let mut map = ShownLightmap::new(grid(), 4, 4, 2, 0.25);
        let mut w = PageWriter::new(&mut map);
        for y in 0..4 {
            for x in 0..4 {
                w.write(Layer::Bundles, 0, x, y, Rgb::splat(1.0));
            }
        }
        for y in 0..8 {
            for x in 0..8 {
                w.write(Layer::Bundles, 1, x, y, Rgb::splat(2.0));
            }
        }
        w.set_cell_lod(Layer::Bundles, 0, 1); // cell 0 (x < 1 m) at LOD 1, cell 1 at LOD 0
        w.finish();
        let uv = Vec2::new(2.0, 2.0);
        let at = |x: f32| map.irradiance(Vec3::new(x, 0.5, 0.5), uv).x;
        assert_eq!(at(0.5), 2.0);
        assert!((at(0.999_99) - 1.0).abs() < 1e-3, "{}", at(0.999_99));
        assert_eq!(at(1.0001), 1.0);
        assert!((at(0.875) - 1.5).abs() < 1e-5, "{}", at(0.875));
    }

    /// The two layers add up, each at its own LOD per cell, each blending at borders by its
    /// own LODs; an unused layer adds nothing, and the pixels written out per LOD hold both.
    #[test]
    fn layers_add_up_each_at_its_own_lod() {
        let mut map = ShownLightmap::new(grid(), 4, 4, 3, 0.25);
        let mut w = PageWriter::new(&mut map);
        for y in 0..4 {
            for x in 0..4 {
                w.write(Layer::Bundles, 0, x, y, Rgb::splat(1.0));
            }
        }
        w.finish();
        let uv = Vec2::new(2.0, 2.0);
        let at = |map: &ShownLightmap, x: f32| map.irradiance(Vec3::new(x, 0.5, 0.5), uv).x;
        assert_eq!(at(&map, 0.5), 1.0);
        assert!(!map.layer(Layer::Punctual).used);
        let mut w = PageWriter::new(&mut map);
        for y in 0..4 {
            for x in 0..4 {
                w.write(Layer::Punctual, 0, x, y, Rgb::splat(10.0));
            }
        }
        for y in 0..16 {
            for x in 0..16 {
                w.write(Layer::Punctual, 2, x, y, Rgb::splat(20.0));
            }
        }
        // Cell 0 shows the punctual layer at LOD 2, cell 1 at LOD 0; the bundles at 0 in both.
        w.set_cell_lod(Layer::Punctual, 0, 2);
        w.finish();
        assert_eq!(at(&map, 0.5), 21.0);
        assert_eq!(at(&map, 1.5), 11.0);
        // The punctual layer blends toward cell 1's LOD 0 at their border; the bundles do not.
        assert!((at(&map, 0.999_99) - 11.0).abs() < 1e-3, "{}", at(&map, 0.999_99));
        assert!((at(&map, 0.875) - 16.0).abs() < 1e-4, "{}", at(&map, 0.875));
        assert_eq!(map.finest_lod(), 2);
        assert_eq!(map.cells_per_lod(Layer::Punctual), vec![map.grid.len() - 1, 0, 1]);
        // LOD 2's pixels: the punctual texel there plus the bundles read from their LOD 0.
        let rect = map.published_rect(2).unwrap();
        assert_eq!(rect, (0, 0, 16, 16));
        assert!(map.level_pixels(2, rect).iter().all(|e| *e == Rgb::splat(21.0)));
        // LOD 1: nothing published in either layer.
        assert!(map.published_rect(1).is_none());
    }
}
