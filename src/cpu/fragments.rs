//! One tile's fragments on the CPU, produced and resolved row by row.
//!
//! The GPU builds per-pixel linked lists in a node buffer of capacity N. The CPU honours the
//! same budget — [`prepare`](TileFragments::prepare) counts the tile's fragments exactly and
//! the caller splits a tile that exceeds N — but never stores a tile's fragments: the count
//! pass keeps the covered spans, bucketed by row, and [`resolve`](TileFragments::resolve)
//! turns one row at a time into per-pixel lists in a row buffer that stays in L1. (A whole
//! tile's lists were ~12 MB at 1 M fragments; writing, sorting and re-reading them was most
//! of the build's time.)
//!
//! A pixel's fragments arrive in triangle order and are insertion-sorted, which is stable:
//! ties keep a deterministic order, and results do not depend on how tiles were split.

use super::prepared::{NO_GROUP, PreparedScene};
use crate::atlas::texels::NO_TEXEL;
use crate::bundle::estimator::{EMITTER_FLAG, FRONT_LOOKS_PLUS, Fragment, NO_SIDE, sort_by_depth};
use crate::bundle::raster::{BundleFrame, Planes, ScreenTriangle, Viewport};
use glam::Vec2;

/// A triangle set up for the current viewport.
struct TileTriangle {
    /// Index into the scene's triangles.
    index: u32,
    screen: ScreenTriangle,
    /// Belongs to the emitter group of the current light pass.
    emitter: bool,
}

/// What a triangle's fragments carry, as affine functions of grid pixel coordinates:
/// depth, and per lit side the UV (LOD pixels) that locates its texel. Only built tiles need
/// them, so they are set up after the count.
struct TileAttributes {
    planes: Planes,
    plus: Option<TileSide>,
    minus: Option<TileSide>,
}

/// A lit side of a triangle in the current viewport: its UV as an affine function of grid
/// pixel coordinates.
struct TileSide {
    gradient: [Vec2; 3],
}

/// Pixels `x0..x1` of one row covered by triangle `tri` (an index into the tile's triangles).
#[derive(Clone, Copy, Debug)]
struct Span {
    tri: u32,
    x0: u32,
    x1: u32,
}

/// Reusable buffers of one worker.
#[derive(Default)]
pub struct TileFragments {
    width: u32,
    tris: Vec<TileTriangle>,
    attributes: Vec<TileAttributes>,
    /// A light pass: only pixels an emitter covers are resolved (no other pixel can receive
    /// light from it).
    emitters_only: bool,
    /// Row r's spans, in triangle order, are `spans[row_start[r]..][..row_len[r]]`; a row's
    /// slots are sized for every triangle whose rows include it.
    row_start: Vec<u32>,
    row_len: Vec<u32>,
    spans: Vec<Span>,
    /// Row buffer: pixel p of the resolved part of the row owns `frags[ends[p]..ends[p + 1]]`.
    ends: Vec<u32>,
    frags: Vec<Fragment>,
    /// Fragments whose UV fell outside every texel through rounding (they still occlude).
    pub lost_lookups: u64,
}

fn tile_side(planes: &Planes, uv: [Vec2; 3]) -> TileSide {
    let gx = planes.gradient([uv[0].x, uv[1].x, uv[2].x]);
    let gy = planes.gradient([uv[0].y, uv[1].y, uv[2].y]);
    TileSide { gradient: [Vec2::new(gx[0], gy[0]), Vec2::new(gx[1], gy[1]), Vec2::new(gx[2], gy[2])] }
}

impl TileFragments {
    /// Sets up `candidates` for `viewport`, keeps their covered spans and counts their
    /// fragments. `emitter_group` makes this a light pass of that group. Returns the count.
    pub fn prepare(
        &mut self,
        scene: &PreparedScene,
        frame: &BundleFrame,
        viewport: &Viewport,
        candidates: &[u32],
        emitter_group: Option<u32>,
    ) -> u64 {
        self.width = viewport.width;
        self.emitters_only = emitter_group.is_some();
        self.tris.clear();
        for &t in candidates {
            let i = t as usize;
            if let Some(screen) = ScreenTriangle::setup(frame, viewport, &scene.geom.corners[i], scene.geom.normals[i]) {
                let emitter = emitter_group.is_some_and(|g| g != NO_GROUP && scene.emitter_group[i] == g);
                self.tris.push(TileTriangle { index: t, screen, emitter });
            }
        }
        self.bucket_rows(viewport.height as usize);
        let mut total = 0u64;
        for (k, tri) in self.tris.iter().enumerate() {
            tri.screen.for_each_span(|y, x0, x1| {
                let len = &mut self.row_len[y as usize];
                self.spans[(self.row_start[y as usize] + *len) as usize] = Span { tri: k as u32, x0, x1 };
                *len += 1;
                total += (x1 - x0) as u64;
            });
        }
        total
    }

    /// Sizes each row's span slots for the triangles whose row range includes it.
    fn bucket_rows(&mut self, height: usize) {
        self.row_start.clear();
        self.row_start.resize(height + 1, 0);
        for tri in &self.tris {
            let (first, last) = tri.screen.rows();
            self.row_start[first as usize] += 1;
            self.row_start[last as usize + 1] = self.row_start[last as usize + 1].wrapping_sub(1);
        }
        // Row-range steps → slots per row → exclusive prefix sum.
        let (mut running, mut start) = (0u32, 0u32);
        for s in self.row_start.iter_mut() {
            running = running.wrapping_add(*s);
            *s = start;
            start += running;
        }
        self.row_len.clear();
        self.row_len.resize(height, 0);
        self.spans.clear();
        self.spans.resize(start as usize, Span { tri: 0, x0: 0, x1: 0 });
    }

    /// Resolves the tile counted by [`prepare`](Self::prepare) (the caller has checked the
    /// count against the node budget): calls `visit(fragments)` with the depth-sorted
    /// fragments of every covered pixel — in a light pass, of every pixel an emitter covers
    /// (at least) — in row-major order. Returns how many pixels it visited.
    pub fn resolve(&mut self, scene: &PreparedScene, mut visit: impl FnMut(&[Fragment])) -> u64 {
        self.set_up_attributes(scene);
        let mut covered = 0;
        for row in 0..self.row_len.len() {
            let Some((lo, hi)) = self.row_window(row) else { continue };
            self.fill_row(scene, row as u32, lo, hi);
            for p in 0..(hi - lo) as usize {
                let (a, b) = (self.ends[p] as usize, self.ends[p + 1] as usize);
                if b > a {
                    let frags = &mut self.frags[a..b];
                    if frags.len() > 1 {
                        sort_by_depth(frags, scene.coincident_depth);
                    }
                    visit(frags);
                    covered += 1;
                }
            }
        }
        covered
    }

    fn set_up_attributes(&mut self, scene: &PreparedScene) {
        self.attributes.clear();
        self.attributes.extend(self.tris.iter().map(|tri| {
            let [front, back] = scene.face_uv[tri.index as usize];
            let (plus, minus) = if tri.screen.front_faces_dir { (front, back) } else { (back, front) };
            let planes = tri.screen.planes();
            TileAttributes {
                plus: plus.map(|uv| tile_side(&planes, uv)),
                minus: minus.map(|uv| tile_side(&planes, uv)),
                planes,
            }
        }));
    }

    fn row_spans(&self, row: usize) -> &[Span] {
        let start = self.row_start[row] as usize;
        &self.spans[start..start + self.row_len[row] as usize]
    }

    /// The pixels `lo..hi` of `row` to resolve: all its spans, or in a light pass the hull
    /// of its emitter spans. `None` when there are none.
    fn row_window(&self, row: usize) -> Option<(u32, u32)> {
        let spans = self.row_spans(row);
        let hull = |lo: u32, s: &Span| lo.min(s.x0);
        let (lo, hi) = if self.emitters_only {
            let emitting = spans.iter().filter(|s| self.tris[s.tri as usize].emitter);
            (emitting.clone().fold(u32::MAX, hull), emitting.map(|s| s.x1).max().unwrap_or(0))
        } else {
            (spans.iter().fold(u32::MAX, hull), spans.iter().map(|s| s.x1).max().unwrap_or(0))
        };
        (lo < hi).then_some((lo, hi))
    }

    /// Builds the per-pixel fragment lists of pixels `lo..hi` of `row` in the row buffer.
    fn fill_row(&mut self, scene: &PreparedScene, row: u32, lo: u32, hi: u32) {
        let start = self.row_start[row as usize] as usize;
        let spans = &self.spans[start..start + self.row_len[row as usize] as usize];
        let clip = |s: &Span| (s.x0.max(lo), s.x1.min(hi));
        // Per-pixel counts as a difference array, turned into pixel p's first slot at
        // `ends[p + 1]`: filling through `ends[p + 1]` as p's cursor then leaves
        // `ends[p]..ends[p + 1]` as its range.
        let n = (hi - lo) as usize;
        self.ends.clear();
        self.ends.resize(n + 2, 0);
        for s in spans {
            let (x0, x1) = clip(s);
            if x0 < x1 {
                self.ends[(x0 - lo) as usize + 1] += 1;
                self.ends[(x1 - lo) as usize + 1] = self.ends[(x1 - lo) as usize + 1].wrapping_sub(1);
            }
        }
        let (mut running, mut start) = (0u32, 0u32);
        for e in self.ends[1..].iter_mut() {
            running = running.wrapping_add(*e);
            *e = start;
            start += running;
        }
        self.frags.clear();
        self.frags.resize(start as usize, Fragment { depth: 0.0, plus: NO_SIDE, minus: NO_SIDE });
        let (tw, th) = (scene.texels.width, scene.texels.height);
        let mut lost = 0u64;
        for s in spans {
            let (x0, x1) = clip(s);
            let tri = &self.tris[s.tri as usize];
            let attr = &self.attributes[s.tri as usize];
            let screen = &tri.screen;
            for x in x0..x1 {
                let (cx, cy) = screen.grid_centre(x, row);
                let plus = attr.plus.as_ref().map_or(NO_SIDE, |side| lookup(scene, tw, th, side, cx, cy, &mut lost));
                let minus = attr.minus.as_ref().map_or(NO_SIDE, |side| lookup(scene, tw, th, side, cx, cy, &mut lost));
                let cursor = &mut self.ends[(x - lo) as usize + 1];
                self.frags[*cursor as usize] = Fragment {
                    depth: attr.planes.depth_at(cx, cy),
                    plus: if tri.emitter { plus | EMITTER_FLAG } else { plus },
                    minus: if screen.front_faces_dir { minus | FRONT_LOOKS_PLUS } else { minus },
                };
                *cursor += 1;
            }
        }
        self.lost_lookups += lost;
    }
}

/// The texel under the pixel centre (cx, cy) of one side. Pixel centres inside the triangle
/// map inside its UV triangle, whose pixels hold its chart's texels; rounding may land a
/// hair outside, in the chart's gutter ring, which maps to the chart's nearest texel.
#[inline]
fn lookup(scene: &PreparedScene, width: u32, height: u32, side: &TileSide, cx: f32, cy: f32, lost: &mut u64) -> u32 {
    let g = &side.gradient;
    let uv = g[0] * cx + g[1] * cy + g[2];
    if uv.x >= 0.0 && uv.y >= 0.0 {
        let (x, y) = (uv.x as u32, uv.y as u32);
        if x < width && y < height {
            let t = scene.texel_lookup[(y * width + x) as usize];
            if t != NO_TEXEL {
                return t;
            }
        }
    }
    *lost += 1;
    NO_SIDE
}
