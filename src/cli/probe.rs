//! `livebake probe`: irradiance at surface points from a JSON file.

use std::path::Path;

use anyhow::{Context, Result};
use glam::Vec3;

use livebake::bake::bake;
use livebake::probe::{LightmapSampler, ProbeError, SurfaceLocator, SurfacePoint};
use livebake::reference::{Bvh, ReferenceTracer};
use livebake::scene::{Rgb, SceneGeometry};

use super::SceneOptions;
use super::bake::load_scene;
use super::options::Backend;
use super::progress::Ui;
use livebake::points::{read_points, write_results};

/// Default samples: 1024 paths per point for the reference backend (~1% noise on a lit
/// interior); 256 directions for bundle backends.
fn default_samples(backend: Backend) -> u32 {
    match backend {
        Backend::Cpu | Backend::Gpu | Backend::Auto => 256,
        Backend::Reference => 1024,
    }
}

pub fn run(scene_path: &Path, points_path: &Path, out: Option<&Path>, options: &SceneOptions, ui: &Ui) -> Result<()> {
    let config = options.bake_config(default_samples)?;
    let points = read_points(points_path)?;
    let (scene, _) = load_scene(scene_path, options, None)?;
    let queries = &points.queries(scene.origin);
    let results: Vec<Result<Rgb, ProbeError>> = match options.backend {
        Backend::Cpu | Backend::Gpu | Backend::Auto => {
            let baked = bake(&scene, &config, ui).with_context(|| format!("cannot bake {}", scene_path.display()))?;
            let geom = SceneGeometry::new(&scene);
            let bvh = Bvh::new(&geom);
            let locator = SurfaceLocator::new(&geom, &bvh);
            let finest = baked.lods.last().context("the bake produced no light map")?;
            let sampler = LightmapSampler::new(&baked.atlas, finest);
            queries.iter().map(|q| locator.locate(q.p, q.n).and_then(|at| sampler.irradiance(&at))).collect()
        }
        Backend::Reference => {
            let tracer = ReferenceTracer::new(&scene).with_threads(config.threads);
            let locator = SurfaceLocator::new(tracer.geometry(), tracer.bvh());
            let geom = tracer.geometry();
            // The back of a single-sided surface is the inside of closed geometry: reported
            // as an error, as the light-map backends do (they have no texels there).
            let lit_side = |at: SurfacePoint| {
                let material = &scene.materials[geom.material[at.tri as usize] as usize];
                if material.has_side(at.side) { Ok(at) } else { Err(ProbeError::BackOfSingleSided) }
            };
            let located: Vec<Result<SurfacePoint, ProbeError>> =
                queries.iter().map(|q| locator.locate(q.p, q.n).and_then(lit_side)).collect();
            // Trace at the given point, over the hemisphere of the given normal (as the
            // Mitsuba cross-check tool does); points on no surface are reported, not traced.
            let ok: Vec<(Vec3, Vec3)> =
                queries.iter().zip(&located).filter(|(_, l)| l.is_ok()).map(|(q, _)| (q.p, q.n.normalize())).collect();
            ui.begin_phase("probe reference", ok.len() as u64);
            let (e, _) = tracer.irradiance_batch(&ok, config.samples, config.seed, &|done| ui.reached_at(done as u64));
            ui.end_phase();
            let mut e = e.into_iter();
            located.into_iter().map(|l| l.map(|_| e.next().unwrap_or(Rgb::ZERO))).collect()
        }
    };
    write_results(&points, &results, out)?;
    if let Some(path) = out {
        ui.say(format!("wrote {} ({} points)", path.display(), results.len()));
    }
    Ok(())
}
