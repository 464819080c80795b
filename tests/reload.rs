//! Hot reload through the runtime, with the real watcher on real files in a temp dir: a box
//! moved in the file (saved in place and by temp file + rename), bad saves, and a soak of
//! rapid saves. Every wait has a generous timeout ([`PATIENCE`]): the machine may be loaded,
//! and nothing here asserts speed (the bench measures reload latency).

mod support;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::{Vec2, Vec3};
use livebake::cpu::CpuProvider;
use livebake::probe::SurfaceLocator;
use livebake::runtime::world::World;
use livebake::runtime::{CameraView, Runtime, RuntimeConfig, RuntimeEvent, invalidation_margin};
use livebake::scene::{LoadOptions, Scene, load_gltf};
use livebake::viewer::{LightSource, RuntimeLight};
use livebake::watch::{Aabb, SceneDiff, WatchConfig};
use serde_json::json;
use support::{Doc, cube};

const PATIENCE: Duration = Duration::from_secs(120);

/// A closed 8 × 3 × 4 m room (single-sided walls facing in, albedo 0.6), a 1 m lamp under the
/// ceiling, and box `i` (a 0.8 m cube, the same mesh on every node) on the floor at `boxes[i]`.
fn room(boxes: &[[f32; 3]]) -> (Vec<u8>, Vec<u8>) {
    let mut d = Doc::new();
    let white = d.push(
        "materials",
        json!({"pbrMetallicRoughness": {"baseColorFactor": [0.6, 0.6, 0.6, 1.0], "metallicFactor": 0.0}}),
    );
    let lamp = d.push("materials", json!({"emissiveFactor": [1.0, 1.0, 1.0], "extensions": {"KHR_materials_emissive_strength": {"emissiveStrength": 12.0}}, "pbrMetallicRoughness": {"baseColorFactor": [0.0, 0.0, 0.0, 1.0]}}));
    d.json["extensionsUsed"] = json!(["KHR_materials_emissive_strength"]);
    let quad = |d: &mut Doc, c: [[f32; 3]; 4], material: usize, name: &str| {
        let prim = d.prim(&c, None, Some(&[0u16, 1, 2, 0, 2, 3]));
        let mut prim = prim;
        prim["material"] = json!(material);
        let mesh = d.push("meshes", json!({"name": name, "primitives": [prim]}));
        let node = d.push("nodes", json!({"name": name, "mesh": mesh}));
        d.add_root(node);
    };
    let (x, y, z) = (8.0, 3.0, 4.0);
    quad(&mut d, [[0.0, 0.0, 0.0], [0.0, 0.0, z], [x, 0.0, z], [x, 0.0, 0.0]], white, "floor");
    quad(&mut d, [[0.0, y, 0.0], [x, y, 0.0], [x, y, z], [0.0, y, z]], white, "ceiling");
    quad(&mut d, [[0.0, 0.0, 0.0], [x, 0.0, 0.0], [x, y, 0.0], [0.0, y, 0.0]], white, "back");
    quad(&mut d, [[0.0, 0.0, z], [0.0, y, z], [x, y, z], [x, 0.0, z]], white, "front");
    quad(&mut d, [[0.0, 0.0, 0.0], [0.0, y, 0.0], [0.0, y, z], [0.0, 0.0, z]], white, "left");
    quad(&mut d, [[x, 0.0, 0.0], [x, 0.0, z], [x, y, z], [x, y, 0.0]], white, "right");
    quad(&mut d, [[3.5, 2.98, 1.5], [4.5, 2.98, 1.5], [4.5, 2.98, 2.5], [3.5, 2.98, 2.5]], lamp, "lamp");
    let (p, n, idx) = cube(0.8);
    let mut prim = d.prim(&p, Some(&n), Some(&idx));
    prim["material"] = json!(white);
    let mesh = d.push("meshes", json!({"name": "box", "primitives": [prim]}));
    for (i, t) in boxes.iter().enumerate() {
        let node = d.push("nodes", json!({"name": format!("box{i}"), "mesh": mesh, "translation": t}));
        d.add_root(node);
    }
    let gltf = serde_json::to_vec_pretty(&d.json_with_buffer(Some("room.bin".into()))).unwrap();
    (gltf, d.bin)
}
const BOXES: [[f32; 3]; 2] = [[1.0, 0.0, 1.6], [6.2, 0.0, 1.6]];

fn moved() -> [[f32; 3]; 2] {
    [[1.6, 0.0, 1.0], BOXES[1]]
}

fn save(path: &Path, bytes: &[u8], by_rename: bool) {
    if by_rename {
        let tmp = path.with_file_name(format!(".{}.tmp", path.file_name().unwrap().to_string_lossy()));
        std::fs::write(&tmp, bytes).unwrap();
        std::fs::rename(&tmp, path).unwrap();
    } else {
        std::fs::write(path, bytes).unwrap();
    }
}

fn write_room(dir: &Path, boxes: &[[f32; 3]], by_rename: bool) -> PathBuf {
    let (gltf, bin) = room(boxes);
    save(&dir.join("room.bin"), &bin, by_rename);
    let path = dir.join("room.gltf");
    save(&path, &gltf, by_rename);
    path
}

fn load(path: &Path) -> Arc<Scene> {
    Arc::new(load_gltf(path, &LoadOptions::default()).expect("load"))
}

fn config() -> RuntimeConfig {
    // Half-metre cells: a box's neighbourhood (its size around it) is a small part of the room.
    // The reload's quick relight at a quarter of the LOD-0 directions, as by default.
    let mut c = RuntimeConfig {
        lods: Some(2),
        cell_size: Some(0.5),
        min_directions: 16,
        max_directions: 48,
        threads: Some(2),
        reload_directions: 16,
        ..RuntimeConfig::default()
    };
    c.atlas.texel_budget = 12_000;
    c.bundle.directions = 64;
    // First light is LOD 0 with all its directions: the clean maps compared are complete.
    c.first_light_directions = c.bundle.directions;
    c
}

/// Until no cell is provisional (a reload's quick relight all re-baked at full quality).
fn wait_refined(runtime: &Runtime, what: &str) {
    let deadline = Instant::now() + PATIENCE;
    while runtime.cells().iter().any(|c| c.provisional) {
        assert!(Instant::now() < deadline, "{what}: the reload's cells were never re-baked at full quality");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn camera() -> CameraView {
    CameraView::looking_at(Vec3::new(4.0, 1.5, 3.8), Vec3::new(4.0, 1.0, 0.0))
}

fn start(path: &Path) -> Runtime {
    let mut runtime = Runtime::start(load(path), config(), Arc::new(CpuProvider::new())).expect("start");
    runtime.watch(path, WatchConfig::default()).expect("watch");
    runtime.set_camera(camera());
    runtime.wait_first_light(PATIENCE).expect("first light");
    runtime
}

/// Events until `until` says stop; panics on `Failed` or after [`PATIENCE`].
fn wait_for(runtime: &Runtime, what: &str, mut until: impl FnMut(&RuntimeEvent) -> bool) {
    let deadline = Instant::now() + PATIENCE;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match runtime.events().recv_timeout(left) {
            Ok(e) => {
                if let RuntimeEvent::Failed { error } = &e.event {
                    panic!("runtime failed: {error}");
                }
                if until(&e.event) {
                    return;
                }
            }
            Err(_) => panic!("timed out waiting for {what}"),
        }
    }
}

/// The floor's irradiance at a grid of points over the room, read from the shown map's LOD 0
/// (the level a reload re-bakes; finer levels differ from a first light by their resolution).
fn floor_samples(world: &World, shown: &livebake::runtime::shown::ShownLightmap) -> Vec<f64> {
    let locator = SurfaceLocator::new(&world.geom, &world.bvh);
    let mut out = Vec::new();
    for i in 0..32 {
        for j in 0..16 {
            let p = Vec3::new(0.125 + i as f32 * 0.25, 0.0, 0.125 + j as f32 * 0.25);
            let Ok(at) = locator.locate(p, Vec3::Y) else { continue };
            if world.geom.normals[at.tri as usize].y < 0.9 || at.distance > 1e-3 {
                out.push(f64::NAN); // under a box
                continue;
            }
            let face = world.atlas.face(at.tri, at.side).expect("lit floor");
            let uv: Vec2 = world.atlas.faces[face as usize].uv_at(at.u, at.v);
            let e = shown.bilinear(0, uv);
            out.push(((e.x + e.y + e.z) / 3.0) as f64);
        }
    }
    out
}

/// RMS of the differences where both have a value, over the RMS of `b`.
fn relative_rms(a: &[f64], b: &[f64]) -> f64 {
    let pairs: Vec<(f64, f64)> =
        a.iter().zip(b).filter(|(x, y)| !x.is_nan() && !y.is_nan()).map(|(x, y)| (*x, *y)).collect();
    let num: f64 = pairs.iter().map(|(x, y)| (x - y).powi(2)).sum();
    let den: f64 = pairs.iter().map(|(_, y)| y * y).sum();
    (num / den).sqrt()
}

/// First light of `path` in a fresh runtime (no reload), with `seed`.
fn clean_first_light(path: &Path, seed: u64) -> Vec<f64> {
    let mut c = config();
    c.bundle.seed = seed;
    c.start_paused = true;
    let runtime = Runtime::start(load(path), c, Arc::new(CpuProvider::new())).expect("start");
    runtime.wait_first_light(PATIENCE).expect("first light");
    let samples = floor_samples(&runtime.world(), &runtime.shown());
    runtime.shutdown().expect("shutdown");
    samples
}

/// Moving one box in the file (saved in place, then back by temp file + rename): the reload
/// events arrive in order; only cells near the box's old and new places drop to LOD 0 (those
/// meeting its bounds grown by the margin, [`invalidation_margin`]); the far end of the room
/// keeps its LOD; and the re-baked floor matches a clean first light of the new file.
///
/// Tolerance: two clean first lights (D = 64 directions) with different seeds differ by
/// their noise, `n` (relative RMS; each has noise σ_D, so n ≈ √2·σ_D). The reloaded map's
/// LOD 0 outside the re-baked cells is older (its refinement read the old scene), so it may
/// differ by more than noise only where the box's shadow moved: a factor 2 for that.
/// * Right after `reload_relit` the re-baked cells have N = 16 directions: their noise is
///   σ_N = σ_D·√(D/N), so against a clean first light they differ by √(σ_N² + σ_D²) =
///   n·√((D/N + 1)/2) (1.58·n): the floor must be within 2·n·√((D/N + 1)/2).
/// * After `reload_refined` (the same cells re-baked with D directions) it must be within
///   2·n, as a full-quality reload.
#[test]
fn moving_a_box_resets_only_the_cells_around_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_room(dir.path(), &BOXES, false);
    let runtime = start(&path);
    // Refine every cell to its target.
    let deadline = Instant::now() + PATIENCE;
    while runtime.stats().queue > 0 {
        assert!(Instant::now() < deadline, "not refined: {:?}", runtime.stats().cells_per_lod);
        std::thread::sleep(Duration::from_millis(50));
    }
    for (round, (layout, by_rename)) in [(moved(), false), (BOXES, true)].into_iter().enumerate() {
        runtime.set_paused(true);
        // Let units in flight land before looking at the cell table.
        while runtime.cells().iter().any(|c| c.working) {
            std::thread::sleep(Duration::from_millis(10));
        }
        let before = runtime.cells();
        write_room(dir.path(), &layout, by_rename);
        let (mut started, mut applied, mut relit) = (false, None, false);
        let mut relit_directions = 0;
        wait_for(&runtime, "reload_relit", |e| {
            match e {
                RuntimeEvent::ReloadStarted { .. } => started = true,
                RuntimeEvent::ReloadApplied { changed_meshes, invalidated_cells, repacked, .. } => {
                    assert!(started, "applied before started");
                    applied = Some((*changed_meshes, *invalidated_cells, *repacked))
                }
                RuntimeEvent::ReloadRelit { directions, .. } => {
                    relit = applied.is_some();
                    relit_directions = *directions;
                }
                RuntimeEvent::ReloadFailed { error, .. } => panic!("round {round}: {error}"),
                _ => {}
            }
            relit
        });
        let (changed, invalidated, repacked) = applied.expect("applied");
        assert_eq!(changed, 1, "round {round}: one box moved");
        assert!(!repacked, "round {round}: a moved box keeps the atlas");
        let world = runtime.world();
        assert!(SceneDiff::between(&world.scene, &load(&path)).is_empty(), "the runtime serves the new file");
        assert_eq!(relit_directions, config().reload_directions, "round {round}: the quick relight");
        let after = runtime.cells();
        let grid = world.grid;
        let near = |c: u32| {
            let (lo, hi) = grid.bounds(c);
            [BOXES[0], moved()[0]].iter().any(|b| {
                let bounds = Aabb { min: Vec3::from(*b), max: Vec3::from(*b) + Vec3::splat(0.8) };
                let margin = invalidation_margin(&bounds, world.texel_size(0));
                let (blo, bhi) = (bounds.min - margin, bounds.max + margin);
                lo.cmple(bhi).all() && hi.cmpge(blo).all()
            })
        };
        // Cells may gain or lose texels near the box; far ones are the same cells as before.
        let before: std::collections::HashMap<u32, _> = before.into_iter().map(|c| (c.cell, c)).collect();
        let mut reset = 0;
        for a in &after {
            if near(a.cell) {
                reset += usize::from(a.shown_lod == 0);
                assert!(a.provisional || a.shown_lod > 0, "round {round}: re-baked cell {} not provisional", a.cell);
            } else {
                let b = before.get(&a.cell).expect("a far cell appeared");
                assert_eq!(a.shown_lod, b.shown_lod, "round {round}: far cell {} lost its LOD", a.cell);
                assert!(a.stale, "round {round}: far cell {} should be marked stale", a.cell);
            }
        }
        assert!(
            reset > 0 && reset == invalidated,
            "round {round}: {reset} near cells reset, {invalidated} invalidated"
        );
        let kept = after.iter().filter(|c| !near(c.cell) && c.shown_lod > 0).count();
        assert!(kept > 10, "round {round}: only {kept} far cells were refined to keep");
        // Light: against clean first lights of the same file.
        let quick = floor_samples(&world, &runtime.shown());
        let (clean, other) = (clean_first_light(&path, 0), clean_first_light(&path, 1));
        let noise = relative_rms(&other, &clean);
        let diff = relative_rms(&quick, &clean);
        let (d, n) = (config().bundle.directions as f64, relit_directions as f64);
        let quick_factor = ((d / n + 1.0) / 2.0).sqrt();
        eprintln!(
            "round {round}: {invalidated} cells re-baked; noise {noise:.4}, quick relight ({n} directions) vs clean \
             {diff:.4} (expected from noise {:.4})",
            noise * quick_factor
        );
        assert!(
            diff <= 2.0 * noise * quick_factor,
            "round {round}: the quick relight differs by {diff} (noise {noise}, ×{quick_factor:.2} for {n} directions)"
        );
        // The workers re-bake the quick cells at full quality first.
        runtime.set_paused(false);
        wait_refined(&runtime, &format!("round {round}"));
        runtime.set_paused(true);
        while runtime.cells().iter().any(|c| c.working) {
            std::thread::sleep(Duration::from_millis(10));
        }
        let refined = floor_samples(&runtime.world(), &runtime.shown());
        let diff = relative_rms(&refined, &clean);
        eprintln!("round {round}: refined ({d} directions) vs clean {diff:.4}");
        assert!(diff <= 2.0 * noise, "round {round}: the refined floor differs by {diff} (noise {noise})");
        runtime.set_paused(false);
    }
    runtime.shutdown().expect("shutdown");
}

/// Bad saves keep the last good scene: truncated JSON → reload_failed; a `.bin` shorter than
/// its buffer → reload_failed (after the watcher's settle time); the `.bin` written first and
/// the `.gltf` later (Blender's order) → one reload of the matching pair; then a good save
/// recovers.
#[test]
fn bad_saves_keep_the_last_good_scene() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_room(dir.path(), &BOXES, false);
    let runtime = start(&path);
    let served = |r: &Runtime| SceneDiff::between(&r.world().scene, &load_good(&BOXES)).is_empty();
    assert!(served(&runtime));
    let expect_failure = |what: &str| {
        let mut failed = false;
        wait_for(&runtime, what, |e| {
            match e {
                RuntimeEvent::ReloadFailed { .. } => failed = true,
                RuntimeEvent::ReloadApplied { .. } => panic!("{what}: a bad save was applied"),
                _ => {}
            }
            failed
        });
    };
    let (gltf, bin) = room(&moved());
    std::fs::write(&path, &gltf[..gltf.len() / 2]).unwrap();
    expect_failure("truncated JSON");
    assert!(served(&runtime), "the old scene is still served");
    std::fs::write(dir.path().join("room.bin"), &bin[..bin.len() - 8]).unwrap();
    std::fs::write(&path, &gltf).unwrap();
    expect_failure("a short .bin");
    assert!(served(&runtime), "the old scene is still served");
    // Blender: the .bin in place first, the .gltf a moment later.
    std::fs::write(dir.path().join("room.bin"), &bin).unwrap();
    std::thread::sleep(Duration::from_millis(400));
    std::fs::write(&path, &gltf).unwrap();
    let mut applied = 0;
    wait_for(&runtime, "the matching pair", |e| {
        match e {
            RuntimeEvent::ReloadApplied { .. } => applied += 1,
            RuntimeEvent::ReloadFailed { error, .. } => panic!("the good pair failed: {error}"),
            _ => {}
        }
        matches!(e, RuntimeEvent::ReloadRelit { .. })
    });
    assert_eq!(applied, 1);
    assert!(SceneDiff::between(&runtime.world().scene, &load_good(&moved())).is_empty());
    runtime.shutdown().expect("shutdown");
}

/// The scene a good save of `boxes` loads to (written in its own directory).
fn load_good(boxes: &[[f32; 3]]) -> Arc<Scene> {
    let dir = tempfile::tempdir().unwrap();
    load(&write_room(dir.path(), boxes, false))
}

/// 200 rapid saves, some corrupt, most moving a box: no panic, memory stays flat, and once
/// the files rest (and the last reload's quick relight is re-baked at full quality) the
/// runtime serves exactly the final file, lit as a clean first light of it is (within twice
/// the noise between two clean first lights, as above).
#[test]
fn soak_of_rapid_saves() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_room(dir.path(), &BOXES, false);
    let runtime = start(&path);
    // Right after first light nothing is baking: pages and the scene's structures only.
    let resident_at_start = runtime.stats().resident_bytes;
    let mut rng = livebake::sampling::Rng::new(3, 4);
    let mut last = BOXES;
    for i in 0..200 {
        let layout = [[0.5 + rng.next_f32() * 2.0, 0.0, 0.5 + rng.next_f32() * 2.5], BOXES[1]];
        match i % 5 {
            0 => {
                let (gltf, _) = room(&layout);
                std::fs::write(&path, &gltf[..gltf.len() * 2 / 3]).unwrap(); // truncated
            }
            1 => {
                let (gltf, bin) = room(&layout);
                std::fs::write(dir.path().join("room.bin"), &bin[..bin.len() / 2]).unwrap(); // half a .bin
                std::fs::write(&path, &gltf).unwrap();
            }
            _ => {
                write_room(dir.path(), &layout, i % 2 == 0);
                last = layout;
            }
        }
        std::thread::sleep(Duration::from_millis(10 + (i % 7) * 5));
        while runtime.events().try_recv().is_ok() {}
    }
    // The last save was good (i = 199 → 199 % 5 = 4). Wait until it is served and relit.
    let deadline = Instant::now() + PATIENCE;
    loop {
        let served = SceneDiff::between(&runtime.world().scene, &load_good(&last)).is_empty();
        if served {
            // Drain what is left; the runtime is quiet once no reload event comes for a while.
            let quiet = runtime.events().recv_timeout(Duration::from_secs(3));
            if quiet.is_err() || !matches!(quiet.map(|e| e.event), Ok(RuntimeEvent::ReloadStarted { .. })) {
                break;
            }
        }
        assert!(Instant::now() < deadline, "the final save was never served");
        std::thread::sleep(Duration::from_millis(100));
    }
    // The final state: the last reload's quick relight re-baked at full quality.
    wait_refined(&runtime, "soak");
    let stats = runtime.stats();
    runtime.set_paused(true);
    while runtime.cells().iter().any(|c| c.working) {
        std::thread::sleep(Duration::from_millis(10));
    }
    let reloaded = floor_samples(&runtime.world(), &runtime.shown());
    runtime.shutdown().expect("no panic");
    // What persists across reloads (shown pages and the scene's structures) must stay flat;
    // bakes in progress are dropped by every reload, so they cannot pile up across saves,
    // and are held to the memory budget (a group bake of neighbouring cells alone can hold
    // a few MB here, more than the start's whole map).
    let persistent = stats.page_bytes + stats.fixed_bytes;
    assert!(
        (persistent as f64) < resident_at_start as f64 * 3.0,
        "memory grew from {resident_at_start} to {persistent} bytes (pages and scene)"
    );
    assert!(
        stats.bake_bytes <= stats.memory_budget,
        "bakes hold {} bytes of {}",
        stats.bake_bytes,
        stats.memory_budget
    );
    let (clean, other) = (clean_first_light(&path, 0), clean_first_light(&path, 1));
    let noise = relative_rms(&other, &clean);
    let diff = relative_rms(&reloaded, &clean);
    eprintln!("soak: noise {noise:.4}, final vs clean {diff:.4}");
    assert!(diff <= 2.0 * noise, "after the soak the floor differs by {diff} (noise {noise})");
}

/// The viewer's light with hot reload (what `livebake view` runs unless --no-watch): a save
/// while viewing reaches the source as a reload (its status has the reload's milliseconds, for
/// the title), its scene becomes the new one (a new generation, so the renderer re-uploads the
/// geometry), and the map it shows changed: the floor where the box stood, black under the box
/// before (its bottom faces the floor, the back of a closed box sees nothing), is lit after.
#[test]
fn viewer_light_follows_a_save() {
    let dir = tempfile::tempdir().unwrap();
    let path = write_room(dir.path(), &BOXES, false);
    let runtime = start(&path);
    // The floor under the first box's middle, in the floor's chart (unchanged by the move).
    // (A locator would find the box's bottom there: it lies on the floor.)
    let world = runtime.world();
    let target = Vec3::new(1.4, 0.0, 2.0);
    let (tri, u, v) = (0..world.geom.corners.len())
        .find_map(|t| {
            let [a, b, c] = world.geom.corners[t];
            if world.geom.normals[t].y < 0.9 || [a, b, c].iter().any(|q| q.y != 0.0) {
                return None;
            }
            // Barycentrics in the xz plane.
            let (e1, e2, d) = (b - a, c - a, target - a);
            let det = e1.x * e2.z - e1.z * e2.x;
            let (u, v) = ((d.x * e2.z - d.z * e2.x) / det, (e1.x * d.z - e1.z * d.x) / det);
            (u >= 0.0 && v >= 0.0 && u + v <= 1.0).then_some((t as u32, u, v))
        })
        .expect("the floor under the box");
    let face = world.atlas.face(tri, livebake::scene::Side::Front).expect("lit floor");
    let (uv, p): (Vec2, Vec3) = (world.atlas.faces[face as usize].uv_at(u, v), world.geom.point(tri, u, v));
    let mut light = RuntimeLight::new(runtime);
    light.poll();
    let (before_state, before) = (light.scene(), light.shown().expect("first light"));
    assert!(light.status().last_reload_ms.is_none() && light.status().last_error.is_none());
    write_room(dir.path(), &moved(), true);
    let deadline = Instant::now() + PATIENCE;
    while light.status().last_reload_ms.is_none() {
        assert!(Instant::now() < deadline, "no reload reached the viewer's source");
        std::thread::sleep(Duration::from_millis(20));
        light.poll();
    }
    let status = light.status();
    assert!(status.last_error.is_none(), "{:?}", status.last_error);
    assert_eq!(light.reloads(), 1);
    let after_state = light.scene();
    assert_eq!(after_state.generation, before_state.generation + 1);
    assert!(!Arc::ptr_eq(&after_state.scene, &before_state.scene));
    let after = light.shown().expect("lit");
    let (e0, e1) = (before.irradiance(p, uv), after.irradiance(p, uv));
    eprintln!("floor at the old box: E {e0} before, {e1} after the reload ({:.0} ms)", status.last_reload_ms.unwrap());
    // Unlit under the box: at most a few per cent of the lit value (bilinear taps at the
    // footprint's middle are all under the box, 0.4 m from its edges).
    assert!(e1.x > 0.0 && e0.x < 0.05 * e1.x, "before {e0}, after {e1}");
    light.shutdown().expect("shutdown");
}

/// Moving the sun is a light change applied through hot reload's path: the sun's light in
/// the room (through its open window) moves, LOD 0 is re-baked everywhere with the grid
/// kept, shown after first light's directions (`reload_relit`) and again at all of them
/// (`reload_refined`); a save of the scene's file afterwards keeps the moved sun. The room
/// is the bundled living room (its window an open frame, grass outside).
#[test]
fn moving_the_sun_relights_through_the_reload_path() {
    use livebake::scene::sun::SunPosition;
    use livebake::scene::{SunPlacement, SurroundingsSpec};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("living_room.glb");
    let source = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/living_room/living_room.glb");
    std::fs::copy(source, &path).unwrap();
    let place = |elevation, azimuth| SunPlacement::Fixed(SunPosition { elevation, azimuth });
    let mut spec = SurroundingsSpec { sun: Some(place(35.0, 150.0)), ..SurroundingsSpec::default() };
    let mut scene = (*load(&path)).clone();
    scene.set_surroundings(&spec.build().unwrap()).unwrap();
    let mut config = config();
    config.cell_size = None;
    config.first_light_directions = 16;
    let surroundings = scene.surroundings();
    let mut runtime = Runtime::start(Arc::new(scene), config.clone(), Arc::new(CpuProvider::new())).expect("start");
    runtime.watch(&path, WatchConfig { surroundings, ..WatchConfig::default() }).expect("watch");
    runtime.wait_first_light(PATIENCE).expect("first light");
    let before = runtime.world();
    // Every LOD-0 texel's light as shown (both layers, at its pixel's centre).
    let punctual = |runtime: &Runtime| {
        let (shown, world) = (runtime.shown(), runtime.world());
        let lod0 = &world.lod0;
        let uv = |p: u32| Vec2::new((p % lod0.width) as f32 + 0.5, (p / lod0.width) as f32 + 0.5);
        lod0.pixel.iter().map(|&p| shown.bilinear(0, uv(p))).collect::<Vec<_>>()
    };
    let lit_before = punctual(&runtime);
    spec.sun = Some(place(35.0, 330.0));
    runtime.set_surroundings(spec.build().unwrap());
    let (mut relit, mut applied) = (None, None);
    wait_for(&runtime, "the sun's relight", |e| {
        match e {
            RuntimeEvent::ReloadApplied { invalidated_cells, repacked, .. } => {
                applied = Some((*invalidated_cells, *repacked))
            }
            RuntimeEvent::ReloadRelit { directions, .. } => relit = Some(*directions),
            _ => {}
        }
        matches!(e, RuntimeEvent::ReloadRefined { .. })
    });
    let after = runtime.world();
    assert_eq!(relit, Some(config.first_light_directions), "shown first after first light's directions");
    assert_eq!(applied, Some((after.non_empty_cells().count(), false)), "every cell re-baked, the atlas kept");
    assert_eq!(before.grid, after.grid, "the grid is kept");
    let sun = |w: &World| w.scene.lights.last().map(|l| l.direction).unwrap();
    assert!(sun(&before).dot(sun(&after)) < 0.0, "the sun moved");
    let lit_after = punctual(&runtime);
    let moved = lit_before.iter().zip(&lit_after).filter(|(a, b)| (**a - **b).abs().max_element() > 1e-3).count();
    assert!(moved > lit_before.len() / 100, "the sunlit texels did not change ({moved} of {})", lit_before.len());
    // A save of the file keeps the sun where it was moved.
    std::fs::copy(source, &path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    save(&path, &bytes, true);
    wait_for(&runtime, "the save", |e| {
        matches!(e, RuntimeEvent::ReloadApplied { .. } | RuntimeEvent::ReloadFailed { .. })
    });
    assert_eq!(sun(&runtime.world()), sun(&after));
    runtime.shutdown().expect("clean shutdown");
}

/// A model that brings no light, loaded with no sky asked for (as `run`, `view` and `serve`
/// load it), is lit by the white stand-in sky. A save that lights its lamp takes the stand-in
/// away, so the room is lit by the lamp alone and not by both; a save that puts the lamp out
/// again brings it back.
#[test]
fn the_stand_in_sky_follows_saves_that_bring_and_take_away_light() {
    let dir = tempfile::tempdir().unwrap();
    let write = |lit: bool| {
        let (gltf, bin) = room(&BOXES);
        let mut j: serde_json::Value = serde_json::from_slice(&gltf).unwrap();
        if !lit {
            j["materials"][1]["emissiveFactor"] = json!([0.0, 0.0, 0.0]);
        }
        save(&dir.path().join("room.bin"), &bin, true);
        let path = dir.path().join("room.gltf");
        save(&path, &serde_json::to_vec(&j).unwrap(), true);
        path
    };
    let path = write(false);
    let mut scene = (*load(&path)).clone();
    scene.sky_automatic = true;
    assert!(scene.stand_in_sky(), "the dark room is not given the stand-in sky");
    let mut runtime = Runtime::start(Arc::new(scene), config(), Arc::new(CpuProvider::new())).expect("start");
    runtime.watch(&path, WatchConfig::default()).expect("watch");
    runtime.set_camera(camera());
    runtime.wait_first_light(PATIENCE).expect("first light");
    let stand_in = livebake::scene::Rgb::splat(livebake::scene::STAND_IN_SKY);
    assert_eq!(runtime.world().scene.sky, stand_in);
    for (lit, sky) in [(true, livebake::scene::Rgb::ZERO), (false, stand_in)] {
        write(lit);
        wait_for(&runtime, "the save", |e| {
            assert!(!matches!(e, RuntimeEvent::ReloadFailed { .. }), "{e:?}");
            matches!(e, RuntimeEvent::ReloadApplied { .. })
        });
        let world = runtime.world();
        assert_eq!(world.scene.sky, sky, "lamp lit: {lit}");
        assert!(world.scene.sky_automatic);
    }
    runtime.shutdown().expect("clean shutdown");
}
