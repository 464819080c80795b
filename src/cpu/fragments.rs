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

use super::scene::CpuScene;
use crate::atlas::lookup::TexelTable;
use crate::atlas::texels::NO_TEXEL;
use crate::bundle::estimator::{
    EMITTER_FLAG, FOREIGN, FRONT_LOOKS_PLUS, Fragment, Layering, NO_SIDE, pack_normal, sort_by_depth,
};
use crate::bundle::raster::{BundleFrame, Planes, ScreenTriangle, Viewport, eval, grid_centre};
use crate::bundle::target::{BakeTarget, NO_GROUP};
use crate::bundle::window::{Points, WindowOutline, clip_to_box, hull_rows};
use crate::scene::Side;
use glam::{Vec2, Vec3};

/// Width in pixels of the strips a tile is resolved in.
const STRIP: u32 = 64;

/// A triangle set up for the current viewport.
struct TileTriangle {
    /// Index into the scene's triangles.
    index: u32,
    screen: ScreenTriangle,
    /// Belongs to the emitter group of the current light pass.
    emitter: bool,
    /// Its front normal in the bundle frame, packed (which fragments are coplanar).
    normal: u32,
}

/// What the fragments of one triangle carry, as affine functions of grid pixel coordinates
/// (see [`Planes`]): depth, and per side how it finds its code. Only built tiles need them,
/// so they are set up after the count.
struct FragmentPlanes {
    depth: [f32; 3],
    /// Barycentrics, for locating a foreign side's surface point.
    planes: Planes,
    plus: SideLookup,
    minus: SideLookup,
    /// Flags the fragments carry: [`EMITTER_FLAG`] on `plus`, [`FRONT_LOOKS_PLUS`] on `minus`.
    plus_flag: u32,
    minus_flag: u32,
    /// The triangle's front normal, packed (which fragments are coplanar).
    normal: u32,
    /// Where its fragments may show a target texel (see [`TileFragments::resolve`]).
    reach: TargetReach,
}

/// Where a tile triangle's fragments may show a target texel.
#[derive(Clone, Copy, PartialEq, Eq)]
enum TargetReach {
    /// Nowhere.
    None,
    /// Wherever it covers.
    Everywhere,
    /// Only over its part inside the target's box: per row from its first, the pixels
    /// `clip_rows[start + row − first]`.
    Rows { start: u32 },
}

/// How a side of a tile triangle gets its code (see [`crate::bundle::estimator`]).
#[derive(Clone, Copy)]
enum SideLookup {
    /// Not a lit face.
    Dark,
    /// A lit face whose chart holds no target texel: always this foreign code.
    Foreign(u32),
    /// A lit face served by the whole-LOD table whose lookups cannot find a target texel
    /// ([`BakeTarget::reach`]): always its foreign code, its UV (as in `Table`) kept for
    /// [`ForeignSides::lod_pixel`].
    Elsewhere { uv: [Vec2; 3], foreign: u32 },
    /// A lit face of a chart with a target table (an index into the target's tables): its
    /// UV, an affine function of grid pixel coordinates in LOD pixels, finds the texel; a
    /// pixel the table does not hold gives the foreign code.
    Table { uv: [Vec2; 3], table: u32, foreign: u32 },
}

impl FragmentPlanes {
    /// Whether a side can show a target texel.
    fn shows_targets(&self) -> bool {
        matches!(self.plus, SideLookup::Table { .. }) || matches!(self.minus, SideLookup::Table { .. })
    }
}

/// Whether a point lies in a box.
fn in_box(p: Vec3, (lo, hi): (Vec3, Vec3)) -> bool {
    p.cmpge(lo).all() && p.cmple(hi).all()
}

/// Whether `screen` may cover a pixel inside the outline (`outline_rows`, per row; empty: no
/// outline): some row of its box where the outline's pixels meet its columns. A triangle
/// that does not has every span cut away ([`TileFragments::bucket_spans`]); in a cell's
/// window that is most of those the tile's bins name (zdm2: of 8.5k set up a tile, 3.7k
/// cover a pixel inside the outline), and each would still have its rows walked, its
/// buckets sized and its planes set up.
#[inline]
fn meets_outline(screen: &ScreenTriangle, outline_rows: &[(u32, u32)]) -> bool {
    if outline_rows.is_empty() {
        return true;
    }
    let ((r0, r1), (c0, c1)) = (screen.rows(), screen.columns());
    // Spans lie within columns c0..=c1: a cut span `max(x0, a)..min(x1, b)` is empty unless
    // a ≤ c1 and b > c0. A row past the outline's is not cut.
    (r0..=r1).any(|y| outline_rows.get(y as usize).is_none_or(|&(a, b)| a < b && a <= c1 && b > c0))
}

/// Pixels `base + x0 .. base + x1` of one row of a strip (`base`: its first column) covered
/// by triangle `tri` (an index into the tile's triangles). 6 B, byte columns and no
/// padding: a tile's spans (one a row and strip of each of its triangles) are a thread's
/// largest buffer beside the fragments.
#[derive(Clone, Copy, Debug)]
#[repr(C, packed(2))]
struct Span {
    tri: u32,
    x0: u8,
    x1: u8,
}

const _: () = assert!(STRIP <= u8::MAX as u32, "a span's columns are bytes within its strip");

impl Span {
    /// Its columns.
    #[inline]
    fn columns(self, base: u32) -> (u32, u32) {
        (base + self.x0 as u32, base + self.x1 as u32)
    }
}

/// Reusable buffers of one worker.
#[derive(Default)]
pub struct TileFragments {
    width: u32,
    height: u32,
    /// The viewport's offset in its pixel grid: attributes are evaluated in grid coordinates.
    offset: (u32, u32),
    /// The viewport's pixel side (m): how far rasterised depths may stray.
    pixel: f32,
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
    /// Per row, the pixels inside the target's outline (a windowed pass; see
    /// [`WindowOutline`]): spans are cut to them. Empty: no cut.
    outline_rows: Vec<(u32, u32)>,
    /// The windowed pass's outline, direction and viewport, for [`TargetReach::Rows`].
    window: Option<(WindowOutline, BundleFrame, Viewport)>,
    /// Rows of the triangles that reach out of the target's box (see [`TargetReach`]).
    clip_rows: Vec<(u32, u32)>,
    clipped: Vec<Vec3>,
    clip_scratch: Vec<Vec3>,
    hull: Vec<Vec2>,
    /// Row buffer: pixel p of the resolved window owns `frags[ends[p]..ends[p + 1]]`.
    ends: Vec<u32>,
    frags: Vec<Fragment>,
}

fn side_uv(planes: &Planes, uv: [Vec2; 3]) -> [Vec2; 3] {
    let gx = planes.gradient([uv[0].x, uv[1].x, uv[2].x]);
    let gy = planes.gradient([uv[0].y, uv[1].y, uv[2].y]);
    [Vec2::new(gx[0], gy[0]), Vec2::new(gx[1], gy[1]), Vec2::new(gx[2], gy[2])]
}

impl TileFragments {
    /// Sets up `candidates` for `viewport`, keeps their covered spans (inside `outline` when
    /// given: no other pixel can credit a target texel) and counts their fragments.
    /// `emitter_group` makes this a light pass of that group. Returns the count.
    pub fn prepare(
        &mut self,
        scene: &CpuScene,
        frame: &BundleFrame,
        viewport: &Viewport,
        candidates: &[u32],
        emitter_group: Option<u32>,
        outline: Option<&WindowOutline>,
    ) -> u64 {
        match outline {
            Some(o) => o.rows(viewport, &mut self.outline_rows),
            None => self.outline_rows.clear(),
        }
        self.window = outline.map(|o| (*o, *frame, *viewport));
        self.width = viewport.width;
        self.height = viewport.height;
        self.offset = viewport.offset;
        self.pixel = viewport.pixel;
        self.emitters_only = emitter_group.is_some();
        self.tris.clear();
        // Grown to the most a tile asks, not doubled past it: with the planes, 276 B a
        // triangle, and a tile may set up tens of thousands.
        self.tris.reserve_exact(candidates.len());
        let geom = &scene.bundle.geom;
        for &t in candidates {
            let i = t as usize;
            if let Some(screen) = ScreenTriangle::setup(frame, viewport, &geom.corners[i], geom.normals[i])
                && meets_outline(&screen, &self.outline_rows)
            {
                let emitter = emitter_group.is_some_and(|g| g != NO_GROUP && scene.bundle.group_of[i] == g);
                let normal = pack_normal(frame.coords(geom.normals[i]));
                self.tris.push(TileTriangle { index: t, screen, emitter, normal });
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
        let outline = &self.outline_rows;
        for (k, tri) in self.tris.iter().enumerate() {
            tri.screen.for_each_span(|y, x0, x1| {
                let (x0, x1) = match outline.get(y as usize) {
                    Some(&(a, b)) => (x0.max(a), x1.min(b)),
                    None => (x0, x1),
                };
                if x0 >= x1 {
                    return;
                }
                total += (x1 - x0) as u64;
                let mut x = x0;
                while x < x1 {
                    let strip = x / STRIP;
                    let end = x1.min((strip + 1) * STRIP);
                    let bucket = (strip * height + y) as usize;
                    let len = &mut self.bucket_len[bucket];
                    let base = strip * STRIP;
                    let span = Span { tri: k as u32, x0: (x - base) as u8, x1: (end - base) as u8 };
                    self.spans[(self.bucket_start[bucket] + *len) as usize] = span;
                    *len += 1;
                    x = end;
                }
            });
        }
        total
    }

    /// Resolves the tile counted by [`prepare`](Self::prepare) (the caller has checked the
    /// count against the node budget) for `target`: calls `visit` with each row of each
    /// strip that holds pixels to resolve — in a light pass, the pixels an emitter covers (at
    /// least) — strip by strip, row by row; see [`Row`]. Returns how many pixels the visits
    /// went through with [`Row::for_each_pixel`]. `prefetch(t)` is called with each target
    /// texel as a row's fill meets it, before the row is visited (see [`super::prefetch`]).
    ///
    /// One call a row, not a pixel: a call per pixel was not inlined (the visits are large)
    /// and cost its set-up, and a stall reading back the pixel centre it had just been
    /// given, on every pixel — about a third of the exchange's time on the Cornell box.
    pub fn resolve(
        &mut self,
        scene: &CpuScene,
        target: &BakeTarget,
        prefetch: impl Fn(u32),
        mut visit: impl FnMut(&mut Row),
    ) -> u64 {
        self.set_up_planes(scene, target);
        let layering = scene.coincidence_at(self.pixel).layering();
        let mut covered = 0;
        for bucket in 0..self.bucket_len.len() {
            let Some(pixels) = self.pixels_to_resolve(bucket) else { continue };
            let (lo, hi) = pixels.bounds();
            self.fill(target, bucket, pixels, &prefetch);
            let ends = &self.ends[..=(hi - lo) as usize];
            let mut row = Row {
                frags: &mut self.frags[..ends[(hi - lo) as usize] as usize],
                ends,
                foreign: ForeignSides { tris: &self.tris, planes: &self.planes },
                layering,
                lo,
                offset: self.offset.0,
                cy: grid_centre(self.offset.1, bucket as u32 % self.height),
                covered: 0,
            };
            visit(&mut row);
            covered += row.covered;
        }
        covered
    }

    fn set_up_planes(&mut self, scene: &CpuScene, target: &BakeTarget) {
        let atlas = &scene.bundle.atlas;
        let scale = (1u64 << target.lod) as f32;
        let lookup = |k: usize, tri: u32, side: Side, minus: bool| {
            let foreign = FOREIGN + 2 * k as u32 + u32::from(minus);
            let Some(f) = atlas.face(tri, side) else { return SideLookup::Dark };
            let face = &atlas.faces[f as usize];
            match target.table_index(face.chart) {
                Some(_) if !target.reaches(f) => SideLookup::Elsewhere { uv: face.uv.map(|p| p * scale), foreign },
                Some(table) => SideLookup::Table { uv: face.uv.map(|p| p * scale), table: table as u32, foreign },
                None => SideLookup::Foreign(foreign),
            }
        };
        self.planes.clear();
        self.planes.reserve_exact(self.tris.len());
        self.clip_rows.clear();
        for (k, tri) in self.tris.iter().enumerate() {
            let (plus_side, minus_side) =
                if tri.screen.front_faces_dir { (Side::Front, Side::Back) } else { (Side::Back, Side::Front) };
            let planes = tri.screen.planes();
            let in_grid = |l: SideLookup| match l {
                SideLookup::Table { uv, table, foreign } => {
                    SideLookup::Table { uv: side_uv(&planes, uv), table, foreign }
                }
                SideLookup::Elsewhere { uv, foreign } => SideLookup::Elsewhere { uv: side_uv(&planes, uv), foreign },
                other => other,
            };
            let mut p = FragmentPlanes {
                depth: planes.depth_coefficients(),
                planes,
                plus: in_grid(lookup(k, tri.index, plus_side, false)),
                minus: in_grid(lookup(k, tri.index, minus_side, true)),
                plus_flag: if tri.emitter { EMITTER_FLAG } else { 0 },
                minus_flag: if tri.screen.front_faces_dir { FRONT_LOOKS_PLUS } else { 0 },
                normal: tri.normal,
                reach: TargetReach::None,
            };
            if p.shows_targets() {
                p.reach = match &self.window {
                    None => TargetReach::Everywhere,
                    Some((outline, frame, viewport)) => {
                        let corners = &scene.bundle.geom.corners[tri.index as usize];
                        let w = outline.window();
                        if corners.iter().all(|&c| in_box(c, w)) {
                            TargetReach::Everywhere
                        } else {
                            // Every fragment showing a target texel lies in the box (see
                            // `BakeTarget::window`): only the part inside can show one.
                            clip_to_box(corners, w, &mut self.clipped, &mut self.clip_scratch);
                            let on_grid = |c: &Vec3| {
                                let f = frame.coords(*c);
                                viewport.grid_position(Vec2::new(f.x, f.y))
                            };
                            self.hull.clear();
                            self.hull.extend(self.clipped.iter().map(on_grid));
                            if self.hull.is_empty() {
                                TargetReach::None
                            } else {
                                let start = self.clip_rows.len() as u32;
                                let (r0, r1) = tri.screen.rows();
                                hull_rows(&self.hull, Points::Polygon, viewport, r0..r1 + 1, &mut self.clip_rows);
                                TargetReach::Rows { start }
                            }
                        }
                    }
                };
            }
            self.planes.push(p);
        }
    }

    fn bucket_spans_of(&self, bucket: usize) -> &[Span] {
        let start = self.bucket_start[bucket] as usize;
        &self.spans[start..start + self.bucket_len[bucket] as usize]
    }

    /// The pixels of a bucket to resolve: those covered by a span of a triangle with a side
    /// that may show a target texel (a `Table` side: no other pixel holds a fragment that
    /// can be credited; a triangle that holds no target texel may still show one, where the
    /// texel's square reaches over it from a neighbour in its chart) — in a windowed pass,
    /// by the triangle's part inside the target's box ([`TargetReach`]: a floor crossing a
    /// cell's box covers much of its outline along slanted directions, and those lines see
    /// it outside the cell) — in a light pass cut to the hull of its emitter spans (no other
    /// pixel can receive its light). `None` when that is empty.
    fn pixels_to_resolve(&self, bucket: usize) -> Option<StripPixels> {
        let spans = self.bucket_spans_of(bucket);
        let base = (bucket / self.height as usize) as u32 * STRIP;
        let row = bucket as u32 % self.height;
        let mut mask = spans.iter().fold(0u64, |m, s| {
            let (x0, x1) = s.columns(base);
            let (x0, x1) = match self.planes[s.tri as usize].reach {
                TargetReach::None => return m,
                TargetReach::Everywhere => (x0, x1),
                TargetReach::Rows { start } => {
                    let first = self.tris[s.tri as usize].screen.rows().0;
                    let (a, b) = self.clip_rows[(start + row - first) as usize];
                    (x0.max(a), x1.min(b))
                }
            };
            if x0 < x1 { m | run_bits(x0 - base, x1 - base) } else { m }
        });
        if self.emitters_only {
            let hull = |(lo, hi): (u32, u32), s: &Span| {
                let (x0, x1) = s.columns(base);
                (lo.min(x0), hi.max(x1))
            };
            let (a, b) = spans.iter().filter(|s| self.tris[s.tri as usize].emitter).fold((u32::MAX, 0), hull);
            mask &= if a < b { run_bits(a - base, b - base) } else { 0 };
        }
        (mask != 0).then_some(StripPixels { base, mask })
    }

    /// Builds the per-pixel fragment lists of a bucket's `pixels` (from the first to the
    /// last, the others left empty) in the row buffer.
    fn fill(&mut self, target: &BakeTarget, bucket: usize, pixels: StripPixels, prefetch: &impl Fn(u32)) {
        let start = self.bucket_start[bucket] as usize;
        let spans = &self.spans[start..start + self.bucket_len[bucket] as usize];
        let row = bucket as u32 % self.height;
        let (lo, hi) = pixels.bounds();
        let clip = |s: &Span| {
            let (x0, x1) = s.columns(pixels.base);
            (x0.max(lo), x1.min(hi))
        };
        // Per-pixel counts as a difference array, turned into pixel p's first slot at
        // `ends[p + 1]`: filling through `ends[p + 1]` as p's cursor then leaves
        // `ends[p]..ends[p + 1]` as its range.
        let n = (hi - lo) as usize;
        self.ends.clear();
        self.ends.resize(n + 2, 0);
        for s in spans {
            let (x0, x1) = clip(s);
            if x0 < x1 {
                for (a, b) in Runs(pixels.within(x0, x1)) {
                    let (a, b) = ((x0 + a - lo) as usize + 1, (x0 + b - lo) as usize + 1);
                    self.ends[a] = self.ends[a].wrapping_add(1);
                    self.ends[b] = self.ends[b].wrapping_sub(1);
                }
            }
        }
        let (mut running, mut total) = (0u32, 0u32);
        for e in self.ends[1..].iter_mut() {
            running = running.wrapping_add(*e);
            *e = total;
            total += running;
        }
        grow(&mut self.frags, total as usize, Fragment { depth: 0.0, plus: NO_SIDE, minus: NO_SIDE, normal: 0 });
        let cy = grid_centre(self.offset.1, row);
        for s in spans {
            let (x0, x1) = clip(s);
            if x0 >= x1 {
                continue;
            }
            let p = &self.planes[s.tri as usize];
            // Attributes are evaluated relative to the triangle's anchor (see `Planes`).
            let (_, dy) = p.planes.local(0.0, cy);
            let span = SpanFill {
                frags: &mut self.frags,
                cursors: &mut self.ends[(x0 - lo) as usize + 1..(x1 - lo) as usize + 1],
                runs: pixels.within(x0, x1),
                x0,
                offset: self.offset.0,
                dy,
                planes: p,
            };
            // One loop per kind of side pair, so the pixel loop tests none.
            let code = |l: &SideLookup| match *l {
                SideLookup::Dark => NO_SIDE,
                SideLookup::Foreign(c) => c,
                SideLookup::Table { foreign, .. } | SideLookup::Elsewhere { foreign, .. } => foreign,
            };
            match (&p.plus, &p.minus) {
                (
                    SideLookup::Table { uv: a, table: ta, foreign: fa },
                    SideLookup::Table { uv: b, table: tb, foreign: fb },
                ) => {
                    let mut a = TexelCursor::new(&target.tables[*ta as usize], a, dy, *fa, prefetch);
                    let mut b = TexelCursor::new(&target.tables[*tb as usize], b, dy, *fb, prefetch);
                    span.fill(|dx| (a.at(dx), b.at(dx)))
                }
                (SideLookup::Table { uv, table, foreign }, other) => {
                    let (mut t, m) =
                        (TexelCursor::new(&target.tables[*table as usize], uv, dy, *foreign, prefetch), code(other));
                    span.fill(|dx| (t.at(dx), m))
                }
                (other, SideLookup::Table { uv, table, foreign }) => {
                    let (mut t, pl) =
                        (TexelCursor::new(&target.tables[*table as usize], uv, dy, *foreign, prefetch), code(other));
                    span.fill(|dx| (pl, t.at(dx)))
                }
                (a, b) => {
                    let (a, b) = (code(a), code(b));
                    span.fill(|_| (a, b))
                }
            }
        }
    }
}

/// One row of a strip as [`TileFragments::resolve`] shows it: each covered pixel's fragments
/// in depth order.
pub struct Row<'a> {
    /// Pixel p of the row (from `lo`) owns `frags[ends[p]..ends[p + 1]]`.
    frags: &'a mut [Fragment],
    ends: &'a [u32],
    foreign: ForeignSides<'a>,
    layering: Layering,
    lo: u32,
    /// The viewport's x offset in its grid, and the row's grid centre.
    offset: u32,
    cy: f32,
    /// Pixels visited by [`for_each_pixel`](Self::for_each_pixel).
    covered: u64,
}

impl Row<'_> {
    /// Calls `visit(fragments, foreign, cx, cy)` with the depth-sorted fragments of every
    /// covered pixel, how to locate their foreign sides, and the pixel's grid centre.
    #[inline(always)]
    pub fn for_each_pixel(&mut self, mut visit: impl FnMut(&[Fragment], &ForeignSides, f32, f32)) {
        for (p, w) in self.ends.windows(2).enumerate() {
            let (a, b) = (w[0] as usize, w[1] as usize);
            if b > a {
                let frags = &mut self.frags[a..b];
                if frags.len() > 1 {
                    sort_by_depth(frags, self.layering);
                }
                visit(frags, &self.foreign, grid_centre(self.offset, self.lo + p as u32), self.cy);
                self.covered += 1;
            }
        }
    }
}

/// Where the surface point of a foreign side code lies, for the tile being resolved.
pub struct ForeignSides<'a> {
    tris: &'a [TileTriangle],
    planes: &'a [FragmentPlanes],
}

impl ForeignSides<'_> {
    /// The triangle, side and barycentrics under grid centre (cx, cy) of foreign code `code`.
    #[inline]
    pub fn locate(&self, code: u32, cx: f32, cy: f32) -> (u32, Side, f32, f32) {
        let k = ((code - FOREIGN) >> 1) as usize;
        let minus = code & 1 == 1;
        let tri = &self.tris[k];
        let plus_is_front = tri.screen.front_faces_dir;
        let side = if plus_is_front != minus { Side::Front } else { Side::Back };
        let (u, v) = self.planes[k].planes.barycentrics(cx, cy);
        (tri.index, side, u, v)
    }

    /// The LOD pixel a side with a table looks up at grid centre (cx, cy), computed as the
    /// span's [`TexelCursor`] computes it (the same float operations, so the same pixel);
    /// `None` for a side without a table, or a UV outside every table.
    #[inline]
    pub fn lod_pixel(&self, code: u32, cx: f32, cy: f32) -> Option<(i64, i64)> {
        let k = ((code - FOREIGN) >> 1) as usize;
        let p = &self.planes[k];
        let lookup = if code & 1 == 1 { &p.minus } else { &p.plus };
        let (SideLookup::Table { uv, .. } | SideLookup::Elsewhere { uv, .. }) = lookup else { return None };
        let (_, dy) = p.planes.local(0.0, cy);
        let (dx, _) = p.planes.local(cx, 0.0);
        let at = uv[0] * dx + uv[1] * dy + uv[2];
        if !(at.x >= 0.0 && at.y >= 0.0 && at.x < 1.6e7 && at.y < 1.6e7) {
            return None;
        }
        let pixel = at.floor();
        Some((pixel.x as i64, pixel.y as i64))
    }
}

/// The codes of one side along a span: its texel under each pixel centre, or `foreign`
/// where its table holds none (a pixel of the chart owned by another region, or a UV that
/// rounds outside every texel). Bundle pixels are about half a texel wide, so consecutive
/// pixels often fall in the same atlas pixel: its code is remembered, not looked up again.
struct TexelCursor<'a, P> {
    table: &'a TexelTable,
    prefetch: &'a P,
    /// The side's UV in LOD pixels as an affine function of the pixel centre (dx, dy)
    /// relative to the triangle's anchor (see `Planes`), on this span's row.
    uv: [Vec2; 3],
    dy: f32,
    foreign: u32,
    /// The atlas pixel last looked up, its coordinates packed (x low, y high; `u64::MAX`:
    /// none yet), and its code.
    last: u64,
    code: u32,
}

impl<'a, P: Fn(u32)> TexelCursor<'a, P> {
    #[inline(always)]
    fn new(table: &'a TexelTable, uv: &[Vec2; 3], dy: f32, foreign: u32, prefetch: &'a P) -> Self {
        TexelCursor { table, prefetch, uv: *uv, dy, foreign, last: u64::MAX, code: foreign }
    }

    /// The code at pixel centre x `dx` (relative to the anchor).
    #[inline(always)]
    fn at(&mut self, dx: f32) -> u32 {
        let uv = &self.uv;
        let p = uv[0] * dx + uv[1] * self.dy + uv[2];
        // ⌊p⌋ as integers; NaN and out-of-range values miss the table.
        if !(p.x >= 0.0 && p.y >= 0.0 && p.x < 1.6e7 && p.y < 1.6e7) {
            return self.foreign;
        }
        // Truncation is ⌊p⌋ here (p ≥ 0), as `ForeignSides::lod_pixel` takes it. `as`
        // would clamp (a third of the cursor's instructions), which the test above makes
        // needless.
        // SAFETY: 0 ≤ p < 1.6e7 (not NaN) on both axes, so both truncate to a u32.
        let (x, y) = unsafe { (p.x.to_int_unchecked::<u32>(), p.y.to_int_unchecked::<u32>()) };
        let key = (y as u64) << 32 | x as u64;
        if key != self.last {
            self.last = key;
            self.code = match self.table.get(x as i64, y as i64) {
                NO_TEXEL => self.foreign,
                t => {
                    (self.prefetch)(t);
                    t
                }
            };
        }
        self.code
    }
}

/// The pixels of one span being filled into the row buffer.
struct SpanFill<'a> {
    frags: &'a mut [Fragment],
    /// Per pixel of the span: its next free slot in `frags`.
    cursors: &'a mut [u32],
    /// The span's pixels to write (bit j: pixel `x0 + j`); the others are not resolved.
    runs: u64,
    /// The span's first pixel and the rectangle's offset in its grid, and the row's centre
    /// relative to the triangle's anchor.
    x0: u32,
    offset: u32,
    dy: f32,
    planes: &'a FragmentPlanes,
}

impl SpanFill<'_> {
    /// Writes each pixel's fragment; `sides(dx)` gives its (plus, minus) texels at the
    /// pixel centre's x relative to the anchor.
    #[inline(always)]
    fn fill(self, mut sides: impl FnMut(f32) -> (u32, u32)) {
        let p = self.planes;
        for (a, b) in Runs(self.runs) {
            // Pixel centres are whole numbers and a half, exact in f32 far beyond any grid
            // (2^23), so stepping by 1 gives each [`grid_centre`] exactly, without converting.
            let mut cx = grid_centre(self.offset, self.x0 + a);
            debug_assert!(cx + ((b - a) as f32) < (1 << 23) as f32);
            for cursor in self.cursors[a as usize..b as usize].iter_mut() {
                let (dx, _) = p.planes.local(cx, 0.0);
                cx += 1.0;
                let (plus, minus) = sides(dx);
                self.frags[*cursor as usize] = Fragment {
                    depth: eval(&p.depth, dx, self.dy),
                    plus: plus | p.plus_flag,
                    minus: minus | p.minus_flag,
                    normal: p.normal,
                };
                *cursor += 1;
            }
        }
    }
}

/// Some pixels of one bucket (a row of a strip): bit i of `mask` is pixel `base + i`.
#[derive(Clone, Copy)]
struct StripPixels {
    base: u32,
    mask: u64,
}

const _: () = assert!(STRIP == u64::BITS, "a strip's row is one u64 mask");

impl StripPixels {
    /// The first pixel and one past the last (a non-empty mask).
    fn bounds(&self) -> (u32, u32) {
        (self.base + self.mask.trailing_zeros(), self.base + u64::BITS - self.mask.leading_zeros())
    }

    /// Which of the pixels `x0..x1` of the strip are in the mask, as bits from `x0`.
    #[inline]
    fn within(&self, x0: u32, x1: u32) -> u64 {
        (self.mask >> (x0 - self.base)) & run_bits(0, x1 - x0)
    }
}

/// Bits `a..b` of a u64 (`a < b ≤ 64`: never empty, so the shifts stay below 64 without a
/// branch).
#[inline]
fn run_bits(a: u32, b: u32) -> u64 {
    debug_assert!(a < b && b <= u64::BITS);
    (u64::MAX >> (u64::BITS - (b - a))) << a
}

/// The runs `a..b` of consecutive set bits of a u64, lowest first. An iterator, not a
/// callback: the fill's per-pixel loop is then written (and inlined) once.
struct Runs(u64);

impl Iterator for Runs {
    type Item = (u32, u32);

    #[inline(always)]
    fn next(&mut self) -> Option<(u32, u32)> {
        if self.0 == 0 {
            return None;
        }
        let a = self.0.trailing_zeros();
        let b = a + (!(self.0 >> a)).trailing_zeros();
        self.0 &= !run_bits(a, b);
        Some((a, b))
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Runs come out lowest first, cover exactly the set bits, and a run may touch either end
    /// of the word.
    #[test]
    fn runs_cover_the_set_bits() {
        let mut rng = crate::sampling::Rng::new(5, 1);
        let cases = [0u64, 1, u64::MAX, 1 << 63, 0x8000_0000_0000_0001, 0x0ff0_00ff_f000_0f0f];
        let random = (0..200).map(|_| (rng.next_f32().to_bits() as u64) << 32 ^ rng.next_f32().to_bits() as u64);
        for bits in cases.into_iter().chain(random) {
            let (mut seen, mut last_end) = (0u64, 0u32);
            for (a, b) in Runs(bits) {
                assert!(a < b && b <= 64 && (seen == 0 || a > last_end), "{bits:#x}: run {a}..{b}");
                let run = run_bits(a, b);
                assert_eq!(run & bits, run, "{bits:#x}: {a}..{b} holds a clear bit");
                seen |= run;
                last_end = b;
            }
            assert_eq!(seen, bits);
        }
        let pixels = StripPixels { base: 128, mask: 0b1011 << 60 };
        assert_eq!(pixels.bounds(), (188, 192));
        assert_eq!(pixels.within(186, 192), 0b101100);
    }
}
