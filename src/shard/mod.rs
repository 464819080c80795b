//! Direction shards (docs/SHARDS.md): one round of a bounce-rounds bake
//! ([`crate::bake::rounds`]) cut into N disjoint shares of its batches, each baked on its own
//! machine into a shard file of per-texel sums; the merge checks that the files belong
//! together and adds them up.

pub mod file;
pub mod layout;
pub mod previous;

use std::path::PathBuf;

use crate::bundle::progressive::{ProgressiveEstimate, SourceKind};
use crate::scene::Rgb;

pub use file::{ShardFile, read_header, write_state};
pub use layout::{Layout, LayoutPlace};
pub use previous::PreviousRound;

/// Most shares a round may be cut into.
pub const MAX_SHARDS: u32 = 1 << 16;

/// What a shard file says about itself.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ShardHeader {
    /// [`WordHash`] of the scene's files (document, buffers, images, environment map).
    pub scene_hash: u64,
    /// [`WordHash`] of every option that changes the result.
    pub options_hash: u64,
    pub lod: u32,
    /// The bounce round (from 1).
    pub round: u32,
    /// The share: batches `b` with `b mod count = index`. A merged state is share 0 of 1.
    pub index: u32,
    pub count: u32,
    pub texels: u64,
    /// Batches and light directions (per emitter group) the sums hold.
    pub batches: u64,
    pub light_directions: u64,
    pub has_light: bool,
    pub has_punctual: bool,
    /// What the share is a share of: directions (every texel, some batches; a merged state
    /// too) or regions (some texels, every batch).
    pub kind: ShardKind,
    /// Texels of the whole LOD (a direction shard's `texels`).
    pub lod_texels: u64,
    /// A region shard's charts (ascending): its texels are theirs, in the order of their
    /// ids in the whole LOD's map. Empty for a direction shard.
    pub charts: Vec<u32>,
}

/// How a round was cut into shares.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShardKind {
    /// Share I of N of the batches, every texel (a merged state is share 0 of 1).
    Directions,
    /// Share I of N of the texels (whole charts), every batch.
    Regions,
}

impl ShardKind {
    pub fn name(self) -> &'static str {
        match self {
            ShardKind::Directions => "direction",
            ShardKind::Regions => "region",
        }
    }
}

/// A shard's (or a merge's) state: its header, the job that made it (JSON: the scene and
/// its options, how to make the same bake again), and the estimate of its sums.
pub struct ShardState {
    pub header: ShardHeader,
    pub job: String,
    pub estimate: ProgressiveEstimate,
}

impl ShardState {
    /// The state of `estimate`, with its counts in the header.
    pub fn new(
        scene_hash: u64,
        options_hash: u64,
        lod: u32,
        round: u32,
        (index, count): (u32, u32),
        job: String,
        estimate: ProgressiveEstimate,
    ) -> Self {
        let header = ShardHeader {
            scene_hash,
            options_hash,
            lod,
            round,
            index,
            count,
            texels: estimate.len() as u64,
            batches: estimate.batches(),
            light_directions: estimate.light_directions(),
            has_light: !estimate.light_sums().is_empty(),
            has_punctual: !estimate.punctual().is_empty(),
            kind: ShardKind::Directions,
            lod_texels: estimate.len() as u64,
            charts: Vec::new(),
        };
        ShardState { header, job, estimate }
    }

    /// Marks the state a region shard's: it holds the texels of `charts` (ascending) of a
    /// LOD of `lod_texels` texels.
    pub fn of_regions(mut self, charts: Vec<u32>, lod_texels: u64) -> Self {
        self.header.kind = ShardKind::Regions;
        self.header.charts = charts;
        self.header.lod_texels = lod_texels;
        self
    }
}

/// Errors of shard files and of a set of them.
#[derive(Debug, thiserror::Error)]
pub enum ShardError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a usable shard file: {why}")]
    Invalid { path: PathBuf, why: String },
    #[error("{path} is not a usable layout file: {why}")]
    InvalidLayout { path: PathBuf, why: String },
    #[error("{path} does not belong with {first}: {why}")]
    Foreign { path: PathBuf, first: PathBuf, why: String },
    #[error("{second} and {first} are both share {index} of {count}")]
    Duplicate { first: PathBuf, second: PathBuf, index: u32, count: u32 },
    #[error("missing {missing} of the {count} shares of round {round} (share {list}; expected file {expected})")]
    Missing { missing: usize, count: u32, round: u32, list: String, expected: String },
    #[error("no shard files given")]
    NoFiles,
    #[error("{path} is a {kind} shard and {first} a {first_kind} shard: one merge takes shards of one kind")]
    MixedKinds { path: PathBuf, kind: &'static str, first: PathBuf, first_kind: &'static str },
    #[error("{second} and {first} both hold chart {chart} (region shards must hold disjoint charts)")]
    Overlap { first: PathBuf, second: PathBuf, chart: u32 },
    #[error("no region shard holds chart {chart} ({texels} texels): the shares do not cover the atlas")]
    Uncovered { chart: u32, texels: u64 },
    #[error("merging {texels} texels takes {need} bytes, more than the limit of {limit} bytes ({source_of_limit})")]
    OutOfMemory { texels: u64, need: u64, limit: u64, source_of_limit: &'static str },
}

/// The file name of share `index` of `count` (zero-padded so that `shard-*` lists them in
/// order).
pub fn shard_file_name(index: u32, count: u32) -> String {
    format!("shard-{index:04}-of-{count:04}.lbshard")
}

/// The merged state a merge writes beside the light maps (read by the next round's shards).
pub const MERGED_STATE: &str = "merged.lbshard";

/// Parses `I/N`: share I (0 ≤ I < N) of N.
pub fn parse_share(s: &str) -> Result<(u32, u32), String> {
    let (i, n) = s.split_once('/').ok_or_else(|| format!("expected I/N (share I of N, from 0), got {s:?}"))?;
    let parse = |v: &str| v.trim().parse::<u32>().map_err(|_| format!("expected I/N with whole numbers, got {s:?}"));
    let (i, n) = (parse(i)?, parse(n)?);
    if n == 0 || n > MAX_SHARDS {
        return Err(format!("N of I/N must be between 1 and {MAX_SHARDS}, got {n}"));
    }
    if i >= n {
        return Err(format!("I of I/N counts from 0 and must be below N, got {i}/{n}"));
    }
    Ok((i, n))
}

/// Checks that `files` are every share of one round of one bake, each once: the same scene,
/// options, LOD, round, share count and texel count as the first; no share twice; none
/// missing. Returns them in share order.
pub fn check_set(mut files: Vec<ShardFile>) -> Result<Vec<ShardFile>, ShardError> {
    let Some(first) = files.first() else { return Err(ShardError::NoFiles) };
    let (f, fp) = (first.header.clone(), first.path.clone());
    for s in &files[1..] {
        let h = &s.header;
        let foreign = |why: String| ShardError::Foreign { path: s.path.clone(), first: fp.clone(), why };
        if h.scene_hash != f.scene_hash {
            return Err(foreign(format!(
                "another scene (content hash {:016x} against {:016x})",
                h.scene_hash, f.scene_hash
            )));
        }
        if h.options_hash != f.options_hash {
            return Err(foreign(format!(
                "other bake options (options hash {:016x} against {:016x})",
                h.options_hash, f.options_hash
            )));
        }
        if (h.lod, h.round) != (f.lod, f.round) {
            return Err(foreign(format!("LOD {} round {} against LOD {} round {}", h.lod, h.round, f.lod, f.round)));
        }
        if h.kind != f.kind {
            return Err(ShardError::MixedKinds {
                path: s.path.clone(),
                kind: h.kind.name(),
                first: fp.clone(),
                first_kind: f.kind.name(),
            });
        }
        if h.count != f.count {
            return Err(foreign(format!("a share of {} against a share of {}", h.count, f.count)));
        }
        if h.lod_texels != f.lod_texels || (h.kind == ShardKind::Directions && h.texels != f.texels) {
            return Err(foreign(format!("a LOD of {} texels against {}", h.lod_texels, f.lod_texels)));
        }
        if h.kind == ShardKind::Regions && (h.batches, h.light_directions) != (f.batches, f.light_directions) {
            return Err(foreign(format!(
                "{} batches and {} light directions against {} and {}",
                h.batches, h.light_directions, f.batches, f.light_directions
            )));
        }
    }
    files.sort_by_key(|s| s.header.index);
    for pair in files.windows(2) {
        if pair[0].header.index == pair[1].header.index {
            return Err(ShardError::Duplicate {
                first: pair[0].path.clone(),
                second: pair[1].path.clone(),
                index: pair[0].header.index,
                count: f.count,
            });
        }
    }
    let present: std::collections::HashSet<u32> = files.iter().map(|s| s.header.index).collect();
    let missing: Vec<u32> = (0..f.count).filter(|i| !present.contains(i)).collect();
    if let Some(&m) = missing.first() {
        let list = missing.iter().take(8).map(|i| i.to_string()).collect::<Vec<_>>().join(", ");
        let list = if missing.len() > 8 { format!("{list}, …") } else { list };
        return Err(ShardError::Missing {
            missing: missing.len(),
            count: f.count,
            round: f.round,
            list,
            expected: shard_file_name(m, f.count),
        });
    }
    Ok(files)
}

/// The sums of shards being merged, texel by texel.
pub struct MergedSums {
    pub bundle: Vec<[f32; 4]>,
    /// Empty until a shard brings light-pass sums (or punctual parts).
    pub light: Vec<Rgb>,
    pub punctual: Vec<Rgb>,
    pub batches: u64,
    pub light_directions: u64,
}

/// Bytes a merge of shards like `header` holds while it adds them up (its sums, whole).
pub fn merge_bytes(header: &ShardHeader) -> Option<u64> {
    header.lod_texels.checked_mul(16 + 12 + 12)
}

/// Where each region shard's texels go (ids in the whole LOD's map, ascending), from the
/// charts each holds: `files` checked by [`check_set`] (in share order), `chart_of(i)` the
/// chart of texel `i` of the whole LOD's `texels`, `charts` the atlas's chart count. The
/// shards' charts must be disjoint, cover every chart holding texels, and hold the texel
/// counts the shards say.
pub fn region_placement(
    files: &[ShardFile],
    texels: usize,
    charts: usize,
    chart_of: impl Fn(usize) -> u32,
) -> Result<Vec<Vec<u32>>, ShardError> {
    const FREE: u32 = u32::MAX;
    let mut owner = vec![FREE; charts];
    for (k, f) in files.iter().enumerate() {
        for &c in &f.header.charts {
            let Some(o) = owner.get_mut(c as usize) else {
                return Err(ShardError::Invalid {
                    path: f.path.clone(),
                    why: format!("it holds chart {c}, and the atlas has {charts} charts"),
                });
            };
            if *o != FREE {
                return Err(ShardError::Overlap {
                    first: files[*o as usize].path.clone(),
                    second: f.path.clone(),
                    chart: c,
                });
            }
            *o = k as u32;
        }
    }
    let mut lists: Vec<Vec<u32>> = files.iter().map(|f| Vec::with_capacity(f.header.texels as usize)).collect();
    for i in 0..texels {
        let c = chart_of(i);
        match owner.get(c as usize) {
            Some(&o) if o != FREE => lists[o as usize].push(i as u32),
            _ => {
                let texels = (0..texels).filter(|&j| chart_of(j) == c).count() as u64;
                return Err(ShardError::Uncovered { chart: c, texels });
            }
        }
    }
    for (f, l) in files.iter().zip(&lists) {
        if l.len() as u64 != f.header.texels {
            return Err(ShardError::Invalid {
                path: f.path.clone(),
                why: format!("it holds {} texels, and its charts hold {} in this atlas", f.header.texels, l.len()),
            });
        }
    }
    Ok(lists)
}

/// Adds up `files` (checked by [`check_set`], in share order) in share order: each texel's
/// sums are added in float, starting from zero, shard 0 first. Region shards
/// (`placement`: each one's texels, [`region_placement`]) each hold their own texels'
/// sums over every batch: they are put in place, not added. `limit`: the most bytes the
/// sums may take, checked before they are allocated (with where the limit comes from).
pub fn merge(
    files: &[ShardFile],
    placement: Option<&[Vec<u32>]>,
    limit: (u64, &'static str),
) -> Result<ProgressiveEstimate, ShardError> {
    let first = files.first().ok_or(ShardError::NoFiles)?;
    let texels = first.header.lod_texels;
    let need = merge_bytes(&first.header).unwrap_or(u64::MAX);
    if need > limit.0 {
        return Err(ShardError::OutOfMemory { texels, need, limit: limit.0, source_of_limit: limit.1 });
    }
    let mut sums = MergedSums {
        bundle: vec![[0.0; 4]; texels as usize],
        light: Vec::new(),
        punctual: Vec::new(),
        batches: 0,
        light_directions: 0,
    };
    for (k, f) in files.iter().enumerate() {
        f.add_sums_to(&mut sums, placement.and_then(|p| p.get(k)).map(Vec::as_slice))?;
    }
    // Every direction shard's light directions count for every group, so the merged count
    // is their sum; the batches too. Every region shard traced every batch.
    if placement.is_some() {
        sums.batches = first.header.batches;
        sums.light_directions = first.header.light_directions;
    }
    Ok(ProgressiveEstimate::from_sums(
        SourceKind::Converged,
        sums.bundle,
        sums.light,
        sums.light_directions,
        sums.batches,
        sums.punctual,
    ))
}

/// A 64-bit hash of a byte stream, word by word (FxHash's step on little-endian 8-byte
/// words, the length mixed in at the end): a content fingerprint for scene files and a
/// checksum for shard files, the same on every machine. Not cryptographic: it tells files
/// apart and catches damage, it does not resist forgery.
#[derive(Clone, Debug)]
pub struct WordHash {
    state: u64,
    tail: [u8; 8],
    tail_len: usize,
    length: u64,
}

impl Default for WordHash {
    fn default() -> Self {
        Self::new()
    }
}

impl WordHash {
    const K: u64 = 0x517c_c1b7_2722_0a95;

    pub fn new() -> Self {
        WordHash { state: 0x6c62_7368_6172_6400, tail: [0; 8], tail_len: 0, length: 0 }
    }

    #[inline]
    fn word(&mut self, w: u64) {
        self.state = (self.state.rotate_left(5) ^ w).wrapping_mul(Self::K);
    }

    pub fn update(&mut self, mut bytes: &[u8]) {
        self.length += bytes.len() as u64;
        if self.tail_len > 0 {
            let take = (8 - self.tail_len).min(bytes.len());
            self.tail[self.tail_len..self.tail_len + take].copy_from_slice(&bytes[..take]);
            self.tail_len += take;
            bytes = &bytes[take..];
            if self.tail_len < 8 {
                return;
            }
            self.word(u64::from_le_bytes(self.tail));
            self.tail_len = 0;
        }
        let mut words = bytes.chunks_exact(8);
        for w in &mut words {
            self.word(u64::from_le_bytes([w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7]]));
        }
        let rest = words.remainder();
        self.tail[..rest.len()].copy_from_slice(rest);
        self.tail_len = rest.len();
    }

    /// Hashes a string with its length first (so that a sequence of them is unambiguous).
    pub fn update_str(&mut self, s: &str) {
        self.update(&(s.len() as u64).to_le_bytes());
        self.update(s.as_bytes());
    }

    pub fn finish(&self) -> u64 {
        let mut h = self.clone();
        if h.tail_len > 0 {
            let mut last = [0u8; 8];
            last[..h.tail_len].copy_from_slice(&h.tail[..h.tail_len]);
            h.word(u64::from_le_bytes(last));
        }
        h.word(h.length);
        crate::sampling::mix64(h.state)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The hash does not depend on how the stream is cut into writes, and tells a byte's
    /// change, a trailing zero and a reordering apart.
    #[test]
    fn the_word_hash_is_the_same_whatever_the_writes() {
        let data: Vec<u8> = (0..1000u32).map(|i| (i * 37 % 251) as u8).collect();
        let mut whole = WordHash::new();
        whole.update(&data);
        for cut in [1, 3, 7, 8, 9, 16, 999] {
            let mut parts = WordHash::new();
            for c in data.chunks(cut) {
                parts.update(c);
            }
            assert_eq!(parts.finish(), whole.finish(), "chunks of {cut}");
        }
        let mut changed = data.clone();
        changed[500] ^= 1;
        let mut longer = data.clone();
        longer.push(0);
        let mut swapped = data.clone();
        swapped.swap(0, 8);
        for other in [changed, longer, swapped] {
            let mut h = WordHash::new();
            h.update(&other);
            assert_ne!(h.finish(), whole.finish());
        }
    }

    #[test]
    fn shares_parse_and_refuse() {
        assert_eq!(parse_share("0/4"), Ok((0, 4)));
        assert_eq!(parse_share("3/4"), Ok((3, 4)));
        for bad in ["4/4", "1/0", "a/4", "3", "-1/4", "1/99999999"] {
            assert!(parse_share(bad).is_err(), "{bad}");
        }
    }
}
