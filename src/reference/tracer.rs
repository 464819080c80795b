//! The reference irradiance estimator.
//!
//! `E(p, n) = ∫_{H(n)} L_in(ω) cosθ dω` (W/m²), estimated by paths that start at the query:
//!
//! * At every vertex (the query point included) light is gathered by next-event estimation
//!   towards one emissive triangle (chosen by power, uniform point) **and** by the
//!   cosine-sampled continuation ray, the two combined with the power heuristic; punctual
//!   lights add their direct irradiance (`PunctualLight::unoccluded_irradiance` + a shadow
//!   ray); rays that escape see the uniform sky (`Scene::sky`, whole sphere) and the
//!   environment map (`Scene::environment`), which next-event estimation also samples by its
//!   luminance ([`EnvironmentSampler`]), combined with the cosine rays by the power heuristic.
//! * The query vertex has "BSDF" 1 (we integrate L·cos), later vertices are Lambertian with
//!   `albedo/π`, so a cosine-sampled bounce multiplies the throughput by π at the query and
//!   by the albedo afterwards.
//! * Russian roulette from bounce [`TracerOptions::rr_start`] on: survival probability
//!   `min(0.95, max(throughput)/π)` (the throughput relative to the query's π), unbiased.
//! * Sidedness: the back of a single-sided surface is the inside of closed geometry: black,
//!   the path ends. The back of a double-sided surface is a real surface (flipped normal,
//!   same albedo, emits if the material emits). Every face blocks light from both sides.
//! * Flat geometric normals (as the Mitsuba cross-check does); vertex normals are ignored.
//!
//! **Ray offset.** New rays start at `x + ε·n_side`, with n_side the normal of the side the
//! path is on (the query normal at the query), and
//! `ε = 1e-5 × (bounding-box diagonal + largest |coordinate|)` of the scene: the same rule as
//! the Mitsuba cross-check (`shared/tools/mitsuba_ref`). An f32 coordinate of magnitude M is
//! exact to ~6e-8·M, so ε leaves a margin of > 100 ulps against self-intersection while
//! staying far below any feature the light map resolves. Shadow rays stop ε short of the
//! light or emitter point. Punctual lights are evaluated at the surface point itself, so
//! inverse-square distances are exact; emitters, the sky and bounces are seen from
//! p + ε·n, a relative difference of order 2ε/d for a source at distance d (2e-5 for a small
//! emitter 2 m away in a 2 m scene: visible only in zero-variance tests).

use std::f32::consts::PI;

use glam::{DVec3, Vec3};

use super::bvh::Bvh;
use super::emitters::EmitterTable;
use super::environment::EnvironmentSampler;
use crate::sampling::{Rng, cosine_hemisphere};
use crate::scene::luminance;
use crate::scene::{Material, Rgb, Scene, SceneGeometry, Side};

/// Knobs of the reference tracer. The defaults are what every test and report uses.
#[derive(Clone, Debug)]
pub struct TracerOptions {
    /// Worker threads for batches; `None` = available parallelism. Results never depend on it.
    pub threads: Option<usize>,
    /// Bounces (after the query vertex) before Russian roulette starts.
    pub rr_start: u32,
    /// Hard cap on bounces, a guard against pathological scenes (albedo 1 everywhere). With
    /// survival ≤ 0.95 a path reaches it with probability < 0.95^(cap − rr_start).
    pub max_bounces: u32,
    /// Up to this many punctual lights are all shadow-tested at every vertex; with more, one
    /// is chosen per vertex in proportion to its unoccluded irradiance (luminance).
    pub all_lights_up_to: usize,
}

impl Default for TracerOptions {
    fn default() -> Self {
        TracerOptions { threads: None, rr_start: 3, max_bounces: 1000, all_lights_up_to: 8 }
    }
}

/// Monte Carlo estimate of E at one query point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct IrradianceEstimate {
    /// Mean over the paths, W/m².
    pub e: Rgb,
    /// Standard error of the mean (1σ, from the sample variance), W/m².
    pub stderr: Rgb,
    /// Rays cast (path segments and shadow rays).
    pub rays: u64,
}

/// The CPU reference path tracer over one scene. See the [module docs](self).
pub struct ReferenceTracer<'s> {
    pub(crate) scene: &'s Scene,
    pub(crate) geom: SceneGeometry,
    pub(crate) bvh: Bvh,
    pub(crate) emitters: EmitterTable,
    pub(crate) eps: f32,
    pub(crate) options: TracerOptions,
    /// Importance sampling of the scene's environment map (`None` without a lit one).
    environment: Option<EnvironmentSampler>,
}

/// Power heuristic (β = 2) weight of a strategy with density `a` against one with `b`.
#[inline]
fn power_heuristic(a: f32, b: f32) -> f32 {
    let r = b / a;
    1.0 / (1.0 + r * r)
}

/// The ray-offset ε of a scene (see the module docs).
pub fn ray_epsilon(scene: &Scene) -> f32 {
    match scene.bounds() {
        Some((lo, hi)) => 1e-5 * ((hi - lo).length() + lo.abs().max(hi.abs()).max_element()),
        None => 1e-5,
    }
    .max(f32::MIN_POSITIVE)
}

impl<'s> ReferenceTracer<'s> {
    /// Builds geometry, BVH (with alpha masks) and emitter table for `scene`.
    pub fn new(scene: &'s Scene) -> Self {
        Self::with_options(scene, TracerOptions::default())
    }

    pub fn with_options(scene: &'s Scene, options: TracerOptions) -> Self {
        let geom = SceneGeometry::new(scene);
        let bvh = Bvh::for_scene(scene, &geom);
        let emitters = EmitterTable::new(scene, &geom);
        let environment = scene.environment.as_deref().and_then(EnvironmentSampler::new);
        ReferenceTracer { scene, geom, bvh, emitters, eps: ray_epsilon(scene), options, environment }
    }

    /// Overrides the batch worker count (`None` = available parallelism).
    pub fn with_threads(mut self, threads: Option<usize>) -> Self {
        self.options.threads = threads;
        self
    }

    pub fn scene(&self) -> &'s Scene {
        self.scene
    }

    pub fn geometry(&self) -> &SceneGeometry {
        &self.geom
    }

    pub fn bvh(&self) -> &Bvh {
        &self.bvh
    }

    pub fn emitters(&self) -> &EmitterTable {
        &self.emitters
    }

    pub fn options(&self) -> &TracerOptions {
        &self.options
    }

    /// The ray-offset ε in metres.
    pub fn epsilon(&self) -> f32 {
        self.eps
    }

    /// Irradiance E (W/m²) on the hemisphere of unit normal `n` at surface point `p`:
    /// the mean of `spp` paths drawn from `Rng::new(seed, stream)`.
    pub fn irradiance(&self, p: Vec3, n: Vec3, spp: u32, seed: u64, stream: u64) -> Rgb {
        self.irradiance_estimate(p, n, spp, seed, stream).e
    }

    /// [`irradiance`](Self::irradiance) with its standard error and ray count.
    pub fn irradiance_estimate(&self, p: Vec3, n: Vec3, spp: u32, seed: u64, stream: u64) -> IrradianceEstimate {
        let n = n.normalize_or_zero();
        if n == Vec3::ZERO || spp == 0 {
            return IrradianceEstimate { e: Rgb::ZERO, stderr: Rgb::ZERO, rays: 0 };
        }
        let mut rng = Rng::new(seed, stream);
        let mut rays = 0u64;
        let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
        for _ in 0..spp {
            let s = self.path(p, n, &mut rng, &mut rays).as_dvec3();
            sum += s;
            sum2 += s * s;
        }
        let k = spp as f64;
        let mean = sum / k;
        let var = if spp > 1 { ((sum2 / k - mean * mean) * (k / (k - 1.0))).max(DVec3::ZERO) } else { DVec3::ZERO };
        IrradianceEstimate { e: mean.as_vec3(), stderr: (var / k).sqrt().as_vec3(), rays }
    }

    #[inline]
    fn material(&self, tri: u32) -> &Material {
        &self.scene.materials[self.geom.material[tri as usize] as usize]
    }

    /// One path's estimate of E at (p, n); counts the rays it casts.
    fn path(&self, p: Vec3, n: Vec3, rng: &mut Rng, rays: &mut u64) -> Rgb {
        let mut e = Rgb::ZERO;
        // Throughput up to the current vertex, and the current vertex's BSDF.
        let mut beta = Rgb::ONE;
        let mut f = Rgb::ONE;
        let (mut x, mut nx) = (p, n);
        for bounce in 0..=self.options.max_bounces {
            let xo = x + nx * self.eps;
            let bf = beta * f;
            e += bf
                * (self.punctual(x, xo, nx, rng, rays)
                    + self.next_event(xo, nx, rng, rays)
                    + self.environment_event(xo, nx, rng, rays));
            let wi = cosine_hemisphere(nx, rng.next_vec2());
            let cos = nx.dot(wi);
            if cos <= 0.0 {
                break;
            }
            beta = bf * PI;
            if bounce >= self.options.rr_start {
                let survive = (beta.max_element() / PI).min(0.95);
                if rng.next_f32() >= survive {
                    break;
                }
                beta /= survive;
            }
            // The ray crosses see-through surfaces (each passing `Sheet::pass`) until one
            // reflects it: at every crossing, pass or reflect is chosen in proportion to
            // mean(pass) and mean(reflect) (the Mitsuba cross-check's rule), the throughput
            // divided by the choice's probability.
            let mut travelled = 0.0;
            let next = loop {
                *rays += 1;
                let Some(hit) = self.bvh.intersect(xo, wi, travelled, f32::INFINITY) else {
                    e += beta * (self.scene.sky + self.environment_seen(wi, cos));
                    break None;
                };
                let ng = self.geom.normals[hit.tri as usize];
                let side = if ng.dot(wi) < 0.0 { Side::Front } else { Side::Back };
                let m = self.material(hit.tri);
                if m.is_emissive() && m.emits_from(side) {
                    let le = self.geom.emission(self.scene, hit.tri, hit.u, hit.v);
                    let pdf_l =
                        EmitterTable::solid_angle_pdf(self.emitters.area_pdf(hit.tri), hit.t * hit.t, ng.dot(wi));
                    e += beta * le * power_heuristic(cos / PI, pdf_l);
                }
                let sheet = self.bvh.alpha().sheet_at(hit.tri, hit.u, hit.v);
                let reflect = match sheet {
                    _ if !m.has_side(side) => Rgb::ZERO,
                    Some(s) => s.reflect,
                    None => self.geom.albedo(self.scene, hit.tri, hit.u, hit.v),
                };
                let pass = sheet.map_or(Rgb::ZERO, |s| s.pass);
                let (p_pass, p_reflect) = (pass.element_sum(), reflect.element_sum());
                if p_pass + p_reflect <= 0.0 {
                    break None;
                }
                if p_pass > 0.0 && rng.next_f32() * (p_pass + p_reflect) < p_pass {
                    beta *= pass * ((p_pass + p_reflect) / p_pass);
                    travelled = hit.t + self.eps;
                    continue;
                }
                beta *= (p_pass + p_reflect) / p_reflect;
                break Some((reflect, self.geom.point(hit.tri, hit.u, hit.v), ng * side.sign()));
            };
            let Some((albedo, point, normal)) = next else { break };
            f = albedo / PI;
            x = point;
            nx = normal;
        }
        e
    }

    /// Next-event estimation towards one emitter point, MIS-weighted against the cosine
    /// sampling of the same vertex. Returns the contribution to ∫ L cos dω at `xo`.
    fn next_event(&self, xo: Vec3, nx: Vec3, rng: &mut Rng, rays: &mut u64) -> Rgb {
        let Some(s) = self.emitters.sample(rng.next_u32(), rng.next_f32(), rng.next_vec2()) else {
            return Rgb::ZERO;
        };
        let y = self.geom.point(s.tri, s.u, s.v);
        let d = y - xo;
        let dist2 = d.length_squared();
        let dist = dist2.sqrt();
        if dist <= self.eps {
            return Rgb::ZERO;
        }
        let wi = d / dist;
        let cos_x = nx.dot(wi);
        let cos_y = -self.geom.normals[s.tri as usize].dot(wi);
        if cos_x <= 0.0 || cos_y == 0.0 {
            return Rgb::ZERO;
        }
        let side = if cos_y > 0.0 { Side::Front } else { Side::Back };
        if !self.material(s.tri).emits_from(side) || !self.bvh.alpha().opaque_at(s.tri, s.u, s.v) {
            return Rgb::ZERO;
        }
        let le = self.geom.emission(self.scene, s.tri, s.u, s.v);
        if le.max_element() <= 0.0 {
            return Rgb::ZERO;
        }
        *rays += 1;
        let pass = self.bvh.transmittance(xo, wi, dist - self.eps, self.eps);
        if pass.max_element() <= 0.0 {
            return Rgb::ZERO;
        }
        let pdf_l = EmitterTable::solid_angle_pdf(s.area_pdf, dist2, cos_y);
        pass * le * (cos_x / pdf_l * power_heuristic(pdf_l, cos_x / PI))
    }

    /// The environment's radiance along an escaping cosine-sampled ray `wi` (cosine `cos` to
    /// the vertex's normal), MIS-weighted against the environment's own sampling.
    fn environment_seen(&self, wi: Vec3, cos: f32) -> Rgb {
        let Some(map) = self.scene.environment.as_deref() else { return Rgb::ZERO };
        let l = map.radiance(wi);
        match &self.environment {
            Some(s) => l * power_heuristic(cos / PI, s.pdf(map, wi)),
            None => l,
        }
    }

    /// Next-event estimation toward one direction drawn from the environment map,
    /// MIS-weighted against the cosine sampling of the same vertex.
    fn environment_event(&self, xo: Vec3, nx: Vec3, rng: &mut Rng, rays: &mut u64) -> Rgb {
        let (Some(map), Some(sampler)) = (self.scene.environment.as_deref(), &self.environment) else {
            return Rgb::ZERO;
        };
        let Some(s) = sampler.sample(map, rng.next_vec2()) else { return Rgb::ZERO };
        let cos = nx.dot(s.direction);
        if cos <= 0.0 {
            return Rgb::ZERO;
        }
        let l = map.radiance(s.direction);
        if l.max_element() <= 0.0 {
            return Rgb::ZERO;
        }
        *rays += 1;
        let pass = self.bvh.transmittance(xo, s.direction, f32::INFINITY, self.eps);
        if pass.max_element() <= 0.0 {
            return Rgb::ZERO;
        }
        pass * l * (cos / s.pdf * power_heuristic(s.pdf, cos / PI))
    }

    /// Direct irradiance from punctual lights at surface point `x` (normal `nx`), shadow rays
    /// from `xo`. All lights when there are few, else one chosen by unoccluded luminance.
    fn punctual(&self, x: Vec3, xo: Vec3, nx: Vec3, rng: &mut Rng, rays: &mut u64) -> Rgb {
        let lights = &self.scene.lights;
        if lights.len() <= self.options.all_lights_up_to {
            let mut e = Rgb::ZERO;
            for i in 0..lights.len() {
                e += self.shadowed_light(i, x, xo, nx, rays);
            }
            return e;
        }
        let total: f32 = lights.iter().map(|l| luminance(l.unoccluded_irradiance(x, nx).0)).sum();
        if total <= 0.0 {
            return Rgb::ZERO;
        }
        let target = rng.next_f32() * total;
        let mut acc = 0.0;
        let mut pick = None;
        for (i, l) in lights.iter().enumerate() {
            let y = luminance(l.unoccluded_irradiance(x, nx).0);
            if y > 0.0 {
                pick = Some((i, y));
                acc += y;
                if acc > target {
                    break;
                }
            }
        }
        let Some((i, y)) = pick else { return Rgb::ZERO };
        self.shadowed_light(i, x, xo, nx, rays) * (total / y)
    }

    /// Unoccluded irradiance of light `i` at `x` times its visibility from `xo`.
    fn shadowed_light(&self, i: usize, x: Vec3, xo: Vec3, nx: Vec3, rays: &mut u64) -> Rgb {
        let light = &self.scene.lights[i];
        let (el, wi, dist) = light.unoccluded_irradiance(x, nx);
        if el.max_element() <= 0.0 {
            return Rgb::ZERO;
        }
        let (dir, tmax) = if dist.is_finite() {
            let d = light.position - xo;
            let l = d.length();
            (d / l, l - self.eps)
        } else {
            (wi, f32::INFINITY)
        };
        *rays += 1;
        if tmax > 0.0 { el * self.bvh.transmittance(xo, dir, tmax, self.eps) } else { el }
    }
}
