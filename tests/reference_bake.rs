//! Analytic cases through the whole bake pipeline: `bake()` with the reference backend on
//! small synthetic scenes, every texel (or every texel of the surface the closed form is
//! about) checked against its exact irradiance, computed from the texel's own position and
//! normal. The reference tracer's unit tests already check the estimator at chosen points;
//! these check what the pipeline adds: unwrap, pack, texel maps (positions, normals, sides,
//! clamped edge texels), seeds and sample counts, and the order of the results.
//!
//! Scenes are deliberately not aligned to the texel grid (sizes are not multiples of the
//! texel size), so charts have partly covered edge texels whose positions are clamped onto
//! the face.
//!
//! Tolerances:
//! * Zero-variance cases (sky over an open plane, punctual lights over planes: every path
//!   returns the same value) are checked to f32 rounding: 1e-5 relative.
//! * Monte Carlo cases (furnace, emissive quad) are checked per texel against 5.5σ, σ being
//!   the standard error of a texel's mean over N paths, estimated by an independent run of
//!   the reference tracer at the same texel queries (other seed, same N). A Gaussian
//!   deviation beyond 5.5σ has probability 3.8e-8; with ≤ 6k texel-channels per test that is
//!   < 3e-4 per test and seed. The mean over texels is checked at 5σ of its own standard
//!   error (√Σσᵢ² / M), which is a few hundredths of a percent: that is where bias shows.
//!   The ratio rms(error) / rms(σ) must be near 1 (the bake really averages N paths per
//!   texel, and texels are independent), and σ itself is bounded so a noisy estimator cannot
//!   pass by having wide error bars. Measured over 25 seeds of both Monte Carlo tests:
//!   largest deviation 4.8σ, noise ratio 0.96–1.06, mean errors within 2.4σ.

use glam::{DVec3, Quat, Vec3};
use livebake::analytic::polygon_irradiance;
use livebake::atlas::AtlasConfig;
use livebake::bake::{BackendKind, BakeConfig, BakeOutput, bake};
use livebake::progress::NoProgress;
use livebake::reference::ReferenceTracer;
use livebake::scene::builder::diffuse;
use livebake::scene::{Rgb, Scene, SceneBuilder, SceneGeometry, Side};

// ---------------------------------------------------------------------------------------------
// helpers

/// One LOD baked by the reference backend at `texel` metres per texel with `spp` paths.
fn bake_reference(scene: &Scene, texel: f32, spp: u32, seed: u64) -> BakeOutput {
    let config = BakeConfig {
        atlas: AtlasConfig { texel_size: Some(texel), ..AtlasConfig::default() },
        lods: 1,
        samples: spp,
        backend: BackendKind::Reference,
        seed,
        ..BakeConfig::default()
    };
    let out = bake(&std::sync::Arc::new(scene.clone()), &config, &NoProgress).expect("bake");
    assert_eq!(out.lods.len(), 1);
    let lod = &out.lods[0];
    assert_eq!(lod.irradiance.len(), lod.texels.len());
    assert!(!lod.texels.is_empty());
    assert_eq!(out.report.lods[0].samples_per_texel, spp);
    out
}

/// Texels (of LOD 0) on mesh `mesh`.
fn texels_of_mesh(scene: &Scene, out: &BakeOutput, mesh: u32) -> Vec<usize> {
    let g = SceneGeometry::new(scene);
    let t = &out.lods[0].texels;
    (0..t.len()).filter(|&i| g.mesh[out.atlas.faces[t.face[i] as usize].tri as usize] == mesh).collect()
}

/// Every texel of the bake equals `exact(position, normal)` to f32 rounding (1e-5 relative,
/// plus 1e-6 W/m² absolute for texels whose exact value is 0).
#[track_caller]
fn assert_exact(out: &BakeOutput, texels: &[usize], exact: impl Fn(Vec3, Vec3) -> Rgb, what: &str) {
    let lod = &out.lods[0];
    assert!(!texels.is_empty(), "{what}: no texels");
    for &i in texels {
        let (p, n) = (lod.texels.position[i], lod.texels.normal[i]);
        let (e, x) = (lod.irradiance[i], exact(p, n));
        for c in 0..3 {
            assert!(
                (e[c] - x[c]).abs() <= 1e-5 * x[c].abs() + 1e-6,
                "{what}: texel {i} at {p} (n = {n}) channel {c}: E = {}, exact {}",
                e[c],
                x[c]
            );
        }
    }
}

/// What [`assert_noisy`] measured (printed with `--nocapture`).
#[derive(Debug)]
#[allow(dead_code)]
struct NoiseReport {
    texels: usize,
    /// Largest |E − exact| / σ over texels and channels.
    max_z: f64,
    /// Mean over texels of E − exact, relative to the mean exact value, per channel.
    mean_rel_error: [f64; 3],
    /// Standard error of that mean, relative.
    mean_rel_sigma: [f64; 3],
    /// rms(E − exact) / rms(σ), per channel.
    noise_ratio: [f64; 3],
}

/// Checks the Monte Carlo texels `texels` of `out` (baked with `spp` paths) against `exact`
/// (see the module docs for the rules). `floor` is a relative allowance for what is not
/// noise (the ray origin's ε offset); `max_rel_sigma` bounds the relative standard error of
/// the mean over texels.
#[track_caller]
#[allow(clippy::too_many_arguments)]
fn assert_noisy(
    scene: &Scene,
    out: &BakeOutput,
    texels: &[usize],
    exact: &[Rgb],
    spp: u32,
    floor: f64,
    max_rel_sigma: f64,
    what: &str,
) -> NoiseReport {
    let lod = &out.lods[0];
    let m = texels.len();
    assert!(m >= 300, "{what}: only {m} texels");
    // σ per texel: an independent estimate at the same queries with the same path count.
    let queries: Vec<(Vec3, Vec3)> = texels.iter().map(|&i| (lod.texels.position[i], lod.texels.normal[i])).collect();
    let tracer = ReferenceTracer::new(scene);
    let (est, _) = tracer.irradiance_batch_estimates(&queries, spp, 0x51_6e_a5, &|_| {});
    let mut max_z = 0.0f64;
    let (mut sum_err, mut sum_exact, mut sum_var, mut sum_err2) = (DVec3::ZERO, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
    for (k, &i) in texels.iter().enumerate() {
        let (e, x, s) = (lod.irradiance[i].as_dvec3(), exact[k].as_dvec3(), est[k].stderr.as_dvec3());
        for c in 0..3 {
            let err = e[c] - x[c];
            let z = err.abs() / s[c].max(1e-30);
            max_z = max_z.max(z);
            assert!(
                err.abs() <= 5.5 * s[c] + floor * x[c].abs(),
                "{what}: texel {i} at {} (n = {}) channel {c}: E = {} ± {} (σ), exact {} ({z:.2}σ)",
                lod.texels.position[i],
                lod.texels.normal[i],
                e[c],
                s[c],
                x[c]
            );
        }
        sum_err += e - x;
        sum_err2 += (e - x) * (e - x);
        sum_exact += x;
        sum_var += s * s;
    }
    let mf = m as f64;
    let mut report =
        NoiseReport { texels: m, max_z, mean_rel_error: [0.0; 3], mean_rel_sigma: [0.0; 3], noise_ratio: [0.0; 3] };
    for c in 0..3 {
        let mean_exact = sum_exact[c] / mf;
        let mean_err = sum_err[c] / mf;
        let sigma_mean = sum_var[c].sqrt() / mf;
        report.mean_rel_error[c] = mean_err / mean_exact;
        report.mean_rel_sigma[c] = sigma_mean / mean_exact;
        report.noise_ratio[c] = (sum_err2[c] / sum_var[c]).sqrt();
        assert!(
            sigma_mean <= max_rel_sigma * mean_exact,
            "{what}: channel {c}: σ of the mean {sigma_mean} is above {max_rel_sigma} of {mean_exact}"
        );
        assert!(
            mean_err.abs() <= 5.0 * sigma_mean + floor * mean_exact,
            "{what}: channel {c}: mean error {mean_err} over {m} texels (σ {sigma_mean}, mean exact {mean_exact})"
        );
        // rms(error)/rms(σ): both are averages over M ≥ 300 texels, so the ratio's own
        // spread is about 1/√(2M) ≤ 4% (more with heavy-tailed paths); ±20% is far outside
        // that, and far inside a factor of 2 (a bake averaging N/4 paths per texel).
        let ratio = report.noise_ratio[c];
        assert!((0.8..=1.2).contains(&ratio), "{what}: channel {c}: rms error / rms σ = {ratio:.3}");
    }
    eprintln!("{what}: {report:?}");
    report
}

// ---------------------------------------------------------------------------------------------
// furnace

#[test]
fn furnace_every_texel_sees_le_over_one_minus_rho() {
    // A closed box, faces looking in, albedo ρ = 0.5 and emission Le everywhere: the
    // radiance is L = Le/(1 − ρ) in every direction, so E = π·Le/(1 − ρ) at every texel.
    // The box is 1.03 × 0.77 × 0.91 m at 6 cm texels: no wall is a multiple of the texel.
    let rho = 0.5;
    let le = Rgb::new(1.0, 0.5, 0.25);
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Vec3::splat(rho), le, false));
    b.cuboid("furnace", Vec3::ZERO, Vec3::new(1.03, 0.77, 0.91), true, m);
    let scene = b.build();
    // 256 paths per texel. A path's estimate has a relative σ of ~0.4 here (measured:
    // next-event estimation at every vertex, Russian roulette after 3 bounces), so a
    // texel's σ is ~2.6% and the mean over ~1460 texels' ~0.07%: bounded at 0.15%.
    let spp = 256;
    let out = bake_reference(&scene, 0.06, spp, 7);
    let lod = &out.lods[0];
    let all: Vec<usize> = (0..lod.texels.len()).collect();
    // Every texel faces into the box.
    let centre = Vec3::new(1.03, 0.77, 0.91) * 0.5;
    for &i in &all {
        assert!(lod.texels.normal[i].dot(centre - lod.texels.position[i]) > 0.0, "texel {i} faces out");
    }
    let e = le * std::f32::consts::PI / (1.0 - rho);
    let exact = vec![e; all.len()];
    // Floor: the ray origin offset ε changes nothing in a furnace (L is the same
    // everywhere), so only f32 rounding: 1e-5.
    let r = assert_noisy(&scene, &out, &all, &exact, spp, 1e-5, 1.5e-3, "furnace");
    assert!(r.texels >= 1000, "{} texels", r.texels);
}

// ---------------------------------------------------------------------------------------------
// sky

#[test]
fn open_plane_under_a_uniform_sky_sees_pi_l() {
    // A double-sided plane (both faces light-mapped) alone under a uniform sky L: each face
    // sees the sky over its whole hemisphere, E = π·L, from every path (cosine-sampled rays
    // all escape): zero variance, so checked to f32 rounding.
    let sky = Rgb::new(0.3, 0.6, 0.9);
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Vec3::splat(0.8), Rgb::ZERO, true));
    let tilt = Quat::from_rotation_z(0.3);
    let corners =
        [Vec3::new(-1.1, 0.0, 0.9), Vec3::new(1.1, 0.0, 0.9), Vec3::new(1.1, 0.0, -0.9), Vec3::new(-1.1, 0.0, -0.9)]
            .map(|c| tilt * c);
    b.grid_quad("plane", corners, 3, m);
    b.sky(sky);
    let scene = b.build();
    let out = bake_reference(&scene, 0.07, 4, 1);
    let lod = &out.lods[0];
    let up = tilt * Vec3::Y;
    let (mut top, mut bottom) = (0, 0);
    for i in 0..lod.texels.len() {
        let side = out.atlas.faces[lod.texels.face[i] as usize].side;
        let n = lod.texels.normal[i];
        match side {
            Side::Front => {
                assert!((n - up).length() < 1e-5);
                top += 1;
            }
            Side::Back => {
                assert!((n + up).length() < 1e-5);
                bottom += 1;
            }
        }
    }
    assert_eq!(top, bottom, "both faces get the same texels");
    assert!(top >= 700, "{top} texels on top");
    let all: Vec<usize> = (0..lod.texels.len()).collect();
    assert_exact(&out, &all, |_, _| sky * std::f32::consts::PI, "plane under the sky");
}

// ---------------------------------------------------------------------------------------------
// punctual lights

#[test]
fn planes_under_a_directional_light_see_i_cos_theta() {
    // Three planes with different normals under a directional light of irradiance I
    // (W/m² on a surface facing it): E = I·max(0, cosθ), θ between the texel's normal and
    // the direction towards the light. No emitters, black sky and black planes (albedo 0:
    // a texel's E does not depend on its own albedo, and no light bounces between planes):
    // every path returns exactly the punctual term, so checked to f32 rounding. The planes
    // are placed so none shadows another (light comes from −x, up, −z; the tilted quad is
    // at +x, the wall at −x is low and far).
    let irradiance = Rgb::new(2.0, 1.5, 1.0);
    let dir = Vec3::new(0.3, -1.0, 0.2).normalize(); // direction the light travels in
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Rgb::ZERO, Rgb::ZERO, false));
    // Floor (normal +Y).
    b.grid_quad(
        "floor",
        [
            Vec3::new(-1.05, 0.0, 0.95),
            Vec3::new(1.05, 0.0, 0.95),
            Vec3::new(1.05, 0.0, -0.95),
            Vec3::new(-1.05, 0.0, -0.95),
        ],
        2,
        m,
    );
    // A quad tilted 40° about z, above the floor level at x ≈ 3 (normal (−sin 40°, cos 40°, 0):
    // facing the light more than the floor does).
    let rot = Quat::from_rotation_z(40f32.to_radians());
    let c = Vec3::new(3.0, 1.0, 0.0);
    b.quad(
        "tilted",
        [
            Vec3::new(-0.55, 0.0, 0.45),
            Vec3::new(0.55, 0.0, 0.45),
            Vec3::new(0.55, 0.0, -0.45),
            Vec3::new(-0.55, 0.0, -0.45),
        ]
        .map(|v| c + rot * v),
        m,
    );
    // A wall at x = −3 facing +x, away from the light: E = 0.
    b.quad(
        "wall",
        [Vec3::new(-3.0, 0.0, 0.5), Vec3::new(-3.0, 0.0, -0.5), Vec3::new(-3.0, 0.8, -0.5), Vec3::new(-3.0, 0.8, 0.5)],
        m,
    );
    b.directional_light(dir, irradiance);
    let scene = b.build();
    let g = SceneGeometry::new(&scene);
    assert!((g.normals[g.mesh_offsets[2] as usize] - Vec3::X).length() < 1e-6, "the wall faces +x");
    let out = bake_reference(&scene, 0.06, 4, 2);
    let all: Vec<usize> = (0..out.lods[0].texels.len()).collect();
    let exact = |_p: Vec3, n: Vec3| {
        let cos = (n.as_dvec3().dot(-dir.as_dvec3())).max(0.0);
        (irradiance.as_dvec3() * cos).as_vec3()
    };
    assert_exact(&out, &all, exact, "directional light");
    // Each plane is really there and lit as expected (not all zero by accident).
    let lod = &out.lods[0];
    for (mesh, lit) in [(0, true), (1, true), (2, false)] {
        let t = texels_of_mesh(&scene, &out, mesh);
        assert!(t.len() >= 100, "mesh {mesh}: {} texels", t.len());
        assert_eq!(t.iter().all(|&i| lod.irradiance[i].x > 0.1), lit, "mesh {mesh}");
    }
}

#[test]
fn plane_under_a_point_light_sees_i_cos_theta_over_d_squared() {
    // A floor under a point light of intensity I (W/sr) at l: E(p) = I·cosθ/d², d = |l − p|,
    // cosθ = n·(l − p)/d. Zero variance (no emitters, black sky): f32 rounding.
    let intensity = Rgb::new(3.0, 2.0, 1.0);
    let light = Vec3::new(0.2, 0.6, -0.1);
    let mut b = SceneBuilder::new();
    let m = b.material(diffuse(Vec3::splat(0.5), Rgb::ZERO, false));
    b.grid_quad(
        "floor",
        [
            Vec3::new(-1.05, 0.0, 0.95),
            Vec3::new(1.05, 0.0, 0.95),
            Vec3::new(1.05, 0.0, -0.95),
            Vec3::new(-1.05, 0.0, -0.95),
        ],
        3,
        m,
    );
    b.point_light(light, intensity);
    let scene = b.build();
    let out = bake_reference(&scene, 0.05, 4, 3);
    let all: Vec<usize> = (0..out.lods[0].texels.len()).collect();
    assert!(all.len() >= 1500);
    let exact = |p: Vec3, n: Vec3| {
        let to = light.as_dvec3() - p.as_dvec3();
        let d = to.length();
        let cos = (n.as_dvec3().dot(to) / d).max(0.0);
        (intensity.as_dvec3() * (cos / (d * d))).as_vec3()
    };
    assert_exact(&out, &all, exact, "point light");
    // The texel under the light is the brightest, by the expected factor over a far corner.
    let lod = &out.lods[0];
    let max = lod.irradiance.iter().map(|e| e.x).fold(0.0, f32::max);
    assert!((max - intensity.x / (0.6 * 0.6)).abs() < 0.02 * max, "peak {max}");
}

// ---------------------------------------------------------------------------------------------
// emissive quad

#[test]
fn floor_under_an_emissive_quad_matches_lamberts_polygon_formula() {
    // A 0.8 × 0.5 m emitter of radiance Le, tilted 20°, about 0.9 m above a 2.1 × 1.9 m
    // floor, facing down. The emitter is black (albedo 0), so light reflected by the floor
    // ends there: each floor texel's E is exactly the polygon formula. Floor texels only:
    // the emitter's own texels see the lit floor (no closed form).
    let le = Rgb::new(4.0, 2.0, 1.0);
    let mut b = SceneBuilder::new();
    let floor_m = b.material(diffuse(Vec3::splat(0.8), Rgb::ZERO, false));
    let emitter_m = b.material(diffuse(Vec3::ZERO, le, false));
    b.grid_quad(
        "floor",
        [
            Vec3::new(-1.05, 0.0, 0.95),
            Vec3::new(1.05, 0.0, 0.95),
            Vec3::new(1.05, 0.0, -0.95),
            Vec3::new(-1.05, 0.0, -0.95),
        ],
        3,
        floor_m,
    );
    // Corners CCW seen from below (so the front faces down), then tilted and moved.
    let rot = Quat::from_rotation_x(20f32.to_radians());
    let centre = Vec3::new(0.3, 0.9, -0.2);
    let emitter = [
        Vec3::new(-0.4, 0.0, -0.25),
        Vec3::new(0.4, 0.0, -0.25),
        Vec3::new(0.4, 0.0, 0.25),
        Vec3::new(-0.4, 0.0, 0.25),
    ]
    .map(|v| centre + rot * v);
    b.quad("emitter", emitter, emitter_m);
    let scene = b.build();
    let g = SceneGeometry::new(&scene);
    let emitter_normal = g.normals[g.mesh_offsets[1] as usize];
    assert!(emitter_normal.y < -0.9, "the emitter faces down: {emitter_normal}");
    // Every emitter corner above every floor point's horizon (the formula's premise).
    assert!(emitter.iter().all(|v| v.y > 0.7));

    // 1024 paths per texel: MIS between emitter sampling and cosine sampling keeps a path's
    // σ near 0.4 of the floor's mean E (measured; relatively more on dim texels far from
    // the emitter, which see it at grazing angles), so a texel's σ is ~1.2% of the mean and
    // the mean over ~1600 floor texels' ~0.03%: bounded at 0.1%. Floor 1e-4 relative: rays
    // start at p + ε·n (ε ≈ 3e-5 m here, emitter ≥ 0.7 m away: ≤ 1e-4).
    let spp = 1024;
    let out = bake_reference(&scene, 0.05, spp, 4);
    let floor = texels_of_mesh(&scene, &out, 0);
    let lod = &out.lods[0];
    let exact: Vec<Rgb> =
        floor.iter().map(|&i| polygon_irradiance(lod.texels.position[i], lod.texels.normal[i], &emitter, le)).collect();
    // The formula spans a wide range over the floor: the check covers bright and dim texels.
    let (lo, hi) = exact.iter().fold((f32::MAX, 0f32), |(lo, hi), e| (lo.min(e.x), hi.max(e.x)));
    assert!(hi > 4.0 * lo, "exact E from {lo} to {hi}");
    assert_noisy(&scene, &out, &floor, &exact, spp, 1e-4, 1e-3, "emissive quad");
}
