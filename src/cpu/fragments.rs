//! One tile's fragments on the CPU, produced and resolved a row of a strip at a time.
//!
//! The GPU builds per-pixel linked lists in a node buffer of capacity N. The CPU honours the
//! same budget — [`prepare`](TileFragments::prepare) counts the tile's fragments exactly and
//! the caller splits a tile that exceeds N — but never stores a tile's fragments: the count
//! pass keeps the covered spans, bucketed by strip and row, and
//! [`resolve`](TileFragments::resolve) turns one bucket at a time into per-pixel lists in a
//! row buffer that stays in L1. (A whole tile's lists were ~12 MB at 1 M fragments; writing,
//! sorting and re-reading them was most of the build's time.)
//!
//! Strips: the texels a bundle row hits are hit again by the next row (about two pixels per
//! texel side). Resolving the tile in vertical strips of [`STRIP`] pixels keeps the texel
//! accumulators and sources of consecutive rows in L1; across a whole 512-pixel row they
//! were not.
//!
//! A pixel's fragments arrive in triangle order and are insertion-sorted, which is stable:
//! ties keep a deterministic order, and results do not depend on how tiles were split.

use super::prepared::{BlockedTable, NO_GROUP, PreparedScene};
use crate::atlas::texels::NO_TEXEL;
use crate::bundle::estimator::{EMITTER_FLAG, FRONT_LOOKS_PLUS, Fragment, NO_SIDE, sort_by_depth};
use crate::bundle::raster::{BundleFrame, Planes, ScreenTriangle, Viewport, eval, grid_centre};
use glam::Vec2;

/// Width in pixels of the strips a tile is resolved in.
const STRIP: u32 = 64;

/// A triangle set up for the current viewport.
struct TileTriangle {
    /// Index into the scene's triangles.
    index: u32,
    screen: ScreenTriangle,
    /// Belongs to the emitter group of the current light pass.
    emitter: bool,
}

/// What the fragments of one triangle carry, as affine functions of grid pixel coordinates
/// (see [`Planes`]): depth, and per lit side the UV (LOD pixels) that locates its texel.
/// Only built tiles need them, so they are set up after the count.
struct FragmentPlanes {
    depth: [f32; 3],
    plus: SideUv,
    minus: SideUv,
    /// Flags the fragments carry: [`EMITTER_FLAG`] on `plus`, [`FRONT_LOOKS_PLUS`] on `minus`.
    plus_flag: u32,
    minus_flag: u32,
}

/// A side's UV as an affine function of grid pixel coordinates, or `None` when the side is
/// not a lit face.
type SideUv = Option<[Vec2; 3]>;

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
    height: u32,
    /// The viewport's offset in its pixel grid: attributes are evaluated in grid coordinates.
    offset: (u32, u32),
    tris: Vec<TileTriangle>,
    planes: Vec<FragmentPlanes>,
    /// A light pass: only pixels an emitter covers are resolved (no other pixel can receive
    /// light from it).
    emitters_only: bool,
    /// Bucket b = strip · height + row holds that row's spans within the strip, in triangle
    /// order: `spans[bucket_start[b]..][..bucket_len[b]]`. Buckets are sized for every
    /// triangle whose rows and columns include them.
    bucket_start: Vec<u32>,
    bucket_len: Vec<u32>,
    spans: Vec<Span>,
    /// Row buffer: pixel p of the resolved window owns `frags[ends[p]..ends[p + 1]]`.
    ends: Vec<u32>,
    frags: Vec<Fragment>,
    /// Fragments whose UV fell outside every texel through rounding (they still occlude).
    pub lost_lookups: u64,
}

fn side_uv(planes: &Planes, uv: [Vec2; 3]) -> [Vec2; 3] {
    let gx = planes.gradient([uv[0].x, uv[1].x, uv[2].x]);
    let gy = planes.gradient([uv[0].y, uv[1].y, uv[2].y]);
    [Vec2::new(gx[0], gy[0]), Vec2::new(gx[1], gy[1]), Vec2::new(gx[2], gy[2])]
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
        self.height = viewport.height;
        self.offset = viewport.offset;
        self.emitters_only = emitter_group.is_some();
        self.tris.clear();
        for &t in candidates {
            let i = t as usize;
            if let Some(screen) = ScreenTriangle::setup(frame, viewport, &scene.geom.corners[i], scene.geom.normals[i])
            {
                let emitter = emitter_group.is_some_and(|g| g != NO_GROUP && scene.emitter_group[i] == g);
                self.tris.push(TileTriangle { index: t, screen, emitter });
            }
        }
        self.size_buckets();
        self.bucket_spans()
    }

    fn strips(&self) -> usize {
        self.width.div_ceil(STRIP) as usize
    }

    /// Sizes each bucket for the triangles whose rows and strips include it (per strip, a
    /// difference array down the rows), then lays the buckets out one after another.
    fn size_buckets(&mut self) {
        let (strips, height) = (self.strips(), self.height as usize);
        let counts = &mut self.bucket_len;
        counts.clear();
        counts.resize(strips * height, 0);
        for tri in &self.tris {
            let (r0, r1) = tri.screen.rows();
            let (c0, c1) = tri.screen.columns();
            for strip in (c0 / STRIP) as usize..=(c1 / STRIP) as usize {
                let column = &mut counts[strip * height..][..height];
                // Modular: a cell may hold a "−1" from an earlier triangle's end.
                column[r0 as usize] = column[r0 as usize].wrapping_add(1);
                if let Some(below) = column.get_mut(r1 as usize + 1) {
                    *below = below.wrapping_sub(1);
                }
            }
        }
        self.bucket_start.clear();
        let mut start = 0u32;
        for column in counts.chunks_mut(height.max(1)) {
            let mut running = 0u32;
            for count in column {
                running = running.wrapping_add(*count);
                self.bucket_start.push(start);
                start += running;
                *count = 0;
            }
        }
        grow(&mut self.spans, start as usize, Span { tri: 0, x0: 0, x1: 0 });
    }

    /// Files every span, cut at strip borders, into its bucket; returns the fragment count.
    fn bucket_spans(&mut self) -> u64 {
        let height = self.height;
        let mut total = 0u64;
        for (k, tri) in self.tris.iter().enumerate() {
            tri.screen.for_each_span(|y, x0, x1| {
                total += (x1 - x0) as u64;
                let mut x = x0;
                while x < x1 {
                    let strip = x / STRIP;
                    let end = x1.min((strip + 1) * STRIP);
                    let bucket = (strip * height + y) as usize;
                    let len = &mut self.bucket_len[bucket];
                    self.spans[(self.bucket_start[bucket] + *len) as usize] = Span { tri: k as u32, x0: x, x1: end };
                    *len += 1;
                    x = end;
                }
            });
        }
        total
    }

    /// Resolves the tile counted by [`prepare`](Self::prepare) (the caller has checked the
    /// count against the node budget): calls `visit(fragments)` with the depth-sorted
    /// fragments of every covered pixel — in a light pass, of every pixel an emitter covers
    /// (at least) — strip by strip, row by row. Returns how many pixels it visited.
    pub fn resolve(&mut self, scene: &PreparedScene, mut visit: impl FnMut(&[Fragment])) -> u64 {
        self.set_up_planes(scene);
        let mut covered = 0;
        for bucket in 0..self.bucket_len.len() {
            let Some((lo, hi)) = self.window(bucket) else { continue };
            self.fill(scene, bucket, lo, hi);
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

    fn set_up_planes(&mut self, scene: &PreparedScene) {
        self.planes.clear();
        self.planes.extend(self.tris.iter().map(|tri| {
            let [front, back] = scene.face_uv[tri.index as usize];
            let (plus, minus) = if tri.screen.front_faces_dir { (front, back) } else { (back, front) };
            let planes = tri.screen.planes();
            FragmentPlanes {
                depth: planes.depth_coefficients(),
                plus: plus.map(|uv| side_uv(&planes, uv)),
                minus: minus.map(|uv| side_uv(&planes, uv)),
                plus_flag: if tri.emitter { EMITTER_FLAG } else { 0 },
                minus_flag: if tri.screen.front_faces_dir { FRONT_LOOKS_PLUS } else { 0 },
            }
        }));
    }

    fn bucket_spans_of(&self, bucket: usize) -> &[Span] {
        let start = self.bucket_start[bucket] as usize;
        &self.spans[start..start + self.bucket_len[bucket] as usize]
    }

    /// The pixels `lo..hi` of a bucket to resolve: all its spans, or in a light pass the
    /// hull of its emitter spans. `None` when there are none.
    fn window(&self, bucket: usize) -> Option<(u32, u32)> {
        let spans = self.bucket_spans_of(bucket);
        let hull = |(lo, hi): (u32, u32), s: &Span| (lo.min(s.x0), hi.max(s.x1));
        let (lo, hi) = if self.emitters_only {
            spans.iter().filter(|s| self.tris[s.tri as usize].emitter).fold((u32::MAX, 0), hull)
        } else {
            spans.iter().fold((u32::MAX, 0), hull)
        };
        (lo < hi).then_some((lo, hi))
    }

    /// Builds the per-pixel fragment lists of pixels `lo..hi` of a bucket in the row buffer.
    fn fill(&mut self, scene: &PreparedScene, bucket: usize, lo: u32, hi: u32) {
        let start = self.bucket_start[bucket] as usize;
        let spans = &self.spans[start..start + self.bucket_len[bucket] as usize];
        let row = bucket as u32 % self.height;
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
                self.ends[(x0 - lo) as usize + 1] = self.ends[(x0 - lo) as usize + 1].wrapping_add(1);
                self.ends[(x1 - lo) as usize + 1] = self.ends[(x1 - lo) as usize + 1].wrapping_sub(1);
            }
        }
        let (mut running, mut total) = (0u32, 0u32);
        for e in self.ends[1..].iter_mut() {
            running = running.wrapping_add(*e);
            *e = total;
            total += running;
        }
        grow(&mut self.frags, total as usize, Fragment { depth: 0.0, plus: NO_SIDE, minus: NO_SIDE });
        let texels = TexelLookup::new(scene);
        let mut lost = 0u64;
        let cy = grid_centre(self.offset.1, row);
        for s in spans {
            let (x0, x1) = clip(s);
            if x0 >= x1 {
                continue;
            }
            let p = &self.planes[s.tri as usize];
            let span = SpanFill {
                frags: &mut self.frags,
                cursors: &mut self.ends[(x0 - lo) as usize + 1..(x1 - lo) as usize + 1],
                x0,
                offset: self.offset.0,
                cy,
                planes: p,
            };
            // One loop per combination of lit sides, so the pixel loop tests none.
            let lost = &mut lost;
            match (&p.plus, &p.minus) {
                (Some(plus), Some(minus)) => {
                    span.fill(|cx| (texels.at(plus, cx, cy, lost), texels.at(minus, cx, cy, lost)))
                }
                (Some(plus), None) => span.fill(|cx| (texels.at(plus, cx, cy, lost), NO_SIDE)),
                (None, Some(minus)) => span.fill(|cx| (NO_SIDE, texels.at(minus, cx, cy, lost))),
                (None, None) => span.fill(|_| (NO_SIDE, NO_SIDE)),
            }
        }
        self.lost_lookups += lost;
    }
}

/// The pixels of one span being filled into the row buffer.
struct SpanFill<'a> {
    frags: &'a mut [Fragment],
    /// Per pixel of the span: its next free slot in `frags`.
    cursors: &'a mut [u32],
    /// The span's first pixel and the rectangle's offset in its grid, and the row's centre.
    x0: u32,
    offset: u32,
    cy: f32,
    planes: &'a FragmentPlanes,
}

impl SpanFill<'_> {
    /// Writes each pixel's fragment; `sides(cx)` gives its (plus, minus) texels.
    #[inline(always)]
    fn fill(self, mut sides: impl FnMut(f32) -> (u32, u32)) {
        let p = self.planes;
        for (x, cursor) in (self.x0..).zip(self.cursors.iter_mut()) {
            let cx = grid_centre(self.offset, x);
            let (plus, minus) = sides(cx);
            self.frags[*cursor as usize] =
                Fragment { depth: eval(&p.depth, cx, self.cy), plus: plus | p.plus_flag, minus: minus | p.minus_flag };
            *cursor += 1;
        }
    }
}

/// Makes `buffer` at least `len` long. Its slots are all written before they are read, so
/// the ones it already has are kept as they are: re-initialising them for every tile and
/// row cost more than filling them.
fn grow<T: Copy>(buffer: &mut Vec<T>, len: usize, value: T) {
    if buffer.len() < len {
        buffer.resize(len, value);
    }
}

/// The atlas-pixel → texel table of the LOD being baked.
struct TexelLookup<'a> {
    table: &'a BlockedTable,
    /// The atlas size in pixels, as far as f32 holds it exactly (2^24: far beyond any atlas).
    size: Vec2,
}

impl<'a> TexelLookup<'a> {
    fn new(scene: &'a PreparedScene) -> Self {
        let (width, height) = (scene.texels.width, scene.texels.height);
        let exact = |n: u32| n.min(1 << 24) as f32;
        TexelLookup { table: &scene.texel_lookup, size: Vec2::new(exact(width), exact(height)) }
    }

    /// The texel under the pixel centre (cx, cy) of a side with UV function `uv`. Pixel
    /// centres inside the triangle map inside its UV triangle, whose pixels hold its chart's
    /// texels; rounding may land a hair outside, in the chart's gutter ring, which maps to
    /// the chart's nearest texel.
    #[inline]
    fn at(&self, uv: &[Vec2; 3], cx: f32, cy: f32, lost: &mut u64) -> u32 {
        let uv = uv[0] * cx + uv[1] * cy + uv[2];
        // 0 ≤ uv < size, i.e. its pixel ⌊uv⌋ is in the atlas (the size is whole pixels).
        if uv.x >= 0.0 && uv.y >= 0.0 && uv.x < self.size.x && uv.y < self.size.y {
            let t = self.table.get(uv.x as u32, uv.y as u32);
            if t != NO_TEXEL {
                return t;
            }
        }
        *lost += 1;
        NO_SIDE
    }
}
