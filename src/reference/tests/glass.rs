//! Light through surfaces: `BLEND` coverage, `KHR_materials_transmission`, and both on
//! shadow rays, path rays, emitters and the sky (the Mitsuba tool's selftest §9–§11 cases).

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use super::{assert_estimate, estimate};
use crate::reference::ReferenceTracer;
use crate::scene::builder::diffuse;
use crate::scene::{AlphaMode, Material, Rgb, Scene, SceneBuilder, Texture, TextureRef, WrapMode};

const TINT: Rgb = Rgb::new(1.0, 0.5, 0.25);

fn sheet(alpha: f32, mode: AlphaMode, albedo: Rgb, transmission: f32, double_sided: bool) -> Material {
    Material { base_color: albedo.extend(alpha), alpha_mode: mode, transmission, double_sided, ..Material::default() }
}

/// A horizontal square of half-side `h` at height `y`, facing down.
fn facing_down(y: f32, h: f32) -> [Vec3; 4] {
    [Vec3::new(-h, y, -h), Vec3::new(h, y, -h), Vec3::new(h, y, h), Vec3::new(-h, y, h)]
}

/// A black floor under 100 m sheets stacked at heights 1, 2, ... (in `sheets` order from the
/// bottom), lit by a 1 W/m² sun straight down: E on the floor is the product of the sheets'
/// T, exactly (the floor reflects nothing and there is no sky).
fn sheets_over_a_black_floor(sheets: &[Material]) -> Scene {
    let mut b = SceneBuilder::new();
    let floor = b.material(diffuse(Rgb::ZERO, Rgb::ZERO, false));
    b.floor("floor", Vec3::ZERO, 100.0, floor);
    for (i, m) in sheets.iter().enumerate() {
        let id = b.material(m.clone());
        b.floor(&format!("sheet{i}"), Vec3::Y * (i + 1) as f32, 100.0, id);
    }
    b.directional_light(Vec3::NEG_Y, Rgb::ONE);
    b.build()
}

#[test]
fn sunlight_through_sheets_is_the_product_of_their_transmittance() {
    let blend = |a: f32| sheet(a, AlphaMode::Blend, Rgb::ONE, 0.0, false);
    let glass = sheet(1.0, AlphaMode::Opaque, TINT, 1.0, false);
    let mask = |a: f32, cutoff: f32| sheet(a, AlphaMode::Mask { cutoff }, Rgb::ONE, 0.0, false);
    let cases: [(&str, Vec<Material>, Rgb); 9] = [
        ("BLEND α 0.4", vec![blend(0.4)], Rgb::splat(0.6)),
        ("transmission 1, tinted", vec![glass.clone()], TINT),
        (
            "BLEND 0.5 with transmission 0.5",
            vec![sheet(0.5, AlphaMode::Blend, TINT, 0.5, false)],
            Rgb::new(0.75, 0.625, 0.5625),
        ),
        ("BLEND 0.4 over tinted glass", vec![glass, blend(0.4)], TINT * 0.6),
        ("MASK α 0.4, cutoff 0.5", vec![mask(0.4, 0.5)], Rgb::ONE),
        ("MASK α 0.6, cutoff 0.5", vec![mask(0.6, 0.5)], Rgb::ZERO),
        ("MASK α 0.3, cutoff 0.3", vec![mask(0.3, 0.3)], Rgb::ZERO),
        ("MASK α 0.29, cutoff 0.3", vec![mask(0.29, 0.3)], Rgb::ONE),
        ("OPAQUE ignores α", vec![sheet(0.0, AlphaMode::Opaque, Rgb::ONE, 0.0, false)], Rgb::ZERO),
    ];
    for (what, sheets, want) in cases {
        let s = sheets_over_a_black_floor(&sheets);
        let t = ReferenceTracer::new(&s);
        // Only the sun lights the floor, through the sheets' T: deterministic, f32 rounding.
        let est = estimate(&t, Vec3::new(3.0, 0.0, -7.0), Vec3::Y, 64);
        assert!((est.e - want).abs().max_element() <= 1e-5, "{what}: E = {} want {want}", est.e);
    }
}

#[test]
fn transmission_textures_are_read_linearly_from_red() {
    // A 1 × 1 texture R = 128 (linear: t = 128/255 = 0.50196) times factor 1.
    let mut s = sheets_over_a_black_floor(&[Material {
        transmission_texture: Some(TextureRef::new(0)),
        ..sheet(1.0, AlphaMode::Opaque, TINT, 1.0, false)
    }]);
    s.textures.push(Texture {
        name: "t".into(),
        width: 1,
        height: 1,
        rgba8: vec![[128, 0, 0, 255]].into(),
        srgb: false,
        wrap_s: WrapMode::Repeat,
        wrap_t: WrapMode::Repeat,
    });
    s.meshes[1].uv0 = Some(vec![Vec2::ZERO; 4]);
    let t = ReferenceTracer::new(&s);
    let want = TINT * (128.0 / 255.0);
    let e = estimate(&t, Vec3::ZERO, Vec3::Y, 16).e;
    assert!((e - want).abs().max_element() <= 1e-5, "E = {e} want {want}");
}

#[test]
fn a_sheet_lit_from_behind_passes_light_and_reflects_only_when_double_sided() {
    // A 1 km BLEND 0.4 sheet (albedo 0.7) facing up at height 1, the sun (1 W/m²) coming
    // up from below onto its back, and a black cap facing down at height 2.
    for double_sided in [false, true] {
        let mut b = SceneBuilder::new();
        let black = b.material(diffuse(Rgb::ZERO, Rgb::ZERO, false));
        let pane = b.material(sheet(0.4, AlphaMode::Blend, Rgb::splat(0.7), 0.0, double_sided));
        b.floor("sheet", Vec3::Y, 1000.0, pane);
        b.quad("cap", facing_down(2.0, 500.0), black);
        b.directional_light(Vec3::Y, Rgb::ONE);
        let s = b.build();
        let t = ReferenceTracer::new(&s);
        // The cap sees the sun through the sheet: T = 0.6 from either side (exact).
        let cap = estimate(&t, Vec3::new(0.0, 2.0, 0.0), Vec3::NEG_Y, 64).e;
        assert!((cap - Rgb::splat(0.6)).abs().max_element() <= 1e-5, "double-sided {double_sided}: cap {cap}");
        // A point below the sheet looking up sees its back: black when single-sided (every
        // path passes and meets the black cap: exactly 0), else a Lambertian sheet of
        // exitance α·a·1 = 0.28 over a view factor 1 − O((1 m / 500 m)²). A path reflects
        // with probability 0.84/2.64, worth 0.28·2.64/0.84 then, else 0: σ per path
        // ≈ 1.5 E, 16 384 paths give σ_mean ≈ 1.2% (bound 2%).
        let want = if double_sided { 0.28 } else { 0.0 };
        let est = estimate(&t, Vec3::ZERO, Vec3::Y, 16_384);
        assert_estimate(&est, Rgb::splat(want), 0.02, 1e-4, &format!("double-sided {double_sided}: under the sheet"));
    }
}

#[test]
fn indirect_light_under_a_blend_ceiling_follows_the_radiosity_of_two_planes() {
    // 1 km planes 1 m apart: floor albedo 0.8, a double-sided ceiling with α 0.5 and
    // albedo 0.8 (T = 0.5, reflectance ρ_c = 0.4). Infinite-plane radiosity:
    // E_floor = T·E_in / (1 − 0.8·0.4), the ceiling's underside 0.8·E_floor. A plane 500 m
    // wide seen from 1 m misses a view factor ~ (1/500)² = 4e-6: far below the noise.
    for (what, sky, sun, e_in) in [("sky 1", Rgb::ONE, None, PI), ("sun 1", Rgb::ZERO, Some(Rgb::ONE), 1.0)] {
        let mut b = SceneBuilder::new();
        let floor = b.material(diffuse(Rgb::splat(0.8), Rgb::ZERO, false));
        let ceiling = b.material(sheet(0.5, AlphaMode::Blend, Rgb::splat(0.8), 0.0, true));
        b.floor("floor", Vec3::ZERO, 1000.0, floor);
        b.floor("ceiling", Vec3::Y, 1000.0, ceiling);
        b.sky(sky);
        if let Some(i) = sun {
            b.directional_light(Vec3::NEG_Y, i);
        }
        let s = b.build();
        let t = ReferenceTracer::new(&s);
        let e_floor = 0.5 * e_in / (1.0 - 0.32);
        // Paths bounce between the planes (mean length ~1/(1 − 0.32)) and choose pass or
        // reflect at every crossing: σ per path ≲ 1.5 E; 16 384 paths give σ_mean ≲ 1.2%.
        let est = estimate(&t, Vec3::new(2.0, 0.0, 1.0), Vec3::Y, 16_384);
        assert_estimate(&est, Rgb::splat(e_floor), 0.012, 1e-4, &format!("{what}: floor"));
        let est = estimate(&t, Vec3::new(-1.0, 1.0, 3.0), Vec3::NEG_Y, 16_384);
        assert_estimate(&est, Rgb::splat(0.8 * e_floor), 0.012, 1e-4, &format!("{what}: ceiling underside"));
    }
}

#[test]
fn emitters_and_the_sky_are_seen_through_sheets() {
    // A 1 km emitter (Le = 1) facing down at 2 m over a point, a black BLEND 0.4 sheet at
    // 1 m between: E = T·π·Le·F with F = 1 − O((2 m / 500 m)²) = 1 − 1.6e-5. Both strategies
    // (emitter sampling through the sheet, cosine rays crossing it) are weighed by MIS, so
    // the emitter's distance must be measured from the vertex, not from the sheet.
    let mut b = SceneBuilder::new();
    let floor = b.material(diffuse(Rgb::ZERO, Rgb::ZERO, false));
    let pane = b.material(sheet(0.4, AlphaMode::Blend, Rgb::ZERO, 0.0, false));
    let lamp = b.material(diffuse(Rgb::ZERO, Rgb::ONE, false));
    b.floor("floor", Vec3::ZERO, 1000.0, floor);
    b.floor("sheet", Vec3::Y, 1000.0, pane);
    b.quad("lamp", facing_down(2.0, 500.0), lamp);
    let s = b.build();
    let t = ReferenceTracer::new(&s);
    // Per path: 0.6π·Le when the cosine ray passes, else the NEE share: σ per path ~ 0.5 E.
    let est = estimate(&t, Vec3::ZERO, Vec3::Y, 8192);
    assert_estimate(&est, Rgb::splat(0.6 * PI), 0.01, 1e-4, "emitter through a BLEND 0.4 sheet");
    // A uniform sky of 1 over a 2 × 2 m black BLEND 0.4 sheet at 1 m: π(1 − F + 0.6F), with
    // F = 0.5541 the square's view factor (see path_rays_pass_through_cut_out_parts).
    let mut b = SceneBuilder::new();
    let floor = b.material(diffuse(Rgb::ZERO, Rgb::ZERO, false));
    let pane = b.material(sheet(0.4, AlphaMode::Blend, Rgb::ZERO, 0.0, false));
    b.floor("floor", Vec3::ZERO, 100.0, floor);
    b.floor("sheet", Vec3::Y, 2.0, pane);
    b.sky(Rgb::ONE);
    let s = b.build();
    let t = ReferenceTracer::new(&s);
    let f = 4.0 / (2.0 * PI) * 2.0 / 2f32.sqrt() * (1.0 / 2f32.sqrt()).atan();
    let est = estimate(&t, Vec3::ZERO, Vec3::Y, 8192);
    assert_estimate(&est, Rgb::splat(PI * (1.0 - 0.4 * f)), 0.01, 1e-4, "sky through a BLEND 0.4 square");
}

#[test]
fn the_inside_of_a_glass_box_is_not_buried() {
    // A floor point under a closed single-sided box of BLEND glass (faces outward): its
    // first surface straight up is the box's back, but light passes it.
    let mut b = SceneBuilder::new();
    let floor = b.material(diffuse(Rgb::splat(0.5), Rgb::ZERO, false));
    let glass = b.material(sheet(0.3, AlphaMode::Blend, Rgb::ONE, 0.0, false));
    let solid = b.material(diffuse(Rgb::splat(0.5), Rgb::ZERO, false));
    b.floor("floor", Vec3::ZERO, 10.0, floor);
    b.cuboid("glass", Vec3::new(-1.0, -0.5, -1.0), Vec3::new(1.0, 1.0, 1.0), false, glass);
    b.cuboid("solid", Vec3::new(2.0, -0.5, 2.0), Vec3::new(3.0, 1.0, 3.0), false, solid);
    let s = b.build();
    let t = ReferenceTracer::new(&s);
    let buried = |p: Vec3| crate::reference::punctual::is_buried(&s, t.geometry(), t.bvh(), 0, p, Vec3::Y, t.epsilon());
    assert!(!buried(Vec3::ZERO), "inside the glass box");
    assert!(buried(Vec3::new(2.5, 0.0, 2.5)), "inside the solid box");
    assert!(!buried(Vec3::new(4.0, 0.0, 4.0)), "in the open");
}
