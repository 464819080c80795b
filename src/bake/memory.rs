//! A bake's memory: what it will hold, estimated from the atlas before anything per texel is
//! allocated, the guard that refuses a bake over the limit, and what it did hold (peak RSS).
//!
//! The model counts what is live at a bake's peak: the end of the last batch of the finest
//! LOD, with every coarser LOD's texel map (without positions, normals and areas unless the
//! config keeps them: `livebake bake` does not) and irradiance kept (they are the output). Per
//! covered texel of the LOD being baked (CPU backend, `L` lanes (see
//! [`crate::bundle::Lanes`]: 2, or 1 from 2²⁰ texels by default), sizes of the structures in
//! [`crate::atlas::texels`], [`crate::atlas::lookup`], [`crate::bundle::progressive`] and
//! [`crate::cpu`]):
//!
//! | structure | bytes |
//! |---|---|
//! | texel map: face (u32) | 4 |
//! | texel map: pixel (u32), held by the lookup table while the bundles run and given back after ([`crate::atlas::TexelMap::drop_pixels`]) | 0 |
//! | texel map: area (f32), read by the light pass alone; an output map of `livebake bake` keeps none | 4 (light pass, or kept), 0 |
//! | texel map: albedo (Vec3); at LOD 0 held for the texels of textured materials alone while the bundles run (12 B each and a bit a texel; the others' is their material's, asked of their face: [`crate::atlas::TexelMap::take_albedo`]); given up while the bundles of a LOD reading a coarser one run (its source is made before them) and recomputed after | 12 × textured share + 0.19 (LOD 0), 0 |
//! | texel map: emission (Vec3), held for the emitting texels alone while the bundles run ([`crate::atlas::TexelMap::take_emission`]) | 0 |
//! | texel map: position, normal (2 × Vec3), given up after the punctual pass and recomputed after the bundles ([`super::bundle::bake_lod_lean`]); `livebake bake` builds its maps without them | 0 |
//! | punctual irradiance (Rgb), only in a scene with punctual lights | 12 |
//! | progressive totals: Σw·S (rgb) and Σw·A, f32 | 16 |
//! | progressive totals: light-pass Σ a·Le/A_texel (rgb, f32), only with a light pass | 12 |
//! | source radiance, reused for the irradiance at the end (Rgb) | 12 |
//! | hit sums per lane, lane 0 being the batch's sums: (Σa·L, Σa) f32 × 4 | 16 L |
//! | light-pass hit sums per lane, only with a light pass (Rgb) | 12 L |
//!
//! plus the lookup table the bundles read: 24 B per 8×8 block of that LOD's atlas pixels,
//! and per gutter pixel its texel (4 B; the map's own list of gutter pixels and their texels,
//! 8 B each, is given up meanwhile, as its texels' pixels are; the number of gutter pixels is
//! only known once the map is built, so a quarter of the texels is assumed: the rooms
//! measured have 13–25%). Per
//! thread, the fragment buffers and the hits kept for their turn ([`cpu_thread_bytes`]).
//! What does not grow with the texels (scene, its decoded textures, BVH, atlas)
//! is already resident when the guard runs and is read from the process's resident set,
//! but for the alpha-only copies of masked materials' textures that the BVH makes after it
//! (4 B a pixel, counted: [`SceneTraits::mask_texture_bytes`]), and the tables a scene that
//! lets light through surfaces gets from the bundle backends after it
//! ([`PassingBytes`]: 4 B a triangle on the CPU; the GPU's mirror of the materials, and 4 B a
//! texel, each target texel's triangle).
//!
//! Before this model (and the changes it describes), the same bake held 253 B per texel plus
//! 8 B per pixel: the texel map whole (60), punctual (12), carried (1), totals in seven f64
//! (56), the area copy (4), source (12), the batch's sums beside the two lanes' (3 × 28) and,
//! at the end, the irradiance and a copy of the punctual part (24) — 265 B per texel
//! measured (peak RSS growth) on the Van Gogh room at 1 cm (1.7 M texels, fill 0.70), with
//! or without a light pass. Then: lane 0 accumulates into the batch's sums, light-pass sums
//! and totals exist only with a light pass, positions and normals are recomputed rather
//! than held through the bundle passes, the irradiance reuses the source buffer, and the
//! light-map images are filled straight from the texels (no full-size copy beside them):
//! 142 B a texel (the slope of peak growth between 2 M and 4 M texels on the Van Gogh
//! room). Now the totals are f32 (see [`crate::bundle::progressive`] for their error), the
//! estimate reads the texel areas from the map and asks which texels the bundles carry the
//! emission of instead of copying them, and texel maps keep no pixel → texel table (4 B a
//! pixel, read by nothing once a map is built), and the lean bake holds the emission of
//! the emitting texels alone, and no punctual array where the scene has no punctual light:
//! 95 B a texel in the plain Van Gogh room and 140 B in the lit one (light pass, point
//! light), by the same slope (`livebake bench --only bake_memory`; the binary returns freed buffers of 1 MiB or more to the system, see
//! [`return_large_buffers_to_the_system`]; glibc's default kept ~7 B a texel of freed temporaries resident).
//! Then a LOD read from a coarser one stopped holding its albedo while its bundles run, and
//! the backend's lane sums go before the texel map is made whole again: a two-LOD bake
//! holds 7 B less a texel of LOD 1 in the plain Van Gogh room (slope 113.5 → 106.4 B), and
//! 131 → 122 B a texel in all in the lit one (`bytes_per_texel`, 32 directions). Then the
//! CPU backend's threads came to share lanes ([`crate::cpu`]), and a target of 2²⁰ texels or
//! more gets one lane by default, one set of sums where two threads kept one each, and
//! `livebake bake`'s output maps stopped getting their positions and normals back (figures
//! in docs/ARCHITECTURE.md, "Memory of a whole-LOD bake"). Then the lookup table stopped
//! holding 4 B a pixel (it ranks the covered pixels of each 8×8 block, whose texels are
//! consecutive ids) and came to hold the map's pixels and gutters while the bundles run,
//! and `livebake bake`'s output maps stopped holding areas (read by the light pass alone).
//! Then a LOD-0 bake came to hold the albedo of textured texels alone, and the light maps
//! to be written without a full-size image (EXR) or radiance array (PNG) beside the map:
//! 76.9 → 52.3 B a texel in the plain Van Gogh room and 112.0 → 88.5 B in the lit one
//! (marginal; 84.5 → 58.8 and 120.1 → 97.9 B in all at 4 M texels).

use serde::Serialize;

use crate::atlas::texels::UniformAlbedos;
use crate::atlas::{Atlas, FaceId};
use crate::scene::{Scene, SceneGeometry};

use super::{BackendKind, BakeConfig};
use crate::cpu::WAITING_HITS_PER_THREAD;

/// Texel-map bytes per covered texel: pixel, face, area (4 B each) and position, normal,
/// albedo, emission (12 B each).
pub const TEXEL_MAP_BYTES: u64 = 12 + 48;
/// What an output map of `livebake bake` gives up of that: positions, normals and areas.
pub const OUTPUT_MAP_SAVING: u64 = 24 + 4;
/// Irradiance kept per texel of a baked LOD (the output, Rgb).
pub const IRRADIANCE_BYTES: u64 = 12;
/// Per 8×8 block of atlas pixels of the LOD being baked: the ranked lookup table's block
/// ([`crate::atlas::lookup::TexelTable`]).
pub const TABLE_BLOCK_BYTES: u64 = 24;
/// Per gutter pixel of the LOD being baked, while its bundles run: its texel in the lookup
/// table (the map's own list is given up meanwhile).
pub const TABLE_GUTTER_BYTES: u64 = 4;
/// Per gutter pixel of a map: (pixel, source texel).
pub const GUTTER_BYTES: u64 = 8;
/// Gutter pixels assumed per covered texel before the map is built.
pub const GUTTER_PER_TEXEL: f64 = 0.25;

/// What a scene brings to a bake's memory beyond its texels: its lights and its textures.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct SceneTraits {
    /// Small emitters, which get the light pass (its sums and totals).
    pub light_pass: bool,
    /// Punctual lights (their exact irradiance per texel).
    pub punctual: bool,
    /// The share of the surface (so, near enough, of the texels) whose material has a
    /// base-colour texture: a LOD-0 bake holds those texels' albedo alone
    /// ([`crate::atlas::TexelMap::take_albedo`]).
    pub textured_share: f64,
    /// Bytes of the alpha-only texture copies the scene's BVH makes for its masked
    /// materials ([`crate::reference::AlphaMasks::texture_bytes`]), built after the guard
    /// has looked at the resident set.
    pub mask_texture_bytes: u64,
    /// The tables of a scene that lets light through surfaces (zero without such surfaces).
    pub passing: PassingBytes,
}

/// Bytes of the tables a scene with `BLEND`, transmission or `MASK` materials gets from the
/// bundle backends, after the guard: all zero for a scene without them.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PassingBytes {
    /// The CPU backend's (and the GPU backend's light pass's): per triangle its material or
    /// none (4 B; `cpu::through::Passing`).
    pub cpu: u64,
    /// The GPU backend's mirror of the materials its resolve reads (`gpu::surface_radiance`):
    /// 40 B a triangle and 48 B more a triangle with vertex colours, 64 B a material, 4 B a
    /// texture texel and the sRGB table (1 KiB).
    /// Each target texel's triangle (4 B) grows with the texels:
    /// [`bake_bytes_per_texel`].
    pub gpu: u64,
}

impl PassingBytes {
    pub fn of(scene: &Scene) -> PassingBytes {
        if !scene.materials.iter().any(|m| m.lets_light_through()) {
            return PassingBytes::default();
        }
        let triangles = scene.triangle_count() as u64;
        let colored: u64 = scene.meshes.iter().filter(|m| m.colors.is_some()).map(|m| m.triangles.len() as u64).sum();
        let texels: u64 = scene.textures.iter().map(|t| t.rgba8.len() as u64).sum();
        // The GPU's records (`gpu::layout`): a triangle's, and its corners' colours (3 × 16 B).
        let triangle = std::mem::size_of::<crate::gpu::layout::SurfaceTriangle>() as u64;
        let gpu = triangle * triangles + 48 * colored + 64 * scene.materials.len() as u64 + 4 * texels + 1024;
        PassingBytes { cpu: 4 * triangles, gpu }
    }

    fn any(&self) -> bool {
        self.gpu > 0
    }
}

impl SceneTraits {
    /// The most a scene can add per texel: both kinds of light, every surface textured (its
    /// masked textures are the scene's own: [`SceneTraits::with_masks`]).
    pub const MOST: SceneTraits = SceneTraits {
        light_pass: true,
        punctual: true,
        textured_share: 1.0,
        mask_texture_bytes: 0,
        passing: PassingBytes { cpu: 0, gpu: 0 },
    };
    /// The least.
    pub const LEAST: SceneTraits = SceneTraits {
        light_pass: false,
        punctual: false,
        textured_share: 0.0,
        mask_texture_bytes: 0,
        passing: PassingBytes { cpu: 0, gpu: 0 },
    };

    /// These traits with `scene`'s masked textures and the tables of its see-through
    /// surfaces and cut-outs.
    pub fn with_masks(self, scene: &Scene) -> SceneTraits {
        let mask_texture_bytes = crate::reference::AlphaMasks::texture_bytes(scene);
        SceneTraits { mask_texture_bytes, passing: PassingBytes::of(scene), ..self }
    }

    /// The traits of `scene` unwrapped into `atlas`; `light_pass`: whether it has small
    /// emitters.
    pub fn of(scene: &Scene, geom: &SceneGeometry, atlas: &Atlas, light_pass: bool) -> SceneTraits {
        let (mut textured, mut all) = (0f64, 0f64);
        let uniform = UniformAlbedos::new(scene);
        for (f, face) in atlas.faces.iter().enumerate() {
            let area = geom.areas[face.tri as usize] as f64;
            all += area;
            if uniform.of_face(geom, atlas, f as FaceId).is_none() {
                textured += area;
            }
        }
        let textured_share = if all > 0.0 { textured / all } else { 0.0 };
        let punctual = !scene.lights.is_empty();
        SceneTraits { light_pass, punctual, textured_share, ..SceneTraits::LEAST }.with_masks(scene)
    }
}

/// Bytes per covered texel of the LOD being baked, its texel map and irradiance included,
/// with `lanes` accumulation lanes and the scene's `traits`, at the bake's peak (the lookup
/// table, per pixel, apart); `coarser`: whether the LOD reads a coarser one's radiance
/// (LOD ≥ 1: its albedo is not held while the bundles run); `keep_area`: whether the map
/// keeps its texels' areas while the bundles run (the light pass reads them; the library's
/// maps keep them, `livebake bake`'s output maps do not).
pub fn bake_bytes_per_texel(
    backend: BackendKind,
    lanes: u32,
    traits: SceneTraits,
    coarser: bool,
    keep_area: bool,
) -> f64 {
    match backend {
        // The texel map and the irradiance; the tracer's state is per thread.
        BackendKind::Reference => (TEXEL_MAP_BYTES + IRRADIANCE_BYTES) as f64,
        BackendKind::Cpu | BackendKind::Gpu | BackendKind::Auto => {
            let lanes = lanes.max(1) as f64;
            let light = if traits.light_pass { 1.0 } else { 0.0 };
            let punctual = if traits.punctual { 12.0 } else { 0.0 };
            // The albedo at LOD 0: that of textured texels alone (12 B each and a bit per
            // texel), unless that is more than all of it.
            let albedo =
                if coarser { 0.0 } else { (12.0 * traits.textured_share.clamp(0.0, 1.0) + 12.0 / 64.0).min(12.0) };
            // face (its pixel is in the lookup table meanwhile), area (with the light pass
            // or kept), albedo + punctual + totals + source (then the irradiance) + lane sums
            let area = if keep_area || traits.light_pass { 4.0 } else { 0.0 };
            let map = 4.0 + area + albedo;
            let cpu = map + punctual + 16.0 + 12.0 * light + 12.0 + lanes * (16.0 + 12.0 * light);
            // The GPU backend keeps the CPU's (its light pass) and adds its buffers, which
            // are host memory on a software adapter: the sources (12 B) and the fixed-point
            // sums with their read-back copy (2 × 32 B), in a scene that lets light through
            // surfaces each texel's triangle (4 B). `auto` may pick either.
            let triangle = if traits.passing.any() { 4.0 } else { 0.0 };
            match backend {
                BackendKind::Cpu => cpu,
                _ => cpu + 12.0 + 64.0 + triangle,
            }
        }
    }
}

/// Bytes of the CPU backend's `threads` threads, sharing `lanes` lanes, that do not grow
/// with the texels: each thread's fragment buffers (up to N fragments of 12 B and as many
/// spans of 6 B, a row of W head pointers), and the hits kept for their turn by threads
/// working ahead of their lane's next unit (20 B each, at most
/// [`WAITING_HITS_PER_THREAD`] × N per thread beyond a lane's first, the cap past which
/// they take no unit ahead; plus each such lane's spare record chunks).
pub fn cpu_thread_bytes(b: &crate::bundle::BundleConfig, threads: u64, lanes: u64) -> u64 {
    let fragments = b.node_capacity.saturating_mul(12 + 6) + b.head_side as u64 * 8;
    let ahead = threads.saturating_sub(lanes);
    let records = b.node_capacity.saturating_mul(20 * WAITING_HITS_PER_THREAD);
    let spare = crate::cpu::SPARE_RECORD_BYTES * ahead.min(lanes);
    fragments.saturating_mul(threads).saturating_add(records.saturating_mul(ahead)) + spare
}

/// What a bake is expected to hold at its peak, before it allocates anything per texel.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MemoryEstimate {
    /// Covered texels of every LOD baked (the finest's estimated from LOD 0's for LOD ≥ 1).
    pub texels: u64,
    /// Bytes that grow with the texels (texel maps, sums, estimates, tables).
    pub texel_bytes: u64,
    /// Bytes of the backend's threads, which do not (fragment buffers, hits kept for
    /// their turn).
    pub thread_bytes: u64,
    /// Accumulation lanes of the finest LOD's bake ([`crate::bundle::Lanes::for_texels`]).
    pub lanes: u32,
    /// Bytes of the alpha-only copies of masked materials' textures (the BVH's).
    pub texture_bytes: u64,
    /// Bytes of the backend's tables for surfaces that let light through ([`PassingBytes`]).
    pub passing_bytes: u64,
    /// Everything: `texel_bytes + thread_bytes + texture_bytes + passing_bytes`.
    pub bytes: u64,
    /// `bytes / texels`.
    pub bytes_per_texel: f64,
}

/// The peak bytes of baking `config.lods` levels of `atlas` (see the module docs).
pub fn estimate(atlas: &Atlas, config: &BakeConfig, traits: SceneTraits) -> MemoryEstimate {
    let hierarchy = atlas.lods(config.lods);
    estimate_from_lod0(atlas.stats.covered_texels_lod0, Some(&|lod| hierarchy.texel_count(lod)), config, traits)
}

/// [`estimate`] from LOD 0's covered texels and each LOD's atlas pixels (`None`: as many as
/// texels, a lower bound, for a guard before the atlas exists). LOD k is taken to cover 4^k
/// times LOD 0's texels: conservative coverage adds a rim of pixels around every face whose
/// share falls at finer LODs, so this bounds finer levels from above (by a few percent on
/// rooms, more on atlases of tiny charts).
pub fn estimate_from_lod0(
    texels0: u64,
    pixels_at: Option<&dyn Fn(u32) -> u64>,
    config: &BakeConfig,
    traits: SceneTraits,
) -> MemoryEstimate {
    let finest = config.lods.saturating_sub(1);
    let finest_texels = texels0.saturating_mul(1u64 << (2 * finest.min(31)));
    let lanes = config.bundle.lanes.for_texels(finest_texels);
    let mut texels = 0u64;
    let mut bytes = 0f64;
    for lod in 0..config.lods {
        let t = texels0.saturating_mul(1u64 << (2 * lod.min(31)));
        let pixels = pixels_at.map_or(t, |p| p(lod));
        texels = texels.saturating_add(t);
        let gutter = (t as f64 * GUTTER_PER_TEXEL).min(pixels.saturating_sub(t) as f64);
        if lod == finest {
            let keep = config.keep_texel_positions;
            let per = bake_bytes_per_texel(config.backend, lanes, traits, lod > 0, keep);
            // The ranked lookup table; the GPU backend uploads it dense (4 B a pixel).
            let table = pixels as f64 * TABLE_BLOCK_BYTES as f64 / 64.0 + gutter * TABLE_GUTTER_BYTES as f64;
            let table_copy = if config.backend == BackendKind::Cpu { 0.0 } else { pixels as f64 * 4.0 };
            bytes += t as f64 * per + table + table_copy;
        } else {
            // A coarser LOD's output: its map, without positions, normals and areas unless
            // kept.
            let map = TEXEL_MAP_BYTES - if config.keep_texel_positions { 0 } else { OUTPUT_MAP_SAVING };
            bytes += t as f64 * (map + IRRADIANCE_BYTES) as f64 + gutter * GUTTER_BYTES as f64;
        }
    }
    let thread_bytes = match config.backend {
        BackendKind::Reference => 0,
        BackendKind::Cpu | BackendKind::Gpu | BackendKind::Auto => {
            let b = &config.bundle;
            let cpu = cpu_thread_bytes(b, config.threads() as u64, lanes as u64);
            // GPU: nodes (8 B) and links (4 B), heads (W² × 4 B), the resolve's group list.
            let gpu = b.node_capacity.saturating_mul(12)
                + (b.head_side as u64).pow(2) * 4
                + crate::gpu::bundle_resolve::groups_bytes(b.head_side);
            if config.backend == BackendKind::Cpu { cpu } else { cpu.saturating_add(gpu) }
        }
    };
    let texel_bytes = bytes.min(u64::MAX as f64 / 2.0) as u64;
    let texture_bytes = traits.mask_texture_bytes;
    let passing_bytes = match config.backend {
        BackendKind::Reference => 0,
        BackendKind::Cpu => traits.passing.cpu,
        BackendKind::Gpu | BackendKind::Auto => traits.passing.cpu + traits.passing.gpu,
    };
    let total = texel_bytes.saturating_add(thread_bytes).saturating_add(texture_bytes).saturating_add(passing_bytes);
    MemoryEstimate {
        texels,
        texel_bytes,
        thread_bytes,
        texture_bytes,
        passing_bytes,
        lanes: if config.backend == BackendKind::Reference { 0 } else { lanes },
        bytes: total,
        bytes_per_texel: if texels > 0 { total as f64 / texels as f64 } else { 0.0 },
    }
}

/// Where a bake's memory limit came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum LimitSource {
    /// `--memory-limit`.
    Option,
    /// Three quarters of the machine's memory.
    Machine,
}

/// The limit a bake's estimated peak is held to: `configured`, else 3/4 of the machine's
/// memory (8 GiB where /proc/meminfo cannot be read).
pub fn memory_limit(configured: Option<u64>) -> (u64, LimitSource) {
    match configured {
        Some(b) => (b, LimitSource::Option),
        None => {
            let total = meminfo_kib("MemTotal:").map(|kib| kib * 1024).unwrap_or(32 << 30);
            (total / 4 * 3, LimitSource::Machine)
        }
    }
}

/// [`memory_limit`] with what set it, as errors name it.
pub fn described_limit(configured: Option<u64>) -> (u64, &'static str) {
    match memory_limit(configured) {
        (l, LimitSource::Option) => (l, "--memory-limit"),
        (l, LimitSource::Machine) => (l, "3/4 of this machine's memory"),
    }
}

fn meminfo_kib(key: &str) -> Option<u64> {
    let m = std::fs::read_to_string("/proc/meminfo").ok()?;
    m.lines().find(|l| l.starts_with(key))?.split_whitespace().nth(1)?.parse().ok()
}

/// A `/proc/self/status` figure in bytes (`VmRSS:` now, `VmHWM:` the peak so far); `None`
/// where it cannot be read.
pub fn process_kib(key: &str) -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let kib: u64 = s.lines().find(|l| l.starts_with(key))?.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// Resident bytes now.
pub fn resident_bytes() -> Option<u64> {
    process_kib("VmRSS:")
}

/// Peak resident bytes so far.
pub fn peak_resident_bytes() -> Option<u64> {
    process_kib("VmHWM:")
}

/// Serves every allocation of 1 MiB or more with its own mapping, unmapped when freed. glibc's
/// default raises that threshold after the first large free (up to 32 MiB), so later buffers
/// of up to 32 MiB come from the heap and, once freed, stay in the resident set: on a
/// 4 M-texel bake that kept ~7 B a texel of freed temporaries resident at the bake's peak,
/// above what the memory estimate counts. Requests this large are few (per-texel and
/// per-pixel arrays, fragment buffers), so a mapping each costs nothing measurable.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
pub fn return_large_buffers_to_the_system() {
    // SAFETY: mallopt only sets an allocator parameter; its callers (the binary, the benches)
    // call it before any other thread exists, and a refusal (return 0) leaves glibc's default
    // in place, which is still correct.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 1 << 20);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
pub fn return_large_buffers_to_the_system() {}

/// A length in metres with three significant digits: `0.0129`, `0.250`, `1.50`.
pub fn metres(m: f64) -> String {
    let decimals = if m > 0.0 && m.is_finite() { (2 - m.log10().floor() as i64).clamp(0, 9) as usize } else { 3 };
    format!("{m:.decimals$}")
}

/// Bytes in a human unit: `12.3 GB`, `512 MB`.
pub fn human_bytes(b: &u64) -> String {
    let b = *b as f64;
    if b >= 1e9 {
        format!("{:.1} GB", b / 1e9)
    } else if b >= 1e6 {
        format!("{:.0} MB", b / 1e6)
    } else {
        format!("{:.0} kB", b / 1e3)
    }
}

/// Parses a byte count: a number with an optional unit K, M, G, T (powers of 1024, an
/// optional trailing `B` or `iB`, case-insensitive): `8G`, `512MiB`, `1000000`.
pub fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let lower = t.to_ascii_lowercase();
    let body = lower.strip_suffix("ib").or_else(|| lower.strip_suffix('b')).unwrap_or(&lower);
    let (num, shift) = match body.chars().next_back() {
        Some('k') => (&body[..body.len() - 1], 10),
        Some('m') => (&body[..body.len() - 1], 20),
        Some('g') => (&body[..body.len() - 1], 30),
        Some('t') => (&body[..body.len() - 1], 40),
        _ => (body, 0),
    };
    let v: f64 = num
        .trim()
        .parse()
        .map_err(|_| format!("expected a size such as 8G, 512M or 1000000 (unit K, M, G or T), got {s:?}"))?;
    let bytes = v * (1u64 << shift) as f64;
    if !(bytes.is_finite() && bytes >= 1.0 && bytes < u64::MAX as f64) {
        return Err(format!("expected a size of at least one byte, got {s:?}"));
    }
    Ok(bytes as u64)
}

/// What the bake's report says about memory.
#[derive(Clone, Debug, Default, Serialize)]
pub struct MemoryReport {
    /// The estimate the guard checked, before any texel map was built.
    pub estimate: MemoryEstimate,
    /// The limit it was held to and where that came from.
    pub limit_bytes: u64,
    pub limit_source: Option<LimitSource>,
    /// Resident bytes before the first texel map (scene, atlas, BVH and backend built).
    pub resident_at_start: Option<u64>,
    /// Peak resident bytes of the process (after writing the light maps, for `livebake bake`).
    pub peak_resident: Option<u64>,
    /// Peak growth over the start: `peak_resident − resident_at_start`.
    pub peak_growth: Option<u64>,
    /// `peak_growth / estimate.texels`: the measured bytes per texel.
    pub measured_bytes_per_texel: Option<f64>,
}

impl MemoryReport {
    /// Reads the peak now and updates the measured figures.
    pub fn measure(&mut self) {
        self.peak_resident = peak_resident_bytes();
        self.peak_growth = match (self.peak_resident, self.resident_at_start) {
            (Some(p), Some(s)) => Some(p.saturating_sub(s)),
            _ => None,
        };
        self.measured_bytes_per_texel =
            self.peak_growth.filter(|_| self.estimate.texels > 0).map(|g| g as f64 / self.estimate.texels as f64);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_parse_with_binary_units() {
        assert_eq!(parse_bytes("8G").unwrap(), 8 << 30);
        assert_eq!(parse_bytes("512MiB").unwrap(), 512 << 20);
        assert_eq!(parse_bytes("1.5k").unwrap(), 1536);
        assert_eq!(parse_bytes("1000000").unwrap(), 1_000_000);
        assert_eq!(parse_bytes("2 gb").unwrap(), 2 << 30);
        for bad in ["", "G", "-1G", "0", "lots", "nanG", "1e30T"] {
            assert!(parse_bytes(bad).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn lengths_keep_three_significant_digits() {
        assert_eq!(metres(0.0129), "0.0129");
        assert_eq!(metres(0.25), "0.250");
        assert_eq!(metres(1.5), "1.50");
        assert_eq!(metres(12.0), "12.0");
    }

    /// A masked material's texture is copied once for the BVH, however many masked
    /// materials share it, and the estimate counts that copy.
    #[test]
    fn masked_textures_are_counted_once() {
        use crate::scene::{AlphaMode, Material, Texture, TextureRef};
        let texture = Texture {
            name: "leaves".into(),
            width: 8,
            height: 4,
            rgba8: vec![[0; 4]; 32].into(),
            srgb: true,
            wrap_s: Default::default(),
            wrap_t: Default::default(),
        };
        let masked = Material {
            alpha_mode: AlphaMode::Mask { cutoff: 0.5 },
            base_color_texture: Some(TextureRef::new(0)),
            ..Material::default()
        };
        let opaque = Material { alpha_mode: AlphaMode::Opaque, ..masked.clone() };
        let scene = Scene {
            materials: vec![masked.clone(), masked, opaque],
            textures: vec![texture.clone(), texture],
            ..Scene::default()
        };
        let traits = SceneTraits::LEAST.with_masks(&scene);
        assert_eq!(traits.mask_texture_bytes, 32 * 4);
        let config = BakeConfig::default();
        let with = estimate_from_lod0(1000, None, &config, traits);
        let without = estimate_from_lod0(1000, None, &config, SceneTraits::LEAST);
        assert_eq!(with.bytes - without.bytes, 128);
        assert_eq!(crate::reference::AlphaMasks::texture_bytes(&scene), 128);
    }

    /// A scene that lets light through surfaces: the CPU backend's per-triangle table, and
    /// on the GPU backend its materials' mirror and each texel's triangle.
    #[test]
    fn tables_of_see_through_surfaces_are_counted() {
        use crate::scene::{AlphaMode, Material, SceneBuilder};
        let mut b = SceneBuilder::new();
        let glass = b.material(Material { alpha_mode: AlphaMode::Blend, ..Material::default() });
        b.cuboid("box", glam::Vec3::ZERO, glam::Vec3::ONE, false, glass);
        let scene = b.build();
        let traits = SceneTraits::LEAST.with_masks(&scene);
        assert_eq!(traits.passing, PassingBytes { cpu: 12 * 4, gpu: 12 * 40 + 64 + 1024 });
        // Vertex colours: 3 × 16 B more a triangle on the GPU.
        let mut colored = scene.clone();
        colored.meshes[0].colors = Some(vec![glam::Vec4::ONE; colored.meshes[0].positions.len()]);
        let colored = SceneTraits::LEAST.with_masks(&colored).passing;
        assert_eq!(colored, PassingBytes { cpu: 12 * 4, gpu: 12 * (40 + 48) + 64 + 1024 });
        for (backend, extra) in [
            (BackendKind::Cpu, 48),
            (BackendKind::Gpu, 48 + 12 * 40 + 64 + 1024 + 1000 * 4),
            (BackendKind::Reference, 0),
        ] {
            let config = BakeConfig { backend, ..BakeConfig::default() };
            let with = estimate_from_lod0(1000, None, &config, traits);
            let without = estimate_from_lod0(1000, None, &config, SceneTraits::LEAST);
            assert_eq!(with.bytes - without.bytes, extra, "{backend:?}");
        }
        let opaque = SceneTraits::LEAST.with_masks(&SceneBuilder::new().build());
        assert_eq!(opaque.passing, PassingBytes::default());
    }

    #[test]
    fn lanes_and_the_lights_cost_what_the_table_says() {
        let plain = SceneTraits::LEAST;
        let small = SceneTraits { light_pass: true, ..plain };
        let cpu = |lanes, traits, coarser| bake_bytes_per_texel(BackendKind::Cpu, lanes, traits, coarser, false);
        // face, the bits saying which texels are textured (none); totals, source, sums
        assert_eq!(cpu(1, plain, false), 4.0 + 0.1875 + 16.0 + 12.0 + 16.0);
        // The light pass keeps the areas (4 B) and adds its totals and sums.
        assert_eq!(cpu(2, small, false) - cpu(2, plain, false), 4.0 + 12.0 + 2.0 * 12.0);
        // The library's maps keep the areas.
        assert_eq!(bake_bytes_per_texel(BackendKind::Cpu, 1, plain, false, true) - cpu(1, plain, false), 4.0);
        assert_eq!(cpu(2, SceneTraits { punctual: true, ..small }, false) - cpu(2, small, false), 12.0);
        assert_eq!(cpu(3, plain, false) - cpu(2, plain, false), 16.0);
        // Textured texels keep their albedo, all of it when most are.
        let half = SceneTraits { textured_share: 0.5, ..plain };
        assert_eq!(cpu(1, half, false) - cpu(1, plain, false), 6.0);
        assert_eq!(
            cpu(1, SceneTraits::MOST, false) - cpu(1, SceneTraits { textured_share: 0.0, ..SceneTraits::MOST }, false),
            12.0 - 0.1875
        );
        // A LOD reading a coarser one holds no albedo while its bundles run.
        assert_eq!(cpu(2, plain, false) - cpu(2, plain, true), 0.1875);
        assert_eq!(cpu(2, SceneTraits::MOST, false) - cpu(2, SceneTraits::MOST, true), 12.0);
    }
}
