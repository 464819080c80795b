//! The viewer in a real window: an X server of its own (Xvfb), the Vulkan adapter the
//! machine has (lavapipe here), never skipped. One test in this binary: winit allows one
//! event loop per process, and `DISPLAY` is set for the whole process.

mod viewer_support;

use std::collections::HashSet;
use std::sync::{Arc, Mutex};

use glam::Vec3;
use livebake::atlas::texels::NO_TEXEL;
use livebake::bake::BakeOutput;
use livebake::gpu::lightmap::SyncReport;
use livebake::runtime::shown::{Layer, PAGE_SIDE, Page, PageWriter, ShownLightmap};
use livebake::scene::Scene;
use livebake::viewer::camera::Camera;
use livebake::viewer::{FrameContext, LightSource, SceneState, SourceStatus, ViewerError, ViewerOptions};
use viewer_support::*;

/// A source whose snapshot the test replaces (a publish), or that fails.
struct TestSource {
    state: SceneState,
    shown: Arc<Mutex<Option<Arc<ShownLightmap>>>>,
    error: Arc<Mutex<Option<String>>>,
}

impl LightSource for TestSource {
    fn scene(&self) -> SceneState {
        self.state.clone()
    }
    fn shown(&self) -> Option<Arc<ShownLightmap>> {
        self.shown.lock().unwrap().clone()
    }
    fn set_camera(&mut self, _camera: &Camera, _aspect: f32, _height_px: u32) {}
    fn status(&self) -> SourceStatus {
        SourceStatus { state: "test".into(), last_error: self.error.lock().unwrap().clone(), ..SourceStatus::default() }
    }
    fn shutdown(&mut self) -> Result<(), String> {
        Ok(())
    }
}

/// Publishes new values for every LOD-0 texel (and its gutter copies) whose surface point
/// lies in `cell`; returns the new snapshot and the LOD-0 pixels written.
fn publish_cell(old: &ShownLightmap, baked: &BakeOutput, cell: u32) -> (ShownLightmap, HashSet<(u32, u32)>) {
    let t = &baked.lods[0].texels;
    let mut next = old.clone();
    let mut written = HashSet::new();
    let mut w = PageWriter::new(&mut next);
    let in_cell: Vec<bool> = t.position.iter().map(|p| old.grid.cell_of(*p) == cell).collect();
    let mut put = |p: u32, i: usize| {
        let (x, y) = (p % t.width, p / t.width);
        w.write(Layer::Bundles, 0, x, y, baked.lods[0].irradiance[i] * 2.0 + Vec3::new(3.0, 0.0, 1.0));
        written.insert((x, y));
    };
    for (i, &p) in t.pixel.iter().enumerate() {
        if in_cell[i] {
            put(p, i);
        }
    }
    for &(p, i) in &t.gutter {
        if i != NO_TEXEL && in_cell[i as usize] {
            put(p, i as usize);
        }
    }
    w.finish();
    (next, written)
}

/// All of LOD 0's pages as the GPU holds them, by page position.
fn gpu_pages(ctx: &FrameContext, shown: &ShownLightmap) -> Vec<Option<Vec<[f32; 4]>>> {
    let level = &shown.layer(Layer::Bundles).levels[0];
    (0..level.pages_x * level.pages_y)
        .map(|i| ctx.renderer.lightmap.read_page(&ctx.renderer.gpu, Layer::Bundles, 0, i as usize).unwrap())
        .collect()
}

/// Under Xvfb: (1) the window's presented frame of the lit Cornell room, seen from its open
/// side, is not black, its red-wall half is redder and its green-wall half greener, and it
/// equals an offscreen render of the same camera: the same pipeline draws both, so they may
/// differ only by the surface format's rounding (at most 1 of 255 per channel, in under 1%
/// of pixels). (2) A cell published while the window is open changes exactly that cell's
/// texels on the GPU (every page read back and compared), and the upload is exactly the
/// changed pages (a page each), nothing else. (3) A capture run whose source fails ends with
/// the source's error instead of waiting for light forever.
#[test]
fn window_shows_the_room_and_a_publish_uploads_only_its_cell() {
    let xvfb = xvfb();
    // SAFETY: the only test of this binary; nothing else reads the environment meanwhile.
    unsafe { std::env::set_var("DISPLAY", &xvfb.display) };
    let (scene, baked, shown): (Arc<Scene>, BakeOutput, Arc<ShownLightmap>) = cornell_lit();
    let snapshot = Arc::new(Mutex::new(Some(shown.clone())));
    let error = Arc::new(Mutex::new(None));
    let mut source = TestSource {
        state: SceneState { generation: 0, scene, atlas: Arc::new(baked.atlas.clone()) },
        shown: snapshot.clone(),
        error: error.clone(),
    };
    // The cell holding the back wall's middle (z = 0, x, y = 1 m).
    let cell = shown.grid.cell_of(Vec3::new(1.1, 1.1, 0.1));
    let (published, written) = publish_cell(&shown, &baked, cell);
    let published = Arc::new(published);
    let changed_pages: HashSet<(u32, u32)> = written.iter().map(|&(x, y)| (x / PAGE_SIDE, y / PAGE_SIDE)).collect();
    let level0 = &shown.layer(Layer::Bundles).levels[0];
    assert!(!written.is_empty() && changed_pages.len() < (level0.pages_x * level0.pages_y) as usize);

    let mut before: Vec<Option<Vec<[f32; 4]>>> = Vec::new();
    let mut checked = (false, false);
    let mut hook = |ctx: &mut FrameContext| -> Result<bool, livebake::gpu::GpuError> {
        match ctx.frame {
            1 => ctx.capture_next = true,
            2 => {
                let window = ctx.window_image.take().expect("frame 2 was captured");
                assert_cornell_colours(&window);
                let (w, h) = ctx.size;
                let offscreen = ctx.renderer.render_offscreen(ctx.camera, w, h, ctx.settings)?;
                let (max, share) = image_difference(&window, &offscreen);
                eprintln!("window vs offscreen: max difference {max}/255 in {:.3}% of pixels", 100.0 * share);
                assert!(max <= 1 && share < 0.01, "window and offscreen differ: max {max}, {share} of pixels");
                before = gpu_pages(ctx, &shown);
                *snapshot.lock().unwrap() = Some(published.clone());
                checked.0 = true;
            }
            3 => {
                // The frame just drawn took the published snapshot.
                let sync: SyncReport = ctx.renderer.last_sync;
                eprintln!("publish of cell {cell}: {sync:?}, {} pixels written", written.len());
                assert_eq!(sync.pages_uploaded, changed_pages.len() as u64);
                assert_eq!(sync.table_entries_uploaded, 0, "pages replaced in place");
                assert_eq!(sync.cells_uploaded, 0);
                assert_eq!(sync.bytes_uploaded, changed_pages.len() as u64 * Page::BYTES as u64);
                let after = gpu_pages(ctx, &published);
                let level = &published.layer(Layer::Bundles).levels[0];
                let mut differing = HashSet::new();
                for (i, (a, b)) in before.iter().zip(&after).enumerate() {
                    let (px, py) = (i as u32 % level.pages_x, i as u32 / level.pages_x);
                    // The GPU holds exactly the published snapshot's pixels.
                    let want = level.page(px, py).map(|p| p.texels.to_vec());
                    assert_eq!(b.as_ref(), want.as_ref(), "page ({px}, {py})");
                    if let (Some(a), Some(b)) = (a, b) {
                        for (j, (ta, tb)) in a.iter().zip(b).enumerate() {
                            if ta != tb {
                                let (x, y) =
                                    (px * PAGE_SIDE + j as u32 % PAGE_SIDE, py * PAGE_SIDE + j as u32 / PAGE_SIDE);
                                differing.insert((x, y));
                            }
                        }
                    } else {
                        assert_eq!(a.is_some(), b.is_some(), "page ({px}, {py}) appeared or vanished");
                    }
                }
                assert_eq!(differing, written, "the texels that changed on the GPU are the cell's");
                checked.1 = true;
            }
            4 => {
                // (3) The source fails (as a runtime whose bake broke): a capture run, which
                // waits for light, ends with the source's error.
                *error.lock().unwrap() = Some("the bake broke".into());
                *snapshot.lock().unwrap() = None;
                ctx.renderer.shown = None;
            }
            5.. => panic!("the viewer went on after its source failed"),
            _ => {}
        }
        Ok(true)
    };
    let options = ViewerOptions {
        pose: Some((Vec3::from(CORNELL_EYE), Vec3::from(CORNELL_TARGET))),
        size: (320, 240),
        frames: Some(1000),
        ..ViewerOptions::default()
    };
    let result = livebake::viewer::run(&mut source, options, Some(&mut hook));
    assert!(checked.0 && checked.1, "the viewer closed before the checks ran: {:?}", result.map(|r| r.frames));
    match result {
        Err(ViewerError::Source(e)) => assert_eq!(e, "the bake broke"),
        other => panic!("expected the source's error, got {:?}", other.map(|r| r.frames)),
    }
}
