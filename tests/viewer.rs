//! Viewer tests that need no window: the GPU twin of the shown light map's sampling
//! function, and offscreen renders of the Cornell room. They run on whatever Vulkan adapter
//! the machine has (Mesa's lavapipe here); nothing is skipped for want of a GPU.

mod viewer_support;

use std::sync::Arc;

use glam::{Vec2, Vec3};
use livebake::gpu::GpuContext;
use livebake::gpu::lightmap::{self, LightmapGpu};
use livebake::gpu::probe::IrradianceProbe;
use livebake::grid::Grid;
use livebake::runtime::shown::{LodPages, PAGE_SIDE, Page, ShownLightmap};
use livebake::viewer::render::DrawSettings;
use livebake::viewer::source::next_page_id;
use livebake::viewer::{Camera, Renderer, SceneState};
use viewer_support::*;

/// xorshift64*: deterministic test data.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f32 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        ((self.0.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 40) as f32) / (1u64 << 24) as f32
    }
}

/// A 4×3×2-cell map with three LODs, cells at mixed LODs, pages missing at random and
/// invalid pixels inside pages: every branch of the sampling rule (missing page, invalid
/// tap, fallback to a coarser LOD, border blending, UVs outside the atlas) is exercised.
fn synthetic_map(rng: &mut Rng) -> ShownLightmap {
    let (atlas_width, atlas_height) = (100u32, 70u32);
    let levels = (0..3)
        .map(|k| {
            let (w, h) = (atlas_width << k, atlas_height << k);
            let (pages_x, pages_y) = (w.div_ceil(PAGE_SIDE), h.div_ceil(PAGE_SIDE));
            let pages = (0..pages_x * pages_y)
                .map(|_| {
                    (rng.next() < 0.8).then(|| {
                        let texels = (0..PAGE_SIDE * PAGE_SIDE)
                            .map(|_| {
                                let valid = rng.next() < 0.85;
                                [10.0 * rng.next(), 10.0 * rng.next(), 10.0 * rng.next(), valid as u32 as f32]
                            })
                            .collect();
                        Arc::new(Page { id: next_page_id(), texels })
                    })
                })
                .collect();
            LodPages { pages_x, pages_y, pages }
        })
        .collect();
    let grid = Grid { origin: Vec3::new(-1.0, 0.5, 2.0), cell_size: 1.0, dims: [4, 3, 2] };
    let cell_lod = (0..grid.cell_count()).map(|_| (rng.next() * 3.0) as u8).collect();
    ShownLightmap { grid, cell_lod, atlas_width, atlas_height, blend_band: 0.3, levels }
}

/// The WGSL `shown_irradiance` equals the CPU's `ShownLightmap::irradiance` at 20 000 random
/// points. Points within 1e-3 m of a cell face are left out: there the cell index is a
/// discontinuous function of a rounded division and CPU and GPU may round to different cells
/// (both right). Tolerance: each result is a handful of f32 products and sums plus one
/// division (WGSL allows 2.5 ulp); 2e-5 relative to (1 + |E|) is ~100 ulp of E ≤ 10 W/m²,
/// while a wrong tap, LOD or blend weight moves the result by O(1).
#[test]
fn gpu_sampling_twins_the_cpu_function() {
    let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
    let shown = synthetic_map(&mut rng);
    let gpu = GpuContext::headless().unwrap();
    let layout = lightmap::bind_group_layout(&gpu.device);
    let mirror = LightmapGpu::new(&gpu, &layout, &shown).unwrap();
    let probe = IrradianceProbe::new(&gpu, &layout).unwrap();
    let g = &shown.grid;
    let mut points = Vec::new();
    while points.len() < 20_000 {
        let q = Vec3::new(rng.next() * 4.0, rng.next() * 3.0, rng.next() * 2.0);
        if (q - q.round()).abs().min_element() < 1e-3 {
            continue;
        }
        let p = g.origin + q * g.cell_size;
        let uv = Vec2::new(rng.next() * 104.0 - 2.0, rng.next() * 74.0 - 2.0);
        points.push((p, uv));
    }
    let on_gpu = probe.run(&gpu, &mirror, &points).unwrap();
    let mut blended = 0;
    let mut worst = 0.0f32;
    for (&(p, uv), got) in points.iter().zip(&on_gpu) {
        let want = shown.irradiance(p, uv);
        let err = (*got - want).abs().max_element() / (1.0 + want.abs().max_element());
        worst = worst.max(err);
        assert!(err < 2e-5, "at p {p} uv {uv}: GPU {got} CPU {want}");
        let c = g.cell_coords(p);
        let lo = g.origin + Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32);
        blended += ((p - lo).min_element() < shown.blend_band || (lo + 1.0 - p).min_element() < shown.blend_band) as usize;
    }
    // The sample covers the blend bands and the fallback, not only the easy interior.
    assert!(blended > 2_000, "{blended} points near cell faces");
    assert!(on_gpu.iter().any(|e| *e == Vec3::ZERO) && on_gpu.iter().filter(|e| **e != Vec3::ZERO).count() > 15_000);
    eprintln!("worst relative difference {worst:e}");
}

fn cornell_camera() -> Camera {
    Camera::look_at(Vec3::from(CORNELL_EYE), Vec3::from(CORNELL_TARGET), 50f32.to_radians(), 3.5)
}

/// The lit Cornell room rendered offscreen from its open side: red wall left, green right.
#[test]
fn offscreen_cornell_room_shows_its_coloured_walls() {
    let (scene, baked, shown) = cornell_lit();
    let gpu = GpuContext::headless().unwrap();
    let state = SceneState { generation: 0, scene, atlas: Arc::new(baked.atlas.clone()) };
    let mut renderer = Renderer::new(gpu, &state).unwrap();
    let unlit = renderer.render_offscreen(&cornell_camera(), 160, 120, &DrawSettings::default()).unwrap();
    renderer.show(shown).unwrap();
    let lit = renderer.render_offscreen(&cornell_camera(), 160, 120, &DrawSettings::default()).unwrap();
    assert_cornell_colours(&lit);
    // Before the light map arrives only the lamp shows: the walls' light is the map's.
    let (l, u) = (mean_rgb(&lit, 0, 160), mean_rgb(&unlit, 0, 160));
    assert!(l.iter().sum::<f64>() > 2.0 * u.iter().sum::<f64>(), "lit {l:?} vs unlit {u:?}");
}
