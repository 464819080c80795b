//! The CPU resolve of lines that cross see-through surfaces or cut-outs: each fragment's
//! transmittance, then [`crate::bundle::through`]'s walk. Only scenes with `BLEND`,
//! `KHR_materials_transmission` or `MASK` materials come here; the others resolve with
//! [`exchange`](crate::bundle::estimator::exchange) and [`emit`](crate::bundle::estimator::emit)
//! as before, untouched.
//!
//! A fragment's transmittance is its surface's [`Sheet::pass`](crate::scene::Sheet) at the
//! point where the line crosses it; a `MASK` surface below its cutoff is no surface and is
//! dropped from the list (no texel is lit there, nothing is stopped). Textured materials
//! are read at that point (barycentrics of the pixel centre in the triangle's projection),
//! untextured ones once per material.

use glam::Vec2;

use super::fragments::ForeignSides;
use crate::atlas::Atlas;
use crate::bundle::estimator::{Fragment, HitSink, Layering, NO_SIDE, is_own, side_code};
use crate::bundle::raster::{BundleFrame, Viewport};
use crate::bundle::sky::SkySeen;
use crate::bundle::target::BakeTarget;
use crate::bundle::through::{Layer, emit_through, exchange_through};
use crate::scene::{AlphaMode, MaterialPoint, Rgb, Scene, SceneGeometry};

const OPAQUE: u32 = u32::MAX;
/// Set on [`Passing::material`] where the triangle's mesh has vertex colours: its alpha and
/// tint vary over it whatever its material's textures.
const COLORED: u32 = 1 << 31;

/// Per scene: which triangles may let light through, and how.
pub struct Passing {
    /// Per triangle: its material when that material may let light through (with
    /// [`COLORED`]), else [`OPAQUE`].
    material: Vec<u32>,
    /// Per material: its transmittance where no texture varies it (`None` inside: cut out).
    uniform: Vec<Option<Option<Rgb>>>,
}

impl Passing {
    /// `None` when every material is opaque (no cut-outs, nothing see-through).
    pub fn new(scene: &Scene, geom: &SceneGeometry) -> Option<Passing> {
        let passes = |m: &crate::scene::Material| m.lets_light_through();
        if !scene.materials.iter().any(passes) {
            return None;
        }
        let material = (0..geom.len())
            .map(|t| {
                let m = geom.material[t];
                match passes(&scene.materials[m as usize]) {
                    true if geom.has_colors(scene, t) => m | COLORED,
                    true => m,
                    false => OPAQUE,
                }
            })
            .collect();
        let uniform = scene
            .materials
            .iter()
            .map(|m| {
                (m.base_color_texture.is_none() && m.transmission_texture.is_none())
                    .then(|| transmittance(m, &scene.textures, MaterialPoint::default()))
            })
            .collect();
        Some(Passing { material, uniform })
    }
}

/// What locates a fragment's surface point in the tile being resolved.
pub struct Line<'a> {
    pub scene: &'a Scene,
    pub geom: &'a SceneGeometry,
    pub atlas: &'a Atlas,
    pub target: &'a BakeTarget<'a>,
    pub frame: &'a BundleFrame,
    pub viewport: &'a Viewport,
    pub foreign: &'a ForeignSides<'a>,
    /// Whether foreign sides are texels of the LOD being baked by another region shard
    /// ([`crate::bundle::SurfaceRadiance::by_lod_pixel`]): their transmittance is then
    /// sampled where a target texel's is (the line's projection), so that it is the same
    /// bits as in the whole LOD's bake.
    pub foreign_as_own: bool,
    /// The pixel's grid centre.
    pub cx: f32,
    pub cy: f32,
}

/// The transmittance of material `m` at `p`; `None` where it is cut out (`MASK` below its
/// cutoff: no surface, no texel lit). A `BLEND` surface with α = 0 passes everything too but
/// is kept: its texels still measure the light there (and reflect none of it).
fn transmittance(m: &crate::scene::Material, textures: &[crate::scene::Texture], p: MaterialPoint) -> Option<Rgb> {
    if let AlphaMode::Mask { cutoff } = m.alpha_mode
        && m.alpha(textures, p) < cutoff
    {
        return None;
    }
    Some(m.sheet(textures, p).pass)
}

impl Passing {
    /// The transmittance of fragment `f` on `line` (zero: opaque; `None`: cut out).
    fn pass(&self, f: &Fragment, line: &Line) -> Option<Rgb> {
        let code = match side_code(f.plus) {
            NO_SIDE => side_code(f.minus),
            c => c,
        };
        if code == NO_SIDE {
            return Some(Rgb::ZERO);
        }
        let (tri, bary) = if is_own(code) {
            (line.atlas.faces[line.target.face[code as usize] as usize].tri, None)
        } else {
            let (tri, _, u, v) = line.foreign.locate(code, line.cx, line.cy);
            (tri, (!line.foreign_as_own).then_some((u, v)))
        };
        let m = self.material[tri as usize];
        if m == OPAQUE {
            return Some(Rgb::ZERO);
        }
        if m & COLORED == 0
            && let Some(t) = self.uniform[m as usize]
        {
            return t;
        }
        let (u, v) = bary.unwrap_or_else(|| projected_barycentrics(line, tri));
        let p = line.geom.material_point(line.scene, tri, u, v);
        transmittance(&line.scene.materials[(m & !COLORED) as usize], &line.scene.textures, p)
    }

    /// Each fragment's transmittance into `scratch`, cut-outs left out.
    fn collect(&self, frags: &[Fragment], line: &Line, scratch: &mut ThroughScratch) {
        scratch.frags.clear();
        scratch.pass.clear();
        for f in frags {
            if let Some(t) = self.pass(f, line) {
                scratch.frags.push(*f);
                scratch.pass.push(t);
            }
        }
    }

    /// [`exchange_through`] of one pixel's depth-sorted fragments.
    #[allow(clippy::too_many_arguments)]
    pub fn exchange(
        &self,
        frags: &[Fragment],
        line: &Line,
        l: Layering,
        a_px: f32,
        sky: SkySeen,
        seen: impl FnMut(u32) -> Rgb,
        sink: &mut impl HitSink,
        scratch: &mut ThroughScratch,
    ) {
        self.collect(frags, line, scratch);
        exchange_through(&scratch.frags, &scratch.pass, l, a_px, sky, seen, sink, &mut scratch.layers);
    }

    /// [`emit_through`] of one pixel's depth-sorted fragments.
    #[allow(clippy::too_many_arguments)]
    pub fn emit(
        &self,
        frags: &[Fragment],
        line: &Line,
        l: Layering,
        a_px: f32,
        emission: impl FnMut(u32) -> Rgb,
        sink: &mut impl HitSink,
        scratch: &mut ThroughScratch,
    ) {
        self.collect(frags, line, scratch);
        emit_through(&scratch.frags, &scratch.pass, l, a_px, emission, sink, &mut scratch.layers);
    }
}

/// Barycentrics (of corners 1 and 2) of the pixel centre in the plane of triangle `tri`
/// projected along the line's direction. Not clamped: `tri` is the triangle of the texel's
/// face, and a texel's square reaches a little over the neighbouring triangles of its chart,
/// whose fragments then read the texture where the face's parametrisation extends to (the
/// same UV where TEXCOORD_0 is affine across them, as over a quad); clamped, they read it
/// along the shared edge instead.
fn projected_barycentrics(line: &Line, tri: u32) -> (f32, f32) {
    let p = line.viewport.origin + Vec2::new(line.cx, line.cy) * line.viewport.pixel;
    let [a, b, c] = line.geom.corners[tri as usize].map(|q| {
        let f = line.frame.coords(q);
        Vec2::new(f.x, f.y)
    });
    let (e1, e2, d) = (b - a, c - a, p - a);
    let det = e1.perp_dot(e2);
    if det == 0.0 {
        return (0.0, 0.0);
    }
    (d.perp_dot(e2) / det, e1.perp_dot(d) / det)
}

/// One worker's buffers for the lines of a scene with [`Passing`].
#[derive(Default)]
pub struct ThroughScratch {
    frags: Vec<Fragment>,
    pass: Vec<Rgb>,
    layers: Vec<Layer>,
}
