//! Punctual lights over a plane. These scenes have no emissive surface and a black sky, so
//! every continuation ray either escapes (adding 0) or hits a black occluder: the estimate is
//! deterministic and exact up to f32 rounding whatever the sample count. The tolerance is
//! therefore rounding only: 1e-5 relative (a few ulps through cos, 1/d² and the mean of
//! identical f64 samples), and exact zeros are asserted exactly.

use glam::Vec3;

use super::estimate;
use crate::reference::ReferenceTracer;
use crate::scene::builder::diffuse;
use crate::scene::{LightKind, PunctualLight, Rgb, Scene, SceneBuilder};

fn close(got: Rgb, want: Rgb, what: &str) {
    let tol = 1e-5 * want.max_element().max(1e-3);
    assert!((got - want).abs().max_element() <= tol, "{what}: {got} vs {want}");
}

/// A single-sided 20 m floor (albedo 0.5) at y = 0 and optional black occluder quads.
fn floor_scene(lights: Vec<PunctualLight>, occluders: &[(Vec3, f32, bool)]) -> Scene {
    let mut b = SceneBuilder::new();
    let floor = b.material(diffuse(Vec3::splat(0.5), Vec3::ZERO, false));
    let black = b.material(diffuse(Vec3::ZERO, Vec3::ZERO, false));
    b.floor("floor", Vec3::ZERO, 20.0, floor);
    for &(c, size, facing_up) in occluders {
        let h = size * 0.5;
        let mut q = [
            c + Vec3::new(-h, 0.0, h),
            c + Vec3::new(h, 0.0, h),
            c + Vec3::new(h, 0.0, -h),
            c + Vec3::new(-h, 0.0, -h),
        ];
        if !facing_up {
            q.reverse();
        }
        b.quad("occluder", q, black);
    }
    for l in lights {
        b.light(l);
    }
    b.build()
}

fn light(kind: LightKind, intensity: Rgb, position: Vec3, direction: Vec3, range: Option<f32>) -> PunctualLight {
    PunctualLight { name: "l".into(), kind, intensity, position, direction: direction.normalize(), range }
}

#[test]
fn directional_light_gives_i_cos_theta_and_nothing_in_shadow() {
    let i = Rgb::new(3.0, 2.0, 1.0);
    for deg in [0.0f32, 30.0, 60.0, 85.0, 95.0] {
        let th = deg.to_radians();
        let dir = Vec3::new(th.sin(), -th.cos(), 0.0);
        let occ = [(Vec3::new(5.0, 1.0, 5.0), 2.0, true), (Vec3::new(-5.0, 1.0, -5.0), 2.0, false)];
        let s = floor_scene(vec![light(LightKind::Directional, i, Vec3::ZERO, dir, None)], &occ);
        let t = ReferenceTracer::new(&s);
        let want = i * th.cos().max(0.0);
        for p in [Vec3::ZERO, Vec3::new(2.0, 0.0, -1.5)] {
            close(estimate(&t, p, Vec3::Y, 64).e, want, &format!("{deg}° at {p}"));
        }
        // Under each occluder, along the light's direction (both the front and the back of a
        // single-sided face block light).
        for c in [Vec3::new(5.0, 1.0, 5.0), Vec3::new(-5.0, 1.0, -5.0)] {
            if deg < 90.0 {
                let p = c + dir * (1.0 / th.cos());
                assert_eq!(estimate(&t, p, Vec3::Y, 64).e, Rgb::ZERO, "{deg}°: shadow under {c}");
            }
        }
    }
}

#[test]
fn point_light_gives_i_cos_over_d_squared() {
    let i = Rgb::new(10.0, 5.0, 2.5);
    let lp = Vec3::new(0.3, 2.0, -0.4);
    let s = floor_scene(vec![light(LightKind::Point, i, lp, Vec3::NEG_Y, None)], &[]);
    let t = ReferenceTracer::new(&s);
    for p in [Vec3::ZERO, Vec3::new(1.5, 0.0, 0.5), Vec3::new(-4.0, 0.0, 3.0), Vec3::new(0.3, 0.0, -0.4)] {
        let d = lp - p;
        let want = i * (d.normalize().y / d.length_squared());
        close(estimate(&t, p, Vec3::Y, 16).e, want, &format!("point light at {p}"));
    }
    // A tilted receiver: cos between its normal and the light direction.
    let n = Vec3::new(0.6, 0.8, 0.0);
    let p = Vec3::new(1.0, 0.0, 1.0);
    let d = lp - p;
    close(estimate(&t, p, n, 16).e, i * (n.dot(d.normalize()) / d.length_squared()), "tilted receiver");
}

#[test]
fn spot_light_cones_follow_gltf_quadratic_falloff() {
    let i = Rgb::splat(8.0);
    let h = 2.0;
    let (inner, outer) = (20.0f32.to_radians(), 30.0f32.to_radians());
    let lp = Vec3::new(0.0, h, 0.0);
    let s = floor_scene(
        vec![light(LightKind::Spot { inner_cone: inner, outer_cone: outer }, i, lp, Vec3::NEG_Y, None)],
        &[],
    );
    let t = ReferenceTracer::new(&s);
    for deg in [0.0f32, 10.0, 19.0, 21.0, 25.0, 29.0, 31.0, 40.0] {
        let a = deg.to_radians();
        let p = Vec3::new(h * a.tan(), 0.0, 0.0);
        let d2 = (lp - p).length_squared();
        // Written out independently of PunctualLight: t = (cos a − cos outer)/(cos inner − cos outer).
        let tt = ((a.cos() - outer.cos()) / (inner.cos() - outer.cos())).clamp(0.0, 1.0);
        let want = i * (a.cos() / d2 * tt * tt);
        close(estimate(&t, p, Vec3::Y, 16).e, want, &format!("spot at {deg}°"));
        if deg > 30.0 {
            assert_eq!(estimate(&t, p, Vec3::Y, 16).e, Rgb::ZERO);
        }
    }
}

#[test]
fn range_window_fades_point_lights_out() {
    let i = Rgb::splat(4.0);
    let lp = Vec3::new(0.0, 1.0, 0.0);
    let range = 3.0f32;
    let s = floor_scene(vec![light(LightKind::Point, i, lp, Vec3::NEG_Y, Some(range))], &[]);
    let t = ReferenceTracer::new(&s);
    for x in [0.0f32, 1.0, 2.0, 2.8, 2.9, 3.5] {
        let p = Vec3::new(x, 0.0, 0.0);
        let d = (lp - p).length();
        let win = (1.0 - (d / range).powi(4)).clamp(0.0, 1.0).powi(2);
        let want = i * ((1.0 / d) / (d * d) * win);
        close(estimate(&t, p, Vec3::Y, 16).e, want, &format!("range at d = {d}"));
        if d >= range {
            assert_eq!(estimate(&t, p, Vec3::Y, 16).e, Rgb::ZERO);
        }
    }
}

#[test]
fn many_lights_are_sampled_without_bias() {
    // 12 point lights (> all_lights_up_to = 8): one light per vertex is chosen by its
    // unoccluded luminance. Exact E = Σ Iᵢ cosθᵢ/dᵢ². The per-path estimate is Eᵢ·Y/Yᵢ
    // (Y = luminance): exact in luminance, noisy only through the lights' different colours:
    // measured σ_mean ≤ 0.5% at 4096 paths; bound 1%; 5σ rule, rounding floor.
    let mut lights = Vec::new();
    let mut want = Rgb::ZERO;
    let p = Vec3::new(0.2, 0.0, -0.1);
    for k in 0..12 {
        let a = k as f32 * 0.7;
        let lp = Vec3::new(2.0 * a.cos(), 1.0 + 0.2 * k as f32, 2.0 * a.sin());
        let i = Rgb::new(1.0 + k as f32, 2.0, 0.5 + 0.1 * k as f32);
        let d = lp - p;
        want += i * (d.normalize().y / d.length_squared());
        lights.push(light(LightKind::Point, i, lp, Vec3::NEG_Y, None));
    }
    let s = floor_scene(lights, &[]);
    let t = ReferenceTracer::new(&s);
    let est = estimate(&t, p, Vec3::Y, 4096);
    super::assert_estimate(&est, want, 0.01, 1e-5, "12 point lights");
}

/// `punctual_irradiance` (one shadow ray per light and texel, with its shadow cache) in a
/// 3 × 3 block of closed rooms, a point light in each: a floor point sees its own room's
/// light, I·cos θ / d², and none of the eight others (walls between). The points run room
/// after room, more than a worker's chunk, so the cache is reused across rooms, where the
/// last wall found is no longer between. Exact up to rounding (no sampling).
#[test]
fn rooms_see_their_own_light_only() {
    use crate::reference::Bvh;
    use crate::reference::punctual::punctual_irradiance;
    use crate::scene::SceneGeometry;
    let mut b = SceneBuilder::new();
    let wall = b.material(diffuse(Vec3::splat(0.5), Vec3::ZERO, false));
    let (size, height, gap) = (4.0f32, 3.0f32, 0.5f32);
    let intensity = Rgb::new(2.0, 1.0, 0.5);
    let mut rooms = Vec::new();
    for k in 0..9 {
        let lo = Vec3::new((k % 3) as f32 * (size + gap), 0.0, (k / 3) as f32 * (size + gap));
        b.cuboid("room", lo, lo + Vec3::new(size, height, size), true, wall);
        let light = lo + Vec3::new(0.3 * size, 0.8 * height, 0.6 * size);
        b.light(self::light(LightKind::Point, intensity, light, Vec3::NEG_Y, None));
        rooms.push((lo, light));
    }
    let scene = b.build();
    let geom = SceneGeometry::new(&scene);
    let bvh = Bvh::new(&geom);
    let (mut positions, mut want) = (Vec::new(), Vec::new());
    for &(lo, light) in &rooms {
        for i in 0..20 {
            for j in 0..20 {
                let p = lo + Vec3::new((i as f32 + 0.5) / 20.0 * size, 0.0, (j as f32 + 0.5) / 20.0 * size);
                let d = light - p;
                let cos = d.y / d.length();
                positions.push(p);
                want.push(intensity * (cos / d.length_squared()));
            }
        }
    }
    let normals = vec![Vec3::Y; positions.len()];
    for threads in [1, 2] {
        let got = punctual_irradiance(&scene, &bvh, &positions, &normals, 1e-4, threads);
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            close(*g, *w, &format!("floor point {i} ({threads} threads)"));
        }
    }
}
