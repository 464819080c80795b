//! The layout file (docs/SHARDS.md "The layout file"): the atlas and LOD 0's texel map of one
//! sharded bake, made by the first process that needs them and read by the rest (`bake
//! --shard … --layout FILE`, `merge … --layout FILE`). Every shard and merge of a bake
//! makes the same atlas and texel map from the same scene and options; made once, they are
//! a read instead of an unwrap, a pack and a rasterisation in every process after.
//!
//! A header (the scene's and the options' hashes it was made for, the counts), the atlas's
//! statistics (JSON), its faces, its charts and the faces of each, then per texel its pixel,
//! face, area, albedo and emission, the gutter pixels, a checksum. Little-endian. The file is
//! input like any other: its size must be what its header says, its memory fits the limit
//! before anything is allocated, and every index in it is checked, so that a damaged or
//! forged file is a clear error, never a panic.

use std::fs::File;
use std::io::{BufReader, Read, Write};
use std::path::{Path, PathBuf};

use glam::Vec2;

use super::ShardError;
use super::file::{HashingReader, read_records, write_atomically, write_words};
use crate::atlas::texels::TexelMap;
use crate::atlas::{Atlas, AtlasFace, AtlasStats, Chart, ChartSource, MAX_ATLAS_SIDE, NO_FACE};
use crate::scene::{Rgb, SceneGeometry, Side};

/// The file's first eight bytes.
pub const LAYOUT_MAGIC: [u8; 8] = *b"LBLAYOUT";
/// The format this build writes and reads.
pub const LAYOUT_VERSION: u32 = 1;
const HEADER_BYTES: usize = 80;
/// Most bytes of the atlas statistics' JSON (a few hundred, more with refused TEXCOORD_1
/// layouts' reasons).
const MAX_STATS_BYTES: u32 = 1 << 20;
/// Bytes of a face (triangle, chart, side, three UVs), a chart (mesh, side, source,
/// rectangle, face count), a texel (pixel, face, area, albedo, emission) and a gutter pixel.
const FACE_BYTES: u64 = 36;
const CHART_BYTES: u64 = 32;
const TEXEL_BYTES: u64 = 36;
const GUTTER_BYTES: u64 = 8;

/// An atlas and its LOD-0 texel map, as a layout file holds them.
pub struct Layout {
    pub atlas: Atlas,
    pub texels: TexelMap,
}

/// Where a sharded bake keeps its layout, and the bake it must be of.
#[derive(Clone, Debug)]
pub struct LayoutPlace {
    pub path: PathBuf,
    pub scene_hash: u64,
    pub options_hash: u64,
}

/// The counts a header gives.
struct Counts {
    width: u32,
    height: u32,
    texel_size: f32,
    triangles: u32,
    faces: u32,
    charts: u32,
    texels: u64,
    gutter: u64,
    stats_bytes: u32,
}

impl Counts {
    /// Bytes of a file with these counts, `None` past `u64`.
    fn file_bytes(&self) -> Option<u64> {
        let parts = [
            (self.faces as u64).checked_mul(FACE_BYTES + 4)?,
            (self.charts as u64).checked_mul(CHART_BYTES)?,
            self.texels.checked_mul(TEXEL_BYTES)?,
            self.gutter.checked_mul(GUTTER_BYTES)?,
        ];
        parts.iter().try_fold(HEADER_BYTES as u64 + self.stats_bytes as u64 + 8, |a, &b| a.checked_add(b))
    }

    /// Bytes the atlas and the texel map take once read (with or without the texels'
    /// attributes), `None` past `u64`.
    fn held_bytes(&self, attributes: bool) -> Option<u64> {
        let per_texel = 12 + if attributes { 24 } else { 0 };
        let parts = [
            (self.faces as u64).checked_mul((size_of::<AtlasFace>() + 4) as u64)?,
            (self.triangles as u64).checked_mul(8)?,
            (self.charts as u64).checked_mul(size_of::<Chart>() as u64)?,
            self.texels.checked_mul(per_texel)?,
            self.gutter.checked_mul(GUTTER_BYTES)?,
            // The pixels' one-bit marks that tell a pixel used twice.
            (self.width as u64 * self.height as u64).div_ceil(8),
        ];
        parts.iter().try_fold(self.stats_bytes as u64, |a, &b| a.checked_add(b))
    }
}

/// Writes `atlas` and its LOD-0 texel map `texels` (with their albedo and emission) to
/// `path` for the bake of `scene_hash` and `options_hash`, through a hidden temporary file
/// of this process's own (shards started together may write the same layout at once; each
/// renames a whole file, and they are the same).
pub fn write_layout(
    path: &Path,
    scene_hash: u64,
    options_hash: u64,
    atlas: &Atlas,
    texels: &TexelMap,
) -> Result<(), ShardError> {
    let unfit =
        |why: &str| ShardError::InvalidLayout { path: path.to_path_buf(), why: format!("cannot be written: {why}") };
    let n = texels.len();
    if texels.lod != 0 || texels.width != atlas.width || texels.height != atlas.height {
        return Err(unfit("the texel map is not the atlas's LOD 0"));
    }
    if texels.albedo.len() != n || texels.emission.len() != n || texels.pixel.len() != n || texels.area.len() != n {
        return Err(unfit("the texel map lacks its pixels, albedo or emission"));
    }
    let stats = serde_json::to_vec(&atlas.stats).map_err(|e| unfit(&e.to_string()))?;
    let counts = Counts {
        width: atlas.width,
        height: atlas.height,
        texel_size: atlas.texel_size,
        triangles: u32::try_from(atlas.face_of.len()).map_err(|_| unfit("too many triangles"))?,
        faces: u32::try_from(atlas.faces.len()).map_err(|_| unfit("too many faces"))?,
        charts: u32::try_from(atlas.charts.len()).map_err(|_| unfit("too many charts"))?,
        texels: n as u64,
        gutter: texels.gutter.len() as u64,
        stats_bytes: u32::try_from(stats.len())
            .ok()
            .filter(|&b| b <= MAX_STATS_BYTES)
            .ok_or_else(|| unfit("statistics too long"))?,
    };
    let mut header = [0u8; HEADER_BYTES];
    header[0..8].copy_from_slice(&LAYOUT_MAGIC);
    header[8..12].copy_from_slice(&LAYOUT_VERSION.to_le_bytes());
    header[16..24].copy_from_slice(&scene_hash.to_le_bytes());
    header[24..32].copy_from_slice(&options_hash.to_le_bytes());
    header[32..36].copy_from_slice(&counts.width.to_le_bytes());
    header[36..40].copy_from_slice(&counts.height.to_le_bytes());
    header[40..44].copy_from_slice(&counts.texel_size.to_bits().to_le_bytes());
    header[44..48].copy_from_slice(&counts.triangles.to_le_bytes());
    header[48..52].copy_from_slice(&counts.faces.to_le_bytes());
    header[52..56].copy_from_slice(&counts.charts.to_le_bytes());
    header[56..64].copy_from_slice(&counts.texels.to_le_bytes());
    header[64..72].copy_from_slice(&counts.gutter.to_le_bytes());
    header[72..76].copy_from_slice(&counts.stats_bytes.to_le_bytes());
    let suffix = format!("{}.partial", std::process::id());
    write_atomically(path, &suffix, |w| {
        w.write_all(&header)?;
        w.write_all(&stats)?;
        let mut buf = Vec::new();
        write_words(
            w,
            atlas.faces.iter().map(|f| {
                let uv = f.uv.map(|p| [p.x.to_bits(), p.y.to_bits()]);
                [f.tri, f.chart, f.side as u32, uv[0][0], uv[0][1], uv[1][0], uv[1][1], uv[2][0], uv[2][1]]
            }),
            &mut buf,
        )?;
        write_words(
            w,
            atlas.charts.iter().map(|c| {
                let source = match c.source {
                    ChartSource::Unwrapped => 0,
                    ChartSource::Uv1 => 1,
                };
                let (r, s) = (c.rect_min, c.rect_size);
                [c.mesh, c.side as u32, source, r.0, r.1, s.0, s.1, c.faces.len() as u32]
            }),
            &mut buf,
        )?;
        write_words(w, atlas.charts.iter().flat_map(|c| c.faces.iter().map(|&f| [f])), &mut buf)?;
        write_words(
            w,
            (0..n).map(|i| {
                let (a, e) = (texels.albedo[i], texels.emission[i]);
                [
                    texels.pixel[i],
                    texels.face[i],
                    texels.area[i].to_bits(),
                    a.x.to_bits(),
                    a.y.to_bits(),
                    a.z.to_bits(),
                    e.x.to_bits(),
                    e.y.to_bits(),
                    e.z.to_bits(),
                ]
            }),
            &mut buf,
        )?;
        write_words(w, texels.gutter.iter().map(|&(p, t)| [p, t]), &mut buf)
    })
}

/// Reads the layout at `place` for a bake of `geom` (the scene it was made from), its
/// texels' albedo and emission with `attributes` (else skipped), `limit` the most bytes it
/// may take. Refuses, naming the file and why, a file that is not a layout, of another
/// format version, of another bake (hashes, triangle count), of the wrong size, too large
/// for the limit, naming a triangle, face, chart, mesh, pixel or texel that is not there,
/// placing a chart outside the atlas, using a pixel twice, or whose checksum does not match.
pub fn read_layout(
    place: &LayoutPlace,
    geom: &SceneGeometry,
    attributes: bool,
    limit: (u64, &'static str),
) -> Result<Layout, ShardError> {
    let path = &place.path;
    let bad = |why: String| ShardError::InvalidLayout { path: path.clone(), why };
    let io = |source| ShardError::Io { path: path.clone(), source };
    // A special file is refused before it is opened (a FIFO's open would wait); the size is
    // the opened file's (another process may rename a new layout into place meanwhile).
    if !std::fs::metadata(path).map_err(io)?.is_file() {
        return Err(bad("not a regular file".into()));
    }
    let file = File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if !meta.is_file() {
        return Err(bad("not a regular file".into()));
    }
    let mut r = HashingReader { inner: BufReader::with_capacity(1 << 20, file), hash: super::WordHash::new() };
    let mut h = [0u8; HEADER_BYTES];
    let head = meta.len().min(HEADER_BYTES as u64) as usize;
    r.read_exact(&mut h[..head]).map_err(io)?;
    if head < LAYOUT_MAGIC.len() || h[0..8] != LAYOUT_MAGIC {
        return Err(bad("not a livebake layout file (its first bytes are not LBLAYOUT)".into()));
    }
    if meta.len() < HEADER_BYTES as u64 + 8 {
        return Err(bad(format!("truncated: {} bytes, shorter than a layout file's header", meta.len())));
    }
    let u32_at = |o: usize| u32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]);
    let u64_at = |o: usize| u64::from_le_bytes(std::array::from_fn(|k| h[o + k]));
    let version = u32_at(8);
    if version != LAYOUT_VERSION {
        return Err(bad(format!("format version {version}; this livebake reads version {LAYOUT_VERSION}")));
    }
    if u32_at(12) != 0 || u32_at(76) != 0 {
        return Err(bad("its reserved header words are not zero".into()));
    }
    if u64_at(16) != place.scene_hash || u64_at(24) != place.options_hash {
        return Err(bad("made for another scene, other scene files or other options".into()));
    }
    let c = Counts {
        width: u32_at(32),
        height: u32_at(36),
        texel_size: f32::from_bits(u32_at(40)),
        triangles: u32_at(44),
        faces: u32_at(48),
        charts: u32_at(52),
        texels: u64_at(56),
        gutter: u64_at(64),
        stats_bytes: u32_at(72),
    };
    if c.triangles as usize != geom.len() {
        return Err(bad(format!("made for {} triangles, the scene has {}", c.triangles, geom.len())));
    }
    let pixels = c.width as u64 * c.height as u64;
    let sides = 1..=MAX_ATLAS_SIDE;
    if !sides.contains(&c.width) || !sides.contains(&c.height) || pixels >= u32::MAX as u64 {
        return Err(bad(format!("an atlas of {}×{} texels", c.width, c.height)));
    }
    if !(c.texel_size.is_finite() && c.texel_size > 0.0) {
        return Err(bad(format!("a texel size of {} m", c.texel_size)));
    }
    if c.stats_bytes > MAX_STATS_BYTES || c.texels.saturating_add(c.gutter) > pixels {
        return Err(bad(format!("{} texels and {} gutter pixels in {pixels} pixels", c.texels, c.gutter)));
    }
    match c.file_bytes() {
        Some(b) if b == meta.len() => {}
        Some(b) => {
            let what = if meta.len() < b { "truncated" } else { "longer than its header says" };
            return Err(bad(format!("{what}: {} bytes, where its header makes {b}", meta.len())));
        }
        None => return Err(bad("its counts are more than a file can hold".into())),
    }
    let need = c.held_bytes(attributes).unwrap_or(u64::MAX);
    if need > limit.0 {
        return Err(ShardError::OutOfMemory { texels: c.texels, need, limit: limit.0, source_of_limit: limit.1 });
    }

    let mut stats = vec![0u8; c.stats_bytes as usize];
    r.read_exact(&mut stats).map_err(io)?;
    let stats: AtlasStats =
        serde_json::from_slice(&stats).map_err(|e| bad(format!("its atlas statistics do not read: {e}")))?;

    let word = |b: &[u8], k: usize| u32::from_le_bytes([b[4 * k], b[4 * k + 1], b[4 * k + 2], b[4 * k + 3]]);
    let float = |b: &[u8], k: usize| f32::from_bits(word(b, k));
    let side_of = |s: u32| match s {
        0 => Some(Side::Front),
        1 => Some(Side::Back),
        _ => None,
    };
    let mut buf = Vec::new();
    // The first thing found wrong (the records are read to the end, then it is the error).
    let mut problem: Option<String> = None;

    // Faces: each names a triangle of the scene and a chart, once a side.
    let mut faces = Vec::with_capacity(c.faces as usize);
    let mut face_of = vec![[NO_FACE; 2]; c.triangles as usize];
    read_records(&mut r, c.faces as usize, FACE_BYTES as usize, &mut buf, |i, b| {
        let (tri, chart, side) = (word(b, 0), word(b, 1), side_of(word(b, 2)));
        let uv: [Vec2; 3] = std::array::from_fn(|k| Vec2::new(float(b, 3 + 2 * k), float(b, 4 + 2 * k)));
        let Some(side) = side.filter(|_| tri < c.triangles && chart < c.charts && uv.iter().all(|p| p.is_finite()))
        else {
            return note(
                &mut problem,
                format!("face {i} names triangle {tri}, chart {chart}, side {}, UVs {uv:?}", word(b, 2)),
            );
        };
        let slot = &mut face_of[tri as usize][side as usize];
        if *slot != NO_FACE {
            return note(&mut problem, format!("faces {} and {i} are the same side of triangle {tri}", *slot));
        }
        *slot = i as u32;
        faces.push(AtlasFace { tri, side, chart, uv });
    })
    .map_err(io)?;
    if let Some(why) = problem.take() {
        return Err(bad(why));
    }

    // Charts: each inside the atlas, of a mesh of the scene, listing its own faces.
    let meshes = geom.mesh_offsets.len().saturating_sub(1) as u32;
    let mut charts = Vec::with_capacity(c.charts as usize);
    let mut counts = Vec::with_capacity(c.charts as usize);
    read_records(&mut r, c.charts as usize, CHART_BYTES as usize, &mut buf, |i, b| {
        let (mesh, side, count) = (word(b, 0), side_of(word(b, 1)), word(b, 7));
        let source = match word(b, 2) {
            0 => Some(ChartSource::Unwrapped),
            1 => Some(ChartSource::Uv1),
            _ => None,
        };
        let (rect_min, rect_size) = ((word(b, 3), word(b, 4)), (word(b, 5), word(b, 6)));
        let inside = |lo: u32, size: u32, side: u32| lo.checked_add(size).is_some_and(|e| e <= side);
        let fits = inside(rect_min.0, rect_size.0, c.width) && inside(rect_min.1, rect_size.1, c.height);
        counts.push(count);
        match (side, source) {
            (Some(side), Some(source)) if mesh < meshes && fits => charts.push(Chart {
                mesh,
                side,
                source,
                rect_min,
                rect_size,
                faces: Vec::with_capacity(count as usize),
            }),
            _ => note(
                &mut problem,
                format!("chart {i} (mesh {mesh}, rectangle {rect_min:?} + {rect_size:?}) is not in this atlas"),
            ),
        }
    })
    .map_err(io)?;
    if let Some(why) = problem.take() {
        return Err(bad(why));
    }
    let listed: u64 = counts.iter().map(|&k| k as u64).sum();
    if listed != c.faces as u64 {
        return Err(bad(format!("its charts list {listed} faces of {}", c.faces)));
    }
    // The listed counts add up to the faces read next: the chart index stays in range.
    let mut chart = 0usize;
    let mut seen = vec![false; c.faces as usize];
    read_records(&mut r, c.faces as usize, 4, &mut buf, |_, b| {
        while charts[chart].faces.len() == counts[chart] as usize {
            chart += 1;
        }
        let f = word(b, 0);
        let ch = &mut charts[chart];
        let belongs = faces.get(f as usize).is_some_and(|face: &AtlasFace| {
            let (lo, hi) = (geom.mesh_offsets[ch.mesh as usize], geom.mesh_offsets[ch.mesh as usize + 1]);
            face.chart as usize == chart && face.side == ch.side && (lo..hi).contains(&face.tri)
        });
        if !belongs || std::mem::replace(&mut seen[f as usize], true) {
            note(&mut problem, format!("chart {chart} lists face {f}, not one of its own (or twice)"));
        }
        // Pushed even when wrong: the chart index follows the listed counts.
        ch.faces.push(f);
    })
    .map_err(io)?;
    if let Some(why) = problem.take() {
        return Err(bad(why));
    }
    drop(seen);

    // Texels: each a pixel of the atlas, used once, of a face there is.
    let n = c.texels as usize;
    let mut used = vec![0u64; (pixels as usize).div_ceil(64)];
    let mut take_pixel = |p: u32| {
        let (w, bit) = (p as usize / 64, 1u64 << (p % 64));
        let free = (p as u64) < pixels && used[w] & bit == 0;
        if free {
            used[w] |= bit;
        }
        free
    };
    let with = |k: usize| if attributes { k } else { 0 };
    let mut map = TexelMap {
        lod: 0,
        width: c.width,
        height: c.height,
        pixel: Vec::with_capacity(n),
        face: Vec::with_capacity(n),
        area: Vec::with_capacity(n),
        albedo: Vec::with_capacity(with(n)),
        emission: Vec::with_capacity(with(n)),
        ..TexelMap::default()
    };
    read_records(&mut r, n, TEXEL_BYTES as usize, &mut buf, |i, b| {
        let (pixel, face, area) = (word(b, 0), word(b, 1), float(b, 2));
        let albedo = Rgb::new(float(b, 3), float(b, 4), float(b, 5));
        let emission = Rgb::new(float(b, 6), float(b, 7), float(b, 8));
        let sound = face < c.faces && area.is_finite() && area >= 0.0 && albedo.is_finite() && emission.is_finite();
        if !(sound && take_pixel(pixel)) {
            return note(
                &mut problem,
                format!("texel {i} (pixel {pixel}, face {face}, area {area}) is not of this atlas"),
            );
        }
        map.pixel.push(pixel);
        map.face.push(face);
        map.area.push(area);
        if attributes {
            map.albedo.push(albedo);
            map.emission.push(emission);
        }
    })
    .map_err(io)?;
    if let Some(why) = problem.take() {
        return Err(bad(why));
    }
    map.gutter.reserve_exact(c.gutter as usize);
    read_records(&mut r, c.gutter as usize, GUTTER_BYTES as usize, &mut buf, |i, b| {
        let (pixel, texel) = (word(b, 0), word(b, 1));
        if (texel as u64) >= c.texels || !take_pixel(pixel) {
            return note(
                &mut problem,
                format!("gutter pixel {i} ({pixel}, copying texel {texel}) is not of this atlas"),
            );
        }
        map.gutter.push((pixel, texel));
    })
    .map_err(io)?;
    if let Some(why) = problem {
        return Err(bad(why));
    }
    let computed = r.hash.finish();
    let mut sum = [0u8; 8];
    r.inner.read_exact(&mut sum).map_err(io)?;
    if u64::from_le_bytes(sum) != computed {
        return Err(bad("its checksum does not match its contents (the file is damaged)".into()));
    }
    let atlas = Atlas {
        texel_size: c.texel_size,
        width: c.width,
        height: c.height,
        faces,
        face_of,
        charts,
        mesh_offsets: geom.mesh_offsets.clone(),
        stats,
    };
    Ok(Layout { atlas, texels: map })
}

/// Keeps the first problem found.
fn note(problem: &mut Option<String>, why: String) {
    problem.get_or_insert(why);
}

/// The layout at `place` when there is one of this bake; `None` (with a warning saying why,
/// unless there is no file yet) when it must be made.
pub fn open_layout(
    place: &LayoutPlace,
    geom: &SceneGeometry,
    attributes: bool,
    limit: (u64, &'static str),
) -> Option<Layout> {
    match read_layout(place, geom, attributes, limit) {
        Ok(layout) => {
            tracing::info!(path = %place.path.display(), "layout read");
            Some(layout)
        }
        Err(ShardError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => None,
        Err(e) => {
            tracing::warn!("{e}; making the atlas and texel map here");
            None
        }
    }
}

/// Writes the layout made here to `place` for the processes after this one; a failure is a
/// warning (this process has what it needs; the next makes the layout again).
pub fn keep_layout(place: &LayoutPlace, atlas: &Atlas, texels: &TexelMap) {
    match write_layout(&place.path, place.scene_hash, place.options_hash, atlas, texels) {
        Ok(()) => tracing::info!(path = %place.path.display(), "layout written"),
        Err(e) => tracing::warn!("cannot keep the layout for the next shards: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::AtlasConfig;
    use crate::atlas::texels::Restore;
    use crate::reference::scenes::{furnished_room, temple};

    const LIMIT: (u64, &str) = (1 << 34, "the test's limit");

    fn made() -> (SceneGeometry, Atlas, TexelMap) {
        let scene = furnished_room();
        let geom = SceneGeometry::new(&scene);
        let config = AtlasConfig { texel_size: Some(0.05), ..AtlasConfig::default() };
        let atlas = Atlas::build(&scene, &geom, &config).expect("atlas");
        let texels = TexelMap::build_with(&scene, &geom, &atlas, 0, Restore::Albedo);
        (geom, atlas, texels)
    }

    fn place(dir: &Path, name: &str) -> LayoutPlace {
        LayoutPlace { path: dir.join(name), scene_hash: 11, options_hash: 22 }
    }

    fn written(dir: &Path, name: &str, atlas: &Atlas, texels: &TexelMap) -> LayoutPlace {
        let p = place(dir, name);
        write_layout(&p.path, p.scene_hash, p.options_hash, atlas, texels).expect("written");
        p
    }

    /// The refusal of `place`'s file, as text.
    fn refusal(place: &LayoutPlace, geom: &SceneGeometry) -> String {
        match read_layout(place, geom, true, LIMIT) {
            Ok(_) => panic!("{} was read", place.path.display()),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn a_layout_reads_back_as_it_was_made() {
        let dir = tempfile::tempdir().expect("temp dir");
        let (geom, atlas, texels) = made();
        assert!(atlas.charts.len() > 20 && texels.len() > 10_000 && !texels.gutter.is_empty());
        assert!(texels.emission.iter().any(|e| e.max_element() > 0.0), "the room has an emitter");
        assert!(atlas.faces.iter().any(|f| f.side == Side::Back), "the room has a double-sided panel");
        let p = written(dir.path(), "layout.lblayout", &atlas, &texels);
        let Layout { atlas: a, texels: t } = read_layout(&p, &geom, true, LIMIT).expect("read");
        assert_eq!((a.texel_size, a.width, a.height), (atlas.texel_size, atlas.width, atlas.height));
        let face = |f: &AtlasFace| (f.tri, f.side, f.chart, f.uv.map(|p| p.to_array().map(f32::to_bits)));
        assert!(a.faces.iter().map(face).eq(atlas.faces.iter().map(face)));
        assert_eq!(a.face_of, atlas.face_of);
        let chart = |c: &Chart| (c.mesh, c.side, c.source, c.rect_min, c.rect_size, c.faces.clone());
        assert!(a.charts.iter().map(chart).eq(atlas.charts.iter().map(chart)));
        assert_eq!((&a.mesh_offsets, &a.stats), (&atlas.mesh_offsets, &atlas.stats));
        assert_eq!((t.lod, t.width, t.height), (0, texels.width, texels.height));
        assert_eq!((&t.pixel, &t.face, &t.gutter), (&texels.pixel, &texels.face, &texels.gutter));
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&t.area), bits(&texels.area));
        assert_eq!((&t.albedo, &t.emission), (&texels.albedo, &texels.emission));
        assert!(t.position.is_empty() && t.normal.is_empty());
        // Without the attributes: the same map, no albedo or emission.
        let t = read_layout(&p, &geom, false, LIMIT).expect("read").texels;
        assert_eq!((&t.pixel, &t.face, &t.gutter), (&texels.pixel, &texels.face, &texels.gutter));
        assert!(t.albedo.is_empty() && t.emission.is_empty());
    }

    #[test]
    fn layouts_of_other_bakes_damaged_or_forged_are_refused() {
        let dir = tempfile::tempdir().expect("temp dir");
        let d = dir.path();
        let (geom, atlas, texels) = made();
        let good = written(d, "good.lblayout", &atlas, &texels);
        let bytes = std::fs::read(&good.path).expect("layout");
        // Another bake: the hashes, or a scene of other triangles.
        for p in [LayoutPlace { scene_hash: 12, ..good.clone() }, LayoutPlace { options_hash: 23, ..good.clone() }] {
            assert!(refusal(&p, &geom).contains("another scene"), "{}", refusal(&p, &geom));
        }
        let other = SceneGeometry::new(&temple());
        assert!(refusal(&good, &other).contains("triangles"), "{}", refusal(&good, &other));
        // Cut, damaged, huge counts, not a layout.
        let file = |name: &str, b: &[u8]| {
            let p = place(d, name);
            std::fs::write(&p.path, b).expect("write");
            p
        };
        let cut = file("cut", &bytes[..bytes.len() - 100]);
        assert!(refusal(&cut, &geom).contains("truncated"), "{}", refusal(&cut, &geom));
        let mut b = bytes.clone();
        let middle = b.len() / 2;
        b[middle] ^= 0x10;
        let damaged = file("damaged", &b);
        assert!(refusal(&damaged, &geom).contains("checksum"), "{}", refusal(&damaged, &geom));
        let mut b = bytes.clone();
        b[48..52].copy_from_slice(&u32::MAX.to_le_bytes());
        let huge = file("huge", &b);
        assert!(refusal(&huge, &geom).contains("truncated"), "{}", refusal(&huge, &geom));
        let mut b = bytes.clone();
        b[56..64].copy_from_slice(&(u64::MAX / 8).to_le_bytes());
        let huge = file("huge-texels", &b);
        assert!(refusal(&huge, &geom).contains("gutter pixels in"), "{}", refusal(&huge, &geom));
        let text = file("text", b"not a layout, some text of about the length of a header ........................");
        assert!(refusal(&text, &geom).contains("not a livebake layout"), "{}", refusal(&text, &geom));
        // More than the memory limit: refused before anything is allocated.
        match read_layout(&good, &geom, true, (1 << 20, "a small limit")) {
            Err(ShardError::OutOfMemory { limit, .. }) => assert_eq!(limit, 1 << 20),
            other => panic!("not refused for its memory: {:?}", other.err()),
        }
        // A folder and a FIFO: not regular files (the FIFO is not opened, so nothing waits).
        std::fs::create_dir(d.join("folder")).expect("dir");
        assert!(refusal(&place(d, "folder"), &geom).contains("not a regular file"));
        let fifo = d.join("fifo");
        let c = std::ffi::CString::new(fifo.to_str().expect("UTF-8")).expect("path");
        // SAFETY: a NUL-terminated path; mkfifo only creates the special file.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        assert!(refusal(&place(d, "fifo"), &geom).contains("not a regular file"));
        // Missing: an I/O error of its own kind (a layout to make, not a problem).
        assert!(matches!(
            read_layout(&place(d, "absent"), &geom, true, LIMIT),
            Err(ShardError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound
        ));
        assert!(open_layout(&place(d, "absent"), &geom, true, LIMIT).is_none());

        // Forged files, their checksums right: every index is checked, nothing panics.
        let forged = |name: &str, a: &Atlas, t: &TexelMap| refusal(&written(d, name, a, t), &geom);
        let mut a = atlas.clone();
        a.faces[3].chart = a.charts.len() as u32;
        assert!(forged("chart", &a, &texels).contains("face 3 names"));
        let mut a = atlas.clone();
        a.faces[5].tri = geom.len() as u32;
        assert!(forged("tri", &a, &texels).contains("face 5 names"));
        let mut a = atlas.clone();
        a.faces[7].uv[1].x = f32::NAN;
        assert!(forged("uv", &a, &texels).contains("face 7 names"));
        let mut a = atlas.clone();
        a.faces[2].side = a.faces[1].side;
        a.faces[2].tri = a.faces[1].tri;
        assert!(forged("twice", &a, &texels).contains("same side"));
        let mut a = atlas.clone();
        a.charts[4].rect_min.0 = a.width - 1;
        assert!(forged("rect", &a, &texels).contains("chart 4"));
        let mut a = atlas.clone();
        a.charts[6].mesh = geom.mesh_offsets.len() as u32;
        assert!(forged("mesh", &a, &texels).contains("chart 6"));
        let mut a = atlas.clone();
        let moved = a.charts[9].faces.pop().expect("a face");
        a.charts[8].faces.push(moved);
        assert!(forged("listed", &a, &texels).contains("chart 8 lists face"));
        let mut t = texels.clone();
        t.pixel[1] = t.pixel[0];
        assert!(forged("pixel", &atlas, &t).contains("texel 1 "));
        let mut t = texels.clone();
        t.face[4] = atlas.faces.len() as u32;
        assert!(forged("face", &atlas, &t).contains("texel 4 "));
        let mut t = texels.clone();
        t.area[6] = f32::INFINITY;
        assert!(forged("area", &atlas, &t).contains("texel 6 "));
        let mut t = texels.clone();
        t.gutter[0].1 = t.len() as u32;
        assert!(forged("gutter", &atlas, &t).contains("gutter pixel 0"));
        let mut t = texels.clone();
        t.gutter[1].0 = t.pixel[2];
        assert!(forged("gutter-texel", &atlas, &t).contains("gutter pixel 1"));
        // And the good one still reads.
        assert!(read_layout(&good, &geom, true, LIMIT).is_ok());
    }
}
