//! Builds one tile's per-pixel fragment lists on the CPU.
//!
//! The GPU builds per-pixel linked lists in a node buffer of capacity N; the CPU builds the
//! same lists contiguously (count per pixel → prefix sum → fill, an "S-buffer"), which needs
//! no pointers and leaves each pixel's fragments adjacent for the depth sort. It honours the
//! same budget: a tile whose fragment count exceeds N has overflowed and is not built.

use glam::Vec2;

use super::prepared::{NO_GROUP, PreparedScene};
use crate::atlas::texels::NO_TEXEL;
use crate::bundle::estimator::{EMITTER_FLAG, FRONT_LOOKS_PLUS, Fragment, NO_SIDE, sort_by_depth};
use crate::bundle::raster::{BundleFrame, Planes, ScreenTriangle, Viewport};

/// A lit side of a triangle in the current viewport: its UV (LOD pixels) as an affine
/// function of pixel coordinates.
struct TileSide {
    gradient: [Vec2; 3],
}

/// A triangle set up for the current viewport, with its sides looking +ω and −ω.
struct TileTriangle {
    screen: ScreenTriangle,
    planes: Planes,
    plus: Option<TileSide>,
    minus: Option<TileSide>,
    emitter: bool,
}

/// Reusable buffers of one worker.
#[derive(Default)]
pub struct FragmentBuffer {
    width: u32,
    tris: Vec<TileTriangle>,
    /// Per pixel: start of its fragments in `frags` (`res² + 1` entries).
    offsets: Vec<u32>,
    frags: Vec<Fragment>,
    /// Next free slot per pixel while filling.
    cursor: Vec<u32>,
    /// Fragments whose UV fell outside every texel through rounding (they still occlude).
    pub lost_lookups: u64,
}

fn tile_side(planes: &Planes, uv: [Vec2; 3]) -> TileSide {
    let gx = planes.gradient([uv[0].x, uv[1].x, uv[2].x]);
    let gy = planes.gradient([uv[0].y, uv[1].y, uv[2].y]);
    TileSide { gradient: [Vec2::new(gx[0], gy[0]), Vec2::new(gx[1], gy[1]), Vec2::new(gx[2], gy[2])] }
}

impl FragmentBuffer {
    /// Sets up `candidates` for `viewport` and counts their fragments. `emitter_group`
    /// flags the fragments of that light-pass group. Returns the fragment count.
    pub fn prepare(
        &mut self,
        scene: &PreparedScene,
        frame: &BundleFrame,
        viewport: &Viewport,
        candidates: &[u32],
        emitter_group: Option<u32>,
    ) -> u64 {
        self.width = viewport.width;
        self.tris.clear();
        for &t in candidates {
            let t = t as usize;
            let Some(screen) = ScreenTriangle::setup(frame, viewport, &scene.geom.corners[t], scene.geom.normals[t]) else {
                continue;
            };
            let [front, back] = scene.face_uv[t];
            let (plus, minus) = if screen.front_faces_dir { (front, back) } else { (back, front) };
            let planes = screen.planes();
            self.tris.push(TileTriangle {
                plus: plus.map(|uv| tile_side(&planes, uv)),
                minus: minus.map(|uv| tile_side(&planes, uv)),
                planes,
                emitter: emitter_group.is_some_and(|g| g != NO_GROUP && scene.emitter_group[t] == g),
                screen,
            });
        }
        let n = viewport.pixels() as usize;
        // Spans as +1/−1 steps (a difference array), turned into per-pixel counts in `build`:
        // one write per span end instead of one per fragment.
        self.offsets.clear();
        self.offsets.resize(n + 1, 0);
        let mut total = 0u64;
        for tri in &self.tris {
            tri.screen.for_each_span(|y, x0, x1| {
                let row = (y * self.width) as usize;
                self.offsets[row + x0 as usize] = self.offsets[row + x0 as usize].wrapping_add(1);
                self.offsets[row + x1 as usize] = self.offsets[row + x1 as usize].wrapping_sub(1);
                total += (x1 - x0) as u64;
            });
        }
        total
    }

    /// Fills and depth-sorts the fragments counted by [`prepare`](Self::prepare). The caller
    /// has checked the count against the node budget.
    pub fn build(&mut self, scene: &PreparedScene) {
        // Steps → per-pixel counts → exclusive prefix sum: offsets[p] = first fragment of p.
        let mut running = 0u32;
        let mut start = 0u32;
        for o in self.offsets.iter_mut() {
            running = running.wrapping_add(*o);
            *o = start;
            start += running;
        }
        let total = *self.offsets.last().unwrap_or(&0) as usize;
        self.frags.clear();
        self.frags.resize(total, Fragment { depth: 0.0, plus: NO_SIDE, minus: NO_SIDE });
        // `cursor[p]` = next free slot of pixel p: the offsets shifted by one.
        let mut cursor = std::mem::take(&mut self.cursor);
        cursor.clear();
        cursor.extend_from_slice(&self.offsets[..self.offsets.len() - 1]);
        let (tw, th) = (scene.texels.width, scene.texels.height);
        let mut lost = 0u64;
        for tri in &self.tris {
            let s = &tri.screen;
            s.for_each_span(|y, x0, x1| {
                for x in x0..x1 {
                    let (cx, cy) = s.grid_centre(x, y);
                    let plus = tri.plus.as_ref().map_or(NO_SIDE, |side| lookup(scene, tw, th, side, cx, cy, &mut lost));
                    let minus = tri.minus.as_ref().map_or(NO_SIDE, |side| lookup(scene, tw, th, side, cx, cy, &mut lost));
                    let p = (y * self.width + x) as usize;
                    let at = cursor[p] as usize;
                    cursor[p] += 1;
                    self.frags[at] = Fragment {
                        depth: tri.planes.depth_at(cx, cy),
                        plus: if tri.emitter { plus | EMITTER_FLAG } else { plus },
                        minus: if s.front_faces_dir { minus | FRONT_LOOKS_PLUS } else { minus },
                    };
                }
            });
        }
        self.lost_lookups += lost;
        self.cursor = cursor;
        for p in 0..self.offsets.len() - 1 {
            let (a, b) = (self.offsets[p] as usize, self.offsets[p + 1] as usize);
            if b - a > 1 {
                sort_by_depth(&mut self.frags[a..b], scene.coincident_depth);
            }
        }
    }

    /// Calls `f(fragments)` for every pixel with at least one fragment; returns how many.
    pub fn for_each_pixel(&self, mut f: impl FnMut(&[Fragment])) -> u64 {
        let mut covered = 0;
        for w in self.offsets.windows(2) {
            if w[1] > w[0] {
                f(&self.frags[w[0] as usize..w[1] as usize]);
                covered += 1;
            }
        }
        covered
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
