//! `livebake probe`: irradiance at surface points from a JSON file.

use std::path::Path;

use anyhow::{Context, Result, bail};
use glam::Vec3;
use serde_json::{Value, json};

use livebake::bake::bake;
use livebake::probe::{LightmapSampler, ProbeError, SurfaceLocator, SurfacePoint};
use livebake::reference::{Bvh, ReferenceTracer};
use livebake::scene::{Rgb, SceneGeometry};

use super::SceneOptions;
use super::bake::load_scene;
use super::options::Backend;
use super::progress::Ui;

/// Default samples: 1024 paths per point for the reference backend (~1% noise on a lit
/// interior); 256 directions for bundle backends.
fn default_samples(backend: Backend) -> u32 {
    match backend {
        Backend::Cpu => 256,
        Backend::Reference => 1024,
    }
}

struct Query {
    p: Vec3,
    n: Vec3,
}

fn vec3_field(point: &Value, key: &str, index: usize) -> Result<Vec3> {
    let arr = point
        .get(key)
        .and_then(Value::as_array)
        .with_context(|| format!("point {index}: missing \"{key}\": [x, y, z]"))?;
    let vals: Vec<f64> = arr.iter().filter_map(Value::as_f64).collect();
    if arr.len() != 3 || vals.len() != 3 {
        bail!("point {index}: \"{key}\" must be three numbers, got {}", Value::Array(arr.clone()));
    }
    Ok(Vec3::new(vals[0] as f32, vals[1] as f32, vals[2] as f32))
}

fn read_points(path: &Path) -> Result<(Value, Vec<Query>)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read points file {}", path.display()))?;
    let doc: Value = serde_json::from_str(&text).with_context(|| format!("{} is not valid JSON", path.display()))?;
    let list = doc.get("points").and_then(Value::as_array).with_context(|| {
        format!("{}: expected {{\"points\": [{{\"p\": [x,y,z], \"n\": [x,y,z]}}, ...]}}", path.display())
    })?;
    let queries = list
        .iter()
        .enumerate()
        .map(|(i, pt)| Ok(Query { p: vec3_field(pt, "p", i)?, n: vec3_field(pt, "n", i)? }))
        .collect::<Result<Vec<_>>>()
        .with_context(|| format!("in {}", path.display()))?;
    Ok((doc, queries))
}

pub fn run(scene_path: &Path, points_path: &Path, out: Option<&Path>, options: &SceneOptions, ui: &Ui) -> Result<()> {
    let config = options.bake_config(default_samples)?;
    let (mut doc, queries) = read_points(points_path)?;
    let (scene, _) = load_scene(scene_path, options)?;
    let results: Vec<Result<Rgb, ProbeError>> = match options.backend {
        Backend::Cpu => {
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
    if let Some(list) = doc.get_mut("points").and_then(Value::as_array_mut) {
        for (pt, r) in list.iter_mut().zip(&results) {
            match r {
                Ok(e) => pt["E"] = json!([e.x, e.y, e.z]),
                Err(err) => pt["error"] = json!(err.to_string()),
            }
        }
    }
    match out {
        Some(path) => {
            livebake::output::write_json(path, &doc)?;
            ui.say(format!("wrote {} ({} points)", path.display(), results.len()));
        }
        None => println!("{}", serde_json::to_string_pretty(&doc)?),
    }
    Ok(())
}
