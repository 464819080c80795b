//! Multi-bounce transport, sky, sidedness (walls between rooms) and alpha masks.

use glam::{Vec2, Vec3, Vec4};

use super::{assert_estimate, estimate};
use crate::reference::ReferenceTracer;
use crate::scene::builder::diffuse;
use crate::scene::{AlphaMode, Material, Rgb, Scene, SceneBuilder, Texture, TextureRef, WrapMode};

fn furnace(albedo: f32, le: Rgb, double_sided: bool) -> Scene {
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Vec3::splat(albedo), le, double_sided));
    b.cuboid("box", Vec3::ZERO, Vec3::new(2.0, 1.0, 1.5), true, m);
    b.build()
}

#[test]
fn furnace_gives_pi_le_over_one_minus_albedo_everywhere() {
    let le = Rgb::new(1.0, 0.5, 0.25);
    let s = 1.0 / 3f32.sqrt();
    let points = [
        ("centre, +x", Vec3::new(1.0, 0.5, 0.75), Vec3::X),
        ("centre, −y", Vec3::new(1.0, 0.5, 0.75), Vec3::NEG_Y),
        ("on the floor", Vec3::new(0.4, 0.0, 1.1), Vec3::Y),
        ("on a wall", Vec3::new(2.0, 0.3, 0.2), Vec3::NEG_X),
        ("1 mm from a corner", Vec3::splat(0.001), Vec3::splat(s)),
        ("near the opposite corner", Vec3::new(1.995, 0.995, 1.495), -Vec3::splat(s)),
        ("in an edge, facing the edge", Vec3::new(1.0, 0.002, 0.002), Vec3::new(0.0, -1.0, -1.0).normalize()),
    ];
    for (albedo, double_sided) in [(0.5, false), (0.8, false), (0.5, true)] {
        let scene = furnace(albedo, le, double_sided);
        let t = ReferenceTracer::new(&scene);
        let want = le * (std::f32::consts::PI / (1.0 - albedo));
        for (what, p, n) in points {
            // Every path sees Le at each vertex, so the per-path spread comes from the path
            // length (RR) and MIS splitting: measured σ per path ≈ 0.4 E (ρ = 0.5) to 0.9 E
            // (ρ = 0.8). 8192 paths give σ_mean ≲ 0.9%; 5σ rule of assert_estimate, and the
            // standard error itself must stay ≤ 1.5% of E. E is uniform in the box, so the ε
            // offset does not matter: rounding floor only.
            let est = estimate(&t, p, n, 8192);
            assert_estimate(&est, want, 0.015, 1e-5, &format!("ρ = {albedo} double-sided {double_sided}: {what}"));
        }
    }
}

#[test]
fn open_plane_under_a_uniform_sky_gets_pi_l() {
    let sky = Rgb::new(1.0, 0.5, 0.25);
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Vec3::splat(0.7), Vec3::ZERO, false));
    b.floor("floor", Vec3::ZERO, 100.0, m);
    b.sky(sky);
    let s = b.build();
    let t = ReferenceTracer::new(&s);
    // Cosine rays from the floor's front all escape: each path contributes exactly π·L, so
    // E is exact up to rounding for any sample count (tolerance: 1e-6 relative).
    for p in [Vec3::ZERO, Vec3::new(10.0, 0.0, -30.0), Vec3::new(49.0, 0.0, 49.0)] {
        let est = estimate(&t, p, Vec3::Y, 256);
        assert_estimate(&est, sky * std::f32::consts::PI, 1e-6, 1e-6, &format!("sky at {p}"));
    }
    // Looking down from 5 cm above the floor: the floor (albedo ρ, itself under the sky)
    // reflects ρ·L. Over a 100 m floor the sky is seen only within ~1e-3 rad of the horizon
    // (cos-weighted share ≈ (0.05/50)² = 1e-6): E = π·ρ·L to 1e-6. Every path again
    // contributes the same π·ρ·L (one bounce, then escape): exact up to rounding.
    let est = estimate(&t, Vec3::new(0.0, 0.05, 0.0), Vec3::NEG_Y, 256);
    assert_estimate(&est, sky * (std::f32::consts::PI * 0.7), 1e-6, 1e-5, "floor seen from above");
}

#[test]
fn the_back_of_a_floor_is_black_when_single_sided_and_reflects_when_double_sided() {
    // The sky is uniform over the whole sphere, so it also lights the floor from below. A
    // point 5 cm under a 100 m floor looking up sees the floor's back over all but a
    // ~(0.05/50)² = 1e-6 share of its cosine-weighted hemisphere.
    let sky = Rgb::new(1.0, 0.5, 0.25);
    let albedo = 0.6;
    let below = Vec3::new(0.0, -0.05, 0.0);
    for double_sided in [false, true] {
        let mut b = SceneBuilder::new();
        let m = b.material(diffuse(Vec3::splat(albedo), Vec3::ZERO, double_sided));
        b.floor("floor", Vec3::ZERO, 100.0, m);
        b.sky(sky);
        let s = b.build();
        let t = ReferenceTracer::new(&s);
        let est = estimate(&t, below, Vec3::Y, 1024);
        if double_sided {
            // The back is a real surface: it sees the lower sky (E = πL), reflects ρ·L, so
            // E = π·ρ·L. Every path contributes exactly that (one bounce, escape): exact up
            // to rounding and the 1e-6 horizon share.
            assert_estimate(&est, sky * (std::f32::consts::PI * albedo), 1e-6, 1e-5, "double-sided back");
        } else {
            // Single-sided: the back is the inside of closed geometry, black; the path ends.
            assert_eq!(est.e, Rgb::ZERO, "single-sided back");
        }
    }
}

/// A 4 × 2 × 2 m closed box (inward, albedo ρ) cut into two rooms by a wall at x = 2
/// (`wall_top` high, facing the lit room x < 2). The lit room has a point light and an
/// emissive ceiling patch.
fn two_rooms(albedo: f32, wall_double_sided: bool, wall_top: f32, light_pos: Vec3) -> Scene {
    let mut b = SceneBuilder::new();
    let walls = b.material(diffuse(Vec3::splat(albedo), Vec3::ZERO, false));
    let divider = b.material(diffuse(Vec3::splat(albedo), Vec3::ZERO, wall_double_sided));
    let lamp = b.material(diffuse(Vec3::ZERO, Vec3::splat(5.0), false));
    b.cuboid("rooms", Vec3::ZERO, Vec3::new(4.0, 2.0, 2.0), true, walls);
    b.quad(
        "divider",
        [
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 0.0, 2.0),
            Vec3::new(2.0, wall_top, 2.0),
            Vec3::new(2.0, wall_top, 0.0),
        ],
        divider,
    );
    b.quad(
        "lamp",
        [Vec3::new(0.5, 1.99, 0.5), Vec3::new(1.0, 1.99, 0.5), Vec3::new(1.0, 1.99, 1.0), Vec3::new(0.5, 1.99, 1.0)],
        lamp,
    );
    b.point_light(light_pos, Rgb::splat(3.0));
    b.build()
}

/// Query points of the dark room x ∈ (2, 4), including the divider's back face.
fn dark_room_points() -> Vec<(Vec3, Vec3)> {
    vec![
        (Vec3::new(3.0, 1.0, 1.0), Vec3::NEG_X),
        (Vec3::new(3.0, 0.0, 1.0), Vec3::Y),
        (Vec3::new(4.0, 1.0, 0.5), Vec3::NEG_X),
        (Vec3::new(2.01, 1.9, 1.9), Vec3::new(-1.0, 1.0, 1.0).normalize()),
        (Vec3::new(2.0, 1.0, 1.0), Vec3::X),
        (Vec3::new(2.0, 0.01, 1.99), Vec3::X),
    ]
}

#[test]
fn a_wall_between_a_lit_and_a_sealed_dark_room_lets_nothing_through() {
    for double_sided in [false, true] {
        let s = two_rooms(0.6, double_sided, 2.0, Vec3::new(1.0, 1.0, 1.0));
        let t = ReferenceTracer::new(&s);
        // Exactly 0 whatever the sample count: no path from the dark room reaches a light.
        for (p, n) in dark_room_points() {
            assert_eq!(estimate(&t, p, n, 2048).e, Rgb::ZERO, "double-sided {double_sided}: dark room at {p} {n}");
        }
        // The divider's front (lit side) is lit: direct light alone is ≥ I·cos/d² = 3/1 = 3.
        let front = estimate(&t, Vec3::new(2.0, 1.0, 1.0), Vec3::NEG_X, 256).e;
        assert!(front.min_element() > 3.0, "front of the divider: {front}");
    }
}

#[test]
fn the_back_of_a_double_sided_wall_is_lit_only_through_transport() {
    // The divider stops 0.6 m below the ceiling; the point light sits low in the lit room and
    // the lamp patch is on the lit side, so the divider's back face sees no light directly.
    let back = [(Vec3::new(2.0, 0.7, 1.0), Vec3::X), (Vec3::new(2.0, 0.2, 0.3), Vec3::X)];
    let light = Vec3::new(1.0, 0.5, 1.0);
    // No reflection anywhere (ρ = 0): the back reads exactly 0.
    let s = two_rooms(0.0, true, 1.4, light);
    let t = ReferenceTracer::new(&s);
    for (p, n) in back {
        assert_eq!(estimate(&t, p, n, 4096).e, Rgb::ZERO, "no transport: back at {p}");
    }
    // With ρ = 0.6 light bounces over the divider: the back is lit, well above its noise,
    // and far below the front, which also gets the direct light.
    let s = two_rooms(0.6, true, 1.4, light);
    let t = ReferenceTracer::new(&s);
    for (p, n) in back {
        let b = estimate(&t, p, n, 4096);
        let f = estimate(&t, p, -n, 4096);
        assert!(b.e.x > 10.0 * b.stderr.x, "back at {p}: {b:?}");
        assert!(f.e.x > 3.0 * b.e.x, "front {f:?} vs back {b:?}");
    }
}

/// A black 2 × 2 m occluder at height 1 above a floor, under a vertical directional light.
fn masked_occluder(material: Material, texture: Option<Texture>) -> Scene {
    let mut b = SceneBuilder::new();
    let floor = b.material(diffuse(Vec3::splat(0.5), Vec3::ZERO, false));
    let occ = b.material(material);
    b.floor("floor", Vec3::ZERO, 10.0, floor);
    b.floor("occluder", Vec3::Y, 2.0, occ);
    b.directional_light(Vec3::NEG_Y, Rgb::splat(2.0));
    let mut s = b.build();
    // floor() corners: (−h, h), (h, h), (h, −h), (−h, −h) in (x, z): u = (x + 1)/2.
    s.meshes[1].uv0 = Some(vec![Vec2::new(0.0, 0.5), Vec2::new(1.0, 0.5), Vec2::new(1.0, 0.5), Vec2::new(0.0, 0.5)]);
    s.textures.extend(texture);
    s
}

fn occluder_material(alpha: f32, mode: AlphaMode, textured: bool) -> Material {
    Material {
        base_color: Vec4::new(0.0, 0.0, 0.0, alpha),
        base_color_texture: textured.then_some(TextureRef::new(0)),
        alpha_mode: mode,
        ..Material::default()
    }
}

#[test]
fn alpha_masked_occluders_cast_shadows_only_where_opaque() {
    // Direct light from a directional light and a black occluder: exact values (2 or 0).
    let under = Vec3::new(0.0, 0.0, 0.0);
    let mask = AlphaMode::Mask { cutoff: 0.5 };
    let cases = [
        ("masked, alpha 0", occluder_material(0.0, mask, false), 2.0),
        ("masked, alpha 1", occluder_material(1.0, mask, false), 0.0),
        ("masked, alpha 0.4 < cutoff", occluder_material(0.4, mask, false), 2.0),
        ("opaque mode ignores alpha", occluder_material(0.0, AlphaMode::Opaque, false), 0.0),
        ("blend α 0.2 passes 0.8", occluder_material(0.2, AlphaMode::Blend, false), 1.6),
    ];
    for (what, m, want) in cases {
        let s = masked_occluder(m, None);
        let t = ReferenceTracer::new(&s);
        assert_eq!(estimate(&t, under, Vec3::Y, 64).e, Rgb::splat(want), "{what}");
    }
    // A 2 × 1 alpha texture (0 | 1), clamped: u < ¼ is cut out, u > ¾ is solid.
    let tex = Texture {
        name: "alpha".into(),
        width: 2,
        height: 1,
        rgba8: vec![[255, 255, 255, 0], [255, 255, 255, 255]].into(),
        srgb: true,
        wrap_s: WrapMode::ClampToEdge,
        wrap_t: WrapMode::ClampToEdge,
    };
    let s = masked_occluder(occluder_material(1.0, mask, true), Some(tex));
    let t = ReferenceTracer::new(&s);
    assert_eq!(estimate(&t, Vec3::new(-0.7, 0.0, 0.3), Vec3::Y, 64).e, Rgb::splat(2.0), "u = 0.15: cut out");
    assert_eq!(estimate(&t, Vec3::new(0.7, 0.0, -0.3), Vec3::Y, 64).e, Rgb::ZERO, "u = 0.85: solid");
}

#[test]
fn path_rays_pass_through_cut_out_parts() {
    // Same black occluder 1 m above the point, no light but a uniform sky: cut out (alpha 0)
    // the point sees the whole sky, E = π·L exactly (every path escapes); opaque it hides a
    // 2 × 2 m square at 1 m, whose cosine-weighted share is the square's view factor
    // F = 4 · (1/2π)·2·(1/√2)·atan(1/√2) = 0.554 (parallel rectangle, four quarters with
    // X = Y = 1): E = π·L·(1 − F) ≈ 0.45·π·L, well below the 0.6·π·L bound (512 paths: the
    // per-path value is π·L or 0, σ_mean = √(F(1−F)/512) ≈ 2.2% of π·L).
    let sky = Rgb::splat(1.5);
    for (alpha, cut) in [(0.0, true), (1.0, false)] {
        let mut s = masked_occluder(occluder_material(alpha, AlphaMode::Mask { cutoff: 0.5 }, false), None);
        s.lights.clear();
        s.sky = sky;
        let t = ReferenceTracer::new(&s);
        let est = estimate(&t, Vec3::ZERO, Vec3::Y, 512);
        if cut {
            assert_estimate(&est, sky * std::f32::consts::PI, 1e-6, 1e-6, "cut-out occluder under a sky");
        } else {
            assert!(est.e.x < 0.6 * std::f32::consts::PI * sky.x, "opaque occluder: {est:?}");
        }
    }
}
