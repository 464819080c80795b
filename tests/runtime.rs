//! The live runtime: cell bakes against offline bakes and their error estimates,
//! publication order, camera moves and shutdown, LOD borders, and multi-bounce with mixed
//! LODs against an independent renderer.

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use glam::{DVec2, DVec3, Vec2, Vec3, Vec4};
use livebake::atlas::Atlas;
use livebake::bundle::BackendProvider;
use livebake::cpu::CpuProvider;
use livebake::probe::SurfaceLocator;
use livebake::reference::RelativeRmsError;
use livebake::runtime::cell_bake::CellBake;
use livebake::runtime::policy::cell_view;
use livebake::runtime::shown::{Layer, ShownLightmap};
use livebake::runtime::world::World;
use livebake::runtime::{
    CameraView, Runtime, RuntimeConfig, RuntimeEvent, TimedEvent, bake_first_light, empty_shown, publish_bake,
};
use livebake::scene::builder::diffuse;
use livebake::scene::{LoadOptions, Rgb, Scene, SceneBuilder, SceneGeometry, load_gltf};
use serde_json::Value;

const ROOM: &str = "cornell_2m/cornell_2m.gltf";

fn asset(rel: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets").join(rel)
}

fn load(rel: &str) -> Arc<Scene> {
    Arc::new(load_gltf(&asset(rel), &LoadOptions::default()).unwrap_or_else(|e| panic!("{rel}: {e}")))
}

fn world(scene: Arc<Scene>, config: &RuntimeConfig) -> Arc<World> {
    let geom = Arc::new(SceneGeometry::new(&scene));
    let atlas = Arc::new(Atlas::build(&scene, &geom, &config.atlas).expect("atlas"));
    Arc::new(World::new(scene, geom, atlas, config).expect("world"))
}

fn first_light(world: &World) -> Arc<ShownLightmap> {
    let mut backend = CpuProvider::new().backend(&world.bundle, 2).expect("backend");
    let never = AtomicBool::new(false);
    Arc::new(bake_first_light(world, &mut backend, 2, empty_shown(world), &never).expect("first light").0)
}

fn luminance(c: Rgb) -> f64 {
    (0.2126 * c.x + 0.7152 * c.y + 0.0722 * c.z) as f64
}

/// Bakes `cell` at `lod` offline, in units of `unit` directions, until `directions`.
fn bake_cell(world: &World, shown: &Arc<ShownLightmap>, cell: u32, lod: u32, seed: u64, directions: u32) -> CellBake {
    let mut backend = CpuProvider::new().backend(&world.bundle, 1).expect("backend");
    let mut bake = CellBake::new(world, &[cell], lod, shown.clone(), seed);
    let never = AtomicBool::new(false);
    while bake.directions() < directions as u64 {
        bake.step(world, &mut backend, 4, &never).expect("not cancelled");
    }
    bake
}

/// The cells of `world` with the most LOD-0 texels, most first.
fn largest_cells(world: &World) -> Vec<u32> {
    let mut cells: Vec<u32> = world.non_empty_cells().collect();
    cells.sort_by_key(|&c| (std::cmp::Reverse(world.lod0_texels[c as usize]), c));
    cells
}

/// Events until `until` returns true or `timeout` passes (then panics with `what`).
fn wait_for(runtime: &Runtime, timeout: Duration, what: &str, mut until: impl FnMut(&TimedEvent) -> bool) {
    let deadline = Instant::now() + timeout;
    loop {
        let left = deadline.saturating_duration_since(Instant::now());
        match runtime.events().recv_timeout(left) {
            Ok(e) => {
                if let RuntimeEvent::Failed { error } = &e.event {
                    panic!("runtime failed: {error}");
                }
                if until(&e) {
                    return;
                }
            }
            Err(_) => panic!("timed out waiting for {what}"),
        }
    }
}

/// The variance-based error estimate against the error measured against a bake with 16×
/// the directions (seeded apart). Bundle directions are stratified (Sobol), so batches are
/// not independent: the spread between batches overstates the error of their mean, and the
/// estimate is an upper bound, by a factor that depends on how much the stratification
/// helps in that cell (1.9–3.2× on these cells). It must never be optimistic:
/// estimate ≥ 0.8 × measured (the measured figure is an RMS over ~3000 texels whose errors
/// are correlated in patches, so it carries ~10% noise; the reference's own error, ≤ 1/4 of
/// this one, inflates it by at most √(1 + 1/16) ≈ 3%); and it must stay informative, within
/// 4× of the measured.
#[test]
fn error_estimate_is_an_honest_upper_bound() {
    let config = RuntimeConfig::default();
    let world = world(load(ROOM), &config);
    let shown = first_light(&world);
    for &cell in largest_cells(&world).iter().take(3) {
        let d = 128;
        let a = bake_cell(&world, &shown, cell, 1, 1, d);
        let r = bake_cell(&world, &shown, cell, 1, 2, 16 * d);
        let (ea, er) = (a.result(), r.result());
        let n = ea.len() as f64;
        let mse: f64 = ea.iter().zip(&er).map(|(x, y)| (luminance(*x) - luminance(*y)).powi(2)).sum::<f64>() / n;
        let mean: f64 = er.iter().map(|y| luminance(*y)).sum::<f64>() / n;
        let measured = mse.sqrt() / mean;
        let estimate = a.error() as f64;
        eprintln!("cell {cell}: {} texels, estimate {estimate:.4}, measured {measured:.4}", a.texels.len());
        assert!(estimate >= 0.8 * measured, "cell {cell}: optimistic estimate {estimate} for a measured {measured}");
        assert!(estimate <= 4.0 * measured, "cell {cell}: estimate {estimate} far above the measured {measured}");
    }
}

fn room_config(threads: usize) -> RuntimeConfig {
    RuntimeConfig {
        lods: Some(2),
        threads: Some(threads),
        bundle: livebake::bundle::BundleConfig { seed: 7, directions: 64, ..RuntimeConfig::default().bundle },
        ..RuntimeConfig::default()
    }
}

/// A camera in one corner of the 2 m room looking at the opposite corner.
fn corner_camera() -> CameraView {
    CameraView::looking_at(Vec3::new(0.25, 1.0, 1.75), Vec3::new(1.75, 0.6, 0.25))
}

/// With one worker the runtime refines cells in order of the on-screen error each bake
/// removes per unit of work (`policy::urgency`): a cell out of view weighs a quarter, and the
/// weight falls with the square of the distance, far more than light and detail differ
/// between the room's cells. Every cell starts at LOD 0 and wants LOD 1 here, so the first
/// cells published are visible ones, nearer than the visible cells are on average, and
/// nearer than the farthest. (One cell a bake here: groups publish their leader's
/// neighbours with it, see `a_group_bakes_exactly_its_cells_texels`.)
#[test]
fn cells_near_the_camera_reach_higher_lods_first() {
    let scene = load(ROOM);
    let config = RuntimeConfig { group_texels: 0, ..room_config(1) };
    let runtime = Runtime::start(scene, config, Arc::new(CpuProvider::new())).expect("start");
    let camera = corner_camera();
    runtime.set_camera(camera);
    let mut published = Vec::new();
    wait_for(&runtime, Duration::from_secs(120), "six cells swapped", |e| {
        if let RuntimeEvent::CellPublished { cell, lod, .. } = e.event {
            assert_eq!(lod, 1);
            // Published again at LOD 1: refined in place; the order is that of the swaps.
            if !published.contains(&cell) {
                published.push(cell);
            }
        }
        published.len() >= 6
    });
    let world = runtime.world().clone();
    runtime.shutdown().expect("clean shutdown");
    let view = |c: u32| cell_view(&camera, &world.grid, c);
    let visible: Vec<u32> = world.non_empty_cells().filter(|&c| view(c).in_frustum).collect();
    assert!(published.iter().all(|&c| view(c).in_frustum), "{published:?}: not all in view");
    let mean = |cells: &[u32]| cells.iter().map(|&c| view(c).distance).sum::<f32>() / cells.len() as f32;
    let far = visible.iter().map(|&c| view(c).distance).fold(0.0, f32::max);
    assert!(
        mean(&published) < mean(&visible),
        "the first six ({} m on average) should be nearer than the visible cells ({} m)",
        mean(&published),
        mean(&visible)
    );
    assert!(published.iter().all(|&c| view(c).distance < far), "{published:?} include the farthest visible");
}

/// A cell publishes at the first unit where its directions reach the minimum and its error
/// estimate the bound (or the maximum), or, sooner, where they reach the shown level's
/// (LOD 0's; an early publish, see the next test), and what it publishes is exactly an
/// offline bake of that cell at that LOD with the same directions against the same shown map
/// (one worker, so no other cell publishes before it: its bundles saw the first-light map).
#[test]
fn a_cell_publishes_at_its_threshold_what_an_offline_bake_gives() {
    let scene = load(ROOM);
    // First light with all of LOD 0's directions: the map it shows is the one the bakes see.
    let mut config = RuntimeConfig { start_paused: true, ..room_config(1) };
    config.first_light_directions = config.bundle.directions;
    let runtime = Runtime::start(scene, config.clone(), Arc::new(CpuProvider::new())).expect("start");
    runtime.set_camera(corner_camera());
    wait_for(&runtime, Duration::from_secs(60), "first light", |e| matches!(e.event, RuntimeEvent::FirstLight { .. }));
    // Whoever wakes on the event reads the first light's pass counters (the bench does).
    let pass = runtime.stats().first_light_pass;
    assert_eq!(pass.directions, u64::from(config.first_light_directions), "first light's counters at its event");
    let first = runtime.shown();
    runtime.set_paused(false);
    let mut got = None;
    wait_for(&runtime, Duration::from_secs(120), "a publish", |e| {
        if let RuntimeEvent::CellPublished { lod, directions, error, group, .. } = &e.event {
            got = Some((group.clone(), *lod, *directions, *error));
            return true;
        }
        false
    });
    let (group, lod, directions, error) = got.expect("published");
    let shown = runtime.shown();
    let world = runtime.world().clone();
    runtime.shutdown().expect("clean shutdown");

    // Replay offline, unit by unit.
    let mut backend = CpuProvider::new().backend(&world.bundle, 1).expect("backend");
    let mut bake = CellBake::new(&world, &group, lod, first.clone(), config.bundle.seed);
    let never = AtomicBool::new(false);
    let (min, shown_directions) = (config.min_directions as u64, config.bundle.directions as u64);
    let ready = |b: &CellBake| {
        let d = b.directions();
        d >= config.max_directions as u64
            || (d >= min && b.error() <= config.error_bound)
            || d >= min.max(shown_directions)
    };
    while !ready(&bake) {
        bake.step(&world, &mut backend, config.unit_directions, &never).expect("not cancelled");
    }
    assert_eq!(bake.directions(), directions, "the runtime published at another unit");
    assert_eq!(bake.error(), error);
    let values = bake.result();
    for (i, p) in bake.texels.pixel.iter().enumerate() {
        let published =
            shown.layer(Layer::Bundles).levels[lod as usize].texel(p[0] as i64, p[1] as i64).expect("published texel");
        assert_eq!(published.to_array(), values[i].to_array(), "texel {i} at {p:?}");
    }
    for &cell in &group {
        assert_eq!(shown.cell_lod(Layer::Bundles, cell), lod);
    }
}

/// What a `cell_published` event says: LOD, directions, error, settled.
type Published = (u32, u64, f32, bool);

/// The early swap and the refinement in place: a cell's bake at LOD 1 is published as soon
/// as it has the directions its shown LOD 0 has (first light's), although its error estimate
/// (an upper bound, `error_estimate_is_an_honest_upper_bound`) is still above the bound;
/// the same bake goes on into the same sums and is published again at LOD 1 each time its
/// directions double, until it is settled (here at `max_directions`). The expected
/// publishes come from an offline replay of the group's bake against the same shown map
/// with the rule as docs/CLI.md states it, and each published map holds exactly that bake's
/// texels at those directions: the same snapshot, seed and directions give the same sums
/// (results depend on the lanes, not on the threads), so they are bit-equal and no
/// tolerance applies. One worker, so nothing is published before the first bake starts: its
/// bundles saw the first-light map.
#[test]
fn a_finer_level_is_published_at_the_shown_directions_then_refined_in_place() {
    let scene = load(ROOM);
    // First light with all of LOD 0's directions (64): the map it shows is the one the bakes
    // see. At most 4× as many at LOD 1: an early publish at 64, one at 128 and the settled
    // one at 256, unless the estimate meets the bound first (then the replay expects that).
    let mut config = RuntimeConfig { start_paused: true, max_directions: 256, ..room_config(1) };
    config.first_light_directions = config.bundle.directions;
    let shown_directions = config.bundle.directions as u64;
    let runtime = Runtime::start(scene, config.clone(), Arc::new(CpuProvider::new())).expect("start");
    runtime.set_camera(corner_camera());
    runtime.wait_first_light(Duration::from_secs(60)).expect("first light");
    let first = runtime.shown();
    runtime.set_paused(false);
    // The first group published, its leader's publishes (LOD, directions, error, settled)
    // and, per publish, a map of a moment showing it (map and cell table read together).
    let mut group: Option<Vec<u32>> = None;
    let mut publishes: Vec<Published> = Vec::new();
    let mut maps: HashMap<u64, Arc<ShownLightmap>> = HashMap::new();
    let deadline = Instant::now() + Duration::from_secs(400);
    loop {
        let (map, cells) = runtime.snapshot();
        if let Some(leader) = group.as_ref().map(|g| g[0])
            && let Some(c) = cells.iter().find(|c| c.cell == leader && c.shown_lod == 1)
        {
            maps.entry(c.directions).or_insert(map);
        }
        if publishes.last().is_some_and(|p| p.3) {
            break;
        }
        while let Ok(e) = runtime.events().try_recv() {
            match e.event {
                RuntimeEvent::CellPublished { cell, lod, directions, error, settled, group: g } => {
                    let first_group = group.get_or_insert_with(|| g.clone());
                    if *first_group == g && cell == g[0] {
                        publishes.push((lod, directions, error, settled));
                    }
                }
                RuntimeEvent::Failed { error } => panic!("runtime failed: {error}"),
                _ => {}
            }
        }
        assert!(Instant::now() < deadline, "the first group was not settled: {publishes:?}");
        // A unit of a few directions takes milliseconds: polling this often sees every
        // publish of the group (its next comes at least 16 units later).
        std::thread::sleep(Duration::from_millis(1));
    }
    let group = group.expect("a publish");
    let world = runtime.world().clone();
    runtime.shutdown().expect("clean shutdown");

    // Replay offline, unit by unit, with the rule written out: settled at `min_directions`
    // with the error within the bound or at `max_directions`; before that, the first publish
    // once it has the shown level's directions (and the minimum), then each time they double.
    let mut backend = CpuProvider::new().backend(&world.bundle, 1).expect("backend");
    let mut bake = CellBake::new(&world, &group, 1, first.clone(), config.bundle.seed);
    let never = AtomicBool::new(false);
    let (min, max) = (config.min_directions as u64, config.max_directions as u64);
    let mut expected: Vec<(Published, Vec<Rgb>)> = Vec::new();
    loop {
        bake.step(&world, &mut backend, config.unit_directions, &never).expect("not cancelled");
        let (d, error) = (bake.directions(), bake.error());
        let settled = d >= max || (d >= min && error <= config.error_bound);
        let early = match expected.last() {
            None => d >= min.max(shown_directions),
            Some(((_, last, _, _), _)) => d >= 2 * last,
        };
        if settled || early {
            expected.push(((1, d, error, settled), bake.result()));
        }
        if settled {
            break;
        }
    }
    let rule: Vec<Published> = expected.iter().map(|e| e.0).collect();
    // What this test is about must have happened: an early publish at exactly the shown
    // level's directions, and at least one more before the level settled.
    assert_eq!((rule[0].1, rule[0].3), (shown_directions, false), "no early publish: {rule:?}");
    assert!(rule.len() >= 3 && !rule[1].3, "no republish in place before settling: {rule:?}");
    assert_eq!(publishes, rule, "the runtime published at other directions than the rule");
    for ((_, d, _, _), values) in &expected {
        let map = maps.get(d).unwrap_or_else(|| panic!("no snapshot showed the publish at {d} directions"));
        for (i, p) in bake.texels.pixel.iter().enumerate() {
            let published =
                map.layer(Layer::Bundles).levels[1].texel(p[0] as i64, p[1] as i64).expect("published texel");
            assert_eq!(published.to_array(), values[i].to_array(), "{d} directions: texel {i} at {p:?}");
        }
        for &cell in &group {
            assert_eq!(map.cell_lod(Layer::Bundles, cell), 1, "cell {cell} at {d} directions");
        }
    }
}

/// A bake of several cells holds exactly the texels the bakes of each cell alone would (the
/// same pixels, each in the cell holding its surface point), and hands every pixel it writes
/// (texels and gutters) to one of its cells.
#[test]
fn a_group_bakes_exactly_its_cells_texels() {
    let config = room_config(1);
    let world = world(load(ROOM), &config);
    let shown = first_light(&world);
    let cells: Vec<u32> = largest_cells(&world).into_iter().take(5).collect();
    let group = CellBake::new(&world, &cells, 1, shown.clone(), 1);
    for &c in &cells {
        let alone = CellBake::new(&world, &[c], 1, shown.clone(), 1);
        let mut expected = alone.texels.pixel.clone();
        let mut got: Vec<[u32; 2]> = (0..group.texels.len())
            .filter(|&i| world.grid.cell_of(group.texels.position[i]) == c)
            .map(|i| group.texels.pixel[i])
            .collect();
        expected.sort_unstable();
        got.sort_unstable();
        assert!(!got.is_empty(), "cell {c} has no texels at LOD 1");
        assert_eq!(got, expected, "cell {c}'s texels in the group");
    }
    let mut written: Vec<[u32; 2]> = group.texels.pixel.clone();
    written.extend(group.texels.gutter.iter().map(|g| g.0));
    written.sort_unstable();
    let mut handed: Vec<[u32; 2]> = group.pixels_per_cell().into_iter().flatten().collect();
    handed.sort_unstable();
    assert_eq!(handed, written, "every pixel of the group belongs to exactly one of its cells");
}

/// Work is kept when the camera leaves a cell and resumes where it was when it comes back;
/// every traced direction is accounted for.
#[test]
fn camera_away_and_back_keeps_accumulated_work() {
    let scene = load(ROOM);
    // Cells never converge here: they keep baking until their maximum.
    let config = RuntimeConfig { min_directions: 4096, max_directions: 4096, ..room_config(1) };
    let runtime = Runtime::start(scene, config, Arc::new(CpuProvider::new())).expect("start");
    runtime.set_camera(corner_camera());
    runtime.wait_first_light(Duration::from_secs(60)).expect("first light");
    let deadline = Instant::now() + Duration::from_secs(60);
    let (cell, before) = loop {
        if let Some(c) = runtime.cells().into_iter().find(|c| c.baking_directions >= 16) {
            break (c.cell, c.baking_directions);
        }
        assert!(Instant::now() < deadline, "no cell got 16 directions");
        std::thread::sleep(Duration::from_millis(20));
    };
    // Far away (every cell's target is LOD 0 at 40 m): nothing is refined.
    runtime.set_camera(CameraView::looking_at(Vec3::new(40.0, 1.0, 1.0), Vec3::new(80.0, 1.0, 1.0)));
    // Let the unit in flight finish.
    let deadline = Instant::now() + Duration::from_secs(60);
    while runtime.cells().iter().any(|c| c.working) {
        assert!(Instant::now() < deadline, "a unit never finished");
        std::thread::sleep(Duration::from_millis(10));
    }
    let parked = runtime.cells().into_iter().find(|c| c.cell == cell).expect("cell").baking_directions;
    assert!(parked >= before, "work was dropped: {parked} < {before}");
    std::thread::sleep(Duration::from_millis(700));
    let idle = runtime.cells().into_iter().find(|c| c.cell == cell).expect("cell").baking_directions;
    assert_eq!(idle, parked, "a cell below no target was refined");
    assert_eq!(runtime.stats().queue, 0);
    runtime.set_camera(corner_camera());
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let now = runtime.cells().into_iter().find(|c| c.cell == cell).expect("cell").baking_directions;
        if now > parked {
            break;
        }
        assert!(Instant::now() < deadline, "the cell did not resume");
        std::thread::sleep(Duration::from_millis(20));
    }
    let stats = runtime.stats();
    let cells = runtime.cells();
    runtime.shutdown().expect("clean shutdown");
    let in_progress: u64 = cells.iter().map(|c| c.baking_directions).sum();
    let published: u64 = cells.iter().filter(|c| c.shown_lod > 0).map(|c| c.directions).sum();
    // The snapshots are taken moments apart: a unit may finish between them.
    let traced = stats.directions_traced;
    let first = 64;
    assert!(
        traced <= first + published + in_progress + 8,
        "{traced} traced, {first} + {published} + {in_progress} kept"
    );
}

/// Many camera moves a second and a shutdown in the middle of units: no panic, no direction
/// lost or counted twice, memory within the budget (with a budget small enough to evict, in
/// both layers).
#[test]
fn stress_camera_moves_and_shutdown_mid_pass() {
    // With a lamp, so that punctual bakes and their evictions are in the mix.
    let mut lit = (*load(ROOM)).clone();
    let mut b = SceneBuilder::new();
    b.point_light(Vec3::new(1.0, 1.6, 1.0), Vec3::splat(2.0));
    lit.lights.extend(b.build().lights);
    let scene = Arc::new(lit);
    let world_probe = world(scene.clone(), &room_config(2));
    // Room for LOD 0's pages and a little more: refinement must evict to go on.
    let lod0_pages = first_light(&world_probe).page_bytes() as u64;
    let budget = lod0_pages + 3 * (1 << 20);
    let config = RuntimeConfig { memory_budget: Some(budget), min_directions: 8, max_directions: 16, ..room_config(2) };
    let runtime = Runtime::start(scene, config, Arc::new(CpuProvider::new())).expect("start");
    runtime.wait_first_light(Duration::from_secs(60)).expect("first light");
    // Move the camera every few milliseconds until refinement has both published and
    // evicted (however slow the machine), for at least 300 moves.
    let deadline = Instant::now() + Duration::from_secs(240);
    let mut i = 0u32;
    let (mut evictions, mut publishes) = (0, 0);
    let mut peak = 0u64;
    while i < 300 || publishes < 6 || evictions == 0 {
        assert!(Instant::now() < deadline, "{publishes} publishes and {evictions} evictions after {i} moves");
        let a = i as f32 * 0.37;
        let eye = Vec3::new(1.0 + 0.8 * a.cos(), 1.0, 1.0 + 0.8 * a.sin());
        runtime.set_camera(CameraView::looking_at(eye, Vec3::new(1.0, 0.8, 1.0) - (eye - Vec3::splat(1.0))));
        while let Ok(e) = runtime.events().try_recv() {
            match e.event {
                RuntimeEvent::CellEvicted { .. } => evictions += 1,
                RuntimeEvent::CellPublished { .. } => publishes += 1,
                RuntimeEvent::Stats(s) => peak = peak.max(s.page_bytes + s.bake_bytes),
                RuntimeEvent::Failed { error } => panic!("{error}"),
                _ => {}
            }
        }
        i += 1;
        std::thread::sleep(Duration::from_millis(5));
    }
    // Shut down in the middle of whatever units are in flight.
    let stats = runtime.stats();
    peak = peak.max(stats.page_bytes + stats.bake_bytes);
    runtime.shutdown().expect("no worker panicked");
    // Bakes reserve their estimated size before starting; pages are shared between cells, so
    // allow a quarter over.
    assert!(peak as f64 <= budget as f64 * 1.25, "peak {peak} bytes for a budget of {budget}");
}

/// Across a border between a cell refined to LOD 1 and a neighbour at LOD 0, the shown
/// irradiance has no step: the finer side blends into the coarser LOD over the band. The
/// noise level is the RMS difference between the two LODs' estimates inside the fine cell
/// (two estimates of the same irradiance); without the blend the step at the border is of
/// that size. The step measured 1 mm either side of the face must be under a quarter of it.
#[test]
fn borders_between_lods_show_no_step_beyond_the_noise() {
    let config = RuntimeConfig::default();
    let world = world(load(ROOM), &config);
    let coarse = first_light(&world);
    // A floor cell (y = 0) with a floor neighbour along +x.
    let grid = world.grid;
    let cell = world
        .non_empty_cells()
        .filter(|&c| grid.coords(c)[1] == 0)
        .find(|&c| grid.neighbour(c, 0, 1).is_some_and(|n| world.lod0_texels[n as usize] > 0) && grid.coords(c)[0] > 0)
        .expect("a floor cell with a neighbour");
    let bake = bake_cell(&world, &coarse, cell, 1, 3, 256);
    let mut map = (*coarse).clone();
    publish_bake(&mut map, &bake, &bake.result());
    let (lo, hi) = grid.bounds(cell);
    let locator_geom = &world.geom;
    let bvh = &world.bvh;
    let locator = SurfaceLocator::new(locator_geom, bvh);
    let sample = |map: &ShownLightmap, x: f32, z: f32| {
        let at = locator.locate(Vec3::new(x, 0.0, z), Vec3::Y).expect("floor");
        let face = world.atlas.face(at.tri, at.side).expect("lit");
        let uv: Vec2 = world.atlas.faces[face as usize].uv_at(at.u, at.v);
        luminance(map.irradiance(world.geom.point(at.tri, at.u, at.v), uv))
    };
    let zs: Vec<f32> = (1..20).map(|i| lo.z + (hi.z - lo.z) * i as f32 / 20.0).collect();
    // Noise: fine against coarse inside the fine cell, away from the band.
    let band = map.blend_band;
    let inner: Vec<(f32, f32)> = (1..10)
        .flat_map(|i| zs.iter().map(move |&z| (lo.x + band + (hi.x - lo.x - 2.0 * band) * i as f32 / 10.0, z)))
        .collect();
    let noise = (inner.iter().map(|&(x, z)| (sample(&map, x, z) - sample(&coarse, x, z)).powi(2)).sum::<f64>()
        / inner.len() as f64)
        .sqrt();
    let border = hi.x;
    let steps: Vec<f64> =
        zs.iter().map(|&z| (sample(&map, border - 1e-3, z) - sample(&map, border + 1e-3, z)).abs()).collect();
    let step = (steps.iter().map(|s| s * s).sum::<f64>() / steps.len() as f64).sqrt();
    eprintln!("noise {noise:.4}, step {step:.5}");
    assert!(noise > 0.0);
    assert!(step < 0.25 * noise, "step {step} against a noise level of {noise}");
}

/// Multi-bounce with neighbours at different LODs: the 2 m room refined near one corner
/// (some cells at LOD 1 and 2, the rest at LOD 0) against Mitsuba 3 at its 332 bundled points
/// (65 536 spp; its noise is taken out in quadrature). First light (LOD 0, 64 directions)
/// measures ~4% on this scene; refined cells read their neighbours' shown radiance,
/// whatever their LOD, so nothing may get worse: every point within 5%, refined cells'
/// points no worse than at first light.
#[test]
fn multi_bounce_with_mixed_lods_matches_the_independent_reference() {
    let scene = load(ROOM);
    let config = RuntimeConfig { lods: Some(3), ..room_config(2) };
    let runtime = Runtime::start(scene, config, Arc::new(CpuProvider::new())).expect("start");
    runtime.set_camera(corner_camera());
    runtime.wait_first_light(Duration::from_secs(60)).expect("first light");
    let first = runtime.shown();
    // However long refinement takes on this machine (about 20 s on two idle cores).
    let deadline = Instant::now() + Duration::from_secs(400);
    loop {
        let s = runtime.stats();
        if s.cells_per_lod.get(1).copied().unwrap_or(0) >= 12 && s.cells_per_lod.get(2).copied().unwrap_or(0) >= 2 {
            break;
        }
        assert!(Instant::now() < deadline, "not refined enough: {:?}", s.cells_per_lod);
        std::thread::sleep(Duration::from_millis(100));
    }
    let shown = runtime.shown();
    let world = runtime.world().clone();
    runtime.shutdown().expect("clean shutdown");
    let text = std::fs::read_to_string(asset("cornell_2m/mitsuba_reference.json")).expect("reference");
    let reference: Value = serde_json::from_str(&text).expect("json");
    let locator = SurfaceLocator::new(&world.geom, &world.bvh);
    let (mut all, mut refined_now, mut refined_before) =
        (RelativeRmsError::default(), RelativeRmsError::default(), RelativeRmsError::default());
    let v3 = |v: &Value| DVec3::new(v[0].as_f64().unwrap(), v[1].as_f64().unwrap(), v[2].as_f64().unwrap());
    for p in reference["points"].as_array().expect("points") {
        let (pos, n) = (v3(&p["p"]).as_vec3(), v3(&p["n"]).as_vec3());
        let at = locator.locate(pos, n).expect("on a surface");
        let face = world.atlas.face(at.tri, at.side).expect("lit side");
        let uv = world.atlas.faces[face as usize].uv_at(at.u, at.v);
        let q = world.geom.point(at.tri, at.u, at.v);
        let (want, err) = (v3(&p["E"]), v3(&p["E_stderr"]));
        let got = shown.irradiance(q, uv).as_dvec3();
        all.add(got, want, err);
        if shown.cell_lod(Layer::Bundles, world.grid.cell_of(q)) > 0 {
            refined_now.add(got, want, err);
            refined_before.add(first.irradiance(q, uv).as_dvec3(), want, err);
        }
    }
    eprintln!(
        "all {:.4}, refined cells {:.4} (at first light {:.4})",
        all.value(),
        refined_now.value(),
        refined_before.value()
    );
    assert!(all.value() < 0.05, "relative RMS error {}", all.value());
    assert!(refined_now.value() <= refined_before.value() * 1.05 + 0.002, "refinement made it worse");
}

/// A 1 m block on an 8 m floor under a sun (no sky): the punctual layer's exact answer is
/// `I·cos θ` where the sun sees the floor and 0 in the block's shadow.
fn sunlit_block() -> (Arc<Scene>, Vec3, f32) {
    let mut b = SceneBuilder::new();
    let grey = b.material(diffuse(Vec3::splat(0.5), Vec3::ZERO, false));
    b.floor("floor", Vec3::ZERO, 8.0, grey);
    b.cuboid("block", Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5), false, grey);
    let travel = Vec3::new(-1.0, -1.2, -0.6).normalize();
    b.directional_light(travel, Vec3::splat(4.0));
    (Arc::new(b.build()), travel, 4.0)
}

/// Whether the ray from `p` toward the sun (against `travel`) meets the block (slab test).
fn block_shadows(p: Vec3, travel: Vec3) -> bool {
    let (lo, hi) = (Vec3::new(-0.5, 0.0, -0.5), Vec3::new(0.5, 1.0, 0.5));
    let d = -travel;
    let (t1, t2) = ((lo - p) / d, (hi - p) / d);
    let (near, far) = (t1.min(t2).max_element(), t1.max(t2).min_element());
    far > near.max(0.0)
}

/// The punctual layer is baked a LOD a bake, from LOD 1 up to the LOD each cell wants, and it
/// is exact: on the floor, away from
/// the shadow's edge (the bilinear mixes lit and shadowed texels within a texel of it, and a
/// border blend reads the coarser neighbour's texels: 2 of those), the layer reads `I·cos θ`
/// or 0 as a slab test against the block says, to f32 rounding (renormalised bilinear weights
/// and blends of equal values: a few ulps). The bundle layer (black but for the floor's
/// bounce off the block: no sky, no emitter) is left to its bakes.
#[test]
fn the_punctual_layer_is_exact_at_the_lod_the_camera_wants() {
    let (scene, travel, sun) = sunlit_block();
    let config = RuntimeConfig {
        atlas: livebake::atlas::AtlasConfig { texel_budget: 2000, ..RuntimeConfig::default().atlas },
        threads: Some(2),
        ..RuntimeConfig::default()
    };
    let runtime = Runtime::start(scene, config, Arc::new(CpuProvider::new())).expect("start");
    runtime.set_camera(CameraView::looking_at(Vec3::new(1.6, 1.4, 1.8), Vec3::new(0.0, 0.0, 0.0)));
    let world = runtime.world();
    let finest = world.lods - 1;
    assert!(finest >= 3, "{} LODs", world.lods);
    // Until every cell's punctual bake at its target has been announced (a bake's event
    // follows its publish).
    let mut bakes: HashMap<u32, Vec<u32>> = HashMap::new();
    wait_for(&runtime, Duration::from_secs(120), "every cell's punctual layer at its target", |e| {
        if let RuntimeEvent::PunctualPublished { cell, lod, .. } = e.event {
            bakes.entry(cell).or_default().push(lod);
        }
        runtime
            .cells()
            .iter()
            .all(|c| c.target_lod == 0 || bakes.get(&c.cell).is_some_and(|b| b.iter().any(|&k| k >= c.target_lod)))
    });
    let (shown, cells) = runtime.snapshot();
    runtime.shutdown().expect("clean shutdown");
    for c in &cells {
        if c.target_lod > 0 {
            let steps: Vec<u32> = (1..=c.punctual_lod).collect();
            assert_eq!(bakes.get(&c.cell), Some(&steps), "cell {}", c.cell);
        }
    }
    assert!(cells.iter().any(|c| c.punctual_lod == finest), "no cell at LOD {finest}");

    let locator = SurfaceLocator::new(&world.geom, &world.bvh);
    let punctual = shown.layer(Layer::Punctual);
    let lit = sun * Vec3::Y.dot(-travel);
    let (mut in_light, mut in_shadow, mut at_finest) = (0, 0, 0);
    let steps = 160;
    for i in 0..steps {
        for j in 0..steps {
            let p = Vec3::new(-3.9 + 7.8 * i as f32 / steps as f32, 0.0, -3.9 + 7.8 * j as f32 / steps as f32);
            let cell = world.grid.cell_of(p);
            let k = shown.cell_lod(Layer::Punctual, cell);
            let coarse = world.texel_size(k.saturating_sub(1));
            if p.x.abs().max(p.z.abs()) < 0.5 + 2.0 * coarse || p.x.abs().max(p.z.abs()) > 4.0 - 2.0 * coarse {
                continue; // under or beside the block, or at the floor's edge
            }
            // Away from the shadow's edge: the same answer on a circle of 2 coarse texels.
            let shadowed = block_shadows(p, travel);
            let ring = (0..16).map(|a| {
                let a = a as f32 * std::f32::consts::TAU / 16.0;
                p + Vec3::new(a.cos(), 0.0, a.sin()) * 2.0 * coarse
            });
            if ring.map(|q| block_shadows(q, travel)).any(|s| s != shadowed) {
                continue;
            }
            let at = locator.locate(p, Vec3::Y).expect("floor");
            let face = world.atlas.face(at.tri, at.side).expect("lit side");
            let uv = world.atlas.faces[face as usize].uv_at(at.u, at.v);
            let got = shown.layer_irradiance(Layer::Punctual, cell, world.geom.point(at.tri, at.u, at.v), uv);
            let want = if shadowed { 0.0 } else { lit };
            assert!((got - Vec3::splat(want)).abs().max_element() <= 1e-5 * lit, "at {p}: {got} for {want}");
            if shadowed {
                in_shadow += 1
            } else {
                in_light += 1
            }
            // Its cell's levels: every one from LOD 0 to the shown one (looked up well inside
            // the cell, where the pixels are the cell's own).
            let (lo, hi) = world.grid.bounds(cell);
            let inside = (p - lo).min(hi - p);
            if k == finest && inside.x.min(inside.z) > 2.0 * world.texel_size(0) {
                at_finest += 1;
                for j in 1..=k {
                    let px = (uv * (1u32 << j) as f32).floor();
                    let has = punctual.levels[j as usize].texel(px.x as i64, px.y as i64).is_some();
                    assert!(has, "LOD {j} at {p}");
                }
            }
        }
    }
    eprintln!("{in_light} lit and {in_shadow} shadowed floor points exact, {at_finest} at LOD {finest}");
    assert!(in_light > 1000 && in_shadow > 100 && at_finest > 100, "{in_light} lit, {in_shadow} shadowed, {at_finest}");
}

/// Cell bakes on the GPU backend (lavapipe here) equal the CPU backend's, foreign sides
/// included: the surfaces outside a cell, which its bundles see through the shown map
/// (albedo/π · E, textured albedo, carried emission), are evaluated in the GPU resolve.
/// Three scenes: the Cornell box (textured walls, its lamp carried by the global bundles),
/// the Van Gogh room (double-sided materials, small emitters, punctual lights: the
/// shown map has both layers) and GlassBrokenWindow under a sky of 1 (glass and a cut-out:
/// the resolve's transmittances read the materials the foreign sides read); and the Cornell
/// box again with every mesh painted by vertex colours (COLOR_0, varying over each wall), whose
/// albedo the GPU reads at the foreign points as the CPU does. The map the bakes
/// see has first light at LOD 0 and two cells published at LOD 1, so foreign points also
/// read LOD 1 and blend across LOD borders.
///
/// Both backends make the same decisions (the resolve follows the CPU's arithmetic), so
/// they look up the same foreign sides: the counts are equal. Per texel the bundle sums
/// differ by (i) the summation: ≤ (k + lanes + 2)·2⁻²⁴ relative for k hits (the CPU's f32
/// additions against the GPU's exact fixed point; see the backend's own twin test), with
/// k ≤ 2·D·(2·os + 1)² per texel for D directions; and (ii) the foreign radiance: the same
/// inputs (barycentrics, point, atlas UV and cell computed the CPU's way), then the shown
/// map's bilinear taps and blend, whose roundings the GPU may fuse or round within WGSL's
/// 2.5 ulp; the sampling twin test (tests/viewer.rs) bounds that by 2·10⁻⁵ relative. A
/// ratio S/A of two sums adds their bounds, and the filter within charts is a positive
/// average, which keeps a relative bound. A hit credited to another texel, or a foreign
/// side read at another point or LOD, moves a texel by O(1/k) ≥ 10⁻³: far above this.
#[test]
fn cell_bakes_on_the_gpu_backend_equal_the_cpu_backends() {
    use livebake::gpu::{GpuContext, GpuProvider};
    let gpu = GpuProvider::new(GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)"));
    let never = AtomicBool::new(false);
    let directions = 16u32;
    // The Cornell box's lamp is made a large emitter (the global bundles carry its light),
    // so foreign sides show emission too.
    // The window is small: at the default finest texel it has a single LOD, and the bakes
    // here publish LOD 1.
    for (rel, small_emitter_fraction, sky, lods, painted) in [
        ("cornell_box/cornellBox-2.79-Cycles-gltf.gltf", 0.0, Rgb::ZERO, None, false),
        ("van_gogh_room/van_gogh_room_lit.gltf", 0.05, Rgb::ZERO, None, false),
        ("glass_broken_window/GlassBrokenWindow.gltf", 0.05, Rgb::ONE, Some(2), false),
        ("cornell_box/cornellBox-2.79-Cycles-gltf.gltf", 0.0, Rgb::ZERO, None, true),
    ] {
        let mut config = RuntimeConfig { lods, ..RuntimeConfig::default() };
        config.bundle.small_emitter_fraction = small_emitter_fraction;
        let mut scene = (*load(rel)).clone();
        scene.sky += sky;
        if painted {
            for mesh in &mut scene.meshes {
                let paint = |p: &Vec3| {
                    Vec4::new(0.6 + 0.4 * (3.0 * p.x).sin(), 0.6 + 0.4 * (2.0 * p.y).cos(), 0.5 + 0.1 * p.z, 1.0)
                };
                mesh.colors = Some(mesh.positions.iter().map(paint).collect());
            }
        }
        let rel = if painted { "the painted Cornell box" } else { rel };
        let world = world(Arc::new(scene), &config);
        let carried = world.bundle.emitters.carried_by_bundles.iter().filter(|&&c| c).count();
        eprintln!("{rel}: {carried} triangles whose emission the global bundles carry");
        let first = first_light(&world);
        let cells = largest_cells(&world);
        // Two cells at LOD 1 in the map the bakes see.
        let mut map = (*first).clone();
        for &cell in &cells[..2] {
            let bake = bake_cell(&world, &first, cell, 1, 5, 8);
            publish_bake(&mut map, &bake, &bake.result());
        }
        let shown = Arc::new(map);
        let bc = &world.bundle.config;
        let k = 2.0 * directions as f64 * (2.0 * bc.oversampling as f64 + 1.0).powi(2);
        let bound = 2.0 * (k + bc.lanes.most() as f64 + 2.0) * 2f64.powi(-24) + 2e-5;
        let mut cpu = CpuProvider::new().backend(&world.bundle, 2).expect("CPU backend");
        let mut on_gpu = gpu.backend(&world.bundle, 2).expect("GPU backend");
        for &cell in &cells[1..4] {
            let mut a = CellBake::new(&world, &[cell], 1, shown.clone(), 9);
            let mut b = CellBake::new(&world, &[cell], 1, shown.clone(), 9);
            let sa = a.step(&world, &mut cpu, directions, &never).expect("not cancelled").pass;
            let sb = b.step(&world, &mut on_gpu, directions, &never).expect("not cancelled").pass;
            assert_eq!(
                (sb.cpu_fallback_batches, sb.unresolved_pixels, sb.saturated_sums, sb.lost_lookups),
                (0, 0, 0, 0),
                "{rel} cell {cell}: the GPU resolved the batch itself"
            );
            assert_eq!(sa.lost_lookups, 0);
            assert!(sa.foreign_lookups > 1000, "{rel} cell {cell}: {} foreign lookups", sa.foreign_lookups);
            assert_eq!(sb.foreign_lookups, sa.foreign_lookups, "{rel} cell {cell}: foreign sides looked up");
            let (ra, rb) = (a.result(), b.result());
            // Dark texels (below 10⁻⁷ of the cell's brightest) are compared at that level:
            // there the GPU's fixed point (one unit is 2⁻⁶² of 64·D texel areas at the
            // batch's brightest source, an emitter's radiance) rounds each hit by up to a
            // unit, which the relative bound does not cover.
            let brightest = ra.iter().fold(0f32, |m, x| m.max(x.max_element())) as f64;
            let mut worst = 0f64;
            let mut beyond = 0;
            for (i, (x, y)) in ra.iter().zip(&rb).enumerate() {
                let scale = (x.abs().max_element().max(y.abs().max_element()) as f64).max(1e-7 * brightest);
                let d = (*x - *y).abs().max_element() as f64 / scale;
                worst = worst.max(d);
                if d > bound {
                    beyond += 1;
                    if beyond <= 3 {
                        eprintln!("{rel} cell {cell} texel {i}: CPU {x} GPU {y}");
                    }
                }
            }
            eprintln!(
                "{rel} cell {cell}: {} texels, {} foreign lookups, worst relative difference {worst:e} (bound {bound:e})",
                ra.len(),
                sa.foreign_lookups
            );
            assert_eq!(beyond, 0, "{rel} cell {cell}: texels beyond the bound");
        }
    }
}

/// One order of work for both layers, by the on-screen error a job removes per unit of work
/// (`policy::urgency`): under a porch around the camera, a floor lit by bounced light and the
/// sky alone, whose LOD 0 (coarse texels straddling the porch's shadow line) is far off; out
/// in the sun 6 m away, a post whose sharp shadow wants fine punctual texels. The porch's
/// cells are refined in the bundle layer before the post's shadow gets its finer punctual
/// levels (LOD 2 and up: each four times the texels of the one before, for an edge that
/// halves). One worker thread: the jobs come one at a time in the order the policy gives,
/// which depends on the seed and the scene alone, so two runs list the same publishes.
#[test]
fn bounced_light_near_the_camera_goes_before_a_finer_sun_shadow() {
    let mut b = SceneBuilder::new();
    let grey = b.material(diffuse(Rgb::splat(0.6), Rgb::ZERO, false));
    b.grid_quad(
        "ground",
        [Vec3::new(-8.0, 0.0, 8.0), Vec3::new(8.0, 0.0, 8.0), Vec3::new(8.0, 0.0, -8.0), Vec3::new(-8.0, 0.0, -8.0)],
        4,
        grey,
    );
    b.cuboid("porch roof", Vec3::new(-3.0, 2.4, -3.0), Vec3::new(3.0, 2.6, 3.0), false, grey);
    b.cuboid("post", Vec3::new(5.9, 0.0, -0.1), Vec3::new(6.1, 2.0, 0.1), false, grey);
    b.directional_light(Vec3::new(-0.5, -1.0, 0.3).normalize(), Rgb::splat(3.0));
    b.sky(Rgb::splat(0.3));
    let scene = Arc::new(b.build());
    let camera = CameraView::looking_at(Vec3::new(0.0, 1.6, 0.0), Vec3::new(6.0, 0.5, 0.0));
    let run = || {
        let config = RuntimeConfig {
            threads: Some(1),
            bundle: livebake::bundle::BundleConfig { seed: 3, directions: 64, ..RuntimeConfig::default().bundle },
            ..RuntimeConfig::default()
        };
        let runtime = Runtime::start(scene.clone(), config, Arc::new(CpuProvider::new())).expect("start");
        runtime.set_camera(camera);
        let world = runtime.world();
        let porch: Vec<u32> = world
            .non_empty_cells()
            .filter(|&c| {
                let (lo, hi) = world.grid.bounds(c);
                lo.x < 2.0 && hi.x > -2.0 && lo.z < 2.0 && hi.z > -2.0 && lo.y < 0.1
            })
            .collect();
        let post = world.grid.cell_of(Vec3::new(6.0, 0.01, 0.5));
        let mut log = Vec::new();
        let (mut porch_refined, mut post_fine) = (None, None);
        wait_for(&runtime, Duration::from_secs(240), "a porch cell refined and the post's shadow at LOD 2", |e| {
            match &e.event {
                RuntimeEvent::CellPublished { cell, lod, .. } if *lod >= 1 && porch.contains(cell) => {
                    porch_refined.get_or_insert(log.len());
                    log.push(format!("bundles {cell} {lod}"));
                }
                RuntimeEvent::PunctualPublished { cell, lod, .. } => {
                    if *cell == post && *lod >= 2 {
                        post_fine.get_or_insert(log.len());
                    }
                    log.push(format!("punctual {cell} {lod}"));
                }
                RuntimeEvent::CellPublished { cell, lod, .. } => log.push(format!("bundles {cell} {lod}")),
                _ => {}
            }
            porch_refined.is_some() && post_fine.is_some()
        });
        runtime.shutdown().expect("no panic");
        (porch_refined.unwrap(), post_fine.unwrap(), log)
    };
    let (porch_refined, post_fine, log) = run();
    eprintln!("porch refined at publish {porch_refined}, the post's shadow at LOD 2 at {post_fine}: {log:?}");
    assert!(porch_refined < post_fine, "publishes: {log:?}");
    let (_, _, again) = run();
    assert_eq!(again, log, "the order of work depends on the seed and the scene alone");
}

/// A cell bake's window holds every surface point a bundle line can credit one of its texels
/// at: wherever a face of a texel's chart covers a point of the texel's pixel (3×3 points a
/// pixel, every face of the chart holding it), that point of the face is inside the window.
/// On zdm2 (a real game map) some of those points lie more than a texel and a half outside
/// the cells' box (faces steep to their chart's plane, which the chart stretches): the
/// window that box grown by 1.5 texels gave lost those lines' hits (up to 8% of a texel's
/// value at LOD 3); the test counts such points, so it would fail on that window.
#[test]
fn a_cell_bakes_window_holds_every_point_its_texels_are_credited_at() {
    let config = RuntimeConfig::default();
    let world = world(load("zdm2/zdm2_sun.gltf"), &config);
    let shown = Arc::new(empty_shown(&world));
    let (mut points, mut beyond_old_reach) = (0u64, 0u64);
    for (k, &cell) in largest_cells(&world).iter().step_by(5).take(30).enumerate() {
        let lod = 1 + k as u32 % 3;
        let bake = CellBake::new(&world, &[cell], lod, shown.clone(), 1);
        let (lo, hi) = bake.window();
        let (cell_lo, cell_hi) = world.cell_box(cell);
        let old_reach = Vec3::splat(world.texel_size(lod) * 1.5);
        for (i, p) in bake.texels.pixel.iter().enumerate() {
            let chart = &world.atlas.charts[world.atlas.faces[bake.texels.face[i] as usize].chart as usize];
            for (sx, sy) in (0..9).map(|s| (s % 3, s / 3)) {
                let q = DVec2::new(p[0] as f64 + (sx as f64 + 0.5) / 3.0, p[1] as f64 + (sy as f64 + 0.5) / 3.0);
                for &f in &chart.faces {
                    let face = &world.atlas.faces[f as usize];
                    let uv = face.uv_lod(lod);
                    let (e1, e2, d) = (uv[1] - uv[0], uv[2] - uv[0], q - uv[0]);
                    let det = e1.perp_dot(e2);
                    if det == 0.0 {
                        continue;
                    }
                    let (u, v) = (d.perp_dot(e2) / det, e1.perp_dot(d) / det);
                    if u < 0.0 || v < 0.0 || u + v > 1.0 {
                        continue;
                    }
                    let at = world.geom.point(face.tri, u as f32, v as f32);
                    points += 1;
                    assert!(
                        at.cmpge(lo).all() && at.cmple(hi).all(),
                        "cell {cell} LOD {lod}: texel {i}'s pixel {p:?} holds {at} of face {f}, outside the window {lo}..{hi}"
                    );
                    beyond_old_reach +=
                        u64::from(!(at.cmpge(cell_lo - old_reach).all() && at.cmple(cell_hi + old_reach).all()));
                }
            }
        }
    }
    assert!(points > 100_000, "{points} points checked");
    assert!(beyond_old_reach > 0, "no point beyond the cells' box grown by 1.5 texels: the test has no teeth on zdm2");
    println!("{points} points, {beyond_old_reach} beyond the cells' box grown by 1.5 texels");
}

/// Building a cell bake's fragments only inside its window's outline, and resolving only the
/// pixels where a triangle that may show a target texel lies inside the window's box (the
/// CPU backend's default), changes no texel: every line that credits a texel crosses its
/// surface inside the window, so the lines left out credit none. Cells of two real scenes at LODs 1–3, 16
/// directions, against the same bakes filling the window's whole square (as the GPU does).
/// Bounds: the same hits arrive in the same order unless a tile overflows in one bake and not
/// the other, which reorders a texel's sums (f32 rounding, ~1e-6 relative); a texel gets about
/// oversampling² = 4 lines a direction, so one lost hit is one of ~64 and moves its value by
/// about a percent (unless that line saw exactly the texel's mean).
#[test]
fn the_outline_clip_changes_no_texel() {
    for rel in ["zdm2/zdm2_sun.gltf", "van_gogh_room/van_gogh_room_lit.gltf"] {
        let config = RuntimeConfig::default();
        let world = world(load(rel), &config);
        let shown = first_light(&world);
        let never = AtomicBool::new(false);
        let backend = || CpuProvider::new().backend(&world.bundle, 1).expect("backend");
        let (mut clipped, mut whole) = (backend(), backend().with_outline_clip(false));
        let mut texels = 0;
        for (k, &cell) in largest_cells(&world).iter().step_by(5).take(24).enumerate() {
            let lod = 1 + k as u32 % 3;
            let mut a = CellBake::new(&world, &[cell], lod, shown.clone(), 3);
            let mut b = CellBake::new(&world, &[cell], lod, shown.clone(), 3);
            while a.directions() < 16 {
                a.step(&world, &mut clipped, 4, &never).expect("not cancelled");
                b.step(&world, &mut whole, 4, &never).expect("not cancelled");
            }
            for (i, (x, y)) in a.result().iter().zip(b.result()).enumerate() {
                let scale = luminance(y).max(1e-3);
                assert!(
                    luminance((*x - y).abs()) <= 1e-5 * scale,
                    "{rel} cell {cell} LOD {lod} texel {i}: {x} with the outline, {y} without"
                );
            }
            texels += a.texels.len();
        }
        assert!(texels > 10_000, "{rel}: {texels} texels compared");
    }
}
