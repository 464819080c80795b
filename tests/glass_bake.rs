//! Light through surfaces in the bundle bake (CPU backend): a floor under a `BLEND` pane, a
//! tinted `KHR_materials_transmission` pane and a `MASK` checkerboard, under a sun and a
//! uniform sky, against closed forms and the reference tracer.
//!
//! Every tolerance is argued from the sample count in the test that uses it.

mod support;

use livebake::analytic::polygon_irradiance;
use livebake::bake::{BackendKind, BakeConfig, BakeOutput, bake};
use livebake::glam::{Vec2, Vec3};
use livebake::progress::NoProgress;
use livebake::reference::{ReferenceTracer, RelativeRmsError};
use livebake::scene::builder::diffuse;
use livebake::scene::{AlphaMode, Material, Rgb, Scene, SceneBuilder, Texture, TextureRef, WrapMode};

const TEXEL: f32 = 0.05;
const SUN: f32 = 2.0;
/// Half the pane's side; it lies at height `PANE_Y` over a 2 × 2 m floor.
const PANE_H: f32 = 0.6;
const PANE_Y: f32 = 0.5;

fn config(directions: u32) -> BakeConfig {
    let mut c = BakeConfig { backend: BackendKind::Cpu, samples: directions, ..BakeConfig::default() };
    c.atlas.texel_size = Some(TEXEL);
    c
}

fn run(scene: &Scene, config: &BakeConfig) -> BakeOutput {
    bake(&std::sync::Arc::new(scene.clone()), config, &NoProgress).expect("bake")
}

fn square(c: Vec3, h: f32) -> [Vec3; 4] {
    [c + Vec3::new(-h, 0.0, h), c + Vec3::new(h, 0.0, h), c + Vec3::new(h, 0.0, -h), c + Vec3::new(-h, 0.0, -h)]
}

/// A single-sided floor (albedo 0.5) under a single-sided pane facing up, a sun straight
/// down and a uniform sky of 1 (each when asked). Nothing sends light back to the floor (the
/// pane's underside is a back: it reflects nothing; what the floor reflects leaves through
/// the pane), so E_floor = SUN·T (under the pane, else SUN) + π − (1 − T)·E_pane, E_pane
/// the irradiance a Lambertian square of radiance 1 in the pane's place gives (Lambert).
fn pane_scene(pane: Material, sun: bool, sky: bool) -> Scene {
    let mut b = SceneBuilder::new();
    let floor = b.material(diffuse(Rgb::splat(0.5), Rgb::ZERO, false));
    let pane = b.material(pane);
    b.grid_quad("floor", square(Vec3::ZERO, 1.0), 4, floor);
    b.quad("pane", square(Vec3::Y * PANE_Y, PANE_H), pane);
    if sky {
        b.sky(Rgb::ONE);
    }
    if sun {
        b.directional_light(Vec3::NEG_Y, Rgb::splat(SUN));
    }
    let mut s = b.build();
    s.meshes[1].uv0 = Some(vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)]);
    s
}

/// Floor texels: (index, position) of those at least a texel from the pane's shadow edge.
fn floor_texels(out: &BakeOutput) -> Vec<(usize, Vec3)> {
    let t = &out.lods[0].texels;
    (0..t.len())
        .filter(|&i| t.position[i].y.abs() < 1e-4 && t.normal[i].y > 0.99)
        .filter(|&i| {
            let p = t.position[i];
            (p.x.abs().max(p.z.abs()) - PANE_H).abs() > TEXEL
        })
        .map(|i| (i, t.position[i]))
        .collect()
}

#[test]
fn a_floor_under_a_pane_gets_the_light_the_pane_passes() {
    let tint = Rgb::new(1.0, 0.5, 0.25);
    let blend =
        Material { base_color: Rgb::splat(0.8).extend(0.4), alpha_mode: AlphaMode::Blend, ..Material::default() };
    let glass = Material { base_color: tint.extend(1.0), transmission: 1.0, ..Material::default() };
    for (what, pane, pass) in [("BLEND α 0.4", blend, Rgb::splat(0.6)), ("tinted transmission", glass, tint)] {
        // The sun alone (the punctual pass: exact at the texel's points, f32 rounding; the
        // bundles add nothing, the floor seeing only the pane's back and a black sky), then
        // the sky alone.
        let sunlit = run(&pane_scene(pane.clone(), true, false), &config(16));
        let out = run(&pane_scene(pane, false, true), &config(256));
        assert_eq!(sunlit.lods[0].texels.position, out.lods[0].texels.position, "one atlas");
        let texels = floor_texels(&out);
        assert!(texels.len() > 1000, "{what}: {} floor texels", texels.len());
        let corners = square(Vec3::Y * PANE_Y, PANE_H);
        let mut error = RelativeRmsError::default();
        let (mut under, mut opaque_error) = (0, RelativeRmsError::default());
        for &(i, p) in &texels {
            let shaded = p.x.abs() < PANE_H && p.z.abs() < PANE_H;
            under += shaded as u32;
            let sun = if shaded { pass * SUN } else { Rgb::splat(SUN) };
            let e_pane = polygon_irradiance(p, Vec3::Y, &corners, Rgb::ONE);
            let sky = Rgb::splat(std::f32::consts::PI) - (Rgb::ONE - pass) * e_pane;
            let direct = sunlit.lods[0].irradiance[i];
            assert!((direct - sun).abs().max_element() <= 1e-5 * SUN, "{what}: texel at {p}: sun {direct} vs {sun}");
            error.add(out.lods[0].irradiance[i].as_dvec3(), sky.as_dvec3(), livebake::glam::DVec3::ZERO);
            let opaque_sky = Rgb::splat(std::f32::consts::PI) - e_pane;
            opaque_error.add(opaque_sky.as_dvec3(), sky.as_dvec3(), livebake::glam::DVec3::ZERO);
        }
        assert!(under > 300, "{what}: {under} texels under the pane");
        // The sky part: each texel's lines see the sky (1) or the sky through the pane (T)
        // by direction; with 256 stratified directions (about half of them reach a floor
        // texel from above) its relative error is ≈ (1 − T)·π·√(F(1 − F)/128)/(π(1 − F(1 − T)))
        // ≤ 0.4·0.5/11.3/0.76 ≈ 2.3% for the BLEND pane (F the pane's view factor, ≤ 0.6),
        // less where F is small; bound 4%. A pane taken as opaque is ≥ 20% off.
        let (e, opaque) = (error.value(), opaque_error.value());
        eprintln!("{what}: sky part relative RMS error {e:.4} (an opaque pane: {opaque:.3})");
        assert!(opaque > 0.2, "{what}: the test cannot tell glass from an opaque pane ({opaque})");
        assert!(e < 0.04, "{what}: {e}");
    }
}

/// A 2 × 2 texel checkerboard of alpha (REPEAT, cutoff 0.5) over the pane's UV square: the
/// bilinear alpha is 0.5 exactly on the quadrant borders (a saddle), so the pane exists on
/// two opposite quadrants. The sun reaches the floor under the holes only; with the sky,
/// the bake agrees with the reference tracer per texel.
#[test]
fn a_mask_checkerboard_cuts_out_holes_for_the_sun_and_the_bundles() {
    let mask = |sun: bool, sky: bool| {
        let mut scene = pane_scene(
            Material {
                base_color: Rgb::splat(0.8).extend(1.0),
                base_color_texture: Some(TextureRef { texture: 0, tex_coord: 0 }),
                alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
                double_sided: false,
                ..Material::default()
            },
            sun,
            sky,
        );
        scene.textures.push(Texture {
            name: "checker".into(),
            width: 2,
            height: 2,
            rgba8: vec![[255, 255, 255, 255], [255, 255, 255, 0], [255, 255, 255, 0], [255, 255, 255, 255]].into(),
            srgb: true,
            wrap_s: WrapMode::Repeat,
            wrap_t: WrapMode::Repeat,
        });
        scene
    };
    let sunlit = run(&mask(true, false), &config(16));
    let texels = floor_texels(&sunlit);
    // uv = ((x + h)/2h, (h − z)/2h) over the pane (the corners' UVs); texels (0, 0) and
    // (1, 1) are solid.
    let solid_at = |p: Vec3| {
        let (u, v) = ((p.x + PANE_H) / (2.0 * PANE_H), (PANE_H - p.z) / (2.0 * PANE_H));
        (u < 0.5) == (v < 0.5)
    };
    let (mut holes, mut solid) = (0, 0);
    // Texels within a texel of a quadrant border are left out: their 2×2 sun points (the
    // punctual pass) may fall on both sides, the reference's centre on one.
    let clear: Vec<(usize, Vec3)> = texels
        .into_iter()
        .filter(|&(_, p)| !(p.x.abs() < PANE_H && p.z.abs() < PANE_H && (p.x.abs() < TEXEL || p.z.abs() < TEXEL)))
        .collect();
    for &(i, p) in &clear {
        let under = p.x.abs() < PANE_H && p.z.abs() < PANE_H;
        let want = if under && solid_at(p) { 0.0 } else { SUN };
        holes += (under && want > 0.0) as u32;
        solid += (want == 0.0) as u32;
        let got = sunlit.lods[0].irradiance[i].x;
        assert!((got - want).abs() <= 1e-5 * SUN, "sun at {p}: {got} vs {want}");
    }
    assert!(holes > 100 && solid > 100, "{holes} texels under holes, {solid} under the solid quadrants");
    // Per texel against the reference tracer (4096 paths; reference noise removed by
    // RelativeRmsError): the bundle noise at 256 directions of the sky seen through or
    // stopped by the quadrants is a few percent, as in the BLEND case; bound 5%. A pane
    // taken as whole (no holes) is off by far more at the texels under it.
    let scene = mask(true, true);
    let out = run(&scene, &config(256));
    let tracer = ReferenceTracer::new(&scene);
    let picks: Vec<usize> = clear.iter().step_by(clear.len() / 150).map(|&(i, _)| i).collect();
    let t = &out.lods[0].texels;
    let queries: Vec<(Vec3, Vec3)> = picks.iter().map(|&i| (t.position[i], t.normal[i])).collect();
    let (reference, _) = tracer.irradiance_batch_estimates(&queries, 4096, 3, &|_| {});
    let mut error = RelativeRmsError::default();
    for (&i, r) in picks.iter().zip(&reference) {
        error.add(out.lods[0].irradiance[i].as_dvec3(), r.e.as_dvec3(), r.stderr.as_dvec3());
    }
    let e = error.value();
    eprintln!("MASK checkerboard: relative RMS error against the reference {e:.4}");
    assert!(e < 0.05, "{e}");
}

/// Khronos GlassBrokenWindow (transmission glass, a MASK for the broken part) under a
/// uniform sky: `probe` (a whole bake at the defaults, 256 directions) at 256 texel centres
/// against the Mitsuba tool (16 384 spp, its variance removed by RelativeRmsError).
/// Measured: 0.57 % (1.5 % at 64 directions, falling with them: the error is the directions'
/// noise). The glass taken as opaque (no transmission, no cut-out) gives 3.5 % at these
/// points (most of them see little through the pane), so the bound, 2 % (3.5× the measured
/// figure), is where this test tells glass from no glass.
#[test]
fn glass_broken_window_matches_mitsuba_under_a_sky() {
    let dir = tempfile::tempdir().unwrap();
    let asset = |f: &str| format!("{}/assets/glass_broken_window/{f}", env!("CARGO_MANIFEST_DIR"));
    let out = dir.path().join("probe.json");
    let args = [
        "-q",
        "probe",
        &asset("GlassBrokenWindow.gltf"),
        "--sky",
        "1",
        "--points",
        &asset("points.json"),
        "--out",
        out.to_str().unwrap(),
    ];
    support::ok(dir.path(), &args);
    let read = |p: &str| -> serde_json::Value { serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap() };
    let got = read(out.to_str().unwrap());
    let want = read(&asset("mitsuba_sky.json"));
    let rgb = |v: &serde_json::Value| {
        livebake::glam::DVec3::new(v[0].as_f64().unwrap(), v[1].as_f64().unwrap(), v[2].as_f64().unwrap())
    };
    let (got, want) = (got["points"].as_array().unwrap(), want["points"].as_array().unwrap());
    assert_eq!(got.len(), want.len());
    let mut error = RelativeRmsError::default();
    for (g, w) in got.iter().zip(want) {
        error.add(rgb(&g["E"]), rgb(&w["E"]), rgb(&w["E_stderr"]));
    }
    let e = error.value();
    eprintln!("GlassBrokenWindow under a sky: relative RMS error against Mitsuba {e:.4}");
    assert!(e < 0.02, "{e}");
}
