//! Light from around the scene: environment maps on the bundle backends (CPU and GPU) and
//! the reference tracer, against closed forms.
//!
//! Every tolerance is argued from the sample count or the filter in the test that uses it.

use std::sync::Arc;

use livebake::bake::{BackendKind, BakeConfig, BakeOutput, bake};
use livebake::bundle::sky::direction_solid_angle;
use livebake::glam::{DVec3, Vec3};
use livebake::progress::NoProgress;
use livebake::reference::ReferenceTracer;
use livebake::scene::builder::diffuse;
use livebake::scene::{Environment, Rgb, Scene, SceneBuilder};

fn config(backend: BackendKind, texel: f32, directions: u32) -> BakeConfig {
    let mut c = BakeConfig { backend, samples: directions, ..BakeConfig::default() };
    c.atlas.texel_size = Some(texel);
    c
}

fn run(scene: &Scene, config: &BakeConfig) -> BakeOutput {
    let out = bake(&Arc::new(scene.clone()), config, &NoProgress).expect("bake");
    if config.backend == BackendKind::Gpu {
        assert_eq!(out.report.backend, "gpu");
        for lod in &out.report.lods {
            let pass = &lod.bundle.as_ref().expect("bundle report").stats.pass;
            assert_eq!((pass.cpu_fallback_batches, pass.unresolved_pixels), (0, 0));
        }
    }
    out
}

/// A map of `width × height` pixels whose pixel holds `f` of the world direction through
/// its centre.
fn map(width: u32, height: u32, rotation: f32, f: impl Fn(DVec3) -> Rgb) -> Environment {
    let probe = Environment::new("probe", 1, 1, vec![Rgb::ZERO], rotation).expect("a map");
    let texels = (0..height)
        .flat_map(|y| (0..width).map(move |x| (x, y)))
        .map(|(x, y)| f(probe.direction((x as f64 + 0.5) / width as f64, (y as f64 + 0.5) / height as f64)))
        .collect();
    Environment::new("test", width, height, texels, rotation).expect("a map")
}

/// A floor with a block on it (the block shades the floor around it, and the floor is lit
/// from below too: the sky is the whole sphere).
fn floor_and_block() -> SceneBuilder {
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Rgb::splat(0.6), Rgb::ZERO, true));
    b.grid_quad(
        "floor",
        [Vec3::new(-1.5, 0.0, 1.5), Vec3::new(1.5, 0.0, 1.5), Vec3::new(1.5, 0.0, -1.5), Vec3::new(-1.5, 0.0, -1.5)],
        3,
        m,
    );
    let block = b.material(diffuse(Rgb::splat(0.4), Rgb::ZERO, false));
    b.cuboid("block", Vec3::new(-0.4, 0.0, -0.4), Vec3::new(0.4, 0.8, 0.4), false, block);
    b
}

/// A uniform map is the uniform sky: the filtered map is the same value everywhere (its
/// weights are normalised), so the bundles see the same radiance at the end of every line
/// and the light maps are those of `--sky`, texel for texel, to the rounding of that value
/// (a few f32 ulps through the sums). On the reference tracer the map is importance-sampled
/// as well, so the estimates differ by noise only: within 4σ of the two estimates'
/// combined standard error.
#[test]
fn a_uniform_environment_map_equals_the_uniform_sky() {
    let sky = Rgb::new(1.0, 0.5, 0.25);
    let mut with_sky = floor_and_block();
    with_sky.sky(sky);
    let with_sky = with_sky.build();
    let mut with_map = floor_and_block();
    with_map.environment(map(64, 32, 0.3, |_| sky));
    let with_map = with_map.build();
    for (backend, directions) in [(BackendKind::Cpu, 64), (BackendKind::Gpu, 16)] {
        let a = run(&with_sky, &config(backend, 0.1, directions));
        let b = run(&with_map, &config(backend, 0.1, directions));
        let (ea, eb) = (&a.lods[0].irradiance, &b.lods[0].irradiance);
        assert_eq!(ea.len(), eb.len());
        let worst = ea
            .iter()
            .zip(eb)
            .map(|(x, y)| ((*x - *y).abs() / x.max(Rgb::splat(1e-6))).max_element())
            .fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "{backend:?}: worst relative difference {worst}");
    }
    let (ta, tb) = (ReferenceTracer::new(&with_sky), ReferenceTracer::new(&with_map));
    for (p, n) in
        [(Vec3::new(1.0, 0.0, 0.9), Vec3::Y), (Vec3::new(0.5, 0.0, 0.0), Vec3::Y), (Vec3::new(0.4, 0.4, 0.0), Vec3::X)]
    {
        let (a, b) = (ta.irradiance_estimate(p, n, 4096, 1, 0), tb.irradiance_estimate(p, n, 4096, 2, 0));
        let sigma = (a.stderr * a.stderr + b.stderr * b.stderr).max_element().sqrt();
        assert!((a.e - b.e).abs().max_element() <= 4.0 * sigma.max(1e-6), "{p}: {} vs {} (σ {sigma})", a.e, b.e);
    }
}

/// A cube in empty space under a map bright (L = 1) in the octant x, y, z > 0 and black
/// elsewhere. A convex cube's faces see only the sky: the faces +X, +Y, +Z each see a
/// quarter of their hemisphere lit, E = ∫ cosθ dω over it = π/4; −X, −Y, −Z see none of it.
///
/// * Reference: at the face centres, within 4σ of π/4, and below 10⁻³ on the dark faces
///   (the map's bilinear rule blurs the octant by half a pixel, 0.35° here).
/// * Bundles, dark faces: the map is filtered over caps of Ω = 2π/D (radius r), so light
///   leaks past the octant's edge by up to r: on a dark face it reaches at most the band
///   within r of its horizon along the octant's quarter-circle edge (π/2 long), where less
///   than half of a cap is lit and the cosine is at most δ: E ≤ (π/2)·∫₀ʳ ½·δ dδ = π·r²/8;
///   the bilinear read of a grid of r/2 pixels widens r by up to a quarter: the face's mean
///   is held to π·(1.25·r)²/8 (measured 4–10 times below it).
/// * Bundles, lit faces: every texel of a face sees the same sky through the same D
///   directions, so the face's mean carries the directions' quadrature error of a lit
///   quarter: with independent cosine-distributed directions its relative standard error
///   would be √((1 − ¼)/¼ / D) = √(3/D); the stratified directions do better (measured 0.2–1 %
///   at D = 1024, 1–6 % at 256), held to √(3/D): 5.4 % on the CPU at 1024, 10.8 % on the GPU
///   at 256.
#[test]
fn an_environment_bright_in_one_octant_lights_only_the_faces_that_see_it() {
    let lit = |d: DVec3| if d.x > 0.0 && d.y > 0.0 && d.z > 0.0 { Rgb::ONE } else { Rgb::ZERO };
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Rgb::splat(0.5), Rgb::ZERO, false));
    b.cuboid("cube", Vec3::splat(-0.5), Vec3::splat(0.5), false, m);
    b.environment(map(512, 256, 0.0, lit));
    let scene = b.build();
    let quarter = std::f32::consts::FRAC_PI_4;
    let faces = [Vec3::X, Vec3::Y, Vec3::Z, Vec3::NEG_X, Vec3::NEG_Y, Vec3::NEG_Z];
    let tracer = ReferenceTracer::new(&scene);
    for n in faces {
        let e = tracer.irradiance_estimate(n * 0.5, n, 8192, 7, 0);
        let want = if n.min_element() < 0.0 { 0.0 } else { quarter };
        if want > 0.0 {
            assert!((e.e.x - want).abs() <= 4.0 * e.stderr.x, "reference {n}: {} ± {}", e.e.x, e.stderr.x);
        } else {
            assert!(e.e.x < 1e-3, "reference {n}: {}", e.e.x);
        }
    }
    for (backend, directions) in [(BackendKind::Cpu, 1024), (BackendKind::Gpu, 256)] {
        let tolerance = (3.0 / directions as f32).sqrt();
        let out = run(&scene, &config(backend, 0.05, directions));
        let lod = &out.lods[0];
        let radius = (1.0 - direction_solid_angle(directions) / (2.0 * std::f64::consts::PI)).acos() as f32;
        let leak = std::f32::consts::PI * (1.25 * radius).powi(2) / 8.0;
        for n in faces {
            let texels: Vec<f32> = (0..lod.irradiance.len())
                .filter(|&t| lod.texels.normal[t].dot(n) > 0.99)
                .map(|t| lod.irradiance[t].x)
                .collect();
            assert!(!texels.is_empty(), "{n}: no texels");
            let mean = texels.iter().sum::<f32>() / texels.len() as f32;
            if n.min_element() < 0.0 {
                assert!(mean <= leak, "{backend:?} {n}: mean {mean} above the filter's leak {leak}");
            } else {
                assert!((mean / quarter - 1.0).abs() < tolerance, "{backend:?} {n}: mean {mean} vs π/4");
            }
        }
    }
}
