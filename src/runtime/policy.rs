//! LOD policy: which LOD each cell should show for the current camera, and which cell to
//! refine next. Pure functions of the camera and the cells, so they are tested alone.

use glam::Vec3;

use crate::grid::{CellId, Grid};
use crate::scene::{Projection, Scene};

/// What the viewer looks through: the runtime refines what this camera sees.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CameraView {
    pub eye: Vec3,
    pub target: Vec3,
    pub up: Vec3,
    /// Vertical field of view, radians.
    pub yfov: f32,
    /// Width / height.
    pub aspect: f32,
    /// Height of the image in pixels (sets how fine a texel the screen can show).
    pub height_px: u32,
}

impl CameraView {
    /// A 60° camera of 1280×720 pixels at `eye` looking at `target`, +Y up.
    pub fn looking_at(eye: Vec3, target: Vec3) -> Self {
        CameraView { eye, target, up: Vec3::Y, yfov: 60f32.to_radians(), aspect: 16.0 / 9.0, height_px: 720 }
    }

    /// The scene's first glTF camera; without one, a view from inside the scene's bounds
    /// (architectural scenes are mostly closed rooms with single-sided walls facing in):
    /// at mid-height, 40% of the way from the centre toward +Z, looking at the centre.
    pub fn for_scene(scene: &Scene) -> CameraView {
        if let Some(c) = scene.cameras.first() {
            let forward = c.rotation * Vec3::NEG_Z;
            let (yfov, aspect) = match c.projection {
                Projection::Perspective { yfov, aspect, .. } => (yfov, aspect.unwrap_or(16.0 / 9.0)),
                Projection::Orthographic { .. } => (60f32.to_radians(), 16.0 / 9.0),
            };
            let view = CameraView {
                eye: c.position,
                target: c.position + forward,
                up: c.rotation * Vec3::Y,
                yfov,
                aspect,
                height_px: 720,
            };
            if view.is_valid() {
                return view;
            }
        }
        let (lo, hi) = scene.bounds().unwrap_or((Vec3::splat(-1.0), Vec3::splat(1.0)));
        let centre = (lo + hi) * 0.5;
        let eye = centre + Vec3::new(0.0, 0.05 * (hi.y - lo.y), 0.4 * (hi.z - lo.z));
        CameraView::looking_at(eye, centre)
    }

    /// Unit forward, right and up vectors (a degenerate pose looks down −Z).
    pub fn basis(&self) -> (Vec3, Vec3, Vec3) {
        let f = (self.target - self.eye).try_normalize().unwrap_or(Vec3::NEG_Z);
        let r = f.cross(self.up).try_normalize().unwrap_or_else(|| f.any_orthonormal_vector());
        (f, r, r.cross(f))
    }

    pub fn is_valid(&self) -> bool {
        self.eye.is_finite()
            && self.target.is_finite()
            && self.up.is_finite()
            && self.yfov.is_finite()
            && self.yfov > 0.0
            && self.yfov < std::f32::consts::PI
            && self.aspect.is_finite()
            && self.aspect > 0.0
            && self.height_px > 0
    }
}

/// Where a cell stands for the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CellView {
    /// Distance from the eye to the cell's box (0 inside it).
    pub distance: f32,
    /// Whether the cell's bounding sphere meets the view frustum.
    pub in_frustum: bool,
}

pub fn cell_view(camera: &CameraView, grid: &Grid, cell: CellId) -> CellView {
    let (lo, hi) = grid.bounds(cell);
    let distance = (camera.eye.clamp(lo, hi) - camera.eye).length();
    let (f, r, u) = camera.basis();
    let c = (lo + hi) * 0.5 - camera.eye;
    let radius = (hi - lo).length() * 0.5;
    let (x, y, z) = (c.dot(r), c.dot(u), c.dot(f));
    let tv = (camera.yfov * 0.5).tan();
    let th = tv * camera.aspect;
    // A sphere meets the pyramid when it is within its radius of each side plane.
    let side = |coord: f32, t: f32| coord.abs() <= z * t + radius * (1.0 + t * t).sqrt();
    let in_frustum = distance == 0.0 || (z > -radius && side(x, th) && side(y, tv));
    CellView { distance, in_frustum }
}

/// The LOD a cell should show: the coarsest at which a texel projects to at most
/// `texel_pixels` screen pixels at the cell's distance (LOD k's texels are `texel0 / 2^k`
/// metres), one coarser outside the frustum (turning the head shows them soon), within
/// `0..levels`.
pub fn target_lod(camera: &CameraView, view: CellView, texel0: f32, texel_pixels: f32, levels: u32) -> u32 {
    // Screen size (m) of one pixel at the cell's distance; 1 cm at least, so that a camera
    // inside a cell asks for no more than the finest level.
    let pixel = view.distance.max(0.01) * camera.yfov / camera.height_px as f32;
    let wanted = (texel0 / (texel_pixels * pixel)).log2().ceil();
    let k = if wanted.is_finite() { wanted.max(0.0) as u32 } else { 0 };
    let k = if view.in_frustum { k } else { k.saturating_sub(1) };
    k.min(levels.saturating_sub(1))
}

/// Which layer a job makes; at equal urgency the punctual layer goes first (one cheap
/// exact bake a cell, where the bundles take many units).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Work {
    Punctual,
    Bundles,
}

/// Sort key of a job on a cell (smaller goes first): refinement before refreshing stale
/// light (`refresh`), cells in view before others, then the largest LOD deficit (target −
/// shown in the layer the job makes: a deficit of d shows texels 2^d times too coarse for
/// the screen, so this goes for the blurriest light on screen first, which is the nearest
/// surfaces'), the punctual layer before the bundles, then the nearest.
pub fn priority(
    view: CellView,
    deficit: u32,
    refresh: bool,
    work: Work,
) -> (bool, bool, std::cmp::Reverse<u32>, Work, u32) {
    (refresh, !view.in_frustum, std::cmp::Reverse(deficit), work, view.distance.to_bits())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid() -> Grid {
        Grid::covering(Vec3::splat(-10.0), Vec3::splat(10.0), 1.0).unwrap()
    }

    #[test]
    fn frustum_and_distance() {
        let g = grid();
        let cam = CameraView::looking_at(Vec3::new(0.5, 0.5, 5.0), Vec3::new(0.5, 0.5, 0.0));
        let ahead = cell_view(&cam, &g, g.cell_of(Vec3::new(0.5, 0.5, -3.5)));
        assert!(ahead.in_frustum);
        assert!((ahead.distance - 8.0).abs() < 1e-4);
        let behind = cell_view(&cam, &g, g.cell_of(Vec3::new(0.5, 0.5, 9.5)));
        assert!(!behind.in_frustum);
        let aside = cell_view(&cam, &g, g.cell_of(Vec3::new(9.5, 0.5, 4.5)));
        assert!(!aside.in_frustum);
        let around = cell_view(&cam, &g, g.cell_of(cam.eye));
        assert!(around.in_frustum && around.distance == 0.0);
    }

    /// Halving the distance halves a texel's screen size: one LOD finer, up to the cap.
    #[test]
    fn nearer_cells_want_finer_lods() {
        let cam = CameraView::looking_at(Vec3::ZERO, Vec3::Z);
        let view = |d: f32| CellView { distance: d, in_frustum: true };
        let k = |d: f32| target_lod(&cam, view(d), 0.16, 2.0, 8);
        // At 100 m a pixel is ~0.145 m: a 0.16 m texel is under 2 pixels: LOD 0.
        assert_eq!(k(100.0), 0);
        let (a, b) = (k(10.0), k(5.0));
        assert_eq!(b, a + 1);
        assert_eq!(target_lod(&cam, view(0.0), 0.16, 2.0, 4), 3);
        assert_eq!(target_lod(&cam, CellView { distance: 5.0, in_frustum: false }, 0.16, 2.0, 8), b - 1);
    }

    #[test]
    fn priority_orders_view_then_deficit_then_layer_then_distance() {
        let v = |d: f32, f: bool| CellView { distance: d, in_frustum: f };
        let b = Work::Bundles;
        let mut keys = [
            priority(v(1.0, false), 3, false, b),
            priority(v(9.0, true), 1, false, b),
            priority(v(2.0, true), 2, false, b),
            priority(v(8.0, true), 2, false, b),
            priority(v(50.0, true), 2, false, Work::Punctual),
            priority(v(0.5, true), 6, true, b),
        ];
        keys.sort();
        assert_eq!(keys[0], priority(v(50.0, true), 2, false, Work::Punctual));
        assert_eq!(keys[1], priority(v(2.0, true), 2, false, b));
        assert_eq!(keys[2], priority(v(8.0, true), 2, false, b));
        assert_eq!(keys[3], priority(v(9.0, true), 1, false, b));
        assert_eq!(keys[4], priority(v(1.0, false), 3, false, b));
        assert_eq!(keys[5], priority(v(0.5, true), 6, true, b), "refreshes last");
    }
}
