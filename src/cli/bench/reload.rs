//! Hot reload: a bundled room copied into a temp dir, the runtime started on it with its
//! defaults and watching its files (as `livebake run --watch`), first light and some
//! refinement, then one mesh moved again and again by rewriting its node's translation in
//! the `.gltf` (the `.bin` untouched; saved in place and by temp file + rename in turn, the
//! two ways editors save), with refinement going on throughout. Per move: `reload_applied.ms`
//! and `reload_relit.ms` (from the change being seen, the runtime's figures), the wall time
//! from the save to the event, the cells invalidated, and an audit of the cells that were
//! not: their LOD-0 light (texels and gutter pixels, from the shown map before the save and
//! right after `reload_relit`) must be unchanged unless a worker published the cell in that
//! window (a stale cell's refresh, by design), and they must keep their shown LOD. The
//! relight is at `RuntimeConfig::reload_directions`; each move then waits for
//! `reload_refined` (the same cells re-baked with first light's directions by the workers)
//! and reports its time, and where the time of `apply` went (`steps_ms`).
//!
//! Also a generated ≥ 100k-triangle scene: the Van Gogh room with a finely tessellated torus
//! (102 400 triangles) hung under the ceiling, written next to the room's copy.

use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use livebake::glam::Vec3;
use serde_json::{Value, json};

use livebake::cpu::CpuProvider;
use livebake::grid::CellId;
use livebake::runtime::shown::ShownLightmap;
use livebake::runtime::world::World;
use livebake::runtime::{CellInfo, Runtime, RuntimeConfig, RuntimeEvent};
use livebake::scene::{LoadOptions, load_gltf};
use livebake::watch::WatchConfig;

use super::assets;
use super::runtime::{PATIENCE, inside_camera, next_event, wait_first_light};
use super::{Bench, Narrator};

/// A room and the node moved in it.
struct Case {
    scene: &'static str,
    node: &'static str,
    /// Add the dense torus.
    dense: bool,
}

const CASES: [Case; 4] = [
    Case { scene: "cornell_box/cornellBox-2.79-Cycles-gltf.gltf", node: "bloc.000", dense: false },
    Case { scene: "cornell_2m/cornell_2m.gltf", node: "block", dense: false },
    // A chair (1590 triangles, about 0.9 × 1.2 × 0.9 m).
    Case { scene: "van_gogh_room/van_gogh_room_lit.gltf", node: "010_13___Defaultddddddddd", dense: false },
    Case { scene: "van_gogh_room/van_gogh_room_lit.gltf", node: "010_13___Defaultddddddddd", dense: true },
];

/// How far the node moves along +x (and back, in turn), metres.
const STEP: f32 = 0.1;
/// The torus: centre, radii and tessellation (2 · 320 · 160 = 102 400 triangles).
const TORUS: ([f32; 3], f32, f32, u32, u32) = ([0.0, 3.0, 4.0], 0.35, 0.08, 320, 160);

fn copy_dir(from: &Path, to: &Path) -> Result<()> {
    std::fs::create_dir_all(to).with_context(|| format!("cannot create {}", to.display()))?;
    for entry in std::fs::read_dir(from).with_context(|| format!("cannot read {}", from.display()))? {
        let entry = entry?;
        let target = to.join(entry.file_name());
        if entry.file_type()?.is_dir() {
            copy_dir(&entry.path(), &target)?;
        } else {
            std::fs::copy(entry.path(), &target)
                .with_context(|| format!("cannot copy {} to {}", entry.path().display(), target.display()))?;
        }
    }
    Ok(())
}

fn push(doc: &mut Value, key: &str, item: Value) -> Result<usize> {
    if doc.get(key).is_none() {
        doc[key] = json!([]);
    }
    let list = doc[key].as_array_mut().with_context(|| format!("\"{key}\" is not an array"))?;
    list.push(item);
    Ok(list.len() - 1)
}

/// Adds the torus to `doc` (its buffer written to `dir/dense.bin`); returns its triangles.
fn add_torus(doc: &mut Value, dir: &Path) -> Result<usize> {
    let (c, r0, r1, n0, n1) = TORUS;
    let centre = Vec3::from(c);
    // Faces wind counter-clockwise seen from outside (the tube's outward normal).
    let (p, tris) = livebake::reference::scenes::torus(centre, r0, r1, n0, n1);
    let normals: Vec<Vec3> = (0..n0)
        .flat_map(|i| {
            let a = i as f32 / n0 as f32 * std::f32::consts::TAU;
            (0..n1).map(move |j| {
                let b = j as f32 / n1 as f32 * std::f32::consts::TAU;
                Vec3::new(b.cos() * a.cos(), b.sin(), b.cos() * a.sin())
            })
        })
        .collect();
    let mut bin = Vec::new();
    for v in p.iter().chain(&normals) {
        for x in v.to_array() {
            bin.extend_from_slice(&x.to_le_bytes());
        }
    }
    let index_offset = bin.len();
    for t in &tris {
        for i in t {
            bin.extend_from_slice(&i.to_le_bytes());
        }
    }
    std::fs::write(dir.join("dense.bin"), &bin).context("cannot write dense.bin")?;
    let (lo, hi) =
        p.iter().fold((Vec3::splat(f32::MAX), Vec3::splat(f32::MIN)), |(lo, hi), v| (lo.min(*v), hi.max(*v)));
    let vertex_bytes = p.len() * 12;
    let buffer = push(doc, "buffers", json!({"uri": "dense.bin", "byteLength": bin.len()}))?;
    let views = [
        push(
            doc,
            "bufferViews",
            json!({"buffer": buffer, "byteOffset": 0, "byteLength": vertex_bytes, "target": 34962}),
        )?,
        push(
            doc,
            "bufferViews",
            json!({"buffer": buffer, "byteOffset": vertex_bytes, "byteLength": vertex_bytes, "target": 34962}),
        )?,
        push(
            doc,
            "bufferViews",
            json!({"buffer": buffer, "byteOffset": index_offset, "byteLength": bin.len() - index_offset, "target": 34963}),
        )?,
    ];
    let position = push(
        doc,
        "accessors",
        json!({"bufferView": views[0], "componentType": 5126, "count": p.len(), "type": "VEC3", "min": lo.to_array(), "max": hi.to_array()}),
    )?;
    let normal = push(
        doc,
        "accessors",
        json!({"bufferView": views[1], "componentType": 5126, "count": p.len(), "type": "VEC3"}),
    )?;
    let indices = push(
        doc,
        "accessors",
        json!({"bufferView": views[2], "componentType": 5125, "count": tris.len() * 3, "type": "SCALAR"}),
    )?;
    let material = push(
        doc,
        "materials",
        json!({"name": "dense torus (bench)", "pbrMetallicRoughness": {"baseColorFactor": [0.7, 0.7, 0.7, 1.0], "metallicFactor": 0.0, "roughnessFactor": 1.0}}),
    )?;
    let mesh = push(
        doc,
        "meshes",
        json!({"name": "dense torus (bench)", "primitives": [{"attributes": {"POSITION": position, "NORMAL": normal}, "indices": indices, "material": material}]}),
    )?;
    let node = push(doc, "nodes", json!({"name": "dense torus (bench)", "mesh": mesh}))?;
    let scene = doc.get("scene").and_then(Value::as_u64).unwrap_or(0) as usize;
    doc["scenes"][scene]["nodes"].as_array_mut().context("the scene has no node list")?.push(json!(node));
    Ok(tris.len())
}

/// The node's translation moved by `dx` along x (its matrix's, if it has one).
fn set_offset(doc: &mut Value, node: usize, base: [f64; 3], dx: f64) -> Result<()> {
    let n = doc["nodes"].get_mut(node).context("no such node")?;
    if n.get("matrix").is_some() {
        n["matrix"][12] = json!(base[0] + dx);
    } else {
        n["translation"] = json!([base[0] + dx, base[1], base[2]]);
    }
    Ok(())
}

fn node_base(doc: &Value, node: usize) -> [f64; 3] {
    let n = &doc["nodes"][node];
    let get = |v: &Value, i: usize| v.get(i).and_then(Value::as_f64).unwrap_or(0.0);
    match n.get("matrix") {
        Some(m) => [get(m, 12), get(m, 13), get(m, 14)],
        None => n.get("translation").map_or([0.0; 3], |t| [get(t, 0), get(t, 1), get(t, 2)]),
    }
}

fn save(path: &Path, bytes: &[u8], by_rename: bool) -> Result<()> {
    if by_rename {
        let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_default();
        let tmp = path.with_file_name(format!(".{name}.tmp"));
        std::fs::write(&tmp, bytes).with_context(|| format!("cannot write {}", tmp.display()))?;
        std::fs::rename(&tmp, path).with_context(|| format!("cannot rename {} to {}", tmp.display(), path.display()))
    } else {
        std::fs::write(path, bytes).with_context(|| format!("cannot write {}", path.display()))
    }
}

/// Reads events for `for_how_long`, noting the cells published or evicted.
/// Waits for first light's last LOD-0 publish (all of its directions), noting the cells
/// published meanwhile.
fn wait_lod0_complete(runtime: &Runtime, touched: &mut HashSet<CellId>) -> Result<()> {
    let all = runtime.config().bundle.directions as u64;
    if runtime.config().first_light_directions as u64 >= all {
        return Ok(()); // first light was the whole LOD 0
    }
    let deadline = Instant::now() + PATIENCE;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            bail!("LOD 0 did not reach its {all} directions within {PATIENCE:?} of first light");
        }
        if let Some(e) = next_event(runtime, left)? {
            match e.event {
                RuntimeEvent::Lod0Published { directions } if directions >= all => return Ok(()),
                RuntimeEvent::CellPublished { cell, .. } | RuntimeEvent::CellEvicted { cell, .. } => {
                    touched.insert(cell);
                }
                _ => {}
            }
        }
    }
}

fn drain(runtime: &Runtime, for_how_long: Duration, touched: &mut HashSet<CellId>) -> Result<()> {
    let end = Instant::now() + for_how_long;
    loop {
        let left = end.saturating_duration_since(Instant::now());
        if left.is_zero() {
            return Ok(());
        }
        if let Some(e) = next_event(runtime, left)? {
            match e.event {
                RuntimeEvent::CellPublished { cell, .. } | RuntimeEvent::CellEvicted { cell, .. } => {
                    touched.insert(cell);
                }
                _ => {}
            }
        }
    }
}

/// One move: what the runtime reported and what the audit found.
struct Move {
    applied_ms: f64,
    /// Where the time went (the runtime's figures).
    steps_ms: livebake::runtime::ReloadSteps,
    relit_ms: f64,
    relit_directions: u32,
    /// `reload_refined.ms`: every invalidated cell re-baked with first light's directions.
    refined_ms: Option<f64>,
    save_to_applied_ms: f64,
    changed_meshes: usize,
    invalidated: usize,
    invalidated_in_table: usize,
    repacked: bool,
    failed_reloads: usize,
    extra_applies: usize,
    /// Cells not invalidated whose LOD-0 light changed without a worker publishing them.
    rebaked_not_invalidated: Vec<CellId>,
    /// Cells not invalidated whose LOD-0 light changed with a worker publish in the window.
    refreshed_by_workers: usize,
    /// Cells not invalidated, not published or evicted, whose shown LOD changed.
    lod_changed_not_invalidated: usize,
    /// Invalidated cells whose LOD-0 light changed (the audit's control: nearly all; a re-bake
    /// is deterministic, so a cell whose inputs came back as they were may get the same values).
    invalidated_with_changed_light: usize,
    audited_cells: usize,
}

/// Not invalidated by the last reload: stale (every other non-empty cell is marked so),
/// or refreshed since (a finite error). Invalidated cells are reset: LOD 0, its error unknown.
fn invalidated(c: &CellInfo) -> bool {
    !c.stale && c.shown_lod == 0 && c.error.is_nan()
}

/// Per cell, LOD-0 pixels (texels and gutters) whose value differs between the snapshots (in
/// either layer).
fn changed_lod0(world: &World, before: &ShownLightmap, after: &ShownLightmap) -> Vec<u32> {
    let lod0 = &world.lod0;
    let w = lod0.width;
    let mut changed = vec![0u32; world.grid.len()];
    let differs = |p: u32| {
        let (x, y) = ((p % w) as i64, (p / w) as i64);
        before.layers.iter().zip(&after.layers).any(|(b, a)| {
            b.levels[0].texel(x, y).map(|e| e.to_array()) != a.levels[0].texel(x, y).map(|e| e.to_array())
        })
    };
    for (i, &p) in lod0.pixel.iter().enumerate() {
        if differs(p) {
            changed[world.grid.cell_of(lod0.position[i]) as usize] += 1;
        }
    }
    for &(g, t) in &lod0.gutter {
        if differs(g) {
            changed[world.grid.cell_of(lod0.position[t as usize]) as usize] += 1;
        }
    }
    changed
}

fn one_move(
    runtime: &Runtime,
    path: &Path,
    doc: &mut Value,
    node: usize,
    base: [f64; 3],
    dx: f64,
    by_rename: bool,
) -> Result<Move> {
    let before = runtime.shown();
    let cells_before = runtime.cells();
    let width_before = runtime.world().atlas.width;
    set_offset(doc, node, base, dx)?;
    let bytes = serde_json::to_vec_pretty(doc)?;
    let saved = Instant::now();
    save(path, &bytes, by_rename)?;
    let mut touched = HashSet::new();
    let (mut applied, mut save_to_applied, mut relit, mut failed, mut applies) = (None, 0.0, None, 0, 0);
    let deadline = Instant::now() + PATIENCE;
    while relit.is_none() {
        let left = deadline.saturating_duration_since(Instant::now());
        if left.is_zero() {
            bail!("no reload_relit within {PATIENCE:?} of the save (applied: {applied:?})");
        }
        let Some(e) = next_event(runtime, left)? else { continue };
        match e.event {
            RuntimeEvent::ReloadApplied { changed_meshes, invalidated_cells, repacked, ms, steps_ms } => {
                applies += 1;
                if changed_meshes > 0 && applied.is_none() {
                    applied = Some((changed_meshes, invalidated_cells, repacked, ms, steps_ms));
                    save_to_applied = saved.elapsed().as_secs_f64() * 1e3;
                }
            }
            RuntimeEvent::ReloadRelit { ms, directions } if applied.is_some() => relit = Some((ms, directions)),
            RuntimeEvent::ReloadFailed { .. } => failed += 1,
            RuntimeEvent::CellPublished { cell, .. } | RuntimeEvent::CellEvicted { cell, .. } => {
                touched.insert(cell);
            }
            _ => {}
        }
    }
    let after = runtime.shown();
    let cells_after = runtime.cells();
    let world = runtime.world();
    // A publish that made it into `after` sends its event right after; collect those too.
    drain(runtime, Duration::from_millis(30), &mut touched)?;
    let (changed_meshes, invalidated_cells, repacked, applied_ms, steps_ms) = applied.context("no reload applied")?;
    let (relit_ms, relit_directions) = relit.context("no reload relit")?;
    let is_invalid: HashSet<CellId> = cells_after.iter().filter(|c| invalidated(c)).map(|c| c.cell).collect();
    let mut m = Move {
        applied_ms,
        steps_ms,
        relit_ms,
        relit_directions,
        refined_ms: None,
        save_to_applied_ms: save_to_applied,
        changed_meshes,
        invalidated: invalidated_cells,
        invalidated_in_table: is_invalid.len(),
        repacked,
        failed_reloads: failed,
        extra_applies: applies - 1,
        rebaked_not_invalidated: Vec::new(),
        refreshed_by_workers: 0,
        lod_changed_not_invalidated: 0,
        invalidated_with_changed_light: 0,
        audited_cells: 0,
    };
    let refine = |m: &mut Move| -> Result<()> {
        // The quick relight is replaced by first light's directions next: wait for it.
        if m.relit_directions >= runtime.config().bundle.directions {
            return Ok(());
        }
        let deadline = Instant::now() + PATIENCE;
        while m.refined_ms.is_none() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                bail!("no reload_refined within {PATIENCE:?} of reload_relit");
            }
            if let Some(e) = next_event(runtime, left)?
                && let RuntimeEvent::ReloadRefined { ms, .. } = e.event
            {
                m.refined_ms = Some(ms);
            }
        }
        Ok(())
    };
    if repacked || world.atlas.width != width_before {
        refine(&mut m)?;
        return Ok(m); // everything was re-baked: nothing to audit
    }
    let changed = changed_lod0(&world, &before, &after);
    m.invalidated_with_changed_light = is_invalid.iter().filter(|&&c| changed[c as usize] > 0).count();
    let lod_before: std::collections::HashMap<CellId, u32> =
        cells_before.iter().map(|c| (c.cell, c.shown_lod)).collect();
    for c in cells_after.iter().filter(|c| !is_invalid.contains(&c.cell)) {
        m.audited_cells += 1;
        let published = touched.contains(&c.cell);
        if changed[c.cell as usize] > 0 {
            if published {
                m.refreshed_by_workers += 1;
            } else {
                m.rebaked_not_invalidated.push(c.cell);
            }
        }
        if !published && lod_before.get(&c.cell).is_some_and(|&l| l != c.shown_lod) {
            m.lod_changed_not_invalidated += 1;
        }
    }
    refine(&mut m)?;
    Ok(m)
}

fn quantiles(v: &[f64]) -> Value {
    let mut v = v.to_vec();
    v.sort_by(f64::total_cmp);
    let q = |f: f64| (!v.is_empty()).then(|| v[((v.len() - 1) as f64 * f).round() as usize]);
    json!({"median": q(0.5), "max": v.last()})
}

fn case(c: &Case, root: &Path, quick: bool, ui: &dyn Narrator) -> Result<Value> {
    // The dense scene's reload is a few times slower (its re-bake traces 100k more triangles).
    let (moves, settle, gap) = if quick { (2usize, 1.0, 0.5) } else { (6, 3.0, 1.0) };
    let moves = if c.dense { moves.div_ceil(2) } else { moves };
    let source = assets().join(c.scene);
    let from = source.parent().context("scene path")?;
    let dir = root.join(format!(
        "{}{}",
        from.file_name().map(|n| n.to_string_lossy()).unwrap_or_default(),
        if c.dense { "_dense" } else { "" }
    ));
    copy_dir(from, &dir)?;
    let path: PathBuf = dir.join(source.file_name().context("scene file name")?);
    let mut doc: Value = serde_json::from_slice(&std::fs::read(&path)?).context("the .gltf is not JSON")?;
    let node = doc["nodes"]
        .as_array()
        .and_then(|n| n.iter().position(|n| n["name"].as_str() == Some(c.node)))
        .with_context(|| format!("no node {:?}", c.node))?;
    let dense_triangles = if c.dense {
        let n = add_torus(&mut doc, &dir)?;
        save(&path, &serde_json::to_vec_pretty(&doc)?, false)?;
        Some(n)
    } else {
        None
    };
    let base = node_base(&doc, node);
    let scene = Arc::new(load_gltf(&path, &LoadOptions::default()).with_context(|| path.display().to_string())?);
    let triangles = scene.triangle_count();
    let camera = inside_camera(&scene);
    let mut runtime = Runtime::start(scene, RuntimeConfig::default(), Arc::new(CpuProvider::new()))?;
    runtime.watch(&path, WatchConfig::default())?;
    runtime.set_camera(camera);
    let (first_light, _, _) = wait_first_light(&runtime)?;
    let mut touched = HashSet::new();
    // The audit compares LOD 0 before and after a save: first light's later publishes (its
    // directions doubling) must all have landed, or they show as light changed unannounced.
    wait_lod0_complete(&runtime, &mut touched)?;
    drain(&runtime, Duration::from_secs_f64(settle), &mut touched)?;
    let cells_per_lod_at_first_move = runtime.stats().cells_per_lod;
    let mut results = Vec::new();
    for i in 0..moves {
        ui.status(&format!("{}: move {}/{moves}", c.scene, i + 1));
        let dx = if i % 2 == 0 { STEP as f64 } else { 0.0 };
        results.push(
            one_move(&runtime, &path, &mut doc, node, base, dx, i % 2 == 1).with_context(|| format!("move {i}"))?,
        );
        drain(&runtime, Duration::from_secs_f64(gap), &mut touched)?;
    }
    let grid = runtime.world().grid;
    let cells = runtime.cells().len();
    runtime.shutdown()?;
    let applied: Vec<f64> = results.iter().map(|m| m.applied_ms).collect();
    let relit: Vec<f64> = results.iter().map(|m| m.relit_ms).collect();
    let refined: Vec<f64> = results.iter().filter_map(|m| m.refined_ms).collect();
    let step = |f: fn(&livebake::runtime::ReloadSteps) -> f64| {
        quantiles(&results.iter().map(|m| f(&m.steps_ms)).collect::<Vec<_>>())["median"].clone()
    };
    let save_to: Vec<f64> = results.iter().map(|m| m.save_to_applied_ms).collect();
    let invalid: Vec<f64> = results.iter().map(|m| m.invalidated as f64).collect();
    let rebaked: usize = results.iter().map(|m| m.rebaked_not_invalidated.len()).sum();
    Ok(json!({
        "scene": c.scene,
        "generated": dense_triangles.map(|n| format!(
            "the room plus a torus of {n} triangles (centre {:?}, radii {} and {} m) under the ceiling, written to a temp dir", TORUS.0, TORUS.1, TORUS.2)),
        "triangles": triangles,
        "moved_node": c.node,
        "move": format!("+{STEP} m along x and back, in turn; saved in place and by rename in turn"),
        "cell_size_m": grid.cell_size,
        "cells": cells,
        "first_light_seconds": first_light,
        "cells_per_lod_at_first_move": cells_per_lod_at_first_move,
        "moves": results.len(),
        "reload_applied_ms": quantiles(&applied),
        "reload_relit_ms": quantiles(&relit),
        "reload_relit_directions": results.first().map(|m| m.relit_directions),
        "reload_refined_ms": quantiles(&refined),
        "steps_ms_median": json!({
            "load": step(|s| s.load),
            "diff": step(|s| s.diff),
            "atlas": step(|s| s.atlas),
            "world": step(|s| s.world),
            "region": step(|s| s.region),
            "bake": step(|s| s.bake),
            "publish": step(|s| s.publish),
        }),
        "save_to_applied_event_ms": quantiles(&save_to),
        "invalidated_cells": quantiles(&invalid),
        "rebaked_not_invalidated": rebaked,
        "per_move": results.iter().map(|m| json!({
            "reload_applied_ms": m.applied_ms,
            "reload_relit_ms": m.relit_ms,
            "reload_relit_directions": m.relit_directions,
            "reload_refined_ms": m.refined_ms,
            "steps_ms": m.steps_ms,
            "save_to_applied_event_ms": m.save_to_applied_ms,
            "changed_meshes": m.changed_meshes,
            "invalidated_cells": m.invalidated,
            "invalidated_in_cell_table": m.invalidated_in_table,
            "repacked": m.repacked,
            "failed_reloads": m.failed_reloads,
            "extra_applies": m.extra_applies,
            "audited_cells": m.audited_cells,
            "rebaked_not_invalidated": m.rebaked_not_invalidated,
            "refreshed_by_workers_in_window": m.refreshed_by_workers,
            "lod_changed_not_invalidated": m.lod_changed_not_invalidated,
            "invalidated_with_changed_light": m.invalidated_with_changed_light,
        })).collect::<Vec<_>>(),
    }))
}

pub fn run(bench: &Bench) -> Result<Value> {
    let (quick, ui) = (bench.quick, bench.ui);
    let root = std::env::temp_dir().join(format!("livebake-bench-reload-{}", std::process::id()));
    let result = CASES.iter().map(|c| case(c, &root, quick, ui).with_context(|| c.scene)).collect::<Result<Vec<_>>>();
    let _ = std::fs::remove_dir_all(&root);
    Ok(json!({
        "config": "RuntimeConfig::default(), CPU bundle backend, WatchConfig::default(); refinement runs throughout",
        "events": "reload_relit: every invalidated cell published again at LOD 0 with reload_relit_directions (RuntimeConfig::reload_directions); reload_refined: all of them re-baked with first light's directions (the next move waits for it)",
        "audit": "rebaked_not_invalidated: cells not invalidated whose LOD-0 light changed between the shown map before the save and right after reload_relit, with no publish of theirs in that window (must be 0)",
        "scenes": result?,
    }))
}
