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

/// Which layer a job makes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Work {
    Punctual,
    Bundles,
}

/// One layer of a cell's light at one LOD, as published: what a job on that layer can gain.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LayerLight {
    /// Mean luminance of the cell's texels (W/m²).
    pub luminance: f32,
    /// Detail the texels show at this LOD: the RMS difference between a texel's luminance
    /// and its chart neighbours' mean, over [`LayerLight::luminance`]. Where light changes
    /// from texel to texel (a shadow's edge, a corner), a finer LOD changes what is shown;
    /// where it is smooth, it changes little.
    pub detail: f32,
}

impl LayerLight {
    /// The light of a cell's texels from their luminances and their squared differences to
    /// their chart neighbours' mean (NaN for a texel with no neighbour, left out).
    pub fn of(luminance: impl Iterator<Item = (f32, f32)>) -> LayerLight {
        let (mut sum, mut n, mut contrast, mut m) = (0.0f64, 0usize, 0.0f64, 0usize);
        for (l, c) in luminance {
            sum += l as f64;
            n += 1;
            if !c.is_nan() {
                contrast += c as f64;
                m += 1;
            }
        }
        if n == 0 || sum <= 0.0 {
            return LayerLight::default();
        }
        let mean = sum / n as f64;
        let detail = if m > 0 { (contrast / m as f64).sqrt() / mean } else { 0.0 };
        LayerLight { luminance: mean as f32, detail: detail as f32 }
    }
}

/// Share of its screen weight a cell outside the frustum keeps: a turning head shows it soon.
pub const OUT_OF_VIEW: f32 = 0.25;

/// Least detail assumed of a level: one that shows none may still hide some below its texels
/// (a crease thinner than a texel), so it is refined, last.
pub const MIN_DETAIL: f32 = 0.01;

/// Work of making one texel of a cell's texel map (rasterised in UV, its surface point and
/// area) in texel-directions, the unit of bundle work: measured on zdm2, a texel map of a
/// cell costs about as much a texel as this many bundle directions.
pub const TEXEL_MAP_WORK: f64 = 24.0;
/// Work of one texel of a punctual bake (its texel map and a shadow ray per light), in
/// texel-directions.
pub const PUNCTUAL_TEXEL_WORK: f64 = 32.0;

/// How much of the screen a cell's surfaces may cover: their area over the squared distance
/// (the cell's half side added, so the cell holding the eye counts as a close one, not an
/// infinite one), [`OUT_OF_VIEW`] of it outside the frustum.
pub fn screen_weight(view: CellView, area: f32, cell_size: f32) -> f32 {
    let h = 0.5 * cell_size;
    let w = area / (view.distance * view.distance + h * h);
    if view.in_frustum { w } else { OUT_OF_VIEW * w }
}

/// A job on one layer of a cell, for [`urgency`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Step {
    /// The bundles' next finer LOD: `texels` there, `directions` still to trace before it is
    /// shown, `new` when its texel map is still to make (no bake of it is parked).
    Refine { texels: u64, directions: u64, new: bool },
    /// The shown level was published early and its bake goes on: its estimated relative
    /// `error` falls by 1/√2 over the `directions` still to trace before it is shown again.
    Continue { texels: u64, directions: u64, error: f32 },
    /// The punctual layer's next finer LOD (`texels` there).
    Punctual { texels: u64 },
}

/// The on-screen error a job is expected to remove per unit of work: the cell's screen
/// weight × the layer's luminance × the relative error the step removes (the detail of the
/// shown level for a finer LOD: its texels halve in size, and the light's variation within
/// them is what the finer level shows), over the work in texel-directions. One scale for
/// both layers: a sharper sun shadow and better bounced light compete by what they change
/// on screen and what they cost.
pub fn urgency(weight: f32, light: LayerLight, step: Step) -> f32 {
    let (gain, work) = match step {
        Step::Refine { texels, directions, new } => {
            let setup = if new { TEXEL_MAP_WORK } else { 0.0 };
            (light.detail.max(MIN_DETAIL), texels as f64 * (setup + directions as f64))
        }
        Step::Continue { texels, directions, error } => {
            let error = if error.is_finite() { error } else { 1.0 };
            (error * (1.0 - std::f32::consts::FRAC_1_SQRT_2), texels as f64 * directions as f64)
        }
        Step::Punctual { texels } => (light.detail.max(MIN_DETAIL), texels as f64 * PUNCTUAL_TEXEL_WORK),
    };
    let u = weight as f64 * light.luminance as f64 * gain as f64 / work.max(1.0);
    if u.is_finite() { u.max(0.0) as f32 } else { 0.0 }
}

/// Which work comes first whatever its urgency: a reload's provisional cells (the change
/// shown at full quality soonest), then refinement, then refreshing stale light.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Tier {
    Provisional,
    Refine,
    Refresh,
}

/// Sort key of a job (smaller goes first): its tier, then the more urgent.
pub fn priority(tier: Tier, urgency: f32) -> (Tier, std::cmp::Reverse<u32>) {
    // Non-negative finite f32s order as their bits.
    (tier, std::cmp::Reverse(urgency.max(0.0).to_bits()))
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

    /// A cell's light at LOD 0, as first light shows it: mean luminance and relative detail.
    #[test]
    fn layer_light_is_mean_luminance_and_relative_contrast() {
        let l = LayerLight::of([(2.0, 0.04), (4.0, f32::NAN), (6.0, 0.0)].into_iter());
        assert_eq!(l.luminance, 4.0);
        assert!((l.detail - (0.02f32).sqrt() / 4.0).abs() < 1e-6, "{l:?}");
        assert_eq!(LayerLight::of(std::iter::empty()), LayerLight::default());
    }

    /// Per unit of work: the brighter, more detailed, nearer, in-view cell first; a level
    /// four times the texels is four times the work; a punctual step competes on one scale.
    #[test]
    fn urgency_weighs_light_detail_screen_and_work() {
        let near = CellView { distance: 1.0, in_frustum: true };
        let far = CellView { distance: 20.0, in_frustum: true };
        let behind = CellView { distance: 1.0, in_frustum: false };
        let (w_near, w_far, w_behind) =
            (screen_weight(near, 10.0, 4.0), screen_weight(far, 10.0, 4.0), screen_weight(behind, 10.0, 4.0));
        assert!(w_near > 50.0 * w_far && (w_behind - OUT_OF_VIEW * w_near).abs() < 1e-6);
        let light = LayerLight { luminance: 2.0, detail: 0.2 };
        let refine = |texels| Step::Refine { texels, directions: 128, new: true };
        let u = urgency(w_near, light, refine(1000));
        assert!((urgency(w_near, light, refine(4000)) - u / 4.0).abs() < 1e-6 * u);
        assert!(urgency(w_far, light, refine(1000)) < u);
        let dim = LayerLight { luminance: 1.0, ..light };
        assert!((urgency(w_near, dim, refine(1000)) - u / 2.0).abs() < 1e-6 * u);
        let flat = LayerLight { detail: 0.0, ..light };
        assert!(urgency(w_near, flat, refine(1000)) > 0.0, "a flat level is refined, last");
        let p = urgency(w_near, light, Step::Punctual { texels: 1000 });
        assert!(p > u, "a punctual step of as many texels is cheaper than a bundle level");
        assert!(urgency(w_near, light, Step::Punctual { texels: 64_000 }) < u);
        assert!(priority(Tier::Refine, 0.0) < priority(Tier::Refresh, 1e9));
        assert!(priority(Tier::Refine, 2.0) < priority(Tier::Refine, 1.0));
    }
}
