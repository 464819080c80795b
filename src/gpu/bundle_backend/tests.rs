use super::*;
use crate::atlas::texels::TexelMap;
use crate::bundle::target::WholeLod;
use crate::bundle::{BundleConfig, JobSequence};
use crate::gpu::bundle_analysis::tests::cornell;
use crate::scene::Rgb;

/// Sums of one batch of `directions` on the whole LOD-`lod` target of `scene`, from
/// both backends, with a made-up source (every texel a different colour, so that
/// which texel a line sees shows in the sums).
fn both(
    scene: &Arc<CpuScene>,
    lod: u32,
    first: u64,
    directions: u64,
) -> (TexelMap, BatchSums, BatchSums, PassStats, PassStats) {
    let bundle = &scene.bundle;
    let texels = TexelMap::build(&bundle.scene, &bundle.geom, &bundle.atlas, lod);
    let whole = WholeLod::new(&bundle.atlas, &texels);
    let target = whole.target(&texels);
    let own = crate::bundle::target::distinct_colours(texels.len());
    let source = SourceRadiance { own: &own, foreign: None };
    let jobs = JobSequence::new(bundle.config.seed, bundle.emitters.small.len(), bundle.config.light_directions);
    let batch: Vec<DirectionJob> = (first..first + directions).map(|i| jobs.job(i)).collect();
    let never = AtomicBool::new(false);
    let mut cpu = CpuBundleBackend::new(scene.clone(), 2);
    let mut cpu_sums = BatchSums::default();
    let t = Instant::now();
    let cpu_stats = cpu.trace_batch(&target, &batch, &source, &mut cpu_sums, &never).unwrap();
    let cpu_seconds = t.elapsed().as_secs_f64();
    let gpu_context = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
    let mut gpu = GpuBundleBackend::new(gpu_context, scene.clone(), 2, false).unwrap();
    let mut gpu_sums = BatchSums::default();
    let t = Instant::now();
    let stats = gpu.trace_batch(&target, &batch, &source, &mut gpu_sums, &never).unwrap();
    // For the record (timings are the bench's business, never asserted here).
    eprintln!("batch of {directions}: CPU {cpu_seconds:.2} s, GPU {:.2} s", t.elapsed().as_secs_f64());
    (texels, cpu_sums, gpu_sums, stats, cpu_stats)
}

/// Largest relative difference of any channel of any texel, and how many texels
/// differ beyond `bound`.
fn compare(cpu: &BatchSums, gpu: &BatchSums, bound: f64) -> (f64, usize) {
    let (mut worst, mut beyond) = (0f64, 0);
    for (t, (c, g)) in cpu.bundle.iter().zip(&gpu.bundle).enumerate() {
        let mut d = 0f64;
        for k in 0..4 {
            let scale = c[k].abs().max(g[k].abs()).max(f32::MIN_POSITIVE) as f64;
            d = d.max((c[k] - g[k]).abs() as f64 / scale);
        }
        if d > bound {
            beyond += 1;
            if beyond <= 3 {
                eprintln!("texel {t}: cpu {c:?} gpu {g:?}");
            }
        }
        worst = worst.max(d);
    }
    (worst, beyond)
}

/// The bound on the difference of one texel's sums: both backends see the same hits
/// (same lines, same sides, same texels: the resolve makes every decision with the CPU's
/// rounding), so the sums differ only by how they are added. The CPU adds k terms in f32
/// (relative error ≤ (k − 1)·2⁻²⁴ for non-negative terms, plus one rounding per lane
/// reduction); the GPU rounds each term once to f32 and adds them exactly in fixed
/// point, then rounds once to f32. So ≤ (k + lanes + 2)·2⁻²⁴. Per direction a texel
/// gets at most (2·oversampling + 1)² lines (tile pixels are between 1 and 2 times
/// finer than texel/oversampling on a uniform-density atlas), doubled for the gutter
/// pixels that map to it: k ≤ 2·D·(2·os + 1)². A line credited to another texel would
/// move a whole hit, 1/k of the sums: far above this.
fn summation_bound(scene: &CpuScene, directions: u64) -> f64 {
    let os = scene.bundle.config.oversampling as f64;
    let k = 2.0 * directions as f64 * (2.0 * os + 1.0).powi(2);
    (k + scene.bundle.config.lanes.most() as f64 + 2.0) * 2f64.powi(-24)
}

/// GPU and CPU backends on the same directions of the bundled Cornell box (whole LOD 0,
/// 507k texels, 14.6 M fragments): every texel's sums agree within the summation bound
/// (measured worst 3.9·10⁻⁶ against a bound of 2.4·10⁻⁵), so no line was credited to a
/// different texel, seen through a different layer or lost.
#[test]
fn gpu_sums_equal_the_cpu_backends_on_the_cornell_box() {
    let scene = cornell();
    let (texels, cpu, gpu, stats, cpu_stats) = both(&scene, 0, 0, 8);
    assert_eq!(
        (stats.cpu_fallback_batches, stats.unresolved_pixels, stats.saturated_sums, stats.unplanned_directions),
        (0, 0, 0, 0)
    );
    // Every pixel with a fragment was resolved (the resolve visits only the listed groups
    // of 8 pixels with fragments).
    assert_eq!(stats.covered_pixels, cpu_stats.covered_pixels);
    let bound = summation_bound(&scene, 8);
    let (worst, beyond) = compare(&cpu, &gpu, bound);
    eprintln!("Cornell box: {} texels, worst relative difference {worst:e} (bound {bound:e})", texels.len());
    assert_eq!(beyond, 0, "texels whose sums differ beyond the summation bound");
    assert!(stats.fragments > 1_000_000);
}

/// The same on the bundled Van Gogh room (a real asset: 2 M fragments a direction, a
/// light pass of small emitters on the CPU beside the GPU's global bundles), at LOD 1
/// so that the resolve reads LOD-scaled UVs.
#[test]
fn gpu_sums_equal_the_cpu_backends_on_the_van_gogh_room() {
    let scene = crate::gpu::bundle_analysis::tests::bundled("van_gogh_room/van_gogh_room_lit.gltf");
    let (texels, cpu, gpu, stats, cpu_stats) = both(&scene, 1, 3, 4);
    assert_eq!(
        (stats.cpu_fallback_batches, stats.unresolved_pixels, stats.saturated_sums, stats.unplanned_directions),
        (0, 0, 0, 0)
    );
    assert_eq!(stats.covered_pixels, cpu_stats.covered_pixels);
    let bound = summation_bound(&scene, 4);
    let (worst, beyond) = compare(&cpu, &gpu, bound);
    eprintln!("Van Gogh room: {} texels, worst relative difference {worst:e} (bound {bound:e})", texels.len());
    assert_eq!(beyond, 0, "texels whose sums differ beyond the summation bound");
    assert_eq!(cpu.light, gpu.light, "the light pass is the CPU's on both");
}

/// Under an environment map that differs in every direction (a sky brighter toward +X
/// and up, an octant 50× brighter, turned by 30°) the ends of each line see the sky in
/// their own direction, ω and −ω, read from the map filtered for the bake's directions:
/// both backends take those values from one function (`BundleSky::seen`) per direction,
/// so on the bundled living room (an open window frame: lines leave the room through it,
/// and the outside walls and the grass see the sky) every texel's sums still agree within
/// the summation bound, and the sky shows in them (the sums differ from a black sky's).
#[test]
fn gpu_sums_equal_the_cpu_backends_under_an_environment_map() {
    use crate::scene::Environment;
    let black = crate::gpu::bundle_analysis::tests::bundled("living_room/living_room.glb");
    let (w, h) = (128u32, 64u32);
    let probe = Environment::uniform(Rgb::ZERO);
    let texels = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| {
            let d = probe.direction((x as f64 + 0.5) / w as f64, (y as f64 + 0.5) / h as f64);
            let octant = if d.x > 0.0 && d.y > 0.0 && d.z > 0.0 { 50.0 } else { 1.0 };
            Rgb::new(1.0 + d.x as f32, 0.5 + d.y.max(0.0) as f32, 0.25) * octant
        })
        .collect();
    let map = Environment::new("test sky", w, h, texels, 30f32.to_radians()).expect("a map");
    let b = &black.bundle;
    let mut scene = (*b.scene).clone();
    scene.environment = Some(Arc::new(map));
    let bundle = BundleScene::new(Arc::new(scene), b.geom.clone(), b.atlas.clone(), b.config.clone());
    let lit = Arc::new(CpuScene::new(Arc::new(bundle)));
    let (texels, cpu, gpu, stats, cpu_stats) = both(&lit, 0, 0, 8);
    assert_eq!((stats.cpu_fallback_batches, stats.unresolved_pixels, stats.saturated_sums), (0, 0, 0));
    assert_eq!(stats.covered_pixels, cpu_stats.covered_pixels);
    let bound = summation_bound(&lit, 8);
    let (worst, beyond) = compare(&cpu, &gpu, bound);
    eprintln!("living room: {} texels, worst relative difference {worst:e} (bound {bound:e})", texels.len());
    assert_eq!(beyond, 0, "texels whose sums differ beyond the summation bound");
    let (_, dark, _, _, _) = both(&black, 0, 0, 8);
    let total = |s: &BatchSums| s.bundle.iter().map(|t| (t[0] + t[1] + t[2]) as f64).sum::<f64>();
    assert!(total(&cpu) > 1.05 * total(&dark), "the sky does not show: {} vs {}", total(&cpu), total(&dark));
}

/// Tiles that overflow the node buffer: with a small buffer planned to its full size
/// (alpha 1, so the planner's estimate often falls short), tiles overflow; their parts
/// are built and resolved in further submissions of the batch (rounds), and the
/// sums are still the CPU backend's within the summation bound (which splits the same
/// tiles the same way: with two lanes it traces planned tiles whole), the same pixels,
/// each line credited once.
#[test]
fn overflowed_tiles_are_redone_in_further_rounds() {
    let cornell = cornell();
    let config = BundleConfig { node_capacity: 20_000, alpha: 1.0, ..cornell.bundle.config.clone() };
    let b = &cornell.bundle;
    let bundle = BundleScene::new(b.scene.clone(), b.geom.clone(), b.atlas.clone(), config);
    let scene = Arc::new(CpuScene::new(Arc::new(bundle)));
    let (texels, cpu, gpu, stats, cpu_stats) = both(&scene, 0, 0, 2);
    eprintln!(
        "{} texels: {} tiles, {} overflowed, {} rounds over {} directions",
        texels.len(),
        stats.tiles,
        stats.overflowed_tiles,
        stats.tile_rounds,
        stats.directions
    );
    assert!(stats.overflowed_tiles > 0, "no tile overflowed: the test tests nothing");
    assert_eq!(stats.covered_pixels, cpu_stats.covered_pixels, "the same pixels resolved");
    assert_eq!((stats.tiles, stats.overflowed_tiles), (cpu_stats.tiles, cpu_stats.overflowed_tiles));
    assert!(stats.tile_rounds >= 2, "overflowed parts make further rounds");
    assert_eq!((stats.cpu_fallback_batches, stats.saturated_sums), (0, 0));
    let (worst, beyond) = compare(&cpu, &gpu, summation_bound(&scene, 2));
    assert_eq!(beyond, 0, "worst {worst:e}");
}

/// Fixed-point scales far too large for the batch (2^20 times the chosen ones): the
/// shader sees the high words overflow, the backend redoes the batch with scales 2^24
/// smaller, and the sums are then the CPU's within the summation bound.
#[test]
fn saturated_fixed_point_sums_are_seen_and_the_batch_redone() {
    let scene = cornell();
    let bundle = &scene.bundle;
    let texels = TexelMap::build(&bundle.scene, &bundle.geom, &bundle.atlas, 0);
    let whole = WholeLod::new(&bundle.atlas, &texels);
    let target = whole.target(&texels);
    let own = vec![Rgb::ONE; texels.len()];
    let source = SourceRadiance { own: &own, foreign: None };
    let jobs = JobSequence::new(1, 0, 0);
    let batch = [jobs.job(0)];
    let never = AtomicBool::new(false);
    let gpu_context = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
    let mut gpu = GpuBundleBackend::new(gpu_context, scene.clone(), 2, false).unwrap();
    gpu.scale_boost_bits = 20;
    let mut gpu_sums = BatchSums::default();
    let stats = gpu.trace_batch(&target, &batch, &source, &mut gpu_sums, &never).unwrap();
    assert_eq!(stats.redone_batches, 1, "the first attempt must saturate");
    assert_eq!((stats.saturated_sums, stats.cpu_fallback_batches), (0, 0));
    let mut cpu = CpuBundleBackend::new(scene.clone(), 2);
    let mut cpu_sums = BatchSums::default();
    cpu.trace_batch(&target, &batch, &source, &mut cpu_sums, &never).unwrap();
    let (worst, beyond) = compare(&cpu_sums, &gpu_sums, summation_bound(&scene, 1));
    assert_eq!(beyond, 0, "worst {worst:e}");
}

/// A scene of the bundled-scene shape ([`bundled`](crate::gpu::bundle_analysis::tests::bundled)'s
/// defaults) built from `scene`.
fn with_defaults(scene: crate::scene::Scene) -> Arc<CpuScene> {
    use crate::atlas::{Atlas, AtlasConfig};
    let scene = Arc::new(scene);
    let geom = crate::scene::SceneGeometry::new(&scene);
    let atlas = Atlas::build(&scene, &geom, &AtlasConfig::default()).expect("atlas");
    let bundle = BundleScene::new(scene, Arc::new(geom), Arc::new(atlas), BundleConfig::default());
    Arc::new(CpuScene::new(Arc::new(bundle)))
}

/// Every way light passes a surface, textured and not, stacked along lines: a floor under
/// a double-sided `BLEND` pane (α 0.4), a single-sided tinted transmission pane whose
/// transmission varies with a linear texture (bilinear, REPEAT), and above both a
/// `MASK` pane cut by a 2 × 2 checker of its base colour's alpha (sRGB colours, alpha
/// linear; bilinear: 0.5 exactly on the quadrant borders, at the cutoff) under a uniform sky.
fn glass_and_cut_outs() -> crate::scene::Scene {
    use crate::scene::builder::diffuse;
    use crate::scene::{AlphaMode, Material, SceneBuilder, Texture, TextureRef, WrapMode};
    use glam::{Vec2, Vec3};
    let square = |c: Vec3, h: f32| {
        [c + Vec3::new(-h, 0.0, h), c + Vec3::new(h, 0.0, h), c + Vec3::new(h, 0.0, -h), c + Vec3::new(-h, 0.0, -h)]
    };
    let mut b = SceneBuilder::new();
    let floor = b.material(diffuse(Rgb::splat(0.5), Rgb::ZERO, false));
    let blend = b.material(Material {
        base_color: Rgb::splat(0.8).extend(0.4),
        alpha_mode: AlphaMode::Blend,
        double_sided: true,
        ..Material::default()
    });
    let tinted = b.material(Material {
        base_color: Rgb::new(1.0, 0.6, 0.3).extend(1.0),
        transmission: 0.9,
        transmission_texture: Some(TextureRef::new(0)),
        ..Material::default()
    });
    let mask = b.material(Material {
        base_color: Rgb::splat(0.9).extend(1.0),
        base_color_texture: Some(TextureRef::new(1)),
        alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
        ..Material::default()
    });
    b.grid_quad("floor", square(Vec3::ZERO, 1.0), 4, floor);
    b.quad("blend pane", square(Vec3::new(-0.5, 0.4, 0.0), 0.4), blend);
    b.quad("transmission pane", square(Vec3::new(0.5, 0.4, 0.0), 0.4), tinted);
    b.quad("mask pane", square(Vec3::new(0.0, 0.8, 0.0), 0.7), mask);
    b.sky(Rgb::ONE);
    let mut scene = b.build();
    let uv = vec![Vec2::new(0.0, 0.0), Vec2::new(1.0, 0.0), Vec2::new(1.0, 1.0), Vec2::new(0.0, 1.0)];
    for mesh in &mut scene.meshes[1..] {
        mesh.uv0 = Some(uv.clone());
    }
    let texture = |name: &str, rgba8: Vec<[u8; 4]>, srgb| Texture {
        name: name.into(),
        width: 2,
        height: 2,
        rgba8: rgba8.into(),
        srgb,
        wrap_s: WrapMode::Repeat,
        wrap_t: WrapMode::Repeat,
    };
    scene.textures.push(texture(
        "transmission",
        vec![[255, 0, 0, 255], [90, 0, 0, 255], [30, 0, 0, 255], [200, 0, 0, 255]],
        false,
    ));
    let checker = vec![[255, 200, 100, 255], [40, 120, 255, 0], [255, 255, 255, 0], [10, 250, 60, 255]];
    scene.textures.push(texture("checker", checker, true));
    scene
}

/// The sums of batches on scenes that let light through surfaces agree with the CPU
/// backend's within the summation bound: every fragment got the CPU's transmittance (the
/// same texture texels, weights and products), cut-outs were dropped at the same
/// fragments, and the walk front to back credited every side the same light (a T off by a
/// rounding moves a hit by an ulp; a cut-out decided the other way, or a pane taken as
/// opaque, by a whole line's light: far beyond the bound). The source gives every texel
/// its own colour, so which texel a line sees through which panes shows in the sums.
#[test]
fn gpu_sums_equal_the_cpu_backends_through_glass_and_cut_outs() {
    let glass = with_defaults(glass_and_cut_outs());
    let window = crate::gpu::bundle_analysis::tests::bundled("glass_broken_window/GlassBrokenWindow.gltf");
    for (what, scene, directions) in [("panes", &glass, 8), ("GlassBrokenWindow", &window, 8)] {
        assert!(scene.passing.is_some(), "{what}: the scene lets light through");
        let (texels, cpu, gpu, stats, cpu_stats) = both(scene, 0, 0, directions);
        assert_eq!(
            (stats.cpu_fallback_batches, stats.unresolved_pixels, stats.saturated_sums, stats.unplanned_directions),
            (0, 0, 0, 0),
            "{what}"
        );
        assert_eq!(stats.covered_pixels, cpu_stats.covered_pixels, "{what}");
        let bound = summation_bound(scene, directions);
        let (worst, beyond) = compare(&cpu, &gpu, bound);
        eprintln!("{what}: {} texels, worst relative difference {worst:e} (bound {bound:e})", texels.len());
        assert_eq!(beyond, 0, "{what}: texels whose sums differ beyond the summation bound");
    }
}
