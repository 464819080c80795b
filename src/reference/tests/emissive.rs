//! Emissive quads seen from a point, against Lambert's exact point-to-polygon formula.

use glam::{Quat, Vec3};

use super::{assert_estimate, estimate};
use crate::analytic::polygon_irradiance;
use crate::reference::ReferenceTracer;
use crate::scene::builder::diffuse;
use crate::scene::{Rgb, Scene, SceneBuilder};

/// A quad of half-size `h` centred at `c`, rotated by `rot` from facing −Y (down).
fn quad_corners(c: Vec3, h: f32, rot: Quat) -> [Vec3; 4] {
    [Vec3::new(-h, 0.0, -h), Vec3::new(h, 0.0, -h), Vec3::new(h, 0.0, h), Vec3::new(-h, 0.0, h)].map(|v| c + rot * v)
}

fn emitter_scene(corners: [Vec3; 4], le: Rgb, double_sided: bool) -> Scene {
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Vec3::splat(0.5), le, double_sided));
    b.quad("emitter", corners, m);
    b.build()
}

#[test]
fn emitter_normals_face_where_the_tests_assume() {
    let s = emitter_scene(quad_corners(Vec3::Y, 0.5, Quat::IDENTITY), Rgb::ONE, false);
    let g = crate::scene::SceneGeometry::new(&s);
    assert!(g.normals.iter().all(|n| (*n - Vec3::NEG_Y).length() < 1e-6));
}

#[test]
fn quads_match_lamberts_polygon_formula() {
    let le = Rgb::new(2.0, 1.0, 0.5);
    // (what, centre, half-size, rotation, query point, query normal)
    let tilt = Quat::from_rotation_x(35f32.to_radians()) * Quat::from_rotation_z(-20f32.to_radians());
    let cases = [
        ("parallel 1 m at 1 m", Vec3::Y, 0.5, Quat::IDENTITY, Vec3::ZERO, Vec3::Y),
        ("parallel, off-axis point", Vec3::Y, 0.5, Quat::IDENTITY, Vec3::new(0.7, 0.0, 0.3), Vec3::Y),
        ("tilted quad", Vec3::new(0.2, 1.2, -0.1), 0.6, tilt, Vec3::ZERO, Vec3::Y),
        (
            "tilted quad, tilted receiver",
            Vec3::new(0.2, 1.2, -0.1),
            0.6,
            tilt,
            Vec3::new(-0.3, 0.0, 0.2),
            Vec3::new(0.3, 0.9, 0.1).normalize(),
        ),
        ("tiny 4 cm emitter at 2 m", Vec3::new(0.0, 2.0, 0.0), 0.02, Quat::IDENTITY, Vec3::ZERO, Vec3::Y),
        ("huge 40 m emitter at 0.5 m", Vec3::new(0.0, 0.5, 0.0), 20.0, Quat::IDENTITY, Vec3::ZERO, Vec3::Y),
    ];
    for (what, c, h, rot, p, n) in cases {
        let corners = quad_corners(c, h, rot);
        let s = emitter_scene(corners, le, false);
        let t = ReferenceTracer::new(&s);
        let want = polygon_irradiance(p, n, &corners, le);
        // 16384 paths. NEE and cosine sampling are combined by MIS at the query, so the
        // per-path relative σ stays small from the tiny to the huge emitter (the light
        // strategy covers the tiny one, the cosine one the huge one): measured 0.16–0.18 for
        // the 1 m and 40 m quads, ~0 for the 4 cm one. σ_mean ≈ 0.18/128 ≈ 0.15%; the bound
        // 0.5% leaves room for the tilted cases. Checked at 5σ of the measured standard error
        // plus a 1e-4 relative floor for the ε offset of the origin (ε ≤ 3.5e-5 m here, at
        // d ≥ 1 m: ≤ 7e-5; the 4 cm emitter, whose σ is ~1e-6, shows it: +2e-5).
        let est = estimate(&t, p, n, 16_384);
        assert_estimate(&est, want, 0.005, 1e-4, what);
    }
}

#[test]
fn single_sided_emitters_are_dark_from_behind_double_sided_lit_from_both_sides() {
    let le = Rgb::splat(3.0);
    // Quad at y = 1 facing +Y (away from the origin below it).
    let corners = quad_corners(Vec3::Y, 0.5, Quat::from_rotation_x(std::f32::consts::PI));
    let single = emitter_scene(corners, le, false);
    let t = ReferenceTracer::new(&single);
    // Below, looking up at its back: nothing, exactly (NEE finds no emitting side facing the
    // point; cosine rays that hit the back of a single-sided face end black).
    assert_eq!(estimate(&t, Vec3::ZERO, Vec3::Y, 4096).e, Rgb::ZERO);
    // Above, looking down at its front: the polygon value.
    let above = Vec3::new(0.1, 2.0, 0.0);
    let want = polygon_irradiance(above, Vec3::NEG_Y, &corners, le);
    assert_estimate(&estimate(&t, above, Vec3::NEG_Y, 16_384), want, 0.005, 1e-4, "single-sided front");

    let double = emitter_scene(corners, le, true);
    let t = ReferenceTracer::new(&double);
    for (p, n) in [(Vec3::ZERO, Vec3::Y), (above, Vec3::NEG_Y)] {
        let want = polygon_irradiance(p, n, &corners, le);
        assert!(want.x > 0.1);
        // Same 16384-path budget, σ bound and 5σ rule as above.
        assert_estimate(&estimate(&t, p, n, 16_384), want, 0.005, 1e-4, &format!("double-sided at {p}"));
    }
}

#[test]
fn textured_emission_is_sampled_by_its_mean_and_integrated_exactly() {
    // A 1 m quad at 1 m whose emissive texture is a 2 × 1 texel pair (0 and full): the left
    // half of the quad dark, the right lit, with a bilinear ramp between the texel centres
    // (u ∈ [¼, ¾]). E is a 1D integral in u of the polygon formula over thin strips; we
    // integrate it with 400 strips (each strip a polygon with its mean radiance over the
    // strip: exact for the piecewise-linear profile up to O(1/400²)).
    use crate::scene::{Texture, TextureRef, WrapMode};
    let le = Rgb::splat(4.0);
    let corners = quad_corners(Vec3::Y, 0.5, Quat::IDENTITY);
    let mut s = emitter_scene(corners, le, false);
    s.textures.push(Texture {
        name: "half".into(),
        width: 2,
        height: 1,
        rgba8: vec![[0, 0, 0, 255], [255, 255, 255, 255]].into(),
        srgb: false,
        wrap_s: WrapMode::ClampToEdge,
        wrap_t: WrapMode::ClampToEdge,
    });
    s.materials[0].emissive_texture = Some(TextureRef::new(0));
    // Corners in order: (−h,−h), (h,−h), (h,h), (−h,h) in (x, z): u = x + ½.
    s.meshes[0].uv0 = Some(vec![
        glam::Vec2::new(0.0, 0.5),
        glam::Vec2::new(1.0, 0.5),
        glam::Vec2::new(1.0, 0.5),
        glam::Vec2::new(0.0, 0.5),
    ]);
    let profile = |u: f32| ((u - 0.25) / 0.5).clamp(0.0, 1.0);
    let (p, n) = (Vec3::new(0.1, 0.0, 0.0), Vec3::Y);
    let strips = 400;
    let mut want = Rgb::ZERO;
    for k in 0..strips {
        let (u0, u1) = (k as f32 / strips as f32, (k + 1) as f32 / strips as f32);
        let mean = (0..8).map(|j| profile(u0 + (u1 - u0) * (j as f32 + 0.5) / 8.0)).sum::<f32>() / 8.0;
        let strip = [
            Vec3::new(u0 - 0.5, 1.0, -0.5),
            Vec3::new(u1 - 0.5, 1.0, -0.5),
            Vec3::new(u1 - 0.5, 1.0, 0.5),
            Vec3::new(u0 - 0.5, 1.0, 0.5),
        ];
        want += polygon_irradiance(p, n, &strip, le * mean);
    }
    let t = ReferenceTracer::new(&s);
    // Half the quad is dark, so per-path σ is larger than for a uniform quad: measured
    // ≈ 0.8·E, so 32768 paths give σ_mean ≈ 0.45%; bound 0.8%; 5σ rule, 1e-4 floor as above
    // (the strip integration error, O(1/400²), is far below it).
    assert_estimate(&estimate(&t, p, n, 32_768), want, 0.008, 1e-4, "textured emitter");
}

#[test]
fn alpha_masked_emitters_emit_only_where_opaque() {
    // A 1 m emissive quad at 1 m, alpha-masked by a 2 × 1 texture (alpha 0 | 1, clamped,
    // cutoff ½): alpha is linear in u between the texel centres, so the quad exists for
    // u ≥ ½, i.e. x ≥ 0. E is the polygon value of that half. Both strategies must agree:
    // cosine rays pass through the cut half, NEE points on it emit nothing.
    use crate::scene::{AlphaMode, Texture, TextureRef, WrapMode};
    let le = Rgb::splat(2.0);
    let corners = quad_corners(Vec3::Y, 0.5, Quat::IDENTITY);
    let mut s = emitter_scene(corners, le, false);
    s.textures.push(Texture {
        name: "alpha".into(),
        width: 2,
        height: 1,
        rgba8: vec![[255, 255, 255, 0], [255, 255, 255, 255]].into(),
        srgb: false,
        wrap_s: WrapMode::ClampToEdge,
        wrap_t: WrapMode::ClampToEdge,
    });
    s.materials[0].base_color_texture = Some(TextureRef::new(0));
    s.materials[0].alpha_mode = AlphaMode::Mask { cutoff: 0.5 };
    s.meshes[0].uv0 = Some(vec![
        glam::Vec2::new(0.0, 0.5),
        glam::Vec2::new(1.0, 0.5),
        glam::Vec2::new(1.0, 0.5),
        glam::Vec2::new(0.0, 0.5),
    ]);
    let half =
        [Vec3::new(0.0, 1.0, -0.5), Vec3::new(0.5, 1.0, -0.5), Vec3::new(0.5, 1.0, 0.5), Vec3::new(0.0, 1.0, 0.5)];
    let t = ReferenceTracer::new(&s);
    for p in [Vec3::ZERO, Vec3::new(-0.4, 0.0, 0.2)] {
        let want = polygon_irradiance(p, Vec3::Y, &half, le);
        // Half of the NEE samples land on the cut half (contributing 0): per-path σ ≈ 1·E
        // (measured 0.98–1.06), 16384 paths give σ_mean ≈ 0.8%; bound 1.2%; 5σ rule and the
        // 1e-4 ε floor.
        assert_estimate(&estimate(&t, p, Vec3::Y, 16_384), want, 0.012, 1e-4, &format!("masked emitter at {p}"));
    }
}
