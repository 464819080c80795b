//! Where a bundle direction looks, the same for every backend: the analysis window of a
//! direction (the target's box or the scene's bounding sphere, projected), the viewport of
//! a planned tile, and the split of a rectangle that overflowed the node buffer.

use glam::{Vec2, Vec3};

use super::BundleConfig;
use super::raster::{BundleFrame, Viewport};
use super::stats::PassStats;
use super::tiles::Tile;

/// What a direction's window is made from.
#[derive(Clone, Copy, Debug)]
pub struct WindowSource {
    /// The target's world box (`BakeTarget::window`); `None`: the whole scene.
    pub target: Option<(Vec3, Vec3)>,
    /// The scene's bounding sphere.
    pub centre: Vec3,
    pub radius: f32,
    /// Bundle pixel side at the target's LOD (texel size / oversampling), metres.
    pub bundle_pixel: f32,
}

/// Bundle pixels per analysis pixel a cell's window aims at (see [`analysis_viewport`]).
const BUNDLE_PIXELS_PER_ANALYSIS_PIXEL: f32 = 8.0;

impl WindowSource {
    /// The window's square along `frame`: the target's box projected (or the scene's
    /// bounding sphere for a whole-scene target), as (lower corner, side).
    pub fn square(&self, frame: &BundleFrame) -> (Vec2, f32) {
        match self.target {
            None => {
                let (r, c) = (self.radius, frame.coords(self.centre));
                (Vec2::new(c.x - r, c.y - r), 2.0 * r)
            }
            Some((lo, hi)) => {
                let (mut a, mut b) = (Vec2::splat(f32::MAX), Vec2::splat(f32::MIN));
                for i in 0..8 {
                    let p = Vec3::new(
                        if i & 1 == 0 { lo.x } else { hi.x },
                        if i & 2 == 0 { lo.y } else { hi.y },
                        if i & 4 == 0 { lo.z } else { hi.z },
                    );
                    let c = frame.coords(p);
                    a = a.min(Vec2::new(c.x, c.y));
                    b = b.max(Vec2::new(c.x, c.y));
                }
                let side = (b - a).max_element().max(1e-6);
                let centre = (a + b) * 0.5;
                (centre - Vec2::splat(side * 0.5), side)
            }
        }
    }

    /// The analysis window of a direction: the square, R pixels, with one spare pixel so
    /// the per-direction jitter never shifts geometry out of it. A small window (a cell's)
    /// needs fewer analysis pixels: R is cut to the power of two giving about
    /// `BUNDLE_PIXELS_PER_ANALYSIS_PIXEL` bundle pixels per analysis pixel at the target's
    /// resolution, at least 8.
    pub fn analysis_viewport(&self, config: &BundleConfig, frame: &BundleFrame, jitter: Vec2) -> Viewport {
        let (corner, side) = self.square(frame);
        let mut res = config.analysis_res;
        if self.target.is_some() {
            let wanted = (side / self.bundle_pixel / BUNDLE_PIXELS_PER_ANALYSIS_PIXEL).ceil().max(8.0) as u32;
            res = res.min(wanted.next_power_of_two());
        }
        let pixel = side / (res - 1) as f32;
        Viewport::square(corner - jitter * pixel, pixel, res)
    }
}

/// The bundle viewport of planned tile `tile` of the analysis window `global`.
pub fn tile_viewport(global: &Viewport, tile: &Tile) -> Viewport {
    let w = tile.window();
    let side = w.side as f32 * global.pixel;
    Viewport::square(global.origin + Vec2::new(w.x as f32, w.y as f32) * global.pixel, side / tile.res as f32, tile.res)
}

/// A rectangle counted more fragments than the node buffer holds: record it and queue its
/// parts (its pixel grid cut in four: the paper's "split and redo", sampling exactly the
/// same pixels), so no sample is lost. Returns false when the rectangle is a single pixel
/// deeper than the whole node buffer (N too small for the scene); the caller then builds it
/// anyway rather than drop samples.
pub fn split_overflowed(
    vp: &Viewport,
    count: u64,
    capacity: u64,
    queue: &mut Vec<Viewport>,
    stats: &mut PassStats,
) -> bool {
    stats.overflowed_tiles += 1;
    stats.overflow_fragments += count - capacity;
    match vp.split() {
        Some(parts) => {
            stats.resplits += 1;
            queue.extend(parts.iter().rev());
            true
        }
        None => {
            stats.unsplittable_tiles += 1;
            false
        }
    }
}

/// Records a direction whose tiles could not be planned (the driver refuses the result).
pub fn unplanned(stats: &mut PassStats, error: &dyn std::fmt::Display) {
    tracing::error!("bundle direction not planned: {error}");
    stats.unplanned_directions += 1;
}
