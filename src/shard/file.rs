//! The shard file (docs/SHARDS.md "The shard file"): a header, the job that made it (JSON),
//! each texel's sums, a checksum. Little-endian; every length read from the file is checked
//! against the file's size and the memory it would take before anything is allocated.

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use crate::scene::Rgb;

use super::{MergedSums, ShardError, ShardHeader, ShardKind, ShardState, WordHash};

/// The file's first eight bytes.
pub const MAGIC: [u8; 8] = *b"LBSHARD\0";
/// The format this build writes and reads (2: the shard kind, the LOD's texel count and a
/// region shard's charts).
pub const FORMAT_VERSION: u32 = 2;
/// Bytes of the fixed header.
pub const HEADER_BYTES: u64 = 96;
/// Most bytes of the job JSON (a scene path and the bake's options: a few hundred bytes).
pub const MAX_JOB_BYTES: u32 = 1 << 20;

const FLAG_LIGHT: u32 = 1;
const FLAG_PUNCTUAL: u32 = 2;

impl ShardHeader {
    /// Bytes of the texels' sums: 16 a texel (the global bundles' `Σ S rgb, Σ A`), 12 more
    /// with the light pass, 12 more with the punctual part.
    pub fn payload_bytes(&self) -> Option<u64> {
        let per_texel = 16 + 12 * u64::from(self.has_light) + 12 * u64::from(self.has_punctual);
        self.texels.checked_mul(per_texel)
    }

    fn encode(&self, job_bytes: u32) -> [u8; HEADER_BYTES as usize] {
        let mut h = [0u8; HEADER_BYTES as usize];
        let flags = (FLAG_LIGHT * u32::from(self.has_light)) | (FLAG_PUNCTUAL * u32::from(self.has_punctual));
        h[0..8].copy_from_slice(&MAGIC);
        h[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
        h[12..16].copy_from_slice(&flags.to_le_bytes());
        h[16..24].copy_from_slice(&self.scene_hash.to_le_bytes());
        h[24..32].copy_from_slice(&self.options_hash.to_le_bytes());
        h[32..36].copy_from_slice(&self.lod.to_le_bytes());
        h[36..40].copy_from_slice(&self.round.to_le_bytes());
        h[40..44].copy_from_slice(&self.index.to_le_bytes());
        h[44..48].copy_from_slice(&self.count.to_le_bytes());
        h[48..56].copy_from_slice(&self.texels.to_le_bytes());
        h[56..64].copy_from_slice(&self.batches.to_le_bytes());
        h[64..72].copy_from_slice(&self.light_directions.to_le_bytes());
        h[72..76].copy_from_slice(&job_bytes.to_le_bytes());
        let kind: u32 = match self.kind {
            ShardKind::Directions => 0,
            ShardKind::Regions => 1,
        };
        h[76..80].copy_from_slice(&kind.to_le_bytes());
        h[80..88].copy_from_slice(&self.lod_texels.to_le_bytes());
        h[88..92].copy_from_slice(&(self.charts.len() as u32).to_le_bytes());
        h
    }
}

/// Writes `state` to `path` through a hidden temporary file in the same folder
/// (`.NAME.partial`, which no `shard-*` pattern matches), flushed to disk, then renamed:
/// a shard killed while writing leaves no file under the final name, and a re-run
/// replaces an older file whole.
pub fn write_state(path: &Path, state: &ShardState) -> Result<(), ShardError> {
    write_atomically(path, "partial", |w| write_body(w, state))
}

/// Writes `body` (then its checksum) to `path` through `.NAME.SUFFIX` in the same folder,
/// flushed to disk, then renamed: no reader ever sees a part of the file under its name.
pub(super) fn write_atomically(
    path: &Path,
    suffix: &str,
    body: impl FnOnce(&mut HashingWriter<BufWriter<File>>) -> std::io::Result<()>,
) -> Result<(), ShardError> {
    let dir = path.parent().filter(|d| !d.as_os_str().is_empty()).unwrap_or(Path::new("."));
    let name = path
        .file_name()
        .ok_or_else(|| ShardError::Io { path: path.to_path_buf(), source: std::io::Error::other("not a file name") })?;
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(".");
    tmp_name.push(suffix);
    let tmp = dir.join(tmp_name);
    let io = |source| ShardError::Io { path: tmp.clone(), source };
    let result = (|| {
        let file = File::create(&tmp).map_err(io)?;
        let mut w = HashingWriter { inner: BufWriter::with_capacity(1 << 20, file), hash: WordHash::new() };
        body(&mut w).map_err(io)?;
        let sum = w.hash.finish();
        w.inner.write_all(&sum.to_le_bytes()).map_err(io)?;
        let file = w.inner.into_inner().map_err(|e| io(e.into_error()))?;
        file.sync_all().map_err(io)?;
        std::fs::rename(&tmp, path).map_err(|source| ShardError::Io { path: path.to_path_buf(), source })
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

fn write_body(w: &mut impl Write, state: &ShardState) -> std::io::Result<()> {
    let h = &state.header;
    let job = state.job.as_bytes();
    let job_bytes = u32::try_from(job.len()).ok().filter(|&n| n <= MAX_JOB_BYTES).ok_or_else(|| {
        std::io::Error::other(format!("the job description is {} bytes, more than {MAX_JOB_BYTES}", job.len()))
    })?;
    if h.charts.len() > u32::MAX as usize {
        return Err(std::io::Error::other("more charts than a shard file can name"));
    }
    w.write_all(&h.encode(job_bytes))?;
    w.write_all(job)?;
    for c in &h.charts {
        w.write_all(&c.to_le_bytes())?;
    }
    let e = &state.estimate;
    let mut buf = Vec::with_capacity(CHUNK_BYTES + 16);
    write_f32s(w, (0..e.len()).map(|i| e.bundle_sums(i)), &mut buf)?;
    for part in [e.light_sums(), e.punctual()] {
        write_f32s(w, part.iter().map(|c| c.to_array()), &mut buf)?;
    }
    Ok(())
}

/// Bytes of records [`write_words`] encodes before each write.
const CHUNK_BYTES: usize = 1 << 16;

/// Writes `records` as little-endian f32s (see [`write_words`]).
fn write_f32s<const K: usize>(
    w: &mut impl Write,
    records: impl Iterator<Item = [f32; K]>,
    buf: &mut Vec<u8>,
) -> std::io::Result<()> {
    write_words(w, records.map(|r| r.map(f32::to_bits)), buf)
}

/// Writes `records` as little-endian 32-bit words, encoded a chunk at a time into `buf`: a
/// write of four bytes through the hashing writer cost more than the encoding (the same
/// bytes), and a record at a time, not a word, the encoding is a few instructions a byte.
pub(super) fn write_words<const K: usize>(
    w: &mut impl Write,
    records: impl Iterator<Item = [u32; K]>,
    buf: &mut Vec<u8>,
) -> std::io::Result<()> {
    buf.clear();
    for r in records {
        for v in r {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        if buf.len() >= CHUNK_BYTES {
            w.write_all(buf)?;
            buf.clear();
        }
    }
    w.write_all(buf)
}

/// Reads `n` records of `size` bytes from `r`, [`CHUNK_BYTES`] or so at a time into
/// `buf`, and calls `f(k, record k)` on each: a read of a record at a time through the hashing
/// reader cost more than the merge's additions (the same bytes, hashed the same).
pub(super) fn read_records(
    r: &mut impl Read,
    n: usize,
    size: usize,
    buf: &mut Vec<u8>,
    mut f: impl FnMut(usize, &[u8]),
) -> std::io::Result<()> {
    let per_chunk = (CHUNK_BYTES / size).max(1);
    buf.resize(per_chunk * size, 0);
    let mut k = 0;
    while k < n {
        let m = per_chunk.min(n - k);
        r.read_exact(&mut buf[..m * size])?;
        for (j, record) in buf[..m * size].chunks_exact(size).enumerate() {
            f(k + j, record);
        }
        k += m;
    }
    Ok(())
}

pub(super) struct HashingWriter<W: Write> {
    pub(super) inner: W,
    pub(super) hash: WordHash,
}

impl<W: Write> Write for HashingWriter<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash.update(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// A shard file's header and job, read and checked (its sums not yet read).
pub struct ShardFile {
    pub path: PathBuf,
    pub header: ShardHeader,
    pub job: String,
    job_bytes: u32,
}

/// Reads `path`'s header and job: a file that is not a shard file, of another format
/// version, or whose size disagrees with what its header says is refused here, naming the
/// file, before its sums are read.
pub fn read_header(path: &Path) -> Result<ShardFile, ShardError> {
    let bad = |why: String| ShardError::Invalid { path: path.to_path_buf(), why };
    let io = |source| ShardError::Io { path: path.to_path_buf(), source };
    let mut file = File::open(path).map_err(io)?;
    let size = file.metadata().map_err(io)?.len();
    let mut h = [0u8; HEADER_BYTES as usize];
    let head = size.min(HEADER_BYTES) as usize;
    file.read_exact(&mut h[..head]).map_err(io)?;
    if head < MAGIC.len() || h[0..8] != MAGIC {
        return Err(bad("not a livebake shard file (its first bytes are not LBSHARD)".into()));
    }
    if size < HEADER_BYTES + 8 {
        return Err(bad(format!("truncated: {size} bytes, shorter than a shard file's header")));
    }
    let u32_at = |o: usize| u32::from_le_bytes([h[o], h[o + 1], h[o + 2], h[o + 3]]);
    let u64_at = |o: usize| u64::from_le_bytes(std::array::from_fn(|k| h[o + k]));
    let version = u32_at(8);
    if version != FORMAT_VERSION {
        return Err(bad(format!("format version {version}; this livebake reads version {FORMAT_VERSION}")));
    }
    let flags = u32_at(12);
    if flags & !(FLAG_LIGHT | FLAG_PUNCTUAL) != 0 {
        return Err(bad(format!("unknown flags {flags:#x}")));
    }
    let kind = match u32_at(76) {
        0 => ShardKind::Directions,
        1 => ShardKind::Regions,
        k => return Err(bad(format!("unknown shard kind {k} (0: directions, 1: regions)"))),
    };
    if u32_at(92) != 0 {
        return Err(bad("its reserved header word is not zero".into()));
    }
    let chart_count = u32_at(88);
    let mut header = ShardHeader {
        scene_hash: u64_at(16),
        options_hash: u64_at(24),
        lod: u32_at(32),
        round: u32_at(36),
        index: u32_at(40),
        count: u32_at(44),
        texels: u64_at(48),
        batches: u64_at(56),
        light_directions: u64_at(64),
        has_light: flags & FLAG_LIGHT != 0,
        has_punctual: flags & FLAG_PUNCTUAL != 0,
        kind,
        lod_texels: u64_at(80),
        charts: Vec::new(),
    };
    match kind {
        ShardKind::Directions if chart_count != 0 || header.texels != header.lod_texels => {
            return Err(bad(format!(
                "a direction shard of {} texels (of {}) naming {chart_count} charts",
                header.texels, header.lod_texels
            )));
        }
        ShardKind::Regions if header.texels > header.lod_texels => {
            return Err(bad(format!("a region of {} texels in a LOD of {}", header.texels, header.lod_texels)));
        }
        _ => {}
    }
    if header.count == 0 || header.index >= header.count || header.round == 0 {
        return Err(bad(format!("share {}/{} of round {} is not a share", header.index, header.count, header.round)));
    }
    let job_bytes = u32_at(72);
    if job_bytes > MAX_JOB_BYTES {
        return Err(bad(format!("a job description of {job_bytes} bytes (at most {MAX_JOB_BYTES})")));
    }
    // The charts' bytes count in the size checked below (read after it).
    let charts_bytes = 4 * chart_count as u64;
    let expected = header
        .payload_bytes()
        .and_then(|p| p.checked_add(HEADER_BYTES + job_bytes as u64 + charts_bytes + 8))
        .ok_or_else(|| bad(format!("{} texels is more than a file can hold", header.texels)))?;
    if size != expected {
        let what = if size < expected { "truncated" } else { "longer than its header says" };
        return Err(bad(format!("{what}: {size} bytes, where its header ({} texels) makes {expected}", header.texels)));
    }
    let mut job = vec![0u8; job_bytes as usize];
    file.read_exact(&mut job).map_err(io)?;
    let job = String::from_utf8(job).map_err(|_| bad("its job description is not UTF-8".into()))?;
    let mut charts = vec![0u8; charts_bytes as usize];
    file.read_exact(&mut charts).map_err(io)?;
    header.charts = charts.chunks_exact(4).map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]])).collect();
    if header.charts.windows(2).any(|w| w[0] >= w[1]) {
        return Err(bad("its charts are not in ascending order (or one is named twice)".into()));
    }
    Ok(ShardFile { path: path.to_path_buf(), header, job, job_bytes })
}

impl ShardFile {
    /// Where the texels' sums start: after the header, the job and a region shard's charts.
    pub fn sums_offset(&self) -> u64 {
        HEADER_BYTES + self.job_bytes as u64 + 4 * self.header.charts.len() as u64
    }

    /// Reads the checksum that ends the file from `r`, which has hashed everything before
    /// it, and compares.
    fn check_trailer<R: Read>(&self, mut r: HashingReader<R>) -> Result<(), ShardError> {
        let computed = r.hash.finish();
        let mut sum = [0u8; 8];
        r.inner.read_exact(&mut sum).map_err(|source| ShardError::Io { path: self.path.clone(), source })?;
        if u64::from_le_bytes(sum) != computed {
            return Err(ShardError::Invalid {
                path: self.path.clone(),
                why: "its checksum does not match its contents (the file is damaged)".into(),
            });
        }
        Ok(())
    }

    /// Reads the whole file once, holding nothing but a buffer, and checks its checksum:
    /// what a reader that takes the sums section by section
    /// ([`super::PreviousRound`]) checks before it reads them.
    pub fn verify(&self) -> Result<(), ShardError> {
        let io = |source| ShardError::Io { path: self.path.clone(), source };
        let file = File::open(&self.path).map_err(io)?;
        let size = file.metadata().map_err(io)?.len();
        let mut r = HashingReader { inner: BufReader::with_capacity(1 << 16, file), hash: WordHash::new() };
        let mut left = size.saturating_sub(8);
        let mut buf = vec![0u8; 1 << 16];
        while left > 0 {
            let n = left.min(buf.len() as u64) as usize;
            r.read_exact(&mut buf[..n]).map_err(io)?;
            left -= n as u64;
        }
        self.check_trailer(r)
    }

    /// Adds the file's sums to `sums` texel by texel, then checks the checksum: its texel k
    /// to texel `place[k]` of `sums` (a region shard's), or to texel k. The caller has
    /// checked the texel count against the atlas (`sums` is of that size) and the memory
    /// it takes.
    pub fn add_sums_to(&self, sums: &mut MergedSums, place: Option<&[u32]>) -> Result<(), ShardError> {
        let io = |source| ShardError::Io { path: self.path.clone(), source };
        let n = self.header.texels as usize;
        let whole = sums.bundle.len();
        let fits = match place {
            Some(p) => p.len() == n && p.iter().all(|&i| (i as usize) < whole),
            None => whole == n,
        };
        if !fits {
            return Err(ShardError::Invalid {
                path: self.path.clone(),
                why: format!("{n} texels where the merge holds {whole}"),
            });
        }
        let at = |k: usize| place.map_or(k, |p| p[k] as usize);
        let file = File::open(&self.path).map_err(io)?;
        let mut r = HashingReader { inner: BufReader::with_capacity(1 << 20, file), hash: WordHash::new() };
        let mut skip = vec![0u8; HEADER_BYTES as usize + self.job_bytes as usize + 4 * self.header.charts.len()];
        r.read_exact(&mut skip).map_err(io)?;
        let f32_at = |b: &[u8], k: usize| f32::from_le_bytes([b[4 * k], b[4 * k + 1], b[4 * k + 2], b[4 * k + 3]]);
        let mut buf = Vec::new();
        read_records(&mut r, n, 16, &mut buf, |t, b| {
            for (k, v) in sums.bundle[at(t)].iter_mut().enumerate() {
                *v += f32_at(b, k);
            }
        })
        .map_err(io)?;
        for (present, part) in
            [(self.header.has_light, &mut sums.light), (self.header.has_punctual, &mut sums.punctual)]
        {
            if !present {
                continue;
            }
            if part.is_empty() {
                part.resize(whole, Rgb::ZERO);
            }
            read_records(&mut r, n, 12, &mut buf, |t, b| {
                part[at(t)] += Rgb::new(f32_at(b, 0), f32_at(b, 1), f32_at(b, 2));
            })
            .map_err(io)?;
        }
        sums.batches += self.header.batches;
        sums.light_directions += self.header.light_directions;
        self.check_trailer(r)
    }
}

pub(super) struct HashingReader<R: Read> {
    pub(super) inner: R,
    pub(super) hash: WordHash,
}

impl<R: Read> Read for HashingReader<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.hash.update(&buf[..n]);
        Ok(n)
    }
}
