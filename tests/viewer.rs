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
use livebake::runtime::shown::{Layer, PAGE_SIDE, PageWriter, ShownLightmap};
use livebake::viewer::render::DrawSettings;
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

/// A 4×3×2-cell map with three LODs in both layers, cells at mixed LODs (each layer its
/// own), pages missing at random and unpublished pixels inside pages: every branch of the
/// sampling rule (missing page, unpublished tap, fallback to a coarser LOD, border blending
/// in each layer, UVs outside the atlas, the layers' sum) is exercised.
fn synthetic_map(rng: &mut Rng) -> ShownLightmap {
    let (atlas_width, atlas_height) = (100u32, 70u32);
    let grid = Grid { origin: Vec3::new(-1.0, 0.5, 2.0), cell_size: 1.0, dims: [4, 3, 2] };
    let mut map = ShownLightmap::new(grid, atlas_width, atlas_height, 3, 0.3);
    let mut w = PageWriter::new(&mut map);
    for layer in Layer::ALL {
        for k in 0..3u32 {
            let (width, height) = (atlas_width << k, atlas_height << k);
            for py in 0..height.div_ceil(PAGE_SIDE) {
                for px in 0..width.div_ceil(PAGE_SIDE) {
                    if rng.next() < 0.2 {
                        continue;
                    }
                    for y in py * PAGE_SIDE..((py + 1) * PAGE_SIDE).min(height) {
                        for x in px * PAGE_SIDE..((px + 1) * PAGE_SIDE).min(width) {
                            if rng.next() < 0.85 {
                                let e = Vec3::new(rng.next(), rng.next(), rng.next()) * 10.0;
                                w.write(layer, k, x, y, e);
                            }
                        }
                    }
                }
            }
        }
        for cell in 0..grid.len() as u32 {
            w.set_cell_lod(layer, cell, (rng.next() * 3.0) as u32);
        }
    }
    w.finish();
    map
}

/// The WGSL `shown_irradiance` equals the CPU's `ShownLightmap::irradiance` (both layers)
/// at 20 000 random points. Points within 1e-3 m of a cell face are left out: there the cell index is a
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
        // A blend happens where a face shared with a coarser neighbour (in a layer) is
        // within the band.
        let cell = g.cell_of(p);
        let (lo, hi) = g.bounds(cell);
        let near_coarser = Layer::ALL.iter().any(|&layer| {
            let k = shown.cell_lod(layer, cell);
            (0..3).any(|axis| {
                [(-1, p[axis] - lo[axis]), (1, hi[axis] - p[axis])].iter().any(|&(step, d)| {
                    d < shown.blend_band && g.neighbour(cell, axis, step).is_some_and(|n| shown.cell_lod(layer, n) < k)
                })
            })
        });
        blended += near_coarser as usize;
    }
    let zeros = on_gpu.iter().filter(|e| **e == Vec3::ZERO).count();
    eprintln!("worst relative difference {worst:e}; {blended} points in blend bands, {zeros} with nothing published");
    // The sample covers blends, points with nothing published and plenty with light.
    assert!(blended > 1_000, "{blended} points blend");
    assert!(zeros > 0 && zeros < 10_000, "{zeros} points with nothing published");
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

/// A `MASK` surface is cut out where its alpha (factor × texture) is below the cutoff: a
/// screen whose texture's alpha is 0 on its left half and 1 on its right, in front of a
/// glowing wall, shows the wall on the left and hides it on the right (the screen itself is
/// black: no light map is shown). The same screen `OPAQUE` hides the wall on both halves.
#[test]
fn cut_out_fragments_are_discarded_and_show_what_is_behind() {
    use livebake::scene::builder::diffuse;
    use livebake::scene::{AlphaMode, Rgb, SceneBuilder, Texture, TextureRef, UvTransform, WrapMode};
    let render = |alpha_mode: AlphaMode, transform: UvTransform| {
        let mut b = SceneBuilder::new();
        let glow = b.material(diffuse(Rgb::splat(0.5), Rgb::splat(5.0), false));
        let screen = b.material(livebake::scene::Material { alpha_mode, ..diffuse(Rgb::ONE, Rgb::ZERO, true) });
        let wall = [
            Vec3::new(-3.0, -3.0, -1.0),
            Vec3::new(3.0, -3.0, -1.0),
            Vec3::new(3.0, 3.0, -1.0),
            Vec3::new(-3.0, 3.0, -1.0),
        ];
        b.quad("wall", wall, glow);
        let quad = [
            Vec3::new(-1.0, -1.0, 0.0),
            Vec3::new(1.0, -1.0, 0.0),
            Vec3::new(1.0, 1.0, 0.0),
            Vec3::new(-1.0, 1.0, 0.0),
        ];
        b.quad("screen", quad, screen);
        let mut scene = b.build();
        // u runs left to right over the screen: texel 0 (alpha 0) left, texel 1 (alpha 1) right.
        scene.meshes[1].uv0 =
            Some(vec![Vec2::new(0.0, 1.0), Vec2::new(1.0, 1.0), Vec2::new(1.0, 0.0), Vec2::new(0.0, 0.0)]);
        scene.textures.push(Texture {
            name: "half".into(),
            width: 2,
            height: 1,
            rgba8: vec![[255, 255, 255, 0], [255, 255, 255, 255]].into(),
            srgb: true,
            wrap_s: WrapMode::ClampToEdge,
            wrap_t: WrapMode::ClampToEdge,
        });
        scene.materials[screen as usize].base_color_texture = Some(TextureRef { texture: 0, tex_coord: 0, transform });
        let mut renderer = unlit_renderer(scene);
        let camera = Camera::look_at(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 50f32.to_radians(), 6.0);
        renderer.render_offscreen(&camera, 160, 120, &DrawSettings::default()).unwrap()
    };
    // At 2 m with a 50° field, 160 × 120: the screen's x = ∓0.6 falls on columns ~41 and ~119.
    let brightness = |img: &image::RgbaImage, x0: u32| mean_rgb(img, x0, x0 + 20).iter().sum::<f64>() / 3.0;
    let mask = AlphaMode::Mask { cutoff: 0.5 };
    let masked = render(mask, UvTransform::IDENTITY);
    let (left, right) = (brightness(&masked, 31), brightness(&masked, 109));
    assert!(left > 0.5, "the wall behind the cut-out half is not seen: {left}");
    assert!(right < 0.05, "the kept half lets the wall through: {right}");
    // KHR_texture_transform mirroring u (scale (−1, 1), offset (1, 0): u' = 1 − u) swaps
    // the halves.
    let mirrored = render(mask, UvTransform::new(Vec2::new(1.0, 0.0), 0.0, Vec2::new(-1.0, 1.0)));
    let (left, right) = (brightness(&mirrored, 31), brightness(&mirrored, 109));
    assert!(left < 0.05 && right > 0.5, "the mirrored texture is not read mirrored: {left}, {right}");
    let opaque = render(AlphaMode::Opaque, UvTransform::IDENTITY);
    let (left, right) = (brightness(&opaque, 31), brightness(&opaque, 109));
    assert!(left < 0.05 && right < 0.05, "an opaque screen lets the wall through: {left}, {right}");
}

/// See-through sheets show what lies behind them through their `pass` and add their own
/// light (`Material::sheet`), composited in linear radiance before the tone curve. In front
/// of a wall glowing with radiance 5 (no light map is shown, so a sheet's own light is its
/// emission alone), the centre pixel must show the tone-mapped radiance the sheet model gives:
/// - green glass (transmission 1, albedo (0.2, 1, 0.2)): 5·(0.2, 1, 0.2);
/// - a `BLEND` sheet of alpha 0.5: 5·0.5;
/// - two `BLEND` sheets of alpha 0.5, the far one also emitting 1, listed near one first:
///   (5·0.5 + 1)·0.5 = 1.75 (drawn in the wrong order it would be 5·0.25 + 1 = 2.25);
/// - an opaque screen: 0;
/// - the green glass and the half-covering sheet again, their colour and alpha from their
///   vertices (glTF COLOR_0) instead of their material factors.
///
/// Tolerance: 1.5 of 255 levels: the 8-bit target's rounding (half a level) plus the
/// half-float radiance target's (2⁻¹¹ relative, under a tenth of a level here); the
/// materials are flat factors, so no texture filtering enters.
#[test]
fn see_through_sheets_show_what_is_behind_them_through_their_pass() {
    use livebake::scene::builder::diffuse;
    use livebake::scene::{AlphaMode, Material, Rgb, SceneBuilder};
    let half = |emission: f32| Material {
        alpha_mode: AlphaMode::Blend,
        base_color: glam::Vec4::new(1.0, 1.0, 1.0, 0.5),
        ..diffuse(Rgb::ONE, Rgb::splat(emission), true)
    };
    let glass = Material { transmission: 1.0, ..diffuse(Rgb::new(0.2, 1.0, 0.2), Rgb::ZERO, true) };
    let square = |z: f32, r: f32| [Vec3::new(-r, -r, z), Vec3::new(r, -r, z), Vec3::new(r, r, z), Vec3::new(-r, r, z)];
    // The centre pixel's colour with `sheets` (material, depth) in front of the wall, each
    // with vertex colour `color` at every corner when given.
    let centre_colored = |sheets: Vec<(Material, f32)>, color: Option<glam::Vec4>| {
        let mut b = SceneBuilder::new();
        let glow = b.material(diffuse(Rgb::splat(0.5), Rgb::splat(5.0), false));
        b.quad("wall", square(-1.0, 3.0), glow);
        for (i, (m, z)) in sheets.into_iter().enumerate() {
            let id = b.material(m);
            b.quad(&format!("sheet {i}"), square(z, 1.0), id);
        }
        let mut scene = b.build();
        for mesh in &mut scene.meshes[1..] {
            mesh.colors = color.map(|c| vec![c; mesh.positions.len()]);
        }
        let mut renderer = unlit_renderer(scene);
        let camera = Camera::look_at(Vec3::new(0.0, 0.0, 2.0), Vec3::ZERO, 50f32.to_radians(), 6.0);
        let img = renderer.render_offscreen(&camera, 160, 120, &DrawSettings::default()).unwrap();
        img.get_pixel(80, 60).0
    };
    let centre = |sheets: Vec<(Material, f32)>| centre_colored(sheets, None);
    // The tone curve (1 − e^(−L) at exposure 1) and sRGB encoding, in 255 levels.
    let shown = |radiance: [f32; 3]| {
        radiance.map(|l| {
            let c = 1.0 - (-l).exp();
            let e = if c <= 0.003_130_8 { 12.92 * c } else { 1.055 * c.powf(1.0 / 2.4) - 0.055 };
            e * 255.0
        })
    };
    let check = |what: &str, got: [u8; 4], radiance: [f32; 3]| {
        let want = shown(radiance);
        for c in 0..3 {
            assert!(
                (got[c] as f32 - want[c]).abs() <= 1.5,
                "{what}: pixel {got:?}, expected {want:?} (radiance {radiance:?})"
            );
        }
    };
    check("nothing in front", centre(vec![]), [5.0; 3]);
    check("green glass", centre(vec![(glass, 0.0)]), [1.0, 5.0, 1.0]);
    check("a half-covering sheet", centre(vec![(half(0.0), 0.0)]), [2.5; 3]);
    check("two sheets, the far one glowing", centre(vec![(half(0.0), 0.5), (half(1.0), 0.0)]), [1.75; 3]);
    check("an opaque screen", centre(vec![(diffuse(Rgb::ONE, Rgb::ZERO, true), 0.0)]), [0.0; 3]);
    // Vertex colours (COLOR_0) multiply the base colour and alpha: white glass coloured green
    // at its vertices is the green glass; a sheet of alpha 1 with vertex alpha 0.5, the
    // half-covering one.
    let white_glass = Material { transmission: 1.0, ..diffuse(Rgb::ONE, Rgb::ZERO, true) };
    let green = glam::Vec4::new(0.2, 1.0, 0.2, 1.0);
    check("glass green by its vertices", centre_colored(vec![(white_glass, 0.0)], Some(green)), [1.0, 5.0, 1.0]);
    let whole = Material { base_color: glam::Vec4::ONE, ..half(0.0) };
    let halved = Some(glam::Vec4::new(1.0, 1.0, 1.0, 0.5));
    check("a sheet half-covering by its vertices", centre_colored(vec![(whole, 0.0)], halved), [2.5; 3]);
}

/// Where no surface is, the viewer shows the sky the scene's rays see, the right way round:
/// under an environment bright (radiance 4) only above the horizon toward +X, the centre
/// pixel looking up toward +X shows 4 tone-mapped (exposure 1: 1 − e⁻⁴, sRGB 253 of 255),
/// looking up toward −X or down toward +X shows black. Under a uniform sky of radiance
/// (0.5, 1, 2) (drawn by clearing to it) every direction shows that. Tolerance: the centre
/// pixel's ray is at least 20° from the bright quarter's edges, where the picture's bilinear
/// blend is exact; 1.5 levels cover 8-bit rounding.
#[test]
fn the_sky_shows_where_no_surface_is_the_right_way_round() {
    use livebake::scene::builder::diffuse;
    use livebake::scene::environment::Environment;
    use livebake::scene::{Rgb, SceneBuilder, Surroundings};
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Rgb::splat(0.5), Rgb::ZERO, false));
    // A tile far below, out of every view: the atlas wants a surface.
    b.floor("tile", Vec3::new(0.0, -50.0, 0.0), 1.0, m);
    let mut scene = b.build();
    // 64 × 32 pixels: rows 0–15 above the horizon, columns 32–63 toward +X (u ≥ ½).
    let texels =
        (0..32).flat_map(|y| (0..64).map(move |x| Rgb::splat(if y < 16 && x >= 32 { 4.0 } else { 0.0 }))).collect();
    let map = Environment::new("upper east", 64, 32, texels, 0.0).unwrap();
    let mut uniform = scene.clone();
    scene.set_surroundings(&Surroundings { environment: Some(Arc::new(map)), ..Surroundings::default() }).unwrap();
    uniform.set_surroundings(&Surroundings { sky: Rgb::new(0.5, 1.0, 2.0), ..Surroundings::default() }).unwrap();
    let shown = |l: f32| 255.0 * (1.055 * (1.0 - (-l).exp()).powf(1.0 / 2.4) - 0.055);
    let (up_east, up_west, down_east) =
        (Vec3::new(1.0, 0.6, 0.0), Vec3::new(-1.0, 0.6, 0.0), Vec3::new(1.0, -0.6, 0.0));
    let sky = [0.5, 1.0, 2.0].map(shown);
    for (scene, views) in [
        (scene, [(up_east, [shown(4.0); 3]), (up_west, [0.0; 3]), (down_east, [0.0; 3])]),
        (uniform, [(up_east, sky), (up_west, sky), (down_east, sky)]),
    ] {
        let mut renderer = unlit_renderer(scene);
        for (toward, want) in views {
            let camera = Camera::look_at(Vec3::ZERO, toward, 30f32.to_radians(), 6.0);
            let got = renderer.render_offscreen(&camera, 64, 48, &DrawSettings::default()).unwrap().get_pixel(32, 24).0;
            for c in 0..3 {
                assert!(
                    (got[c] as f32 - want[c]).abs() <= 1.5,
                    "looking toward {toward}: pixel {got:?}, expected {want:?}"
                );
            }
        }
    }
}

/// A renderer of `scene` (10 cm texels) showing no light map yet: E = 0 everywhere, so what
/// a test sees is emission, sky and compositing alone.
fn unlit_renderer(scene: livebake::scene::Scene) -> Renderer {
    use livebake::atlas::{Atlas, AtlasConfig};
    let geom = livebake::scene::SceneGeometry::new(&scene);
    let atlas = Atlas::build(&scene, &geom, &AtlasConfig { texel_size: Some(0.1), ..AtlasConfig::default() }).unwrap();
    let state = SceneState { generation: 0, scene: Arc::new(scene), atlas: Arc::new(atlas) };
    Renderer::new(GpuContext::headless().unwrap(), &state).unwrap()
}

fn livebake() -> std::process::Command {
    std::process::Command::new(env!("CARGO_BIN_EXE_livebake"))
}

/// `livebake view --screenshot --frames` in a real window under Xvfb: exits 0, writes the
/// picture of the lit room (red left, green right) and the run's figures.
#[test]
fn view_command_writes_a_screenshot_under_xvfb() {
    let xvfb = xvfb();
    let dir = tempfile::tempdir().unwrap();
    let (shot, stats) = (dir.path().join("shot.png"), dir.path().join("stats.json"));
    let mut cmd = livebake();
    cmd.env("DISPLAY", &xvfb.display)
        .arg("-q")
        .arg("view")
        .arg(cornell_path())
        .args(["--frames", "2", "--size", "320x240", "--camera", "1,1,4.5,1,1,0"])
        .args(["--texel-size", "0.05", "--samples", "32"])
        .arg("--screenshot")
        .arg(&shot)
        .arg("--stats")
        .arg(&stats);
    let (code, stderr) = run_bounded(&mut cmd, 300);
    assert_eq!(code, Some(0), "{stderr}");
    let img = image::open(&shot).unwrap().to_rgba8();
    assert_eq!(img.dimensions(), (320, 240));
    assert_cornell_colours(&img);
    let stats: serde_json::Value = serde_json::from_slice(&std::fs::read(&stats).unwrap()).unwrap();
    assert_eq!(stats["lit_frames"], 2);
    assert!(stats["first_lit_frame_seconds"].as_f64().is_some_and(|s| s > 0.0), "{stats}");
    assert!(stats["lightmap_bytes_uploaded"].as_u64().is_some_and(|b| b > 0), "{stats}");
}

/// `livebake view` with a GPU pool far smaller than the shown map grows (320 pages of 16×16:
/// the Cornell box's LOD 0 fills ~200, its finer LODs want thousands):
/// it opens, every frame (500) is lit, and it shows the room about as bright as a run with the
/// device's whole pool (within a factor of 2 in mean brightness: the same view, one at
/// coarser LODs), having uploaded less of the map (the runtime keeps the shown map within
/// the pool; the mirror shows a coarser level where a page is left out).
#[test]
fn view_with_a_pool_smaller_than_the_map_keeps_drawing_lit_frames() {
    let xvfb = xvfb();
    let dir = tempfile::tempdir().unwrap();
    let view = |pages: Option<&str>| {
        let name = pages.unwrap_or("all");
        let (shot, stats) = (dir.path().join(format!("{name}.png")), dir.path().join(format!("{name}.json")));
        let mut cmd = livebake();
        cmd.env("DISPLAY", &xvfb.display)
            .arg("-q")
            .arg("view")
            .arg(cornell_path())
            .args(["--frames", "500", "--size", "320x240", "--camera", "1,1,4.5,1,1,0"])
            .arg("--screenshot")
            .arg(&shot)
            .arg("--stats")
            .arg(&stats);
        if let Some(p) = pages {
            cmd.args(["--gpu-pages", p]);
        }
        let (code, stderr) = run_bounded(&mut cmd, 300);
        assert_eq!(code, Some(0), "{stderr}");
        let stats: serde_json::Value = serde_json::from_slice(&std::fs::read(&stats).unwrap()).unwrap();
        assert_eq!(stats["lit_frames"], 500, "{stats}");
        let img = image::open(&shot).unwrap().to_rgb8();
        let mean = img.pixels().map(|p| p.0.iter().map(|&c| c as f64).sum::<f64>() / 3.0).sum::<f64>()
            / img.len() as f64
            * 3.0;
        (stats, mean)
    };
    let (capped, capped_mean) = view(Some("320"));
    let (whole, whole_mean) = view(None);
    assert_eq!(capped["gpu_page_cap"], 320, "{capped}");
    assert!(capped_mean > 0.5 * whole_mean && whole_mean > 10.0, "mean {capped_mean:.1} against {whole_mean:.1}");
    let uploaded = |s: &serde_json::Value| s["lightmap_bytes_uploaded"].as_u64().unwrap();
    assert!(uploaded(&capped) < uploaded(&whole), "{capped} against {whole}");
}

/// Without a display the viewer says so (and what works without one) instead of panicking.
#[test]
fn view_without_a_display_is_a_clear_error() {
    let mut cmd = livebake();
    cmd.env_remove("DISPLAY").env_remove("WAYLAND_DISPLAY").arg("view").arg(cornell_path());
    cmd.args(["--texel-size", "0.1", "--samples", "8"]);
    let (code, stderr) = run_bounded(&mut cmd, 120);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(stderr.contains("display") && !stderr.contains("internal error"), "{stderr}");
}

/// Bad options are refused before anything opens.
#[test]
fn view_refuses_bad_options() {
    for args in [["--camera", "1,2,3"], ["--size", "10x10"], ["--exposure", "-1"], ["--frames", "0"], ["--lods", "9"]] {
        let out = livebake().env_remove("DISPLAY").arg("view").arg(cornell_path()).args(args).output().unwrap();
        assert!(!out.status.success(), "{args:?} accepted");
        assert!(!String::from_utf8_lossy(&out.stderr).contains("internal error"), "{args:?}");
    }
}

/// The mirror grows its page pool on the GPU when a publish brings more pages than it holds
/// (the first pool, one row of page slots, copied, not re-uploaded), and frees the slots of
/// pages a publish removes: after each sync every page reads back as published and the GPU
/// sampling still equals the CPU's.
#[test]
fn mirror_grows_its_pool_and_frees_removed_pages() {
    // 32 × 10 pages: more than the first pool's one row of at most 256 slots.
    const PX: u32 = 32;
    const PY: u32 = 10;
    let grid = Grid { origin: Vec3::ZERO, cell_size: 1.0, dims: [1, 1, 1] };
    let mut map = ShownLightmap::new(grid, PX * PAGE_SIDE, PY * PAGE_SIDE, 1, 0.0);
    let mut w = PageWriter::new(&mut map);
    w.write(Layer::Bundles, 0, 5, 5, Vec3::splat(1.0));
    w.finish();
    let gpu = GpuContext::headless().unwrap();
    let layout = lightmap::bind_group_layout(&gpu.device);
    let mut mirror = LightmapGpu::new(&gpu, &layout, &map).unwrap();
    let first_capacity = mirror.capacity();
    // One pixel in each page.
    let mut grown = map.clone();
    let mut w = PageWriter::new(&mut grown);
    for py in 0..PY {
        for px in 0..PX {
            w.write(Layer::Bundles, 0, px * PAGE_SIDE + 7, py * PAGE_SIDE + 9, Vec3::new(px as f32, py as f32, 1.0));
        }
    }
    w.finish();
    let sync = mirror.sync(&gpu, &layout, &grown).unwrap();
    let pages = (PX * PY) as u64;
    assert!(
        mirror.capacity() as u64 >= pages && (first_capacity as u64) < pages,
        "{first_capacity} -> {}",
        mirror.capacity()
    );
    // Page (0, 0) changed too (a second pixel): every page uploaded, all but one new table entries.
    assert_eq!((sync.pages_uploaded, sync.table_entries_uploaded), (pages, pages - 1));
    // Remove the pages of the top row but one.
    let mut shrunk = grown.clone();
    let mut w = PageWriter::new(&mut shrunk);
    for px in 1..PX {
        w.clear(Layer::Bundles, 0, px * PAGE_SIDE + 7, 9);
    }
    w.finish();
    let sync = mirror.sync(&gpu, &layout, &shrunk).unwrap();
    let removed = (PX - 1) as u64;
    assert_eq!((sync.pages_uploaded, sync.table_entries_uploaded, sync.bytes_uploaded), (0, removed, removed * 4));
    let probe = IrradianceProbe::new(&gpu, &layout).unwrap();
    let level = &shrunk.layer(Layer::Bundles).levels[0];
    let mut points = Vec::new();
    for py in 0..PY {
        for px in 0..PX {
            let want = level.page(px, py).map(|p| p.texels.to_vec());
            assert_eq!(
                mirror.read_page(&gpu, Layer::Bundles, 0, (py * PX + px) as usize).unwrap(),
                want,
                "page ({px}, {py})"
            );
            points.push((
                Vec3::splat(0.5),
                Vec2::new((px * PAGE_SIDE + 7) as f32 + 0.5, (py * PAGE_SIDE + 9) as f32 + 0.5),
            ));
        }
    }
    let on_gpu = probe.run(&gpu, &mirror, &points).unwrap();
    for (&(p, uv), got) in points.iter().zip(&on_gpu) {
        assert_eq!(*got, shrunk.irradiance(p, uv), "uv {uv}");
    }
}

/// A map that outgrows the pool (capped at 24 pages: LOD 0 takes 10, LOD 1 would take 40)
/// never fails to sync: LOD 0 stays whole, LOD 1 keeps what fits and the rest is left out,
/// and where a page is left out the GPU samples what the CPU function samples in the same
/// map without that page: the coarser level. A later publish of more LOD-0 pages takes
/// slots from LOD 1.
#[test]
fn a_map_larger_than_the_pool_shows_coarser_levels_where_it_overflows() {
    let grid = Grid { origin: Vec3::ZERO, cell_size: 1.0, dims: [1, 1, 1] };
    let (w0, h0) = (5 * PAGE_SIDE, 2 * PAGE_SIDE);
    let mut map = ShownLightmap::new(grid, w0, h0, 2, 0.0);
    let gpu = GpuContext::headless().unwrap();
    let layout = lightmap::bind_group_layout(&gpu.device);
    let mut mirror = LightmapGpu::new(&gpu, &layout, &map).unwrap();
    mirror.set_page_cap(24);
    let mut w = PageWriter::new(&mut map);
    for y in 0..h0 {
        for x in 0..w0 {
            w.write(Layer::Bundles, 0, x, y, Vec3::new(1.0, x as f32 / w0 as f32, 0.0));
        }
    }
    for y in 0..2 * h0 {
        for x in 0..2 * w0 {
            w.write(Layer::Bundles, 1, x, y, Vec3::new(2.0, 0.0, y as f32 / h0 as f32));
        }
    }
    w.set_cell_lod(Layer::Bundles, 0, 1);
    w.finish();
    let sync = mirror.sync(&gpu, &layout, &map).unwrap();
    assert_eq!((sync.pages_uploaded, sync.pages_left_out), (24, 26), "{sync:?}");
    assert_eq!(mirror.page_cap(), 24);
    let resident = |mirror: &LightmapGpu, lod: usize, pages: usize| {
        (0..pages).filter(|&i| mirror.read_page(&gpu, Layer::Bundles, lod, i).unwrap().is_some()).count()
    };
    assert_eq!(resident(&mirror, 0, 10), 10, "LOD 0 is whole");
    assert_eq!(resident(&mirror, 1, 40), 14);
    // What the GPU shows: the map without the LOD-1 pages it left out.
    let mut seen = map.clone();
    let level = map.layer(Layer::Bundles).levels[1].clone();
    let mut w = PageWriter::new(&mut seen);
    for py in 0..level.pages_y {
        for px in 0..level.pages_x {
            if mirror.read_page(&gpu, Layer::Bundles, 1, (py * level.pages_x + px) as usize).unwrap().is_none() {
                for y in py * PAGE_SIDE..(py + 1) * PAGE_SIDE {
                    for x in px * PAGE_SIDE..(px + 1) * PAGE_SIDE {
                        w.clear(Layer::Bundles, 1, x, y);
                    }
                }
            }
        }
    }
    w.finish();
    let mut rng = Rng(7);
    let points: Vec<(Vec3, Vec2)> =
        (0..2000).map(|_| (Vec3::splat(0.5), Vec2::new(rng.next() * w0 as f32, rng.next() * h0 as f32))).collect();
    let probe = IrradianceProbe::new(&gpu, &layout).unwrap();
    let on_gpu = probe.run(&gpu, &mirror, &points).unwrap();
    let mut coarse = 0;
    for (&(p, uv), got) in points.iter().zip(&on_gpu) {
        let want = seen.irradiance(p, uv);
        assert!((*got - want).length() <= 1e-5 * (1.0 + want.length()), "uv {uv}: {got} against {want}");
        coarse += usize::from(want.x < 1.5);
    }
    assert!(coarse > 500, "{coarse} of 2000 points fell back to LOD 0");
    // More LOD-0 pages (a taller atlas is another map; here: a second layer at LOD 0) take
    // the slots of LOD-1 pages.
    let mut more = map.clone();
    let mut w = PageWriter::new(&mut more);
    for y in 0..h0 {
        for x in 0..w0 {
            w.write(Layer::Punctual, 0, x, y, Vec3::splat(0.5));
        }
    }
    w.finish();
    let sync = mirror.sync(&gpu, &layout, &more).unwrap();
    assert_eq!(sync.pages_given_up, 10, "{sync:?}");
    assert_eq!(resident(&mirror, 1, 40), 4);
}

/// `livebake` without arguments, with a display (Xvfb): it opens the viewer on the default
/// scene (the window's GPU device is set up: the headless run never makes one) instead of
/// running headless (which would write ./out). The window stays until closed; the test kills it.
#[test]
fn no_arguments_with_a_display_opens_the_viewer() {
    use std::io::{BufRead, BufReader};
    let xvfb = xvfb();
    let dir = tempfile::tempdir().unwrap();
    let mut child = livebake()
        .current_dir(dir.path())
        .env("DISPLAY", &xvfb.display)
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("RUST_LOG")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let stderr = child.stderr.take().unwrap();
    // Read stderr on a thread; the lines come back over a channel so the wait is bounded.
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(120);
    let mut seen = Vec::new();
    let opened = loop {
        let left = deadline.saturating_duration_since(std::time::Instant::now());
        match rx.recv_timeout(left) {
            Ok(line) if line.contains("GPU device") => break true,
            Ok(line) => seen.push(line),
            Err(_) => break false,
        }
    };
    let exited = child.try_wait().unwrap();
    let _ = child.kill();
    let _ = child.wait();
    assert!(opened, "no window's GPU device within 120 s (exited: {exited:?}); stderr:\n{}", seen.join("\n"));
    assert!(exited.is_none(), "livebake exited instead of showing the window");
    assert!(seen.iter().all(|l| !l.contains("headless")), "{}", seen.join("\n"));
    assert!(!dir.path().join("out").exists(), "the headless run wrote ./out");
}
