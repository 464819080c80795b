//! What the bundles of a cell bake see: every surface's outgoing radiance read from a
//! snapshot of the shown light map through the one sampling function.

use std::sync::Arc;

use glam::Vec2;

use super::shown::{Layer, ShownLightmap};
use crate::atlas::sparse::SparseTexels;
use crate::bundle::{BundleScene, SurfaceRadiance};
use crate::scene::{Rgb, Side};

/// Outgoing radiance of lit surfaces from a shown-light-map snapshot: `albedo/π · E` plus
/// emission where the global bundles carry it (large emitters); small emitters reach the
/// bundles through the light pass instead.
pub struct ShownSource {
    pub shown: Arc<ShownLightmap>,
    pub bundle: Arc<BundleScene>,
}

impl ShownSource {
    /// Outgoing radiance of each texel of `texels` (their own surface points and UVs).
    pub fn own(&self, texels: &SparseTexels, carried: &[bool]) -> Vec<Rgb> {
        let scale = 1.0 / (1u64 << texels.lod) as f32;
        (0..texels.len())
            .map(|i| {
                let [x, y] = texels.pixel[i];
                let uv = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) * scale;
                let e = self.shown.irradiance(texels.position[i], uv);
                let reflected = texels.albedo[i] * e * std::f32::consts::FRAC_1_PI;
                if carried[i] { reflected + texels.emission[i] } else { reflected }
            })
            .collect()
    }

    /// Mean luminance of the punctual layer over `texels` (0 when it is unused).
    pub fn punctual_mean(&self, texels: &SparseTexels) -> f64 {
        if !self.shown.layer(Layer::Punctual).used || texels.is_empty() {
            return 0.0;
        }
        let scale = 1.0 / (1u64 << texels.lod) as f32;
        let sum: f64 = (0..texels.len())
            .map(|i| {
                let [x, y] = texels.pixel[i];
                let uv = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) * scale;
                let p = texels.position[i];
                let e = self.shown.layer_irradiance(Layer::Punctual, self.shown.grid.cell_of(p), p, uv);
                crate::scene::luminance(e) as f64
            })
            .sum();
        sum / texels.len() as f64
    }
}

impl SurfaceRadiance for ShownSource {
    fn radiance(&self, tri: u32, side: Side, u: f32, v: f32) -> Rgb {
        let b = &self.bundle;
        let Some(face) = b.atlas.face(tri, side) else { return Rgb::ZERO };
        let p = b.geom.point(tri, u, v);
        let e = self.shown.irradiance(p, b.atlas.faces[face as usize].uv_at(u, v));
        let reflected = b.geom.albedo(&b.scene, tri, u, v) * e * std::f32::consts::FRAC_1_PI;
        if b.emitters.carried_by_bundles[tri as usize] { reflected + self.emission(tri, side, u, v) } else { reflected }
    }

    fn emission(&self, tri: u32, side: Side, u: f32, v: f32) -> Rgb {
        let b = &self.bundle;
        let m = &b.scene.materials[b.geom.material[tri as usize] as usize];
        if m.is_emissive() && m.emits_from(side) { b.geom.emission(&b.scene, tri, u, v) } else { Rgb::ZERO }
    }

    /// The GPU resolve evaluates this source itself (`gpu::surface_radiance`).
    fn as_any(&self) -> Option<&dyn std::any::Any> {
        Some(self)
    }
}
