//! `livebake bake`: load, bake, write light maps and the report, print a summary.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use livebake::bake::{BakeConfig, BakeOutput, bake};
use livebake::export::{ExportOptions, export_gltf};
use livebake::output::{irradiance_image, write_json, write_lightmaps};
use livebake::scene::{Rgb, STAND_IN_SKY, Scene, SurroundingsSpec, load_gltf};

use super::SceneOptions;
use super::progress::Ui;

use super::options::Backend;

/// Default samples: 256 bundle directions (under 5% error on a lit room); 16 paths per texel
/// for the reference backend (a recognisable preview in tens of seconds, not a converged bake).
pub(super) fn default_samples(backend: Backend) -> u32 {
    match backend {
        Backend::Cpu | Backend::Gpu | Backend::Auto => 256,
        Backend::Reference => 16,
    }
}

/// Loads the scene with the options' file and texture limits (`memory_limit`: `--memory-limit`,
/// where the command has one) and their surroundings (sky, environment map, sun), refusing
/// light too bright for the scene's sums.
pub fn load_scene(path: &Path, options: &SceneOptions, memory_limit: Option<u64>) -> Result<(Arc<Scene>, f64)> {
    load_scene_with(path, options, memory_limit).map(|(scene, seconds, _)| (scene, seconds))
}

/// [`load_scene`], with how its surroundings are made (for front ends that move the sun).
pub fn load_scene_with(
    path: &Path,
    options: &SceneOptions,
    memory_limit: Option<u64>,
) -> Result<(Arc<Scene>, f64, SurroundingsSpec)> {
    let t0 = Instant::now();
    let load = options.load_options(memory_limit);
    // The options first: a bad one fails before the scene loads.
    let spec = options.outdoors.spec(options.sky.unwrap_or(Rgb::ZERO), &load)?;
    let surroundings = spec.build().map_err(anyhow::Error::msg)?;
    let mut scene = load_gltf(path, &load).context("cannot load the scene")?;
    scene.set_surroundings(&surroundings).context("--sky, --environment or --sun")?;
    let nothing = "has no light of its own (no KHR_lights_punctual light, no emissive material)";
    if options.sky.is_some() {
        if !scene.has_light() {
            tracing::warn!("{}: the scene {nothing} and --sky is black: every light map will be black", path.display());
        }
    } else {
        // A white sky shows a model that brings no lighting as daylight from every side would
        // (a light map of sky exposure) until the user says how it is lit; a reload that
        // brings light takes it away (`Scene::stand_in_sky`).
        scene.sky_automatic = true;
        if scene.stand_in_sky() {
            tracing::warn!(
                "{}: the scene {nothing}, and no --sky, --sun, --environment or --sky-model was given: \
                 lit by a white sky of {STAND_IN_SKY} W/(sr·m²) while nothing else lights it (give one of those to light it yourself)",
                path.display()
            );
        }
    }
    Ok((Arc::new(scene), t0.elapsed().as_secs_f64(), spec))
}

/// What `bake` exports beside its light maps.
pub struct Exports<'a> {
    /// `--export-gltf OUT.gltf`
    pub gltf: Option<&'a Path>,
    /// `--export-web DIR`
    pub web: Option<&'a Path>,
}

pub fn run(
    scene_path: &Path,
    out: &Path,
    exports: Exports<'_>,
    memory_limit: Option<u64>,
    bounce_rounds: Option<u32>,
    options: &SceneOptions,
    ui: &Ui,
) -> Result<()> {
    // The light maps, their previews and the export read no texel positions.
    let config = BakeConfig {
        memory_limit,
        keep_texel_positions: false,
        bounce_rounds,
        ..options.bake_config(default_samples)?
    };
    let (scene, load_seconds) = load_scene(scene_path, options, memory_limit)?;
    tracing::info!(
        "loaded {}: {} meshes, {} triangles, {} lights in {:.2} s",
        scene_path.display(),
        scene.meshes.len(),
        scene.triangle_count(),
        scene.lights.len(),
        load_seconds
    );
    let mut baked = bake(&scene, &config, ui).with_context(|| format!("cannot bake {}", scene_path.display()))?;
    let t_write = Instant::now();
    let mut files = write_lightmaps(out, &baked)?;
    let web_gltf = exports.web.map(|dir| dir.join("scene.gltf"));
    for gltf in exports.gltf.into_iter().chain(web_gltf.as_deref()) {
        // The finest level baked.
        let lod = baked.lods.last().context("the bake produced no light-map level")?;
        let export = ExportOptions { load: options.load_options(memory_limit) };
        if let Some(dir) = gltf.parent() {
            std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
        }
        let report = export_gltf(&scene, &baked.atlas, &irradiance_image(lod), gltf, &export)
            .with_context(|| format!("cannot export {}", gltf.display()))?;
        files.extend([report.gltf, report.bin, report.hdr, report.png]);
    }
    if let Some(dir) = exports.web {
        // Every cell at the finest LOD baked: one cell over the whole scene.
        let (lo, hi) = scene.bounds().context("the scene has no geometry")?;
        let grid = livebake::grid::Grid::covering(lo, hi, (hi - lo).max_element().max(1e-3) * 1.001)
            .context("cannot cover the scene with one cell")?;
        let shown = livebake::viewer::source::shown_from_bake(&baked, grid, 0.0);
        let written = livebake::serve::export::export_web(dir, &scene, &baked.atlas, &shown, None, None)
            .with_context(|| format!("cannot export the web page into {}", dir.display()))?;
        files.extend(written);
    }
    baked.report.phases.load = load_seconds;
    baked.report.phases.write = t_write.elapsed().as_secs_f64();
    // The peak again, now that the light maps are written.
    baked.report.memory.measure();
    baked.report.bytes_per_texel = baked.report.memory.measured_bytes_per_texel;
    let report_path = out.join("report.json");
    write_json(&report_path, &baked.report)?;
    summarise(ui, scene_path, &baked, &files, &report_path);
    Ok(())
}

fn summarise(ui: &Ui, scene_path: &Path, baked: &BakeOutput, files: &[std::path::PathBuf], report: &Path) {
    let r = &baked.report;
    ui.say(format!(
        "livebake: {} ({} triangles, {} emissive materials, {} lights)",
        scene_path.display(),
        r.scene.triangles,
        r.scene.emissive_materials,
        r.scene.punctual_lights
    ));
    ui.say(format!(
        "  atlas {}×{} at {:.2} cm/texel, {} charts, fill {:.0}%",
        r.atlas.width,
        r.atlas.height,
        r.atlas.texel_size * 100.0,
        r.atlas.stats.charts,
        r.atlas.stats.fill_ratio * 100.0
    ));
    for l in &r.lods {
        // A bundle backend's sample is a direction shared by every texel.
        let samples = match l.bundle {
            Some(_) => format!("{} directions", l.samples_per_texel),
            None => format!("{} paths/texel", l.samples_per_texel),
        };
        ui.say(format!(
            "  LOD {}: {}×{}, {} texels, {samples}, {:.2} s, {:.2} M rays/s, mean E {:.3} W/m²",
            l.lod,
            l.width,
            l.height,
            l.texels,
            l.bake_seconds,
            l.rays_per_second / 1e6,
            (l.mean_irradiance[0] + l.mean_irradiance[1] + l.mean_irradiance[2]) / 3.0
        ));
    }
    for f in files {
        ui.say(format!("  wrote {}", f.display()));
    }
    ui.say(format!("  wrote {} ({:.2} s baking, backend {})", report.display(), r.total_seconds, r.backend));
}
