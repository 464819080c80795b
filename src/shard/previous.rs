//! The previous round's merged state as a shard's round reads it (`bake --shard …
//! --previous merged.lbshard`): streamed from the file, not held. A round reads of it each
//! texel's irradiance (its source is `albedo/π · E` plus the carried emission) and the
//! punctual part it carries: 12 B a texel (and 12 B a carried punctual texel), where the
//! merged sums read whole took 40 B a texel of the LOD beside the texel map.

use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};

use crate::bundle::progressive::irradiance_of_sums;
use crate::scene::Rgb;

use super::{ShardError, ShardFile, ShardHeader};

/// Bytes a reader of the sums buffers per section.
const BUFFER_BYTES: usize = 1 << 16;

/// A merged state (share 0 of 1) whose checksum has been checked, read section by section.
pub struct PreviousRound {
    file: ShardFile,
}

/// One section of the sums: `width` f32 a texel from `offset`.
struct Section {
    reader: BufReader<File>,
    width: usize,
}

impl Section {
    fn read(&mut self, into: &mut [f32; 4]) -> std::io::Result<()> {
        let mut b = [0u8; 16];
        self.reader.read_exact(&mut b[..4 * self.width])?;
        for (k, v) in into.iter_mut().enumerate().take(self.width) {
            *v = f32::from_le_bytes([b[4 * k], b[4 * k + 1], b[4 * k + 2], b[4 * k + 3]]);
        }
        Ok(())
    }
}

impl PreviousRound {
    /// The merged state `file` (checked by the caller as this bake's: share 0 of 1, of the
    /// same scene and options), once its checksum holds (one pass over the file, nothing
    /// held). `limit`: the most bytes its reading may take (12 B a texel, 24 B with a
    /// punctual part), checked first.
    pub fn open(file: ShardFile, limit: (u64, &'static str)) -> Result<Self, ShardError> {
        let h = &file.header;
        let need = h.lod_texels.saturating_mul(12 + 12 * u64::from(h.has_punctual));
        if need > limit.0 {
            return Err(ShardError::OutOfMemory {
                texels: h.lod_texels,
                need,
                limit: limit.0,
                source_of_limit: limit.1,
            });
        }
        if h.texels != h.lod_texels {
            return Err(ShardError::Invalid {
                path: file.path.clone(),
                why: format!("a merged state of {} texels of a LOD of {}", h.texels, h.lod_texels),
            });
        }
        file.verify()?;
        Ok(PreviousRound { file })
    }

    pub fn header(&self) -> &ShardHeader {
        &self.file.header
    }

    /// Texels of the LOD the state holds.
    pub fn texels(&self) -> usize {
        self.file.header.texels as usize
    }

    fn io(&self) -> impl Fn(std::io::Error) -> ShardError + '_ {
        |source| ShardError::Io { path: self.file.path.clone(), source }
    }

    /// A reader of the section `index` (0: the global bundles' sums, 1: the light pass's,
    /// 2: the punctual part), or none when the file holds no such section.
    fn section(&self, index: usize) -> Result<Option<Section>, ShardError> {
        let h = &self.file.header;
        let n = h.texels;
        let present = [true, h.has_light, h.has_punctual];
        if !present[index] {
            return Ok(None);
        }
        let widths = [16u64, 12, 12];
        let before: u64 = (0..index).filter(|&k| present[k]).map(|k| widths[k] * n).sum();
        let mut file = File::open(&self.file.path).map_err(self.io())?;
        file.seek(SeekFrom::Start(self.file.sums_offset() + before)).map_err(self.io())?;
        Ok(Some(Section { reader: BufReader::with_capacity(BUFFER_BYTES, file), width: widths[index] as usize / 4 }))
    }

    /// Each texel's irradiance: what [`super::merge`] of this file alone, then
    /// [`crate::bundle::progressive::ProgressiveEstimate::irradiance_of`], give, from the
    /// same float operations (each sum added to zero, as the merge does, then
    /// [`irradiance_of_sums`]), so a round reading it makes the single bake's source bits.
    pub fn irradiance(&self) -> Result<Vec<Rgb>, ShardError> {
        let io = self.io();
        let h = &self.file.header;
        let mut bundle = self.section(0)?;
        let mut light = self.section(1)?;
        let mut punctual = self.section(2)?;
        let mut out = Vec::with_capacity(self.texels());
        let (mut b, mut l, mut p) = ([0f32; 4], [0f32; 4], [0f32; 4]);
        let zero_plus = |v: [f32; 4]| v.map(|x| 0.0f32 + x);
        for _ in 0..self.texels() {
            if let Some(s) = bundle.as_mut() {
                s.read(&mut b).map_err(&io)?;
            }
            let light_sum = match light.as_mut() {
                Some(s) => {
                    s.read(&mut l).map_err(&io)?;
                    let l = zero_plus(l);
                    Some(Rgb::new(l[0], l[1], l[2]))
                }
                None => None,
            };
            let punctual_part = match punctual.as_mut() {
                Some(s) => {
                    s.read(&mut p).map_err(&io)?;
                    let p = zero_plus(p);
                    Some(Rgb::new(p[0], p[1], p[2]))
                }
                None => None,
            };
            out.push(irradiance_of_sums(zero_plus(b), light_sum, h.light_directions, punctual_part));
        }
        Ok(out)
    }

    /// The punctual part the state carries, of texels `keep` (ascending ids) or of every
    /// texel; empty when it holds none.
    pub fn punctual(&self, keep: Option<&[u32]>) -> Result<Vec<Rgb>, ShardError> {
        let io = self.io();
        let Some(mut s) = self.section(2)? else { return Ok(Vec::new()) };
        let n = self.texels();
        let mut out = Vec::with_capacity(keep.map_or(n, <[u32]>::len));
        let mut p = [0f32; 4];
        let mut wanted = keep.map(|k| k.iter().copied().peekable());
        for i in 0..n as u32 {
            let take = match wanted.as_mut() {
                Some(w) => match w.peek() {
                    Some(&k) if k == i => {
                        w.next();
                        true
                    }
                    Some(_) => false,
                    None => break,
                },
                None => true,
            };
            s.read(&mut p).map_err(&io)?;
            if take {
                let p = p.map(|x| 0.0f32 + x);
                out.push(Rgb::new(p[0], p[1], p[2]));
            }
        }
        Ok(out)
    }
}
