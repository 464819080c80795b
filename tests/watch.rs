//! Hot reload with the real watcher on real files in a temp dir: saves in place and by
//! temp-file-and-rename, corrupt and half-written saves, Blender's `.bin`-then-`.gltf` order,
//! referenced files elsewhere, a soak of rapid saves, and shutdown with unread reports.
//!
//! Timing: every wait for a report has a generous timeout ([`PATIENCE`]) because the machine
//! may be loaded; nothing asserts how fast a report came. The only timed rule tested is an
//! ordering one (a `.bin` saved without its `.gltf` is held for the settle time), and the
//! delays the tests put between files are well inside the settle time they configure.

mod support;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use glam::Vec3;
use livebake::scene::{LoadOptions, Scene, load_gltf};
use livebake::watch::{Aabb, FailureKind, SceneDiff, SceneWatcher, WatchConfig, WatchError, WatchEvent};
use serde_json::json;
use support::{Doc, cube};

/// How long to wait for a report before calling the test failed.
const PATIENCE: Duration = Duration::from_secs(60);

/// What the test scene looks like. Box `i` is the shared unit-cube mesh, its vertices scaled by
/// `vertex_scale` in the `.bin`, on node `box{i}` translated to `at[i]` in the `.gltf`. With
/// `extra`, a second mesh (a tetrahedron) on node `extra` makes the `.bin` longer.
#[derive(Clone, Debug)]
struct Layout {
    at: Vec<[f32; 3]>,
    vertex_scale: f32,
    extra: bool,
}

impl Layout {
    fn three_boxes() -> Layout {
        Layout { at: vec![[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [6.0, 0.0, 0.0]], vertex_scale: 1.0, extra: false }
    }

    fn moved(&self, i: usize, by: [f32; 3]) -> Layout {
        let mut l = self.clone();
        l.at[i] = (Vec3::from(l.at[i]) + Vec3::from(by)).to_array();
        l
    }

    /// The `.gltf` text (its buffer at `bin_uri`) and the `.bin` bytes.
    fn files(&self, bin_uri: &str) -> (Vec<u8>, Vec<u8>) {
        let mut d = Doc::new();
        let (positions, normals, indices) = cube(self.vertex_scale);
        let prim = d.prim(&positions, Some(&normals), Some(&indices));
        let cube_mesh = d.push("meshes", json!({ "name": "box", "primitives": [prim] }));
        for (i, t) in self.at.iter().enumerate() {
            let node = d.push("nodes", json!({ "name": format!("box{i}"), "mesh": cube_mesh, "translation": t }));
            d.add_root(node);
        }
        if self.extra {
            let p = [[0.0, 5.0, 0.0], [1.0, 5.0, 0.0], [0.0, 6.0, 0.0], [0.0, 5.0, 1.0]];
            let prim = d.prim(&p, None, Some(&[0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3]));
            let mesh = d.push("meshes", json!({ "name": "tetra", "primitives": [prim] }));
            let node = d.push("nodes", json!({ "name": "extra", "mesh": mesh }));
            d.add_root(node);
        }
        let gltf = serde_json::to_vec_pretty(&d.json_with_buffer(Some(bin_uri.to_string()))).unwrap();
        (gltf, d.bin)
    }

    /// World bounds of box `i`: its translation plus the scaled unit cube.
    fn box_bounds(&self, i: usize) -> Aabb {
        let min = Vec3::from(self.at[i]);
        Aabb { min, max: min + Vec3::splat(self.vertex_scale) }
    }
}
fn save_in_place(path: &Path, bytes: &[u8]) {
    std::fs::write(path, bytes).unwrap();
}

/// What most editors do: write a temporary file beside the target, rename it over the target.
fn save_by_rename(path: &Path, bytes: &[u8]) {
    let name = path.file_name().unwrap().to_string_lossy();
    let tmp = path.with_file_name(format!(".{name}.tmp"));
    std::fs::write(&tmp, bytes).unwrap();
    std::fs::rename(&tmp, path).unwrap();
}

/// A temp dir with `scene.gltf` + its `.bin` (at `bin_uri`, relative) and a watcher on it.
struct Fixture {
    _dir: tempfile::TempDir,
    gltf: PathBuf,
    bin: PathBuf,
    bin_uri: String,
    watcher: SceneWatcher,
}

impl Fixture {
    fn new(layout: &Layout, bin_uri: &str, config: WatchConfig) -> Fixture {
        let dir = tempfile::tempdir().unwrap();
        let gltf = dir.path().join("scene.gltf");
        let bin = dir.path().join(bin_uri);
        std::fs::create_dir_all(bin.parent().unwrap()).unwrap();
        let (g, b) = layout.files(bin_uri);
        std::fs::write(&bin, b).unwrap();
        std::fs::write(&gltf, g).unwrap();
        let watcher = SceneWatcher::start(&gltf, config).unwrap();
        Fixture { _dir: dir, gltf, bin, bin_uri: bin_uri.to_string(), watcher }
    }

    /// Saves both files of `layout`, the `.bin` first (as Blender does), each with `save`.
    fn save(&self, layout: &Layout, save: fn(&Path, &[u8])) {
        let (g, b) = layout.files(&self.bin_uri);
        save(&self.bin, &b);
        save(&self.gltf, &g);
    }

    fn gltf_bytes(&self, layout: &Layout) -> Vec<u8> {
        layout.files(&self.bin_uri).0
    }

    fn bin_bytes(&self, layout: &Layout) -> Vec<u8> {
        layout.files(&self.bin_uri).1
    }

    fn next(&self) -> WatchEvent {
        self.watcher
            .events()
            .recv_timeout(PATIENCE)
            .unwrap_or_else(|e| panic!("no report from the watcher within {PATIENCE:?}: {e}"))
    }

    /// The next episode: a `Started` (its paths) and then its outcome.
    fn episode(&self) -> (Vec<PathBuf>, WatchEvent) {
        let paths = match self.next() {
            WatchEvent::Started { paths, .. } => paths,
            other => panic!("expected Started, got {}", describe(&other)),
        };
        match self.next() {
            e @ (WatchEvent::Loaded { .. } | WatchEvent::Failed { .. }) => (paths, e),
            other => panic!("expected Loaded or Failed, got {}", describe(&other)),
        }
    }

    fn loaded(&self) -> (Vec<PathBuf>, Arc<Scene>) {
        match self.episode() {
            (started, WatchEvent::Loaded { scene, .. }) => (started, scene),
            (_, other) => panic!("expected Loaded, got {}", describe(&other)),
        }
    }

    fn failed(&self) -> (PathBuf, String, FailureKind) {
        match self.episode() {
            (_, WatchEvent::Failed { path, error, kind, .. }) => (path, error, kind),
            (_, other) => panic!("expected Failed, got {}", describe(&other)),
        }
    }

    fn clean_load(&self) -> Scene {
        load_gltf(&self.gltf, &LoadOptions::default()).unwrap()
    }
}

fn describe(e: &WatchEvent) -> String {
    match e {
        WatchEvent::Started { paths, .. } => format!("Started {paths:?}"),
        WatchEvent::Loaded { scene, .. } => format!("Loaded ({} meshes)", scene.meshes.len()),
        WatchEvent::Failed { error, .. } => format!("Failed: {error}"),
    }
}

/// Bit-for-bit equality of what the two scenes hold (compared field by field here, not with
/// the diff under test).
fn assert_same_scene(a: &Scene, b: &Scene) {
    assert_eq!(a.meshes.len(), b.meshes.len(), "mesh counts differ");
    for (x, y) in a.meshes.iter().zip(&b.meshes) {
        assert_eq!(x.name, y.name);
        assert_eq!(x.triangles, y.triangles, "{}", x.name);
        let bits = |v: &[Vec3]| v.iter().flat_map(|p| p.to_array().map(f32::to_bits)).collect::<Vec<_>>();
        assert_eq!(bits(&x.positions), bits(&y.positions), "{} positions", x.name);
        assert_eq!(bits(&x.normals), bits(&y.normals), "{} normals", x.name);
        assert_eq!(x.material, y.material);
    }
    assert_eq!(a.materials.len(), b.materials.len());
    assert_eq!(a.lights.len(), b.lights.len());
}

fn config() -> WatchConfig {
    WatchConfig { settle: Duration::from_secs(3), ..WatchConfig::default() }
}

/// Moves box 1 twice (the second save proves the watch survived the first, which matters for
/// a rename: it replaces the file's inode). Each save is one episode whose scene equals a clean
/// load of the file and whose diff against the previous scene names box 1 only, with the
/// box's old and new bounds.
fn move_one_box(save: fn(&Path, &[u8])) {
    let mut layout = Layout::three_boxes();
    let f = Fixture::new(&layout, "scene.bin", config());
    let mut old = f.clean_load();
    for step in 0..2 {
        let moved = layout.moved(1, [0.0, 0.0, 2.0]);
        save(&f.gltf, &f.gltf_bytes(&moved));
        let (started, scene) = f.loaded();
        assert_eq!(started, vec![f.watcher.scene_path().to_path_buf()], "step {step}");
        assert_same_scene(&scene, &f.clean_load());

        let diff = SceneDiff::between(&old, &scene);
        assert_eq!(diff.unchanged, vec![(0, 0), (2, 2)], "step {step}: {diff:?}");
        assert!(diff.added.is_empty() && diff.removed.is_empty(), "{diff:?}");
        assert!(!diff.lights_changed && !diff.sky_changed && !diff.materials_changed);
        let [c] = diff.changed.as_slice() else { panic!("step {step}: {diff:?}") };
        assert_eq!(scene.meshes[c.new].name, "box1/box/0");
        assert!(c.geometry_changed && !c.material_changed);
        assert_eq!(c.old_bounds, layout.box_bounds(1), "step {step}");
        assert_eq!(c.new_bounds, moved.box_bounds(1), "step {step}");
        layout = moved;
        old = Scene::clone(&scene);
    }
}

#[test]
fn moving_a_box_saved_in_place_reloads_and_the_diff_names_that_box() {
    move_one_box(save_in_place);
}

#[test]
fn moving_a_box_saved_by_temp_file_and_rename_reloads_and_the_diff_names_that_box() {
    move_one_box(save_by_rename);
}

#[test]
fn truncated_json_fails_then_a_good_save_recovers() {
    let layout = Layout::three_boxes();
    let f = Fixture::new(&layout, "scene.bin", config());
    let moved = layout.moved(0, [0.0, 1.0, 0.0]);
    let good = f.gltf_bytes(&moved);
    save_in_place(&f.gltf, &good[..good.len() / 2]);
    let (path, error, kind) = f.failed();
    assert_eq!(kind, FailureKind::Load);
    assert_eq!(path, f.watcher.scene_path());
    assert!(error.contains("malformed glTF JSON"), "{error}");

    save_by_rename(&f.gltf, &good);
    let (_, scene) = f.loaded();
    assert_same_scene(&scene, &f.clean_load());
    assert_eq!(Aabb::of_points(&scene.meshes[0].positions), moved.box_bounds(0));
}

#[test]
fn a_bin_of_the_wrong_length_is_reported_after_the_settle_time_then_a_good_save_recovers() {
    let layout = Layout::three_boxes();
    let f = Fixture::new(&layout, "scene.bin", config());
    let bin = f.bin_bytes(&layout);
    save_in_place(&f.bin, &bin[..bin.len() - 10]);
    let (path, error, kind) = f.failed();
    assert_eq!(kind, FailureKind::Incomplete);
    assert_eq!(path.file_name(), f.bin.file_name());
    assert!(error.contains(&format!("is {} bytes but", bin.len() - 10)), "{error}");

    // Longer than declared: the loader alone would read its first bytes; the watcher waits,
    // then reports.
    let mut longer = bin.clone();
    longer.extend_from_slice(&[0; 8]);
    save_by_rename(&f.bin, &longer);
    let (_, error, kind) = f.failed();
    assert_eq!(kind, FailureKind::Incomplete);
    assert!(error.contains(&format!("is {} bytes but", bin.len() + 8)), "{error}");

    // The .gltf saved as well, the .bin still short: still incomplete, still not loaded.
    save_in_place(&f.bin, &bin[..bin.len() - 10]);
    let moved = layout.moved(2, [1.0, 0.0, 0.0]);
    save_in_place(&f.gltf, &f.gltf_bytes(&moved));
    assert_eq!(f.failed().2, FailureKind::Incomplete);

    f.save(&moved, save_in_place);
    let (_, scene) = f.loaded();
    assert_same_scene(&scene, &f.clean_load());
    assert_eq!(Aabb::of_points(&scene.meshes[2].positions), moved.box_bounds(2));
}

/// Blender's order with a pause between the files, once with a longer `.bin` (a mesh added)
/// and once with one of the same length (the vertices edited): either way the only scene
/// reported is the new pair's, never the old `.gltf` read with the new `.bin`.
#[test]
fn bin_then_gltf_with_a_delay_loads_only_the_matching_pair() {
    let layout = Layout::three_boxes();
    let f = Fixture::new(&layout, "scene.bin", config());
    let longer = Layout { extra: true, ..layout.moved(0, [0.0, 0.0, -1.0]) };
    // New vertices and a new translation: the old .gltf read with this .bin would differ from both saves.
    let same_length = Layout { vertex_scale: 2.0, ..longer.moved(1, [0.0, 2.0, 0.0]) };
    assert_ne!(f.bin_bytes(&longer).len(), f.bin_bytes(&layout).len());
    assert_eq!(f.bin_bytes(&same_length).len(), f.bin_bytes(&longer).len());
    for next in [&longer, &same_length] {
        save_in_place(&f.bin, &f.bin_bytes(next));
        // Longer than the debounce and the quiet time, well inside the settle time.
        std::thread::sleep(Duration::from_millis(600));
        save_in_place(&f.gltf, &f.gltf_bytes(next));
        let (started, scene) = f.loaded();
        assert!(started.iter().any(|p| p.file_name() == f.bin.file_name()), "{started:?}");
        assert_same_scene(&scene, &f.clean_load());
        assert_eq!(scene.meshes.len(), 4);
        assert_eq!(Aabb::of_points(&scene.meshes[1].positions), next.box_bounds(1));
    }
}

/// A buffer in a subdirectory is watched there: editing only it reloads.
#[test]
fn a_buffer_in_a_subdirectory_is_watched() {
    let layout = Layout::three_boxes();
    let config = WatchConfig { settle: Duration::from_millis(500), ..WatchConfig::default() };
    let f = Fixture::new(&layout, "data/scene.bin", config);
    let bigger = Layout { vertex_scale: 1.5, ..layout };
    save_by_rename(&f.bin, &f.bin_bytes(&bigger));
    let (started, scene) = f.loaded();
    assert_eq!(started.len(), 1);
    assert!(started[0].ends_with("data/scene.bin"), "{started:?}");
    assert_same_scene(&scene, &f.clean_load());
    assert_eq!(Aabb::of_points(&scene.meshes[0].positions), bigger.box_bounds(0));
}

/// A save that points the `.gltf` at a new `.bin` makes that file one of the scene's: a later
/// edit of it alone reloads.
#[test]
fn the_set_of_referenced_files_follows_the_document() {
    let layout = Layout::three_boxes();
    let config = WatchConfig { settle: Duration::from_millis(500), ..WatchConfig::default() };
    let f = Fixture::new(&layout, "scene.bin", config);
    let renamed = f.gltf.with_file_name("renamed.bin");
    let (g, b) = layout.files("renamed.bin");
    save_in_place(&renamed, &b);
    save_in_place(&f.gltf, &g);
    f.loaded();

    let bigger = Layout { vertex_scale: 1.25, ..layout };
    save_in_place(&renamed, &bigger.files("renamed.bin").1);
    let (started, scene) = f.loaded();
    assert_eq!(started.len(), 1);
    assert_eq!(started[0].file_name(), renamed.file_name());
    assert_same_scene(&scene, &f.clean_load());
    assert_eq!(Aabb::of_points(&scene.meshes[2].positions), bigger.box_bounds(2));
}

/// A good save of generation `g` moves every box up by `g · 1 cm` (in the `.gltf`) and scales
/// the cube by `1 + g/1000` (in the `.bin`); every third generation adds a mesh (a longer
/// `.bin`). A loaded scene tells which generation each of its files came from, so a `.gltf`
/// loaded with another save's `.bin` cannot pass unseen.
fn generation(g: u32) -> Layout {
    let base = Layout::three_boxes();
    let lift = g as f32 * 0.01;
    Layout {
        at: base.at.iter().map(|&[x, y, z]| [x, y + lift, z]).collect(),
        vertex_scale: 1.0 + g as f32 * 1e-3,
        extra: g % 3 == 0,
    }
}

/// The generations of a loaded scene's `.gltf` (box 0's lift) and `.bin` (its size), and
/// whether it has the extra mesh.
fn generations_of(scene: &Scene) -> (u32, u32, bool) {
    let b = Aabb::of_points(&scene.meshes[0].positions);
    let from_gltf = (b.min.y / 0.01).round() as u32;
    let from_bin = ((b.max.x - b.min.x - 1.0) / 1e-3).round() as u32;
    (from_gltf, from_bin, scene.meshes.len() == 4)
}

fn rss_kib() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// 200 rapid saves of every kind while a reader takes the reports: good pairs in place and by
/// rename, truncated and non-JSON `.gltf`s, short `.bin`s. Every episode is one `Started` and
/// one outcome; every loaded scene is one whole good save (its `.gltf` and `.bin` of the same
/// generation); the last one equals a clean load of the final files.
#[test]
fn soak_of_rapid_saves_never_half_applies_and_ends_on_the_final_file() {
    let f = Fixture::new(&generation(0), "scene.bin", config());
    assert!(f.watcher.events().capacity().is_some(), "the report queue must be bounded");
    let rss_before = rss_kib();
    let reader = {
        let events = f.watcher.events().clone();
        std::thread::spawn(move || {
            let mut log = Vec::new();
            while let Ok(e) = events.recv_timeout(PATIENCE) {
                let done = matches!(&e, WatchEvent::Loaded { scene, .. } if generations_of(scene).0 == FINAL);
                log.push(e);
                if done {
                    break;
                }
            }
            log
        })
    };
    const FINAL: u32 = 200;
    let mut rng = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        rng ^= rng << 13;
        rng ^= rng >> 7;
        rng ^= rng << 17;
        rng
    };
    let (mut good, mut corrupt) = (0, 0);
    for g in 1..=FINAL {
        let layout = generation(g);
        let (gltf, bin) = layout.files(&f.bin_uri);
        let action = if g == FINAL { 0 } else { next() % 5 };
        match action {
            0 => f.save(&layout, save_in_place),
            1 => f.save(&layout, save_by_rename),
            2 => save_in_place(&f.gltf, &gltf[..gltf.len() * 2 / 3]),
            3 => save_by_rename(&f.gltf, b"not json at all"),
            _ => {
                save_in_place(&f.bin, &bin[..bin.len() / 2]);
                save_in_place(&f.gltf, &gltf);
            }
        }
        if action < 2 {
            good += 1
        } else {
            corrupt += 1
        }
        std::thread::sleep(Duration::from_millis(next() % 30));
    }
    let log = reader.join().unwrap();
    eprintln!(
        "{good} good and {corrupt} corrupt saves gave {} reports; RSS before {:?} KiB, after {:?} KiB",
        log.len(),
        rss_before,
        rss_kib()
    );

    let mut open = false;
    let mut last_loaded = None;
    for e in &log {
        match e {
            WatchEvent::Started { .. } => {
                assert!(!open, "Started inside an open episode");
                open = true;
            }
            WatchEvent::Loaded { scene, .. } => {
                assert!(open, "Loaded without Started");
                open = false;
                let (from_gltf, from_bin, extra) = generations_of(scene);
                assert_eq!(from_gltf, from_bin, "a .gltf loaded with another save's .bin");
                assert_eq!(extra, from_gltf % 3 == 0, "generation {from_gltf} with the wrong meshes");
                last_loaded = Some(Arc::clone(scene));
            }
            WatchEvent::Failed { .. } => {
                assert!(open, "Failed without Started");
                open = false;
            }
        }
    }
    let last = last_loaded.expect("the final save was never loaded");
    assert_eq!(generations_of(&last).0, FINAL);
    assert_same_scene(&last, &f.clean_load());
}

/// A reader that stops reading: the worker fills the bounded queue and waits. Stopping the
/// watcher then still returns (its threads join), and before that, reading resumes with every
/// report intact, ending on the last save.
#[test]
fn an_unread_queue_holds_the_worker_back_and_stop_still_joins() {
    let f = Fixture::new(&generation(0), "scene.bin", config());
    let capacity = f.watcher.events().capacity().unwrap();
    let deadline = Instant::now() + PATIENCE;
    let mut g = 0;
    // One episode (two reports) per save, until the queue is full.
    while f.watcher.events().len() < capacity {
        assert!(Instant::now() < deadline, "the queue never filled");
        let queued = f.watcher.events().len();
        g += 1;
        f.save(&generation(g), save_in_place);
        while f.watcher.events().len() < (queued + 2).min(capacity) {
            assert!(Instant::now() < deadline, "no report for save {g}");
            std::thread::sleep(Duration::from_millis(20));
        }
    }
    // Two more saves while the queue is full: the worker cannot report them yet.
    for _ in 0..2 {
        g += 1;
        f.save(&generation(g), save_by_rename);
        std::thread::sleep(Duration::from_millis(400));
    }
    let mut last: Option<Arc<Scene>> = None;
    while last.as_ref().is_none_or(|s| generations_of(s).0 != g) {
        if let WatchEvent::Loaded { scene, .. } = f.next() {
            assert_eq!(generations_of(&scene).0, generations_of(&scene).1);
            last = Some(scene);
        }
    }
    assert_same_scene(last.as_ref().unwrap(), &f.clean_load());

    // Fill the queue again and stop without reading.
    for _ in 0..3 {
        g += 1;
        f.save(&generation(g), save_in_place);
        std::thread::sleep(Duration::from_millis(400));
    }
    let Fixture { watcher, _dir, .. } = f;
    let (done_tx, done_rx) = crossbeam_channel::bounded(1);
    let stopper = std::thread::spawn(move || {
        watcher.stop();
        let _ = done_tx.send(());
    });
    done_rx.recv_timeout(PATIENCE).expect("stop() did not return");
    stopper.join().unwrap();
}

#[test]
fn watching_a_scene_in_a_missing_directory_is_a_clear_error() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no such dir").join("scene.gltf");
    match SceneWatcher::start(&missing, WatchConfig::default()) {
        Err(e @ WatchError::Directory { .. }) => assert!(e.to_string().contains("no such dir"), "{e}"),
        Err(e) => panic!("wrong error: {e}"),
        Ok(_) => panic!("watching a missing directory succeeded"),
    }
}
