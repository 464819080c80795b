//! Light through surfaces in the bundle bake: a floor under a `BLEND` pane, a tinted
//! `KHR_materials_transmission` pane and a `MASK` checkerboard, under a sun and a uniform
//! sky, against closed forms and the reference tracer, on the CPU backend and on the GPU
//! backend (lavapipe here), whose light maps equal the CPU's within the summation bound
//! ([`backend_bound`]).
//!
//! Every tolerance is argued from the sample count in the test that uses it.

mod support;

use livebake::analytic::polygon_irradiance;
use livebake::bake::{BackendKind, BakeConfig, BakeOutput};
use livebake::glam::{Vec2, Vec3, Vec4};
use livebake::reference::{ReferenceTracer, RelativeRmsError};
use livebake::scene::builder::diffuse;
use livebake::scene::{AlphaMode, Material, Rgb, Scene, SceneBuilder, Texture, TextureRef, UvTransform, WrapMode};

const TEXEL: f32 = 0.05;
const SUN: f32 = 2.0;
/// Half the pane's side; it lies at height `PANE_Y` over a 2 × 2 m floor.
const PANE_H: f32 = 0.6;
const PANE_Y: f32 = 0.5;

fn config(backend: BackendKind, directions: u32) -> BakeConfig {
    let mut c = BakeConfig { backend, samples: directions, ..BakeConfig::default() };
    c.atlas.texel_size = Some(TEXEL);
    c
}

fn run(scene: &Scene, config: &BakeConfig) -> BakeOutput {
    support::bake(scene, config)
}

/// The bundle backends every case runs on.
const BACKENDS: [BackendKind; 2] = [BackendKind::Cpu, BackendKind::Gpu];

/// How far (relative, per channel) a texel's irradiance may differ between the GPU and the
/// CPU backends baking the same scene with `config`'s directions. Both make the same hits
/// (the GPU resolve makes each decision with the CPU's rounding: sides, layers, each
/// fragment's transmittance from the same texture texels, cut-outs), and the punctual and
/// light passes are the CPU's on both, so the light maps differ only by how hits are added.
/// In a batch of d directions a texel gets k ≤ 2·d·(2·os + 1)² hits (the bound of the
/// backends' batch test); the CPU adds them in f32 in its lanes (relative error ≤
/// (k + lanes)·u, u = 2⁻²⁴, for non-negative terms), the GPU exactly, rounding once: a
/// batch's sums S and A differ by δ ≤ (k + lanes + 2)·u. Batch b reads a source made from
/// batch b − 1's E = π·S/A (non-negative sums again), so its relative difference ε grows
/// by at most 2δ and a few roundings (5u) a batch; the result weighs the batches
/// (non-negative weights, one rounding each). Over D directions in B ≤ D batches:
/// ε ≤ (4·D·(2·os + 1)² + 2·D·(lanes + 5))·u, lanes ≤ 64 (`MAX_LANES`). For 256 directions
/// at oversampling 2 that is 3.6·10⁻³. (A line credited to another texel, or seen through
/// a pane with another T, moves a texel by a whole hit; the backends' batch test holds
/// that apart per batch, at ≤ 10⁻⁵.)
fn backend_bound(config: &BakeConfig) -> f32 {
    let d = config.samples as f64;
    let os = config.bundle.oversampling as f64;
    let lanes = livebake::bundle::MAX_LANES as f64;
    ((4.0 * d * (2.0 * os + 1.0).powi(2) + 2.0 * d * (lanes + 5.0)) * 2f64.powi(-24)) as f32
}

/// The largest relative difference of any channel of any texel between the two bakes'
/// LOD 0, after checking it is within [`backend_bound`] (`what` names the case).
fn assert_backends_agree(what: &str, cpu: &BakeOutput, gpu: &BakeOutput, config: &BakeConfig) -> f32 {
    assert_eq!(cpu.lods[0].texels.position, gpu.lods[0].texels.position, "{what}: one atlas");
    let bound = backend_bound(config);
    let mut worst = 0f32;
    for (i, (c, g)) in cpu.lods[0].irradiance.iter().zip(&gpu.lods[0].irradiance).enumerate() {
        let d = (*c - *g).abs() / c.abs().max(g.abs()).max(Vec3::splat(f32::MIN_POSITIVE));
        let d = d.max_element();
        assert!(d <= bound, "{what}: texel {i}: CPU {c} GPU {g} ({d:e} > {bound:e})");
        worst = worst.max(d);
    }
    eprintln!("{what}: GPU against CPU, worst relative difference {worst:e} (bound {bound:e})");
    worst
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
    let cases = [("BLEND α 0.4", blend, Rgb::splat(0.6)), ("tinted transmission", glass, tint)];
    for (pane_kind, pane, pass) in cases {
        let mut sky_part = Vec::new();
        for backend in BACKENDS {
            let what = format!("{pane_kind} ({backend:?})");
            sky_part.push(check_the_floor_under_a_pane(&what, &pane, pass, backend));
        }
        assert_backends_agree(pane_kind, &sky_part[0], &sky_part[1], &config(BackendKind::Gpu, 256));
    }
}

/// [`a_floor_under_a_pane_gets_the_light_the_pane_passes`] on one backend: its sky-lit bake.
fn check_the_floor_under_a_pane(what: &str, pane: &Material, pass: Rgb, backend: BackendKind) -> BakeOutput {
    // The sun alone (the punctual pass: exact at the texel's points, f32 rounding; the
    // bundles add nothing, the floor seeing only the pane's back and a black sky), then
    // the sky alone.
    let sunlit = run(&pane_scene(pane.clone(), true, false), &config(backend, 16));
    let out = run(&pane_scene(pane.clone(), false, true), &config(backend, 256));
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
    out
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
                base_color_texture: Some(TextureRef::new(0)),
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
    // The sun on both backends (the punctual pass is the same code on both; the GPU's
    // bundles must not add light where the CPU's add none).
    let sunlit: Vec<BakeOutput> = BACKENDS.map(|b| run(&mask(true, false), &config(b, 16))).into();
    let texels = floor_texels(&sunlit[0]);
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
        for (backend, out) in BACKENDS.iter().zip(&sunlit) {
            let got = out.lods[0].irradiance[i].x;
            assert!((got - want).abs() <= 1e-5 * SUN, "{backend:?}: sun at {p}: {got} vs {want}");
        }
    }
    assert!(holes > 100 && solid > 100, "{holes} texels under holes, {solid} under the solid quadrants");
    // Per texel against the reference tracer (4096 paths; reference noise removed by
    // RelativeRmsError): the bundle noise at 256 directions of the sky seen through or
    // stopped by the quadrants is a few percent, as in the BLEND case; bound 5%. A pane
    // taken as whole (no holes) is off by far more at the texels under it.
    let scene = mask(true, true);
    let sky_config = |b| config(b, 256);
    let outs: Vec<BakeOutput> = BACKENDS.map(|b| run(&scene, &sky_config(b))).into();
    let tracer = ReferenceTracer::new(&scene);
    let picks: Vec<usize> = clear.iter().step_by(clear.len() / 150).map(|&(i, _)| i).collect();
    let t = &outs[0].lods[0].texels;
    let queries: Vec<(Vec3, Vec3)> = picks.iter().map(|&i| (t.position[i], t.normal[i])).collect();
    let (reference, _) = tracer.irradiance_batch_estimates(&queries, 4096, 3, &|_| {});
    for (backend, out) in BACKENDS.iter().zip(&outs) {
        let mut error = RelativeRmsError::default();
        for (&i, r) in picks.iter().zip(&reference) {
            error.add(out.lods[0].irradiance[i].as_dvec3(), r.e.as_dvec3(), r.stderr.as_dvec3());
        }
        let e = error.value();
        eprintln!("MASK checkerboard ({backend:?}): relative RMS error against the reference {e:.4}");
        assert!(e < 0.05, "{backend:?}: {e}");
    }
    assert_backends_agree("MASK checkerboard, sun", &sunlit[0], &sunlit[1], &config(BackendKind::Gpu, 16));
    assert_backends_agree("MASK checkerboard, sun and sky", &outs[0], &outs[1], &sky_config(BackendKind::Gpu));
}

/// A cut-out pane read through `KHR_texture_transform` (or from TEXCOORD_1) casts the shadow of
/// the same pane whose TEXCOORD_0 holds the transformed coordinates, written here by hand
/// from the extension's rule uv' = T·R·S·uv at the pane's corners (0, 0), (1, 0), (1, 1),
/// (0, 1). The texture is 4 × 4 with its top-left 2 × 2 texels solid (no symmetry: a
/// rotation the wrong way round, or any transform dropped, casts another shadow).
#[test]
fn a_texture_transform_moves_a_cut_out_where_the_extension_puts_it() {
    let pane = |texture: TextureRef, uv0: [[f32; 2]; 4], uv1: Option<[[f32; 2]; 4]>, sun: bool, sky: bool| {
        let material = Material {
            base_color_texture: Some(texture),
            alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
            ..Material::default()
        };
        let mut scene = pane_scene(material, sun, sky);
        scene.meshes[1].uv0 = Some(uv0.map(Vec2::from).to_vec());
        scene.meshes[1].uv1 = uv1.map(|uv| uv.map(Vec2::from).to_vec());
        let solid = |i: usize| (i % 4 < 2 && i / 4 < 2) as u8 * 255;
        scene.textures.push(Texture {
            name: "quadrant".into(),
            width: 4,
            height: 4,
            rgba8: (0..16).map(|i| [255, 255, 255, solid(i)]).collect::<Vec<_>>().into(),
            srgb: true,
            wrap_s: WrapMode::Repeat,
            wrap_t: WrapMode::Repeat,
        });
        scene
    };
    let square_uv = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]];
    let read = |tex_coord, transform| TextureRef { texture: 0, tex_coord, transform };
    let plain = read(0, UvTransform::IDENTITY);
    // The light map must not come from TEXCOORD_1 here (it is the light-map UV candidate).
    let cfg = |backend, directions| {
        let mut c = config(backend, directions);
        c.atlas.use_uv1 = false;
        c
    };
    // Offset (0.25, 0.5), scale (0.5, 2): uv' = (0.5u + 0.25, 2v + 0.5), exact in f32, so the
    // bakes must be the same bits, sun and sky, on both backends; and so must a texture read
    // from TEXCOORD_1 through it.
    let shifted = read(0, UvTransform::new(Vec2::new(0.25, 0.5), 0.0, Vec2::new(0.5, 2.0)));
    let by_hand = [[0.25, 0.5], [0.75, 0.5], [0.75, 2.5], [0.25, 2.5]];
    let from_uv1 = read(1, UvTransform::new(Vec2::new(0.25, 0.5), 0.0, Vec2::new(0.5, 2.0)));
    for backend in BACKENDS {
        let c = cfg(backend, 64);
        let want = run(&pane(plain, by_hand, None, true, true), &c);
        for (what, scene) in [
            ("offset and scale", pane(shifted, square_uv, None, true, true)),
            ("offset and scale on TEXCOORD_1", pane(from_uv1, [[0.0, 0.0]; 4], Some(square_uv), true, true)),
        ] {
            let got = run(&scene, &c);
            assert_eq!(got.lods[0].texels.position, want.lods[0].texels.position, "{what}: one atlas");
            assert!(got.lods[0].irradiance == want.lods[0].irradiance, "{backend:?}: {what}: not the same light map");
        }
    }
    // Rotation π/2 and offset (0, 1): uv' = (v, 1 − u). cos(π/2) rounds to −4.4·10⁻⁸ in f32,
    // so the coordinates differ from the hand-written ones by that much, far below a
    // texture texel (0.25): the sun's points (the punctual pass, four a texel) land on the
    // same side of the cut-out's edge, and each texel's sun is the same to rounding.
    let turned = read(0, UvTransform::new(Vec2::new(0.0, 1.0), std::f32::consts::FRAC_PI_2, Vec2::ONE));
    let by_hand = [[0.0, 1.0], [0.0, 0.0], [1.0, 0.0], [1.0, 1.0]];
    let c = cfg(BackendKind::Cpu, 16);
    let want = run(&pane(plain, by_hand, None, true, false), &c);
    let got = run(&pane(turned, square_uv, None, true, false), &c);
    let untransformed = run(&pane(plain, square_uv, None, true, false), &c);
    let (mut moved, mut checked) = (0, 0);
    for (i, _) in floor_texels(&want) {
        let (w, g) = (want.lods[0].irradiance[i], got.lods[0].irradiance[i]);
        assert!((w - g).abs().max_element() <= 1e-5 * SUN, "rotation: floor texel {i}: {g} vs {w}");
        moved += ((untransformed.lods[0].irradiance[i] - w).abs().max_element() > 0.5 * SUN) as u32;
        checked += 1;
    }
    // The solid quadrant's shadow moves by a quarter turn: a quarter of the pane's
    // ~580 floor texels at this texel size gain the sun and another quarter lose it.
    assert!(
        moved > 100,
        "the rotated pane's shadow is where the untransformed one's is ({moved} of {checked} texels moved)"
    );
}

/// Vertex colours (glTF COLOR_0) multiply the base colour and its alpha, wherever light
/// meets the surface:
/// - a see-through pane (`BLEND`, transmission 0.5) coloured (0.8, 0.4, 0.2, α 0.5) at every
///   vertex bakes the same bits as the same pane whose material factor is that colour, on
///   the CPU and on the GPU backend, sun and sky (the floor under it gets the tinted
///   T = (1 − α) + α·t·a; the pane's own texels its albedo);
/// - a `MASK` pane whose vertex alpha runs 0 → 1 across it (cutoff 0.5) is cut out on its
///   α < 0.5 half, x < 0: under a sun alone the floor gets the whole sun there and none
///   under the other half (the punctual pass), and both backends agree through the cut-out
///   under a sky;
/// - a floor coloured by a gradient holds, per texel, its factor times the colour at the
///   texel's point (the colour is affine in x, so the point's colour is that of its x).
#[test]
fn vertex_colours_tint_and_cut_out_as_the_base_colour_does() {
    let colored = |material: Material, colors: [Vec4; 4], sun: bool, sky: bool| {
        let mut scene = pane_scene(material, sun, sky);
        scene.meshes[1].colors = Some(colors.to_vec());
        scene
    };
    let tint = Vec4::new(0.8, 0.4, 0.2, 0.5);
    let glass =
        |base_color| Material { base_color, alpha_mode: AlphaMode::Blend, transmission: 0.5, ..Material::default() };
    for backend in BACKENDS {
        let c = config(backend, 64);
        let want = run(&pane_scene(glass(tint), true, true), &c);
        let got = run(&colored(glass(Vec4::ONE), [tint; 4], true, true), &c);
        assert_eq!(got.lods[0].texels.position, want.lods[0].texels.position, "one atlas");
        assert!(got.lods[0].texels.albedo == want.lods[0].texels.albedo, "{backend:?}: the pane's albedo");
        assert!(got.lods[0].irradiance == want.lods[0].irradiance, "{backend:?}: not the same light map");
        // The tint reaches the floor: the sun alone gives red SUN·α·t·(a_r − a_b) = 0.3 more
        // than blue under the pane (T's channels), and the sky through it adds to that.
        let (i, _) = floor_texels(&got).into_iter().find(|(_, p)| p.x.abs() < 0.3 && p.z.abs() < 0.3).unwrap();
        let e = got.lods[0].irradiance[i];
        assert!(e.x - e.z > 0.3, "{backend:?}: the floor under the tinted pane is not tinted: {e}");
    }

    // Alpha 0 on the pane's x = −h corners (0 and 3), 1 on the x = +h ones.
    let ramp = [Vec4::new(1.0, 1.0, 1.0, 0.0), Vec4::ONE, Vec4::ONE, Vec4::new(1.0, 1.0, 1.0, 0.0)];
    let grille = Material { alpha_mode: AlphaMode::Mask { cutoff: 0.5 }, ..Material::default() };
    let out = run(&colored(grille.clone(), ramp, true, false), &config(BackendKind::Cpu, 16));
    let (mut lit, mut shaded) = (0, 0);
    for (i, p) in floor_texels(&out) {
        // Away from the cut-out's edge (x = 0) by a texel.
        if p.x.abs().max(p.z.abs()) > PANE_H || p.x.abs() < TEXEL {
            continue;
        }
        let e = out.lods[0].irradiance[i].x;
        let want = if p.x < 0.0 { SUN } else { 0.0 };
        assert!((e - want).abs() <= 1e-4 * SUN, "floor texel at {p}: {e}, want {want}");
        (lit, shaded) = (lit + (p.x < 0.0) as u32, shaded + (p.x > 0.0) as u32);
    }
    assert!(lit > 50 && shaded > 50, "{lit} lit and {shaded} shaded floor texels checked");
    let sky = |backend| config(backend, 32);
    let cpu = run(&colored(grille.clone(), ramp, false, true), &sky(BackendKind::Cpu));
    let gpu = run(&colored(grille, ramp, false, true), &sky(BackendKind::Gpu));
    assert_backends_agree("vertex-alpha cut-out, sky", &cpu, &gpu, &sky(BackendKind::Gpu));

    // A floor whose colour runs from (1, 0, 0) at x = −1 to (0, 1, 0) at x = 1.
    let mut scene = pane_scene(Material::default(), true, false);
    let floor = &mut scene.meshes[0];
    let color_at = |x: f32| Vec4::new((1.0 - x) * 0.5, (1.0 + x) * 0.5, 0.0, 1.0);
    floor.colors = Some(floor.positions.iter().map(|p| color_at(p.x)).collect());
    let out = run(&scene, &config(BackendKind::Cpu, 4));
    let t = &out.lods[0].texels;
    let floor_ids: Vec<usize> = (0..t.len()).filter(|&i| t.position[i].y.abs() < 1e-4).collect();
    assert!(floor_ids.len() > 1000, "{} floor texels", floor_ids.len());
    for i in floor_ids {
        let want = color_at(t.position[i].x).truncate() * 0.5;
        assert!(
            (t.albedo[i] - want).abs().max_element() < 1e-5,
            "floor texel at {}: {} vs {want}",
            t.position[i],
            t.albedo[i]
        );
    }
}

/// Khronos GlassBrokenWindow (transmission glass, a MASK for the broken part) under a
/// uniform sky: `probe` (a whole bake at the defaults, 256 directions) at 256 texel centres
/// against the Mitsuba tool (16 384 spp, its variance removed by RelativeRmsError).
/// Measured: 0.57 % (1.5 % at 64 directions, falling with them: the error is the directions'
/// noise). The glass taken as opaque (no transmission, no cut-out) gives 3.5 % at these
/// points (most of them see little through the pane), so the bound, 2 % (3.5× the measured
/// figure), is where this test tells glass from no glass. On both backends; the GPU's
/// points equal the CPU's within [`backend_bound`] (a point reads its texels bilinearly:
/// non-negative weights, so the texels' relative bound holds for it, plus a rounding).
#[test]
fn glass_broken_window_matches_mitsuba_under_a_sky() {
    let dir = tempfile::tempdir().unwrap();
    let asset = |f: &str| format!("{}/assets/glass_broken_window/{f}", env!("CARGO_MANIFEST_DIR"));
    let read = |p: &str| -> serde_json::Value { serde_json::from_str(&std::fs::read_to_string(p).unwrap()).unwrap() };
    let rgb = |v: &serde_json::Value| {
        livebake::glam::DVec3::new(v[0].as_f64().unwrap(), v[1].as_f64().unwrap(), v[2].as_f64().unwrap())
    };
    let want = read(&asset("mitsuba_sky.json"));
    let want = want["points"].as_array().unwrap();
    let mut points = Vec::new();
    for backend in ["cpu", "gpu"] {
        let out = dir.path().join(format!("probe-{backend}.json"));
        let args = [
            "-q",
            "probe",
            &asset("GlassBrokenWindow.gltf"),
            "--sky",
            "1",
            "--points",
            &asset("points.json"),
            "--backend",
            backend,
            "--out",
            out.to_str().unwrap(),
        ];
        support::ok(dir.path(), &args);
        let got: Vec<livebake::glam::DVec3> =
            read(out.to_str().unwrap())["points"].as_array().unwrap().iter().map(|g| rgb(&g["E"])).collect();
        assert_eq!(got.len(), want.len());
        let mut error = RelativeRmsError::default();
        for (g, w) in got.iter().zip(want) {
            error.add(*g, rgb(&w["E"]), rgb(&w["E_stderr"]));
        }
        let e = error.value();
        eprintln!("GlassBrokenWindow under a sky ({backend}): relative RMS error against Mitsuba {e:.4}");
        assert!(e < 0.02, "{backend}: {e}");
        points.push(got);
    }
    // Plus the taps' weighted sum and renormalisation: a few roundings each.
    let bound = backend_bound(&BakeConfig::default()) as f64 + 8.0 * 2f64.powi(-24);
    let mut worst = 0f64;
    for (k, (c, g)) in points[0].iter().zip(&points[1]).enumerate() {
        let d = ((*c - *g).abs() / c.abs().max(g.abs()).max(livebake::glam::DVec3::splat(1e-30))).max_element();
        assert!(d <= bound, "point {k}: CPU {c} GPU {g} ({d:e} > {bound:e})");
        worst = worst.max(d);
    }
    eprintln!("GlassBrokenWindow: GPU against CPU, worst relative difference {worst:e} (bound {bound:e})");
}
