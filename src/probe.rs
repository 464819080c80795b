//! Irradiance at arbitrary surface points: find the surface under a point and the side facing
//! the given normal, then either read the baked light map there (bilinear, in that side's
//! chart) or path-trace it directly.

use glam::{Vec2, Vec3};

use crate::atlas::texels::NO_TEXEL;
use crate::atlas::{Atlas, TexelMap};
use crate::bake::BakedLod;
use crate::reference::{Bvh, Hit};
use crate::scene::{Rgb, SceneGeometry, Side, TriangleId};

/// Where a probe point landed.
#[derive(Clone, Copy, Debug)]
pub struct SurfacePoint {
    pub tri: TriangleId,
    /// Barycentrics (weights of corners 1 and 2).
    pub u: f32,
    pub v: f32,
    pub side: Side,
    /// Distance from the query point to the surface, metres.
    pub distance: f32,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProbeError {
    #[error("normal {0:?} is not a finite non-zero vector")]
    BadNormal([f32; 3]),
    #[error("point {0:?} is not finite")]
    BadPoint([f32; 3]),
    #[error("no surface within {tolerance} m of the point")]
    NoSurface { tolerance: f32 },
    #[error("the surface under the point is single-sided and the normal looks at its back, which has no light map")]
    BackOfSingleSided,
}

/// Finds surfaces under query points.
pub struct SurfaceLocator<'a> {
    geom: &'a SceneGeometry,
    bvh: &'a Bvh,
    /// How far a query point may be from the surface, metres.
    pub tolerance: f32,
}

/// Surfaces a locating ray looks through before it gives up on finding the point's own
/// (beyond it the nearest so far is taken).
const MAX_CROSSINGS: usize = 16;

impl<'a> SurfaceLocator<'a> {
    /// Tolerance defaults to 1e-3 of the scene's bounding-box diagonal (1 cm in a 10 m room),
    /// loose enough for coordinates typed by hand or printed with few digits.
    pub fn new(geom: &'a SceneGeometry, bvh: &'a Bvh) -> Self {
        let (lo, hi) = geom
            .corners
            .iter()
            .flatten()
            .fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), p| (lo.min(*p), hi.max(*p)));
        let diag = if lo.x <= hi.x { (hi - lo).length() } else { 1.0 };
        SurfaceLocator { geom, bvh, tolerance: (1e-3 * diag).max(1e-5) }
    }

    /// The surface under `p` whose side faces `n`. A short ray from just above the point
    /// (along `n`) back down the normal finds the surface the point lies on even in corners,
    /// where the nearest triangle may be the adjoining wall; of the surfaces it crosses, the
    /// one nearest the point. (The first it met was taken before: the tolerance is a
    /// thousandth of the scene's size, 17 cm in the 120 m temple, and a floor point under a
    /// column's base ring 10 cm above read the ring's inside.) The nearest triangle is the
    /// fallback for normals that do not match the surface.
    pub fn locate(&self, p: Vec3, n: Vec3) -> Result<SurfacePoint, ProbeError> {
        if !p.is_finite() {
            return Err(ProbeError::BadPoint(p.to_array()));
        }
        let n = n.try_normalize().ok_or(ProbeError::BadNormal(n.to_array()))?;
        let tol = self.tolerance;
        let origin = p + n * tol;
        // Hits come in order along the ray: walk them until one is at or past the point.
        let mut nearest: Option<Hit> = None;
        let mut tmin = 0.0;
        for _ in 0..MAX_CROSSINGS {
            let Some(hit) = self.bvh.intersect(origin, -n, tmin, 2.0 * tol) else { break };
            if nearest.is_none_or(|b| (hit.t - tol).abs() < (b.t - tol).abs()) {
                nearest = Some(hit);
            }
            if hit.t >= tol {
                break;
            }
            // Past this surface (and any coincident with it: either would do).
            tmin = hit.t + tol * 1e-4;
        }
        if let Some(hit) = nearest {
            let side = Side::facing(self.geom.normals[hit.tri as usize], n);
            return Ok(SurfacePoint { tri: hit.tri, u: hit.u, v: hit.v, side, distance: (hit.t - tol).abs() });
        }
        let c = self.bvh.closest_point(p, tol).ok_or(ProbeError::NoSurface { tolerance: tol })?;
        let side = Side::facing(self.geom.normals[c.tri as usize], n);
        Ok(SurfacePoint { tri: c.tri, u: c.u, v: c.v, side, distance: c.distance })
    }
}

/// Where located points read one light-map level: the texel under every pixel (gutters
/// filled), so a point's bilinear taps can be found once and read from any irradiance per
/// texel of that level, finished or still accumulating.
pub struct LightmapLookup<'a> {
    atlas: &'a Atlas,
    lod: u32,
    width: u32,
    height: u32,
    /// Texel index per pixel; [`NO_TEXEL`] outside every chart.
    texel: Vec<u32>,
}

/// Up to four texels and their bilinear weights: what a located point reads.
#[derive(Clone, Copy, Debug)]
pub struct BilinearTaps {
    taps: [(u32, f32); 4],
    count: usize,
}

impl BilinearTaps {
    /// The filtered value of per-texel `value`s; weights renormalised over the taps present.
    pub fn read(&self, value: impl Fn(usize) -> Rgb) -> Rgb {
        let mut sum = Rgb::ZERO;
        let mut wsum = 0.0;
        for &(t, w) in &self.taps[..self.count] {
            sum += value(t as usize) * w;
            wsum += w;
        }
        if wsum > 0.0 { sum / wsum } else { Rgb::ZERO }
    }
}

impl<'a> LightmapLookup<'a> {
    pub fn new(atlas: &'a Atlas, texels: &TexelMap) -> Self {
        let index: Vec<u32> = (0..texels.len() as u32).collect();
        LightmapLookup {
            atlas,
            lod: texels.lod,
            width: texels.width,
            height: texels.height,
            texel: texels.to_image(&index, NO_TEXEL),
        }
    }

    /// The taps of a located surface point, in its side's chart.
    pub fn taps(&self, at: &SurfacePoint) -> Result<BilinearTaps, ProbeError> {
        let face = self.atlas.face(at.tri, at.side).ok_or(ProbeError::BackOfSingleSided)?;
        let [a, b, c] = self.atlas.faces[face as usize].uv;
        let uv = a + (b - a) * at.u + (c - a) * at.v;
        Ok(self.bilinear(uv * (1u32 << self.lod) as f32))
    }

    /// Bilinear taps at a pixel-space position; empty pixels (which gutters make impossible
    /// next to a chart, but be safe) are left out and the rest renormalised when read.
    fn bilinear(&self, p: Vec2) -> BilinearTaps {
        let q = p - Vec2::splat(0.5);
        let base = q.floor();
        let f = q - base;
        let mut taps = BilinearTaps { taps: [(0, 0.0); 4], count: 0 };
        for (dx, dy, w) in
            [(0, 0, (1.0 - f.x) * (1.0 - f.y)), (1, 0, f.x * (1.0 - f.y)), (0, 1, (1.0 - f.x) * f.y), (1, 1, f.x * f.y)]
        {
            let (x, y) = (base.x as i64 + dx, base.y as i64 + dy);
            if x < 0 || y < 0 || x >= self.width as i64 || y >= self.height as i64 {
                continue;
            }
            let t = self.texel[(y as u32 * self.width + x as u32) as usize];
            if t != NO_TEXEL {
                taps.taps[taps.count] = (t, w);
                taps.count += 1;
            }
        }
        taps
    }
}

/// Bilinear reads from one baked light-map level.
pub struct LightmapSampler<'a> {
    lookup: LightmapLookup<'a>,
    irradiance: Vec<Rgb>,
}

impl<'a> LightmapSampler<'a> {
    pub fn new(atlas: &'a Atlas, baked: &BakedLod) -> Self {
        LightmapSampler { lookup: LightmapLookup::new(atlas, &baked.texels), irradiance: baked.irradiance.clone() }
    }

    /// Irradiance (W/m²) at a located surface point, bilinearly filtered in its side's chart.
    pub fn irradiance(&self, at: &SurfacePoint) -> Result<Rgb, ProbeError> {
        Ok(self.lookup.taps(at)?.read(|t| self.irradiance[t]))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneBuilder;
    use crate::scene::builder::diffuse;

    /// A 120 m floor (tolerance 0.17 m) under a closed, double-sided box hovering 5 cm above
    /// it: a point on the floor with its normal up lies on the floor (distance 0), not on the
    /// box's bottom 5 cm above, whose inside faces up too.
    #[test]
    fn a_point_is_located_on_its_own_surface_not_one_within_the_tolerance() {
        let mut b = SceneBuilder::new();
        let grey = b.material(diffuse(Vec3::splat(0.5), Vec3::ZERO, false));
        let both_sides = b.material(diffuse(Vec3::splat(0.5), Vec3::ZERO, true));
        b.floor("floor", Vec3::ZERO, 120.0, grey);
        b.cuboid("box", Vec3::new(-0.5, 0.05, -0.5), Vec3::new(0.5, 0.5, 0.5), false, both_sides);
        let scene = b.build();
        let geom = SceneGeometry::new(&scene);
        let bvh = Bvh::new(&geom);
        let locator = SurfaceLocator::new(&geom, &bvh);
        assert!(locator.tolerance > 0.1, "tolerance {}", locator.tolerance);
        let floor_mesh = 0;
        for p in [Vec3::new(0.1, 0.0, 0.2), Vec3::new(-0.3, 0.0, 0.4), Vec3::new(3.0, 0.0, 3.0)] {
            let at = locator.locate(p, Vec3::Y).expect("a surface");
            assert_eq!(geom.mesh[at.tri as usize], floor_mesh, "at {p}");
            assert!(at.distance < 1e-5, "at {p}: {}", at.distance);
        }
        // And the box's inside bottom, from within the box, is the box's.
        let at = locator.locate(Vec3::new(0.1, 0.05, 0.2), Vec3::Y).expect("a surface");
        assert_ne!(geom.mesh[at.tri as usize], floor_mesh);
        assert!(at.distance < 1e-5);
    }
}
