//! The runtime's refinement work on a fixed workload, side by side with a whole-scene bake:
//! the "refinement throughput ≥ 1.0× a whole bake" as a figure that two builds can
//! be compared on.
//!
//! `runtime_real` reports the live runtime's own texel-samples a second, which depends on
//! which cells its scheduler took when: it moves by 2× and more between runs of one build.
//! Here the work is fixed: the cells nearest `runtime_real`'s eye on zdm2 (sun and sky) and
//! in the lit Van Gogh room, each baked alone (a group of one) at the LOD the runtime shows
//! there after 30 s, to a fixed number of directions, on one thread, after first light. The
//! whole-scene bake then bakes the same scene at that LOD's texel size on one thread; the
//! two alternate, three times (once in a quick run), and the medians and the median of
//! the repeats' ratios are reported. Both rates are texel-samples (texels × directions) per
//! second of their bundle passes; the cell bakes' texel set-up (the runtime's
//! `cell_setup_seconds`) is reported apart. The same cells are also baked as one group, one
//! bake whose every direction serves them all: the most that sharing each direction
//! between the bakes in flight could give them.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use anyhow::{Context, Result, anyhow};
use glam::Vec3;
use serde_json::{Value, json};

use livebake::atlas::AtlasConfig;
use livebake::bake::{BakeConfig, bake};
use livebake::bundle::BackendProvider;
use livebake::bundle::stats::PassStats;
use livebake::cpu::CpuProvider;
use livebake::progress::NoProgress;
use livebake::runtime::cell_bake::CellBake;
use livebake::runtime::shown::ShownLightmap;
use livebake::runtime::world::World;
use livebake::runtime::{RuntimeConfig, bake_first_light, empty_shown};
use livebake::sampling::mix64;
use livebake::scene::{LoadOptions, Rgb, SceneGeometry, load_gltf};

use super::runtime::quantile;
use super::{Bench, assets, seconds};

/// A scene of the workload: the eye whose nearest cells are baked, and the LOD.
struct Workload {
    name: &'static str,
    scene: &'static str,
    sky: Rgb,
    eye: Vec3,
    /// The bundle layer's median LOD at `runtime_real`'s points after 30 s.
    lod: u32,
}

const WORKLOADS: [Workload; 2] = [
    Workload {
        name: "zdm2 (real game map) under a sun and a sky",
        scene: "zdm2/zdm2_sun.gltf",
        sky: Rgb::new(0.4, 0.45, 0.5),
        eye: Vec3::new(0.0, 10.9, 0.0),
        lod: 3,
    },
    Workload {
        name: "Van Gogh room, lit (ceiling panel and lamp)",
        scene: "van_gogh_room/van_gogh_room_lit.gltf",
        sky: Rgb::ZERO,
        eye: Vec3::new(-0.1, 1.6, 2.6),
        lod: 2,
    },
];

/// Per direction, ms, of the phases that grow with a direction's triangles (analysis and
/// its mips and plan; build: set-up and the fragment count) and fragments (resolve).
fn per_direction_ms(p: &PassStats) -> Value {
    let per = |s: f64| 1e3 * s / p.directions.max(1) as f64;
    json!({
        "analysis": per(p.analysis_seconds + p.mip_seconds + p.subdivision_seconds),
        "build": per(p.build_seconds),
        "resolve": per(p.resolve_seconds),
        "light": per(p.light_seconds),
    })
}

/// Where a pass's resolve time goes: per pixel resolved, and how often a hit read the
/// radiance of a surface outside the target (a cell bake's lines mostly meet other cells'
/// surfaces, whose radiance comes from the shown map; a whole bake's from its own texels).
fn resolve_costs(p: &PassStats, texel_samples: f64) -> (f64, f64) {
    (1e9 * p.resolve_seconds / p.covered_pixels.max(1) as f64, p.foreign_lookups as f64 / texel_samples.max(1.0))
}

fn traced_seconds(p: &PassStats) -> f64 {
    p.analysis_seconds + p.mip_seconds + p.subdivision_seconds + p.build_seconds + p.resolve_seconds + p.light_seconds
}

fn one(bench: &Bench, w: &Workload) -> Result<Value> {
    let (cells_wanted, directions, whole_directions) = if bench.quick { (3, 8, 4) } else { (8, 32, 8) };
    let path = assets().join(w.scene);
    let mut loaded = load_gltf(&path, &LoadOptions::default()).with_context(|| format!("{}", path.display()))?;
    loaded.sky = w.sky;
    let scene = Arc::new(loaded);
    let config = RuntimeConfig::default();
    let geom = Arc::new(SceneGeometry::new(&scene));
    let atlas = Arc::new(livebake::atlas::Atlas::build(&scene, &geom, &config.atlas)?);
    let world = Arc::new(World::new(scene.clone(), geom, atlas, &config)?);
    let never = AtomicBool::new(false);
    let mut first = CpuProvider::new().backend(&world.bundle, config.threads()).map_err(|e| anyhow!("{e}"))?;
    let shown = Arc::new(
        bake_first_light(&world, &mut first, config.threads(), empty_shown(&world), &never)
            .map_err(|_| anyhow!("first light was cancelled"))?
            .0,
    );
    drop(first);

    // The non-empty cells nearest the eye (ties by id): what a viewer standing there refines.
    let mut cells: Vec<u32> = world.non_empty_cells().collect();
    let distance = |c: u32| {
        let (lo, hi) = world.cell_box(c);
        w.eye.clamp(lo, hi).distance(w.eye)
    };
    cells.sort_by(|&a, &b| distance(a).total_cmp(&distance(b)).then(a.cmp(&b)));
    cells.truncate(cells_wanted);

    let lod = w.lod.min(world.lods - 1);
    let texel = world.texel_size(lod);
    bench.ui.say(format!(
        "  {}: {} cells nearest the eye at LOD {lod} ({texel:.3} m texels), {directions} directions each ...",
        w.name,
        cells.len()
    ));
    let repeats = if bench.quick { 1 } else { 3 };
    let bake_config = BakeConfig {
        atlas: AtlasConfig { texel_size: Some(texel), ..config.atlas.clone() },
        samples: whole_directions,
        threads: Some(1),
        ..BakeConfig::default()
    };
    let (mut cell_rates, mut whole_rates, mut ratios) = (Vec::new(), Vec::new(), Vec::new());
    let (mut ceilings, mut checksums) = (Vec::new(), Vec::new());
    let (mut group_rates, mut group_ratios) = (Vec::new(), Vec::new());
    let (alone, together): (Vec<Vec<u32>>, _) = (cells.iter().map(|&c| vec![c]).collect(), [cells.clone()]);
    let mut last = None;
    for r in 0..repeats {
        bench.ui.status(&format!("cell_bakes: {}, repeat {} of {repeats}", w.scene, r + 1));
        let grouped = bake_cells(&world, &shown, &together, lod, directions)?;
        let cells = bake_cells(&world, &shown, &alone, lod, directions)?;
        let whole = bake(&scene, &bake_config, &NoProgress)?;
        let lod0 = whole.report.lods.first().ok_or_else(|| anyhow!("the whole bake has no LOD"))?;
        let whole_pass = lod0.bundle.as_ref().map(|b| b.stats.pass.clone()).unwrap_or_default();
        let whole_samples = lod0.texels as f64 * whole_directions as f64;
        let whole_rate = whole_samples / traced_seconds(&whole_pass).max(1e-9);
        cell_rates.push(cells.rate());
        whole_rates.push(whole_rate);
        ratios.push(cells.rate() / whole_rate);
        group_rates.push(grouped.rate());
        group_ratios.push(grouped.rate() / whole_rate);
        ceilings.push(cells.lines_rate() / whole_rate);
        checksums.push(format!("{:016x}", cells.checksum));
        last = Some((cells, lod0.texels, whole_pass, whole_samples));
    }
    let (cell_bakes, whole_texels, whole_pass, whole_samples) = last.ok_or_else(|| anyhow!("no repeat ran"))?;
    let median = |v: &[f64]| quantile(v, 0.5).unwrap_or(f64::NAN);
    let ratio = median(&ratios);
    let (cell_ns, cell_foreign) = resolve_costs(&cell_bakes.pass, cell_bakes.texel_samples as f64);
    let (whole_ns, whole_foreign) = resolve_costs(&whole_pass, whole_samples);
    bench.ui.say(format!(
        "  {}: cell bakes {:.2} M texel-samples/s, as one group {:.2} M, whole bake {:.2} M: ratio {ratio:.3}, \
         as one group {:.3} (medians of {repeats})",
        w.name,
        median(&cell_rates) / 1e6,
        median(&group_rates) / 1e6,
        median(&whole_rates) / 1e6,
        median(&group_ratios),
    ));
    Ok(json!({
        "scene": w.name,
        "file": w.scene,
        "triangles": scene.triangle_count(),
        "eye": w.eye.to_array(),
        "lod": lod,
        "texel_size_m": texel,
        "repeats": repeats,
        "cell_bakes": {
            "cells": cells,
            "texels": cell_bakes.texels,
            "directions_each": directions,
            "texel_samples": cell_bakes.texel_samples,
            "texel_set_up_seconds": cell_bakes.setup_seconds,
            "texel_samples_per_second": median(&cell_rates),
            "texel_samples_per_second_each": cell_rates,
            "fragments_per_texel_sample": cell_bakes.pass.fragments as f64 / cell_bakes.texel_samples.max(1) as f64,
            "resolved_pixels_per_texel_sample":
                cell_bakes.pass.covered_pixels as f64 / cell_bakes.texel_samples.max(1) as f64,
            "resolve_ns_per_resolved_pixel": cell_ns,
            "foreign_lookups_per_texel_sample": cell_foreign,
            "per_direction_ms": per_direction_ms(&cell_bakes.pass),
            "result_checksum_each": checksums,
        },
        "whole_bake": {
            "texels": whole_texels,
            "directions": whole_directions,
            "texel_samples_per_second": median(&whole_rates),
            "texel_samples_per_second_each": whole_rates,
            "fragments_per_texel_sample": whole_pass.fragments as f64 / whole_samples.max(1.0),
            "resolved_pixels_per_texel_sample": whole_pass.covered_pixels as f64 / whole_samples.max(1.0),
            "resolve_ns_per_resolved_pixel": whole_ns,
            "foreign_lookups_per_texel_sample": whole_foreign,
            "per_direction_ms": per_direction_ms(&whole_pass),
        },
        "one_group": {
            "texel_samples_per_second": median(&group_rates),
            "texel_samples_per_second_each": group_rates,
            "ratio_over_whole_bake": median(&group_ratios),
            "ratio_each": group_ratios,
        },
        "ratio_cell_bakes_over_whole_bake": ratio,
        "ratio_each": ratios,
        "ratio_with_per_triangle_phases_free": median(&ceilings),
        "goal_ratio": 1.0,
    }))
}

/// What the cell bakes of one repeat did.
struct CellBakes {
    texels: usize,
    texel_samples: u64,
    setup_seconds: f64,
    pass: PassStats,
    /// The published irradiance of every cell, folded bit by bit: equal for two builds whose
    /// cell bakes give the same bits (the bench's check that a faster build baked the same).
    checksum: u64,
}

impl CellBakes {
    fn rate(&self) -> f64 {
        self.texel_samples as f64 / traced_seconds(&self.pass).max(1e-9)
    }

    /// The rate over the resolve and light pass alone: what the cell bakes would reach if
    /// their analysis, tiling and triangle set-up cost nothing. Their lines are still the
    /// whole scene's (each pays every fragment along it, not only the cell's), so this
    /// bounds what cheaper per-triangle work can give against the whole bake.
    fn lines_rate(&self) -> f64 {
        self.texel_samples as f64 / (self.pass.resolve_seconds + self.pass.light_seconds).max(1e-9)
    }
}

/// Bakes each group of `groups` at `lod` to `directions`, on one thread.
fn bake_cells(
    world: &World,
    shown: &Arc<ShownLightmap>,
    groups: &[Vec<u32>],
    lod: u32,
    directions: u64,
) -> Result<CellBakes> {
    let config = RuntimeConfig::default();
    let never = AtomicBool::new(false);
    let mut backend = CpuProvider::new().backend(&world.bundle, 1).map_err(|e| anyhow!("{e}"))?;
    let mut done =
        CellBakes { texels: 0, texel_samples: 0, setup_seconds: 0.0, pass: PassStats::default(), checksum: 0 };
    for group in groups {
        let t = Instant::now();
        let mut cell_bake = CellBake::new(world, group, lod, shown.clone(), 7);
        done.setup_seconds += seconds(t);
        done.texels += cell_bake.texels.len();
        while cell_bake.directions() < directions {
            let unit = cell_bake
                .step(world, &mut backend, config.unit_directions, &never)
                .map_err(|_| anyhow!("a cell bake was cancelled"))?;
            done.texel_samples += unit.texel_samples;
            done.pass.add(&unit.pass);
        }
        for e in cell_bake.result() {
            for c in [e.x, e.y, e.z] {
                done.checksum = mix64(done.checksum ^ u64::from(c.to_bits()));
            }
        }
    }
    Ok(done)
}

pub fn run(bench: &Bench) -> Result<Value> {
    Ok(Value::Array(WORKLOADS.iter().map(|w| one(bench, w)).collect::<Result<Vec<_>>>()?))
}
