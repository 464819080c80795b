//! The socket's messages (docs/SERVE.md describes them for the page's side). Everything
//! binary is little-endian and starts with a one-byte kind; entries are 4-byte aligned so
//! that the page reads them through typed arrays without copying.
//!
//! Server to page: the scene description (JSON text, [`SceneMessage`]), the geometry
//! ([`GEOMETRY`]), one message per material texture ([`TEXTURE`]), the sky ([`SKY`], when
//! it is not black), then light-map
//! updates ([`UPDATE`]): the first is the whole shown map (flag [`FULL`]), every later one
//! the pages one publish wrote and the cells whose shown LOD changed.
//!
//! Page to server: its pose ([`POSE`]), the acknowledgements of an update (once its upload
//! calls returned, and once the GPU has done them: [`ACK`], [`AckStage`]) and its frame
//! times ([`FRAMES`]). Anything else is malformed and closes that client.

use std::sync::Arc;

use glam::Vec3;
use serde::Serialize;

use crate::runtime::shown::{Page, PageChange, PageKey, ShownLightmap};

/// Server → page, binary: vertices of the scene's triangles.
pub const GEOMETRY: u8 = 1;
/// Server → page, binary: a material texture's RGBA8 pixels.
pub const TEXTURE: u8 = 2;
/// Server → page, binary: light-map pages and cell LODs.
pub const UPDATE: u8 = 3;
/// Server → page, binary: the sky picture (`scene::SkyPicture`), `u8 4, 3 × pad, u32 width,
/// u32 height`, then per pixel, row by row, RGBA f32 (A = 1).
pub const SKY: u8 = 4;
/// [`UPDATE`] flag: the page drops what it holds first (a whole map follows).
pub const FULL: u8 = 1;

/// Page → server: the viewer's pose.
pub const POSE: u8 = 1;
/// Page → server: an update's pages reached the page's texture (seq 0: a whole map's), at
/// the stage its second byte says ([`AckStage`]).
pub const ACK: u8 = 2;
/// Page → server: frame times.
pub const FRAMES: u8 = 3;

/// Bytes of an [`UPDATE`]'s header.
pub const UPDATE_HEADER: usize = 32;
/// Bytes of one cell-LOD entry of an [`UPDATE`].
pub const CELL_ENTRY: usize = 8;
/// Bytes before a page's texels in an [`UPDATE`] (layer, LOD, page position).
pub const PAGE_ENTRY_HEADER: usize = 12;
/// 4-byte words a vertex has in [`GEOMETRY`]: 9 floats (position, material UV, light-map UV
/// of the front face and of the back face, negative: no face), then the vertex colour as four
/// unorm16 (linear RGBA, white where the mesh has none).
pub const VERTEX_WORDS: usize = 11;

/// The scene description sent first (and again after a reload), as JSON text.
#[derive(Clone, Debug, Serialize)]
pub struct SceneMessage {
    #[serde(rename = "type")]
    pub kind: &'static str,
    /// Changes when a reload replaced the scene (the page drops its geometry and map).
    pub generation: u32,
    /// LOD-0 atlas size in texels (LOD k: 2^k times larger).
    pub atlas: [u32; 2],
    pub lods: u32,
    pub page_side: u32,
    /// Pages per row and rows of pages of each LOD (`[pages_x, pages_y]`).
    pub page_tables: Vec<[u32; 2]>,
    pub grid: GridMessage,
    pub blend_band: f32,
    /// Radiance scale before the tone curve 1 − exp(−L·exposure), then sRGB.
    pub exposure: f32,
    pub start: StartPose,
    pub materials: Vec<MaterialMessage>,
    pub batches: Vec<BatchMessage>,
    pub textures: Vec<TextureMessage>,
    /// The sky picture's width and height, sent in a [`SKY`] message; `None`: a black sky
    /// (the page shows its backdrop).
    pub sky: Option<[u32; 2]>,
    pub vertex_count: u32,
}

#[derive(Clone, Debug, Serialize)]
pub struct GridMessage {
    pub origin: [f32; 3],
    pub cell_size: f32,
    pub dims: [u32; 3],
}

/// Where the page starts: `view`'s start pose (glTF camera, else a framing view).
#[derive(Clone, Copy, Debug, Serialize)]
pub struct StartPose {
    pub eye: [f32; 3],
    pub target: [f32; 3],
    pub yfov: f32,
    pub znear: f32,
    pub zfar: f32,
    /// Fly speed, metres a second.
    pub speed: f32,
}

#[derive(Clone, Debug, Serialize)]
pub struct MaterialMessage {
    /// Linear RGBA factor.
    pub base_color: [f32; 4],
    /// W/(sr·m²).
    pub emission: [f32; 3],
    pub base_color_texture: Option<usize>,
    pub emissive_texture: Option<usize>,
    /// `MASK`'s cutoff (alpha below it is cut out); `None` for the other modes.
    pub alpha_cutoff: Option<f32>,
    /// `BLEND`: alpha is the fraction of the light the surface meets.
    pub blend: bool,
    /// `KHR_materials_transmission` factor, multiplied by `transmission_texture`'s red channel.
    pub transmission: f32,
    pub transmission_texture: Option<usize>,
}

/// One material's triangles: `count` vertices from `first`.
#[derive(Clone, Debug, Serialize)]
pub struct BatchMessage {
    pub material: usize,
    pub first: u32,
    pub count: u32,
    pub double_sided: bool,
}

#[derive(Clone, Debug, Serialize)]
pub struct TextureMessage {
    pub width: u32,
    pub height: u32,
    pub srgb: bool,
    /// "repeat", "mirrored_repeat" or "clamp_to_edge" for s and t.
    pub wrap: [&'static str; 2],
}

/// The viewer's pose as the page sends it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Pose {
    pub eye: Vec3,
    pub target: Vec3,
    pub yfov: f32,
    pub aspect: f32,
    pub height_px: u32,
}

/// What the page sent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ClientMessage {
    Pose(Pose),
    /// Update `seq` reached the page's texture at `stage`; `page_ms` is the page's clock then.
    Ack {
        seq: u32,
        stage: AckStage,
        page_ms: f64,
    },
    /// `frames` frames drawn, their mean time in milliseconds.
    Frames {
        frames: u32,
        mean_ms: f64,
    },
}

/// How far an update has got into the page's texture when the page acknowledges it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AckStage {
    /// The upload calls (`texSubImage2D`) returned: the GL has the texels, its GPU may not
    /// have written them yet (byte 0).
    Uploaded = 0,
    /// A fence placed after those calls is signalled: the texture holds them (byte 1).
    Done = 1,
}

/// Why a page's message was refused (the client is closed).
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ProtocolError {
    #[error("a text message where only binary ones are expected")]
    Text,
    #[error("an empty message")]
    Empty,
    #[error("unknown message kind {0}")]
    UnknownKind(u8),
    #[error("message kind {kind} is {len} bytes long, {want} expected")]
    Length { kind: u8, len: usize, want: usize },
    #[error("a pose with non-finite or degenerate values")]
    BadPose,
    #[error("frame statistics with non-finite values")]
    BadFrames,
    #[error("an acknowledgement of unknown stage {0}")]
    BadAckStage(u8),
}

fn f32_at(b: &[u8], at: usize) -> f32 {
    f32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn f64_at(b: &[u8], at: usize) -> f64 {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[at..at + 8]);
    f64::from_le_bytes(a)
}

/// Parses a binary message from the page; every length and value is checked.
pub fn parse_client(b: &[u8]) -> Result<ClientMessage, ProtocolError> {
    let kind = *b.first().ok_or(ProtocolError::Empty)?;
    let want = match kind {
        POSE => 40,
        ACK => 16,
        FRAMES => 16,
        k => return Err(ProtocolError::UnknownKind(k)),
    };
    if b.len() != want {
        return Err(ProtocolError::Length { kind, len: b.len(), want });
    }
    match kind {
        POSE => {
            let v = |i: usize| f32_at(b, 4 + 4 * i);
            let eye = Vec3::new(v(0), v(1), v(2));
            let target = Vec3::new(v(3), v(4), v(5));
            let (yfov, aspect, height_px) = (v(6), v(7), u32_at(b, 36));
            let ok = eye.is_finite()
                && target.is_finite()
                && eye != target
                && yfov.is_finite()
                && yfov > 0.0
                && yfov < std::f32::consts::PI
                && aspect.is_finite()
                && aspect > 0.0
                && (1..=65536).contains(&height_px);
            if !ok {
                return Err(ProtocolError::BadPose);
            }
            Ok(ClientMessage::Pose(Pose { eye, target, yfov, aspect, height_px }))
        }
        ACK => {
            let page_ms = f64_at(b, 8);
            if !page_ms.is_finite() {
                return Err(ProtocolError::BadFrames);
            }
            let stage = match b[1] {
                0 => AckStage::Uploaded,
                1 => AckStage::Done,
                s => return Err(ProtocolError::BadAckStage(s)),
            };
            Ok(ClientMessage::Ack { seq: u32_at(b, 4), stage, page_ms })
        }
        _ => {
            let mean_ms = f64_at(b, 8);
            if !(mean_ms.is_finite() && mean_ms >= 0.0) {
                return Err(ProtocolError::BadFrames);
            }
            Ok(ClientMessage::Frames { frames: u32_at(b, 4), mean_ms })
        }
    }
}

/// The page's side of [`parse_client`] (tests and the bench's own client speak it).
pub fn encode_pose(p: &Pose) -> Vec<u8> {
    let mut b = vec![POSE, 0, 0, 0];
    for v in [p.eye.x, p.eye.y, p.eye.z, p.target.x, p.target.y, p.target.z, p.yfov, p.aspect] {
        b.extend_from_slice(&v.to_le_bytes());
    }
    b.extend_from_slice(&p.height_px.to_le_bytes());
    b
}

/// The page's acknowledgement of update `seq` at `stage` (the page's clock `page_ms`): the
/// other half of [`parse_client`]'s [`ACK`], for clients other than the page (tests).
pub fn encode_ack(seq: u32, stage: AckStage, page_ms: f64) -> Vec<u8> {
    let mut b = vec![ACK, stage as u8, 0, 0];
    b.extend_from_slice(&seq.to_le_bytes());
    b.extend_from_slice(&page_ms.to_le_bytes());
    b
}

/// A cell whose shown LOD in a layer changed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CellLod {
    pub cell: u32,
    pub layer: u8,
    pub lod: u8,
}

/// The cells whose shown LOD differs between two snapshots (every cell against nothing).
pub fn changed_cells(now: &ShownLightmap, before: Option<&ShownLightmap>) -> Vec<CellLod> {
    let mut out = Vec::new();
    for (l, layer) in now.layers.iter().enumerate() {
        let old = before.map(|b| &b.layers[l].cell_lod).filter(|o| o.len() == layer.cell_lod.len());
        if old.is_some_and(|o| Arc::ptr_eq(o, &layer.cell_lod)) {
            continue;
        }
        for (cell, &lod) in layer.cell_lod.iter().enumerate() {
            if old.is_none_or(|o| o[cell] != lod) {
                out.push(CellLod { cell: cell as u32, layer: l as u8, lod });
            }
        }
    }
    out
}

/// An [`UPDATE`] message: header, cell LODs, written pages (key + 16×16 RGBA f32 texels),
/// dropped page keys.
pub fn encode_update(
    seq: u32,
    generation: u32,
    publish_ms: f64,
    full: bool,
    cells: &[CellLod],
    pages: &[PageChange],
) -> Vec<u8> {
    let written: Vec<(&PageKey, &Arc<Page>)> = pages
        .iter()
        .filter_map(|c| match c {
            PageChange::Written(k, p) => Some((k, p)),
            PageChange::Dropped(_) => None,
        })
        .collect();
    let dropped: Vec<&PageKey> = pages
        .iter()
        .filter_map(|c| match c {
            PageChange::Dropped(k) => Some(k),
            PageChange::Written(..) => None,
        })
        .collect();
    let mut b = Vec::with_capacity(
        UPDATE_HEADER
            + cells.len() * CELL_ENTRY
            + written.len() * (PAGE_ENTRY_HEADER + Page::BYTES)
            + dropped.len() * PAGE_ENTRY_HEADER,
    );
    b.extend_from_slice(&[UPDATE, if full { FULL } else { 0 }, 0, 0]);
    b.extend_from_slice(&seq.to_le_bytes());
    b.extend_from_slice(&publish_ms.to_le_bytes());
    b.extend_from_slice(&generation.to_le_bytes());
    for n in [cells.len(), written.len(), dropped.len()] {
        b.extend_from_slice(&(n as u32).to_le_bytes());
    }
    debug_assert_eq!(b.len(), UPDATE_HEADER);
    for c in cells {
        b.extend_from_slice(&c.cell.to_le_bytes());
        b.extend_from_slice(&[c.layer, c.lod, 0, 0]);
    }
    let key = |b: &mut Vec<u8>, k: &PageKey| {
        b.extend_from_slice(&[k.layer as u8, k.lod as u8, 0, 0]);
        b.extend_from_slice(&k.px.to_le_bytes());
        b.extend_from_slice(&k.py.to_le_bytes());
    };
    for (k, p) in written {
        key(&mut b, k);
        for t in p.texels.iter() {
            for v in t {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    for k in dropped {
        key(&mut b, k);
    }
    b
}

/// Where a page goes: layer, LOD, page column and row.
pub type PageAt = (u8, u8, u32, u32);

/// A decoded [`UPDATE`] (tests and the bench read what the page would).
#[derive(Clone, Debug, PartialEq)]
pub struct Update {
    pub seq: u32,
    pub generation: u32,
    pub publish_ms: f64,
    pub full: bool,
    pub cells: Vec<CellLod>,
    /// (layer, LOD, px, py) and the page's texels as RGBA f32.
    pub pages: Vec<(PageAt, Vec<[f32; 4]>)>,
    pub dropped: Vec<PageAt>,
}

/// Reads an [`UPDATE`]; `None` when it is not one or is cut short.
pub fn decode_update(b: &[u8]) -> Option<Update> {
    if b.len() < UPDATE_HEADER || b[0] != UPDATE {
        return None;
    }
    let (n_cells, n_pages, n_dropped) = (u32_at(b, 20) as usize, u32_at(b, 24) as usize, u32_at(b, 28) as usize);
    let want = UPDATE_HEADER
        .checked_add(n_cells.checked_mul(CELL_ENTRY)?)?
        .checked_add(n_pages.checked_mul(PAGE_ENTRY_HEADER + Page::BYTES)?)?
        .checked_add(n_dropped.checked_mul(PAGE_ENTRY_HEADER)?)?;
    if b.len() != want {
        return None;
    }
    let mut at = UPDATE_HEADER;
    let mut cells = Vec::with_capacity(n_cells);
    for _ in 0..n_cells {
        cells.push(CellLod { cell: u32_at(b, at), layer: b[at + 4], lod: b[at + 5] });
        at += CELL_ENTRY;
    }
    let key = |at: usize| (b[at], b[at + 1], u32_at(b, at + 4), u32_at(b, at + 8));
    let mut pages = Vec::with_capacity(n_pages);
    for _ in 0..n_pages {
        let k = key(at);
        at += PAGE_ENTRY_HEADER;
        let texels = (0..Page::BYTES / 16).map(|i| std::array::from_fn(|c| f32_at(b, at + 16 * i + 4 * c))).collect();
        at += Page::BYTES;
        pages.push((k, texels));
    }
    let dropped = (0..n_dropped).map(|i| key(at + i * PAGE_ENTRY_HEADER)).collect();
    Some(Update {
        seq: u32_at(b, 4),
        generation: u32_at(b, 16),
        publish_ms: f64_at(b, 8),
        full: b[1] & FULL != 0,
        cells,
        pages,
        dropped,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::Grid;
    use crate::runtime::shown::{Layer, PAGE_SIDE, PageWriter};
    use crate::scene::Rgb;

    #[test]
    fn poses_round_trip_and_nonsense_is_refused() {
        let p = Pose { eye: Vec3::new(1.0, 2.0, 3.0), target: Vec3::ZERO, yfov: 1.0, aspect: 1.5, height_px: 720 };
        assert_eq!(parse_client(&encode_pose(&p)), Ok(ClientMessage::Pose(p)));
        let mut nan = encode_pose(&p);
        nan[4..8].copy_from_slice(&f32::NAN.to_le_bytes());
        assert_eq!(parse_client(&nan), Err(ProtocolError::BadPose));
        assert_eq!(parse_client(&encode_pose(&p)[..39]), Err(ProtocolError::Length { kind: POSE, len: 39, want: 40 }));
        assert_eq!(parse_client(&[]), Err(ProtocolError::Empty));
        assert_eq!(parse_client(&[9, 0, 0]), Err(ProtocolError::UnknownKind(9)));
        let same = Pose { target: p.eye, ..p };
        assert_eq!(parse_client(&encode_pose(&same)), Err(ProtocolError::BadPose));
    }

    #[test]
    fn acks_say_their_stage_and_an_unknown_one_is_refused() {
        let ack = |stage: u8| {
            let mut b = vec![ACK, stage, 0, 0];
            b.extend(7u32.to_le_bytes());
            b.extend(12.5f64.to_le_bytes());
            parse_client(&b)
        };
        for stage in [AckStage::Uploaded, AckStage::Done] {
            assert_eq!(
                parse_client(&encode_ack(7, stage, 12.5)),
                Ok(ClientMessage::Ack { seq: 7, stage, page_ms: 12.5 })
            );
        }
        assert_eq!(ack(0), Ok(ClientMessage::Ack { seq: 7, stage: AckStage::Uploaded, page_ms: 12.5 }));
        assert_eq!(ack(1), Ok(ClientMessage::Ack { seq: 7, stage: AckStage::Done, page_ms: 12.5 }));
        assert_eq!(ack(2), Err(ProtocolError::BadAckStage(2)));
    }

    #[test]
    fn an_update_carries_exactly_the_written_pages() {
        let grid = Grid::covering(Vec3::ZERO, Vec3::new(2.0, 1.0, 1.0), 1.0).unwrap();
        let mut a = ShownLightmap::new(grid, 2 * PAGE_SIDE, PAGE_SIDE, 2, 0.0);
        let mut w = PageWriter::new(&mut a);
        w.write(Layer::Bundles, 0, 1, 1, Rgb::ONE);
        w.finish();
        let mut b = a.clone();
        let mut w = PageWriter::new(&mut b);
        w.write(Layer::Bundles, 1, 2 * PAGE_SIDE + 3, 4, Rgb::new(1.0, 2.0, 3.0));
        w.set_cell_lod(Layer::Bundles, 1, 1);
        w.finish();
        let changes = b.changed_pages(Some(&a));
        let cells = changed_cells(&b, Some(&a));
        assert_eq!(cells, vec![CellLod { cell: 1, layer: 0, lod: 1 }]);
        let bytes = encode_update(7, 2, 12.5, false, &cells, &changes);
        // One page: the header, one cell entry, one page entry; nothing else.
        assert_eq!(bytes.len(), UPDATE_HEADER + CELL_ENTRY + PAGE_ENTRY_HEADER + Page::BYTES);
        let u = decode_update(&bytes).unwrap();
        assert_eq!((u.seq, u.generation, u.publish_ms, u.full), (7, 2, 12.5, false));
        assert_eq!(u.pages.len(), 1);
        let ((layer, lod, px, py), texels) = &u.pages[0];
        assert_eq!((*layer, *lod, *px, *py), (0, 1, 2, 0));
        let page = b.layers[0].levels[1].page(2, 0).unwrap();
        assert_eq!(texels.as_slice(), &page.texels[..]);
        assert_eq!(texels[(4 * PAGE_SIDE + 3) as usize], [1.0, 2.0, 3.0, 1.0]);
        assert!(decode_update(&bytes[..bytes.len() - 1]).is_none());
    }
}
