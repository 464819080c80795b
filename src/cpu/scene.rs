//! Per-scene data the CPU bundle passes read for every direction, built once per scene and
//! shared (`Arc`) by every worker: texel densities, the triangles' bounding-box tree, the
//! scene's bounding sphere and when fragments are one layer.

use std::sync::Arc;

use glam::Vec3;

use super::bounds_tree::BoundsTree;
use super::through::Passing;
use crate::bundle::BundleScene;
use crate::bundle::estimator::Coincidence;
use crate::bundle::raster::snapped_depth_slack;
use crate::reference::ray_epsilon;
use crate::scene::Side;

pub struct CpuScene {
    pub bundle: Arc<BundleScene>,
    /// Per triangle: LOD-0 light-map texels per m² (the larger of its two faces; 0 without
    /// faces). At LOD k it is 4^k times this: the importance of Sect. 3, in rays per m².
    pub density: Vec<f32>,
    /// Bounding boxes of the triangles, for culling against bundle windows along any
    /// direction.
    pub bounds: BoundsTree,
    /// Centre and radius of the scene's bounding sphere.
    pub centre: Vec3,
    pub radius: f32,
    /// When fragments are one layer ([`Coincidence`]): `rounding` is far below any real
    /// wall thickness and above f32 rounding of depths at this scene's scale (~10⁻⁷
    /// relative); `stacked` is the scene's ray offset ε, as the reference tracer's; `snap`
    /// is left to each tile ([`CpuScene::coincidence_at`]).
    pub coincidence: Coincidence,
    /// Which triangles let light through (`None`: every one is opaque, and lines resolve
    /// without transmittances).
    pub passing: Option<Passing>,
}

impl CpuScene {
    /// The layer tolerances of a tile with pixels of side `pixel` (metres).
    pub fn coincidence_at(&self, pixel: f32) -> Coincidence {
        Coincidence { snap: snapped_depth_slack(pixel), ..self.coincidence }
    }

    pub fn new(bundle: Arc<BundleScene>) -> Self {
        let (geom, atlas) = (&bundle.geom, &bundle.atlas);
        let density = (0..geom.len() as u32)
            .map(|t| {
                Side::BOTH
                    .iter()
                    .filter_map(|&s| atlas.face(t, s))
                    .map(|f| atlas.texel_density(geom, f, 0))
                    .fold(0.0f32, f32::max)
            })
            .collect();
        let (lo, hi) = geom
            .corners
            .iter()
            .flatten()
            .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        let centre = (lo + hi) * 0.5;
        let radius = geom.corners.iter().flatten().map(|p| (*p - centre).length()).fold(0.0f32, f32::max).max(1e-6);
        let bounds = BoundsTree::new(&geom.corners);
        let rounding = 1e-6 * (radius + centre.abs().max_element());
        // `snap` depends on each tile's pixel size: set per tile.
        let coincidence = Coincidence { rounding, stacked: ray_epsilon(&bundle.scene).max(rounding), snap: 0.0 };
        let passing = Passing::new(&bundle.scene, geom);
        CpuScene { bundle, density, bounds, centre, radius, coincidence, passing }
    }
}
