//! Shared by the viewer tests: a private X server (Xvfb) and the Cornell room lit by a bake.

#![allow(dead_code)]

use std::path::PathBuf;
use std::sync::Arc;

use image::RgbaImage;
use livebake::bake::{BakeConfig, BakeOutput, bake};
use livebake::progress::NoProgress;
use livebake::runtime::shown::ShownLightmap;
use livebake::scene::{LoadOptions, Scene, load_gltf};
use livebake::viewer::source::{grid_over, shown_from_bake};
pub use livebake::viewer::xvfb::Xvfb;

/// A private X server for the test (killed when dropped).
pub fn xvfb() -> Xvfb {
    Xvfb::start().unwrap()
}

pub fn cornell_path() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/assets/cornell_2m/cornell_2m.gltf"))
}

/// The camera of the Cornell tests: outside the open (front, z = 2) side, looking in. The
/// red wall (x = 0) fills the left of the picture, the green one (x = 2) the right.
pub const CORNELL_EYE: [f32; 3] = [1.0, 1.0, 4.5];
pub const CORNELL_TARGET: [f32; 3] = [1.0, 1.0, 0.0];

/// The Cornell room baked at LOD 0 (4 cm texels, 64 directions: a quick bake), shown with
/// 0.5 m cells.
pub fn cornell_lit() -> (Arc<Scene>, BakeOutput, Arc<ShownLightmap>) {
    let scene = Arc::new(load_gltf(&cornell_path(), &LoadOptions::default()).unwrap());
    let mut config = BakeConfig { samples: 64, ..BakeConfig::default() };
    config.atlas.texel_size = Some(0.04);
    let baked = bake(&scene, &config, &NoProgress).unwrap();
    let shown = Arc::new(shown_from_bake(&baked, grid_over(&scene, 0.5).unwrap(), 0.0));
    (scene, baked, shown)
}

/// Mean linear-ish colour (sRGB bytes / 255) of the columns `x0..x1` of `img`.
pub fn mean_rgb(img: &RgbaImage, x0: u32, x1: u32) -> [f64; 3] {
    let mut sum = [0.0f64; 3];
    let mut n = 0.0;
    for y in 0..img.height() {
        for x in x0..x1 {
            let p = img.get_pixel(x, y).0;
            for c in 0..3 {
                sum[c] += p[c] as f64 / 255.0;
            }
            n += 1.0;
        }
    }
    sum.map(|s| s / n)
}

/// Checks a Cornell view: not black, the left (red wall) half redder than the right
/// (green wall) half and the right half greener than the left.
pub fn assert_cornell_colours(img: &RgbaImage) {
    let w = img.width();
    let (left, right) = (mean_rgb(img, 0, w / 2), mean_rgb(img, w / 2, w));
    let all = mean_rgb(img, 0, w);
    assert!(all.iter().sum::<f64>() > 0.15, "the picture is (nearly) black: mean {all:?}");
    let redness = |c: [f64; 3]| c[0] - c[1];
    assert!(redness(left) > redness(right) + 0.05, "left {left:?} not redder than right {right:?}");
    assert!(-redness(right) > -redness(left) + 0.05, "right {right:?} not greener than left {left:?}");
}

/// Largest per-channel difference between two images and the share of pixels that differ.
pub fn image_difference(a: &RgbaImage, b: &RgbaImage) -> (u8, f64) {
    assert_eq!(a.dimensions(), b.dimensions());
    let mut max = 0u8;
    let mut differing = 0usize;
    for (p, q) in a.pixels().zip(b.pixels()) {
        let d = (0..3).map(|c| p.0[c].abs_diff(q.0[c])).max().unwrap_or(0);
        max = max.max(d);
        differing += (d > 0) as usize;
    }
    (max, differing as f64 / (a.width() * a.height()) as f64)
}

/// Runs `cmd` with its output in files and kills it after `seconds` (a hung window must fail
/// the test, not stall the suite); returns the exit code (`None`: killed) and stderr.
pub fn run_bounded(cmd: &mut std::process::Command, seconds: u64) -> (Option<i32>, String) {
    let dir = tempfile::tempdir().unwrap();
    let (out, err) = (dir.path().join("stdout"), dir.path().join("stderr"));
    let mut child =
        cmd.stdout(std::fs::File::create(&out).unwrap()).stderr(std::fs::File::create(&err).unwrap()).spawn().unwrap();
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(seconds);
    let status = loop {
        if let Some(status) = child.try_wait().unwrap() {
            break Some(status);
        }
        if std::time::Instant::now() > deadline {
            let _ = child.kill();
            let _ = child.wait();
            break None;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    };
    let stderr = std::fs::read_to_string(&err).unwrap_or_default();
    assert!(status.is_some(), "killed after {seconds} s; stderr: {stderr}");
    (status.and_then(|s| s.code()), stderr)
}
