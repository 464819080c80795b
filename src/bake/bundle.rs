//! Bundle backends in the bake driver: directions in batches, light jobs per emitter group,
//! the punctual pass, and the progressive estimate of a whole LOD or a region of one.

use std::ops::ControlFlow;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use crate::atlas::lookup::TexelTable;
use crate::atlas::texels::{Restore, TexelAlbedo, TexelEmission, TexelView, UniformAlbedos};
use crate::atlas::{FaceId, TexelMap};
use crate::bundle::progressive::{BatchSums, ProgressiveEstimate, Reflectance, SourceKind};
use crate::bundle::stats::PassStats;
use crate::bundle::{
    BakeTarget, BundleBackend, BundleScene, Cancelled, DirectionJob, JobSequence, SourceRadiance, SurfaceRadiance,
};
use crate::progress::Progress;
use crate::reference::punctual::punctual_irradiance_of_texels;
use crate::reference::{Bvh, ray_epsilon};
use crate::scene::Rgb;

/// What one LOD's bundle bake did.
#[derive(Clone, Debug, Default, Serialize, Deserialize)]
pub struct BundleLodStats {
    pub directions: u64,
    pub batches: u64,
    pub light_directions_per_group: u64,
    pub light_pass_groups: usize,
    pub emitter_triangles_in_global_bundles: usize,
    pub punctual_seconds: f64,
    pub bundle_seconds: f64,
    /// Texels no global bundle hit (their indirect light is missing).
    pub unsampled_texels: usize,
    pub pass: PassStats,
}

/// A coarser LOD's converged irradiance, read as the source radiance of a finer bake.
pub struct CoarserLod<'a> {
    pub texels: &'a TexelMap,
    pub irradiance: &'a [Rgb],
}

/// Bakes one whole LOD with a bundle backend: punctual pass, then batches of directions,
/// the source radiance refreshed after each (multi-bounce, see
/// [`progressive`](crate::bundle::progressive)), or read once from a converged coarser LOD.
#[allow(clippy::too_many_arguments)]
pub fn bake_lod(
    bundle: &BundleScene,
    bvh: &Bvh,
    backend: &mut dyn BundleBackend,
    texels: &TexelMap,
    coarser: Option<CoarserLod>,
    threads: usize,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<LodIrradiance, Cancelled> {
    bake_lod_observed(bundle, bvh, backend, texels, coarser, threads, progress, cancel, &mut |_| {
        ControlFlow::Continue(())
    })
}

/// The running estimate of a bake after a batch, shown to the observer of
/// [`bake_lod_observed`].
pub struct BatchDone<'a> {
    /// Global directions folded in so far.
    pub directions: u64,
    pub estimate: &'a ProgressiveEstimate,
}

/// An observer of a progressive bake: called after every batch; `Break` ends the bake there.
pub type Observer<'a> = dyn FnMut(&BatchDone) -> ControlFlow<()> + 'a;

/// [`bake_lod`] showing `observe` the running estimate after every batch; `Break` ends the
/// bake there, with the directions done so far (a prefix of the full bake's: direction `i`
/// and the batches before it do not depend on how many follow).
#[allow(clippy::too_many_arguments)]
pub fn bake_lod_observed(
    bundle: &BundleScene,
    bvh: &Bvh,
    backend: &mut dyn BundleBackend,
    texels: &TexelMap,
    coarser: Option<CoarserLod>,
    threads: usize,
    progress: &dyn Progress,
    cancel: &AtomicBool,
    observe: &mut Observer,
) -> Result<LodIrradiance, Cancelled> {
    let tables = [TexelTable::of_map(texels)];
    let converged = coarser.map(|c| source_from_coarser(bundle, texels, &c));
    let punctual = PunctualPass::of_map(bundle, bvh, texels, &tables[0], threads);
    let region =
        Region { texels: texels.view(), tables: &tables, window: None, foreign: None, triangles: None, reach: None };
    bake_region_observed(bundle, backend, &region, converged, punctual, threads, progress, cancel, observe)
}

/// [`bake_lod`] holding less at its peak: the punctual pass first (it reads the texels'
/// faces and pixels), then the texels' positions and normals (read by nothing the bake
/// runs) are given up while the bundles run and
/// recomputed at the end ([`TexelMap::restore_geometry`]: the same values), and their
/// emission is held for the emitting texels alone ([`TexelMap::take_emission`]). With a
/// coarser LOD, whose radiance is made the source once, before the bundles, the albedo is
/// given up and recomputed as well. The texels' pixels and the gutter pixels are held by
/// the lookup table alone meanwhile ([`TexelMap::drop_pixels`]), and given back after. The
/// backend's own per-texel buffers are given back before anything is recomputed; `restore`
/// says what is ([`Restore::Albedo`]: the positions and normals stay given up, and the
/// areas, which the light pass alone reads, are given up too, before the bundles when the
/// scene has no light pass). A map built without positions and normals
/// ([`TexelMap::build_with`]) bakes the same. Same result, except that the punctual part is
/// empty where the scene has no punctual lights (no 12 B a texel of zeros at the end, when
/// the texel map is whole again).
#[allow(clippy::too_many_arguments)]
pub fn bake_lod_lean(
    bundle: &BundleScene,
    bvh: &Bvh,
    backend: &mut dyn BundleBackend,
    texels: &mut TexelMap,
    coarser: Option<CoarserLod>,
    restore: Restore,
    threads: usize,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<LodIrradiance, Cancelled> {
    // A scene without punctual lights gets no punctual array (zero everywhere, 12 B a texel
    // at the peak): the estimate reads a missing one as zero. The pass reads faces and
    // pixels, not the map's positions.
    // The lookup table holds the texels' pixels and the gutters while the bundles run (given
    // up by the map meanwhile); the punctual pass reads it first.
    let tables = [TexelTable::of_map(texels)];
    let punctual = PunctualPass::of_map(bundle, bvh, texels, &tables[0], threads);
    texels.drop_geometry();
    // Emission read from the coarser LOD's source before the dense array goes.
    let converged = coarser.map(|c| source_from_coarser(bundle, texels, &c));
    // A converged source is all the bundles need of the albedo (a bake's own multi-bounce
    // source is remade from it after every batch).
    // Otherwise the albedo of texels of untextured materials is their material's, asked of
    // their face rather than held.
    let textured = if converged.is_some() {
        texels.drop_albedo();
        None
    } else {
        texels.take_albedo(&bundle.scene, &bundle.geom, &bundle.atlas)
    };
    let emitting = texels.take_emission();
    let pixels_given_up = texels.drop_pixels(&tables[0]);
    // The light pass alone reads the areas; an output map without positions keeps none.
    let light_pass = !bundle.emitters.small.is_empty();
    if restore == Restore::Albedo && !light_pass {
        texels.drop_area();
    }
    let result = {
        let texels = &*texels;
        let mut view = texels.view();
        if let Some(e) = &emitting {
            view.emission = TexelEmission::Emitting(e);
        }
        if let Some(t) = &textured {
            view.albedo = TexelAlbedo::Textured(t);
        }
        let region =
            Region { texels: view, tables: &tables, window: None, foreign: None, triangles: None, reach: None };
        let never_stop = &mut |_: &BatchDone| ControlFlow::Continue(());
        bake_region_observed(bundle, backend, &region, converged, punctual, threads, progress, cancel, never_stop)
    };
    backend.release_texel_buffers();
    if pixels_given_up {
        texels.restore_pixels(&tables[0]);
    }
    drop(tables);
    if restore == Restore::Albedo {
        texels.drop_area();
    }
    if let Some(e) = &emitting {
        texels.restore_emission(e);
    }
    if let Some(t) = &textured {
        texels.restore_albedo(t, &bundle.scene, &bundle.geom, &bundle.atlas);
    }
    texels.restore_geometry(&bundle.scene, &bundle.geom, &bundle.atlas, threads, restore);
    result
}

/// The punctual pass of a set of texels: each texel's direct light from the punctual lights
/// over its visible part ([`punctual_irradiance_of_texels`]).
pub struct PunctualPass {
    /// Irradiance per texel (W/m²); empty in a scene without punctual lights (zero everywhere).
    pub irradiance: Vec<Rgb>,
    pub seconds: f64,
}

impl PunctualPass {
    /// The pass over the texels of LOD `lod` on `faces`, texel `i` at LOD pixel `pixel(i)`
    /// in the chart table `table(i)`; a buried texel shows its chart neighbours' mean
    /// ([`crate::atlas::chart_filter::fill_within_charts`]).
    pub fn of<'t>(
        bundle: &BundleScene,
        bvh: &Bvh,
        lod: u32,
        faces: &[FaceId],
        pixel: &(dyn Fn(usize) -> [u32; 2] + Sync),
        table: impl Fn(usize) -> &'t TexelTable,
        threads: usize,
    ) -> PunctualPass {
        let t0 = Instant::now();
        if bundle.scene.lights.is_empty() {
            return PunctualPass { irradiance: Vec::new(), seconds: 0.0 };
        }
        let irradiance = punctual_irradiance_of_texels(
            &bundle.scene,
            &bundle.geom,
            &bundle.atlas,
            bvh,
            lod,
            faces,
            pixel,
            table,
            ray_epsilon(&bundle.scene),
            threads,
        );
        PunctualPass { irradiance, seconds: t0.elapsed().as_secs_f64() }
    }

    /// The pass over a whole-LOD texel map (its pixels held) whose lookup table is `table`
    /// ([`TexelTable::of_map`], which the bundles read too).
    pub fn of_map(
        bundle: &BundleScene,
        bvh: &Bvh,
        texels: &TexelMap,
        table: &TexelTable,
        threads: usize,
    ) -> PunctualPass {
        if bundle.scene.lights.is_empty() {
            return PunctualPass { irradiance: Vec::new(), seconds: 0.0 };
        }
        let w = texels.width;
        let pixel = |i: usize| [texels.pixel[i] % w, texels.pixel[i] / w];
        PunctualPass::of(bundle, bvh, texels.lod, &texels.face, &pixel, |_| table, threads)
    }
}

/// Texels to bake with a bundle backend, and what lies around them.
pub struct Region<'a> {
    pub texels: TexelView<'a>,
    /// Their lookup (see [`BakeTarget::tables`]).
    pub tables: &'a [TexelTable],
    /// A box holding them (`None`: the whole scene).
    pub window: Option<(Vec3, Vec3)>,
    /// The radiance of lit faces outside the region (`None`: the region is every lit face).
    pub foreign: Option<&'a dyn SurfaceRadiance>,
    /// The triangles whose texel density sets the bundles' resolution (ascending; `None`:
    /// those holding the region's texels). A region shard gives the whole LOD's, so that its
    /// bundles are laid out as the whole LOD's are.
    pub triangles: Option<&'a [u32]>,
    /// Per face, whether its lookups may find a texel of the region, when its one table is
    /// whole-LOD shaped (see [`BakeTarget::reach`]); `None`: every face may.
    pub reach: Option<&'a [bool]>,
}

/// Bakes a region's texels: their punctual pass (made by the caller), then batches of
/// directions. Without `converged`
/// (each texel's outgoing radiance from an already converged estimate) the source radiance
/// is the bake's own estimate, refreshed after each batch (multi-bounce inside the region;
/// what lies outside is seen through `region.foreign`).
#[allow(clippy::too_many_arguments)]
pub fn bake_region(
    bundle: &BundleScene,
    backend: &mut dyn BundleBackend,
    region: &Region,
    converged: Option<Vec<Rgb>>,
    punctual: PunctualPass,
    threads: usize,
    progress: &dyn Progress,
    cancel: &AtomicBool,
) -> Result<LodIrradiance, Cancelled> {
    let never_stop = &mut |_: &BatchDone| ControlFlow::Continue(());
    bake_region_observed(bundle, backend, region, converged, punctual, threads, progress, cancel, never_stop)
}

/// [`bake_region`] with an observer (see [`bake_lod_observed`]).
#[allow(clippy::too_many_arguments)]
fn bake_region_observed(
    bundle: &BundleScene,
    backend: &mut dyn BundleBackend,
    region: &Region,
    converged: Option<Vec<Rgb>>,
    punctual: PunctualPass,
    threads: usize,
    progress: &dyn Progress,
    cancel: &AtomicBool,
    observe: &mut Observer,
) -> Result<LodIrradiance, Cancelled> {
    let share = DirectionShare::whole(bundle.config.seed);
    let traced = trace_region(bundle, backend, region, converged, punctual, share, threads, progress, cancel, observe)?;
    let Traced { estimate, stats, source } = traced;
    // The irradiance goes into the source buffer, and the punctual part is moved out: no
    // per-texel buffer is added at the bake's peak.
    let mut irradiance = source;
    estimate.irradiance_into(threads, &mut irradiance);
    let unsampled = estimate.unsampled_texels();
    Ok(LodIrradiance { irradiance, punctual: estimate.into_punctual(), unsampled, stats })
}

/// Which batches of a bake's direction sequence a bake traces: batch `b` (of the batches
/// [`BundleConfig::batch_size`](crate::bundle::BundleConfig::batch_size) or
/// [`progressive_batch`](crate::bundle::BundleConfig::progressive_batch) cut) when
/// `b mod count = index`, of the sequence of seed `seed`. A whole bake is share 0 of 1.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DirectionShare {
    pub seed: u64,
    pub index: u32,
    pub count: u32,
}

impl DirectionShare {
    /// Every batch of the sequence of `seed`.
    pub fn whole(seed: u64) -> Self {
        DirectionShare { seed, index: 0, count: 1 }
    }

    /// Whether batch `b` is this share's.
    pub fn takes(&self, b: u64) -> bool {
        b % self.count.max(1) as u64 == self.index as u64
    }
}

/// What [`trace_region`] leaves: the estimate, the figures and the source buffer (to be
/// reused).
pub(super) struct Traced {
    pub estimate: ProgressiveEstimate,
    pub stats: BundleLodStats,
    pub source: Vec<Rgb>,
}

/// The batches of `share` traced into the region's estimate: its punctual pass (made by the
/// caller) and the global and light bundles of every batch of the share, the source radiance
/// `converged` or, without it, the bake's own running estimate refreshed after each batch.
#[allow(clippy::too_many_arguments)]
pub(super) fn trace_region(
    bundle: &BundleScene,
    backend: &mut dyn BundleBackend,
    region: &Region,
    converged: Option<Vec<Rgb>>,
    punctual: PunctualPass,
    share: DirectionShare,
    threads: usize,
    progress: &dyn Progress,
    cancel: &AtomicBool,
    observe: &mut Observer,
) -> Result<Traced, Cancelled> {
    let texels = &region.texels;
    let config = &bundle.config;
    let mut stats = BundleLodStats::default();
    let PunctualPass { irradiance: punctual, seconds } = punctual;
    stats.punctual_seconds = seconds;

    let uniform = UniformAlbedos::new(&bundle.scene);
    let reflectance = || FaceReflectance::new(bundle, &uniform, texels);
    let own_triangles;
    let triangles = match region.triangles {
        Some(t) => t,
        None => {
            own_triangles = crate::bundle::target::target_triangles(&bundle.atlas, texels.face);
            &own_triangles
        }
    };
    let target = BakeTarget {
        lod: texels.lod,
        face: texels.face,
        emission: texels.emission,
        tables: region.tables,
        window: region.window,
        triangles,
        reach: region.reach,
    };

    let kind = if converged.is_some() { SourceKind::Converged } else { SourceKind::Progressive };
    let mut estimate = if punctual.is_empty() {
        ProgressiveEstimate::without_punctual(kind, texels.len())
    } else {
        ProgressiveEstimate::new(kind, punctual)
    };
    let mut source = Vec::new();
    match converged {
        Some(c) => source = c,
        None => estimate.initial_source(&reflectance, texels.emission, threads, &mut source),
    }
    stats.light_pass_groups = bundle.emitters.small.len();
    stats.emitter_triangles_in_global_bundles = bundle.emitters.carried_by_bundles.iter().filter(|&&c| c).count();

    let t1 = Instant::now();
    let jobs = JobSequence::new(share.seed, bundle.emitters.small.len(), config.light_directions);
    // Sized by the backend (lane 0's buffer; light-pass sums only with a light pass).
    let mut sums = BatchSums::default();
    progress.begin(&format!("LOD {} bundles", texels.lod), config.directions as u64);
    let (mut first, mut batch_index, mut traced) = (0u64, 0u64, 0u64);
    while first < config.directions as u64 {
        // A progressive bake's batches grow with the batches folded in: a share of one
        // would cut them otherwise than the whole bake (shards bake converged sources).
        let per_batch = match kind {
            SourceKind::Progressive => config.progressive_batch(estimate.batches()),
            SourceKind::Converged => config.batch_size(),
        };
        let count = (per_batch as u64).min(config.directions as u64 - first);
        let mine = share.takes(batch_index);
        batch_index += 1;
        if !mine {
            first += count;
            progress.advance(count);
            continue;
        }
        let batch: Vec<DirectionJob> = (first..first + count).map(|i| jobs.job(i)).collect();
        let own = SourceRadiance { own: &source, foreign: region.foreign };
        let pass = match backend.trace_batch(&target, &batch, &own, &mut sums, cancel) {
            Ok(pass) => pass,
            Err(Cancelled) => {
                progress.end();
                return Err(Cancelled);
            }
        };
        stats.pass.add(&pass);
        let light_directions = count * config.light_directions as u64;
        match kind {
            SourceKind::Progressive => estimate.add_batch_and_source(
                &sums,
                texels.area,
                light_directions,
                &reflectance,
                texels.emission,
                threads,
                &mut source,
            ),
            SourceKind::Converged => estimate.add_batch(&sums, texels.area, light_directions, threads),
        }
        first += count;
        traced += count;
        progress.advance(count);
        if observe(&BatchDone { directions: first, estimate: &estimate }).is_break() {
            break;
        }
    }
    progress.end();
    stats.bundle_seconds = t1.elapsed().as_secs_f64();
    stats.directions = traced;
    stats.batches = estimate.batches();
    stats.light_directions_per_group = estimate.light_directions();
    stats.unsampled_texels = estimate.unsampled();
    Ok(Traced { estimate, stats, source })
}

/// [`Reflectance`] of a bake's texels, asked of a texel's face once per run of texels on one
/// face (texels follow their charts' pixels, so a face's lie together) instead of through
/// face, triangle and mesh for every texel in every batch.
struct FaceReflectance<'a> {
    bundle: &'a BundleScene,
    uniform: &'a UniformAlbedos,
    face: &'a [FaceId],
    albedo: TexelAlbedo<'a>,
    /// The face of the last texel asked (none yet: `FaceId::MAX`), its material's uniform
    /// albedo and whether the bundles carry its emission.
    last: FaceId,
    known: (Option<Rgb>, bool),
}

impl<'a> FaceReflectance<'a> {
    fn new(bundle: &'a BundleScene, uniform: &'a UniformAlbedos, texels: &TexelView<'a>) -> Self {
        let (face, albedo) = (texels.face, texels.albedo);
        FaceReflectance { bundle, uniform, face, albedo, last: FaceId::MAX, known: (None, false) }
    }
}

impl Reflectance for FaceReflectance<'_> {
    #[inline(always)]
    fn at(&mut self, i: usize) -> (Rgb, bool) {
        let face = self.face[i];
        if face != self.last {
            let b = self.bundle;
            self.known = (self.uniform.of_face(&b.geom, &b.atlas, face), b.carried(face));
            self.last = face;
        }
        let of_face = self.known.0;
        (self.albedo.at_or(i, || of_face), self.known.1)
    }
}

/// A whole LOD's bundle bake.
pub struct LodIrradiance {
    /// Irradiance per texel (W/m²).
    pub irradiance: Vec<Rgb>,
    /// Its exact punctual-light part; empty (zero everywhere) from [`bake_lod_lean`] in a
    /// scene without punctual lights.
    pub punctual: Vec<Rgb>,
    /// Texels no global bundle reached (ascending): their irradiance is their direct part
    /// alone (see [`crate::atlas::chart_filter::filter_within_charts`] for how they are shown).
    pub unsampled: Vec<u32>,
    pub stats: BundleLodStats,
}

/// Source radiance of a finer LOD's texels read from the converged coarser LOD: each texel
/// takes the coarser irradiance under its centre (bilinear, gutters make that chart-safe).
fn source_from_coarser(bundle: &BundleScene, texels: &TexelMap, coarser: &CoarserLod) -> Vec<Rgb> {
    let c = coarser.texels;
    let image = c.to_image(coarser.irradiance, Rgb::ZERO);
    let scale = (1u32 << texels.lod) as f32 / (1u32 << c.lod) as f32;
    let carried = |i: usize| bundle.carried(texels.face[i]);
    Vec::from_iter((0..texels.len()).map(|i| {
        let p = texels.pixel[i];
        let centre = Vec2::new((p % texels.width) as f32 + 0.5, (p / texels.width) as f32 + 0.5) / scale;
        let e = bilinear(&image, c.width, c.height, centre);
        let reflected = texels.albedo[i] * e * std::f32::consts::FRAC_1_PI;
        if carried(i) { reflected + texels.emission[i] } else { reflected }
    }))
}

fn bilinear(image: &[Rgb], w: u32, h: u32, p: Vec2) -> Rgb {
    let q = p - Vec2::splat(0.5);
    let (x0, y0) = (q.x.floor(), q.y.floor());
    let (fx, fy) = (q.x - x0, q.y - y0);
    let at = |x: f32, y: f32| {
        let x = (x.max(0.0) as u32).min(w - 1);
        let y = (y.max(0.0) as u32).min(h - 1);
        image[(y * w + x) as usize]
    };
    let top = at(x0, y0) * (1.0 - fx) + at(x0 + 1.0, y0) * fx;
    let bottom = at(x0, y0 + 1.0) * (1.0 - fx) + at(x0 + 1.0, y0 + 1.0) * fx;
    top * (1.0 - fy) + bottom * fy
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use super::*;
    use crate::atlas::{Atlas, AtlasConfig};
    use crate::bundle::BundleConfig;
    use crate::bundle::target::BackendProvider;
    use crate::cpu::CpuProvider;
    use crate::progress::NoProgress;
    use crate::scene::{LoadOptions, SceneGeometry, load_gltf};

    /// Asserts `a` and `b` equal bit for bit, naming the first texel that differs.
    fn assert_same_bits(a: &[Rgb], b: &[Rgb], what: &str) {
        assert_eq!(a.len(), b.len(), "{what}: lengths");
        let bits = |c: &Rgb| c.to_array().map(f32::to_bits);
        if let Some(i) = (0..a.len()).find(|&i| bits(&a[i]) != bits(&b[i])) {
            panic!("{what}: texel {i} is {} against {}", a[i], b[i]);
        }
    }

    /// The lean bake gives up positions, normals, most of the emission and (at LOD 0) the
    /// albedo of untextured texels while its bundles run and puts them back: its irradiance, punctual part and texel map are the plain
    /// bake's bit for bit, at LOD 0 (its own multi-bounce source, a light pass over the
    /// Cornell box's lamp, texels emitting) and at LOD 1 (source read from LOD 0); with a
    /// point light added, and without one (then it holds no punctual part at all).
    #[test]
    fn the_lean_bake_equals_the_plain_one_bit_for_bit() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("assets/cornell_box/cornellBox-2.79-Cycles-gltf.gltf");
        let unlit = load_gltf(&path, &LoadOptions::default()).expect("Cornell box");
        assert!(unlit.lights.is_empty());
        let mut lit = unlit.clone();
        let mut lamp = crate::scene::SceneBuilder::new();
        lamp.point_light(glam::Vec3::new(0.5, 1.5, 0.3), Rgb::splat(3.0));
        lit.lights.extend(lamp.build().lights);
        for scene in [unlit, lit] {
            check_lean_bake(Arc::new(scene));
        }
    }

    fn check_lean_bake(scene: Arc<crate::scene::Scene>) {
        let geom = Arc::new(SceneGeometry::new(&scene));
        let atlas_config = AtlasConfig { texel_budget: 4000, ..AtlasConfig::default() };
        let atlas = Arc::new(Atlas::build(&scene, &geom, &atlas_config).expect("atlas"));
        let config = BundleConfig { directions: 16, ..BundleConfig::default() };
        let bundle = Arc::new(BundleScene::new(scene.clone(), geom.clone(), atlas.clone(), config));
        assert!(!bundle.emitters.small.is_empty(), "the lamp should get the light pass");
        let bvh = Bvh::for_scene(&scene, &geom);
        let mut backend = CpuProvider::new().backend(&bundle, 2).expect("CPU backend");
        let never = AtomicBool::new(false);
        let mut coarser: Option<(TexelMap, Vec<Rgb>)> = None;
        for lod in 0..2 {
            let plain_map = TexelMap::build(&scene, &geom, &atlas, lod);
            // The box's textured materials cover some texels and not others: at LOD 0 the
            // lean bake holds the albedo of those alone.
            let textured = plain_map.clone().take_albedo(&scene, &geom, &atlas).expect("few textured texels");
            assert!(!textured.is_empty() && textured.len() * 4 < plain_map.len(), "{} textured", textured.len());
            let emitting = plain_map.emission.iter().filter(|e| **e != Rgb::ZERO).count();
            assert!(emitting > 0 && emitting * 4 < plain_map.len(), "LOD {lod}: {emitting} emitting texels");
            let c = coarser.as_ref().map(|(t, e)| CoarserLod { texels: t, irradiance: e });
            let plain = bake_lod(&bundle, &bvh, &mut backend, &plain_map, c, 2, &NoProgress, &never).expect("plain");
            let mut lean_map = TexelMap::build(&scene, &geom, &atlas, lod);
            let c = coarser.as_ref().map(|(t, e)| CoarserLod { texels: t, irradiance: e });
            let lean =
                bake_lod_lean(&bundle, &bvh, &mut backend, &mut lean_map, c, Restore::All, 2, &NoProgress, &never)
                    .expect("lean");
            let lights = scene.lights.len();
            assert_same_bits(&lean.irradiance, &plain.irradiance, &format!("{lights} lights, LOD {lod}: irradiance"));
            if lights == 0 {
                assert!(lean.punctual.is_empty() && plain.punctual.iter().all(|&e| e == Rgb::ZERO));
            } else {
                assert!(plain.punctual.iter().any(|&e| e != Rgb::ZERO), "the point light lights something");
                assert_same_bits(&lean.punctual, &plain.punctual, &format!("LOD {lod}: punctual part"));
            }
            for (name, a, b) in [
                ("position", &lean_map.position, &plain_map.position),
                ("normal", &lean_map.normal, &plain_map.normal),
                ("emission", &lean_map.emission, &plain_map.emission),
                ("albedo", &lean_map.albedo, &plain_map.albedo),
            ] {
                assert_same_bits(a, b, &format!("{lights} lights, LOD {lod}: {name}"));
            }
            assert_eq!(
                (&lean_map.pixel, &lean_map.face, &lean_map.gutter),
                (&plain_map.pixel, &plain_map.face, &plain_map.gutter)
            );
            // As `livebake bake` does it: a map built without positions (the punctual pass
            // reads faces and pixels), its output without positions and areas.
            let mut out_map = TexelMap::build_with(&scene, &geom, &atlas, lod, Restore::Albedo);
            let c = coarser.as_ref().map(|(t, e)| CoarserLod { texels: t, irradiance: e });
            let out =
                bake_lod_lean(&bundle, &bvh, &mut backend, &mut out_map, c, Restore::Albedo, 2, &NoProgress, &never)
                    .expect("output map");
            assert_same_bits(&out.irradiance, &plain.irradiance, &format!("{lights} lights, LOD {lod}: output"));
            assert_same_bits(&out_map.albedo, &plain_map.albedo, "output albedo");
            assert_same_bits(&out_map.emission, &plain_map.emission, "output emission");
            assert_eq!(
                (&out_map.pixel, &out_map.face, &out_map.gutter),
                (&plain_map.pixel, &plain_map.face, &plain_map.gutter)
            );
            assert!(out_map.position.is_empty() && out_map.normal.is_empty() && out_map.area.is_empty());
            // Where most texels emit, the dense emission is the smaller and stays.
            let mut glowing = TexelMap::build(&scene, &geom, &atlas, lod);
            glowing.emission.fill(Rgb::ONE);
            assert!(glowing.take_emission().is_none() && glowing.emission.len() == glowing.len());
            coarser = Some((plain_map, plain.irradiance));
        }
    }
}
