//! Atlas pixel → texel lookup tables: what a bundle fragment's light-map UV is turned into.

use std::borrow::Cow;

use super::raster::PixelRect;
use super::texels::{NO_TEXEL, TexelMap};

/// A lookup over a rectangle of LOD pixels, in 8×8-pixel blocks (row-major blocks): a bundle
/// span walks a line across the atlas in any direction, and blocks keep the entries it reads
/// next to each other far more often than rows do. A pixel's entry is a texel id (a gutter
/// pixel holds the id of the texel it copies, so a fragment whose UV rounds a hair outside
/// its chart's covered pixels still finds its own chart's texel), or [`NO_TEXEL`].
#[derive(Clone, Debug)]
pub struct TexelTable {
    /// The chart whose faces this table serves; `None` for a whole-LOD table serving all.
    pub chart: Option<u32>,
    pub rect: PixelRect,
    /// The rect's sides, for the bounds test of every lookup.
    size: (u64, u64),
    blocks_x: i64,
    storage: Storage,
}

#[derive(Clone, Debug)]
enum Storage {
    /// Every entry, row-major inside its block (4 B a pixel): any texel ids, as the
    /// per-chart tables of a sparse LOD have (their charts' texels interleave).
    Dense(Vec<u32>),
    /// A whole-LOD map's texels, whose ids follow the blocks (Z-order inside a block,
    /// [`super::texels::block_order`]): a block's texels are consecutive ids, so a pixel's
    /// is the block's first plus the covered pixels before it, counted in a bit mask.
    /// Gutter pixels keep their texel in a list, in the same order (24 B a block and 4 B a
    /// gutter pixel, against 4 B a pixel).
    Ranked { blocks: Vec<RankedBlock>, gutter_texels: Vec<u32> },
}

/// One 8×8 block of a [`Storage::Ranked`] table; bit `m` of a mask is the pixel at Z-order
/// index `m` inside the block.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct RankedBlock {
    texels: u64,
    gutter: u64,
    first_texel: u32,
    first_gutter: u32,
}

/// Z-order index inside a block of the pixel at `(x, y)` from the block's corner: x's bits
/// at the even positions, y's at the odd ones. A 64-entry table (one cache line), indexed
/// by the row-major position: spreading the bits took a tenth of the bundle fill's time.
#[inline(always)]
fn z_index(x: i64, y: i64) -> u32 {
    Z_OF_ROW_MAJOR[((y & 7) << 3 | (x & 7)) as usize] as u32
}

const Z_OF_ROW_MAJOR: [u8; 64] = {
    const fn spread(v: usize) -> u8 {
        ((v & 1) | (v & 2) << 1 | (v & 4) << 2) as u8
    }
    let mut table = [0u8; 64];
    let mut i = 0;
    while i < 64 {
        table[i] = spread(i & 7) | spread(i >> 3) << 1;
        i += 1;
    }
    table
};

fn sides(rect: PixelRect) -> (u64, u64) {
    (rect.width() as u64, rect.height() as u64)
}

/// The coordinate in a block whose bits are the even ones of `m` (the inverse of `z_index`).
#[inline(always)]
fn z_coordinate(m: u32) -> i64 {
    ((m & 1) | (m >> 1 & 2) | (m >> 2 & 4)) as i64
}

/// The set bits of `mask` below bit `m`: the rank of a held item among those of its
/// 64-item word (the lookup table's blocks, [`super::texels::TexelSubset`]'s words).
#[inline(always)]
pub(super) fn before(mask: u64, m: u32) -> u32 {
    (mask & ((1u64 << m) - 1)).count_ones()
}

impl TexelTable {
    /// A table with every entry [`NO_TEXEL`], to be filled with [`set`](Self::set).
    pub fn new(chart: Option<u32>, rect: PixelRect) -> Self {
        let blocks_x = (rect.width() + 7) >> 3;
        let blocks_y = (rect.height() + 7) >> 3;
        let entries = vec![NO_TEXEL; (blocks_x * blocks_y * 64) as usize];
        TexelTable { chart, rect, size: sides(rect), blocks_x, storage: Storage::Dense(entries) }
    }

    /// The table of a whole-LOD texel map: every texel and gutter pixel, for all charts.
    /// Ranked when the map's texel ids follow its blocks (as [`TexelMap::build`] makes
    /// them), dense otherwise.
    pub fn of_map(map: &TexelMap) -> Self {
        let rect = PixelRect::new(0, 0, map.width as i64, map.height as i64);
        match ranked(map, rect) {
            Some(t) => t,
            None => {
                let mut t = TexelTable::new(None, rect);
                let w = map.width;
                for (&pixel, texel) in map.pixel.iter().zip(0..).chain(map.gutter.iter().map(|(p, t)| (p, *t))) {
                    t.set((pixel % w) as i64, (pixel / w) as i64, texel);
                }
                t
            }
        }
    }

    #[inline(always)]
    fn block(&self, x: i64, y: i64) -> usize {
        ((y >> 3) * self.blocks_x + (x >> 3)) as usize
    }

    #[inline(always)]
    fn dense_index(&self, x: i64, y: i64) -> usize {
        self.block(x, y) << 6 | ((y & 7) << 3 | (x & 7)) as usize
    }

    /// Whether one of the pixels `x0..=x1` × `y0..=y1` holds an entry. Blocks holding none
    /// are passed over whole (64 pixels a test), so a large rectangle over empty blocks
    /// costs its blocks, not its pixels.
    pub fn any_in(&self, x0: i64, y0: i64, x1: i64, y1: i64) -> bool {
        let r = self.rect;
        let (bx0, by0) = ((x0.max(r.x0) - r.x0) >> 3, (y0.max(r.y0) - r.y0) >> 3);
        let (bx1, by1) = (x1.min(r.x1 - 1) - r.x0, y1.min(r.y1 - 1) - r.y0);
        if bx1 < 0 || by1 < 0 {
            return false;
        }
        (by0..=by1 >> 3).any(|by| {
            (bx0..=bx1 >> 3).any(|bx| {
                let b = (by * self.blocks_x + bx) as usize;
                let empty = match &self.storage {
                    Storage::Dense(entries) => entries[b << 6..][..64].iter().all(|&e| e == NO_TEXEL),
                    Storage::Ranked { blocks, .. } => blocks[b].texels | blocks[b].gutter == 0,
                };
                // The block's pixels inside the rectangle.
                let (px, py) = (r.x0 + (bx << 3), r.y0 + (by << 3));
                !empty
                    && (py.max(y0)..=(py + 7).min(y1))
                        .any(|y| (px.max(x0)..=(px + 7).min(x1)).any(|x| self.get(x, y) != NO_TEXEL))
            })
        })
    }

    /// The entry of LOD pixel `(x, y)`; [`NO_TEXEL`] outside the table.
    #[inline(always)]
    pub fn get(&self, x: i64, y: i64) -> u32 {
        // Inside the rect ⇔ both offsets from its corner, as unsigned, are below its sides
        // (a negative offset wraps to a huge one): two compares, not four.
        let (x, y) = (x.wrapping_sub(self.rect.x0), y.wrapping_sub(self.rect.y0));
        if x as u64 >= self.size.0 || y as u64 >= self.size.1 {
            return NO_TEXEL;
        }
        match &self.storage {
            Storage::Dense(entries) => entries[self.dense_index(x, y)],
            Storage::Ranked { blocks, gutter_texels } => {
                let b = &blocks[self.block(x, y)];
                let m = z_index(x, y);
                if b.texels >> m & 1 == 1 {
                    b.first_texel + before(b.texels, m)
                } else if b.gutter >> m & 1 == 1 {
                    gutter_texels[(b.first_gutter + before(b.gutter, m)) as usize]
                } else {
                    NO_TEXEL
                }
            }
        }
    }

    /// Sets the entry of LOD pixel `(x, y)`, inside the rectangle, of a table made by
    /// [`new`](Self::new).
    ///
    /// # Panics
    /// On a ranked table ([`of_map`](Self::of_map)), which is made whole.
    pub fn set(&mut self, x: i64, y: i64, v: u32) {
        let i = self.dense_index(x - self.rect.x0, y - self.rect.y0);
        match &mut self.storage {
            Storage::Dense(entries) => entries[i] = v,
            Storage::Ranked { .. } => panic!("a ranked texel table is made whole by TexelTable::of_map"),
        }
    }

    /// Every entry in the dense order (8×8 blocks, row-major blocks, row-major pixels
    /// inside), for uploads: the entry of (x, y) is at `((y' >> 3)·blocks_x + (x' >> 3)) << 6
    /// | (y' & 7) << 3 | (x' & 7)` with (x', y') relative to the rect's corner. Borrowed from
    /// a dense table, made for a ranked one.
    pub fn dense_entries(&self) -> Cow<'_, [u32]> {
        match &self.storage {
            Storage::Dense(entries) => Cow::Borrowed(entries),
            Storage::Ranked { blocks, .. } => {
                let mut entries = vec![NO_TEXEL; blocks.len() * 64];
                for (b, block) in entries.chunks_exact_mut(64).enumerate() {
                    let (bx, by) = ((b as i64 % self.blocks_x) << 3, (b as i64 / self.blocks_x) << 3);
                    for (k, e) in block.iter_mut().enumerate() {
                        let (x, y) = (bx + (k as i64 & 7), by + (k as i64 >> 3));
                        *e = self.get(x + self.rect.x0, y + self.rect.y0);
                    }
                }
                Cow::Owned(entries)
            }
        }
    }

    /// Entries of [`dense_entries`](Self::dense_entries).
    pub fn dense_len(&self) -> usize {
        match &self.storage {
            Storage::Dense(entries) => entries.len(),
            Storage::Ranked { blocks, .. } => blocks.len() * 64,
        }
    }

    /// A hash of every entry (FNV-1a), without making the dense entries of a ranked table.
    pub fn fingerprint(&self) -> u64 {
        let mut h = 0xcbf2_9ce4_8422_2325u64;
        let mut add = |w: u64| {
            h ^= w;
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        };
        match &self.storage {
            Storage::Dense(entries) => entries.iter().for_each(|&e| add(e as u64)),
            Storage::Ranked { blocks, gutter_texels } => {
                for b in blocks {
                    for w in [b.texels, b.gutter, b.first_texel as u64, b.first_gutter as u64] {
                        add(w);
                    }
                }
                gutter_texels.iter().for_each(|&t| add(t as u64));
            }
        }
        h
    }

    /// 8×8 blocks per row of the entries.
    pub fn blocks_x(&self) -> i64 {
        self.blocks_x
    }

    pub fn bytes(&self) -> usize {
        match &self.storage {
            Storage::Dense(entries) => entries.len() * 4,
            Storage::Ranked { blocks, gutter_texels } => {
                blocks.len() * std::mem::size_of::<RankedBlock>() + gutter_texels.len() * 4
            }
        }
    }

    /// Whether [`map_pixels`](Self::map_pixels) gives back the map's pixels.
    pub fn holds_map_pixels(&self) -> bool {
        matches!(self.storage, Storage::Ranked { .. })
    }

    /// The texels' pixels and the gutter pixels with their texels of the map a ranked table
    /// was made from ([`TexelMap::pixel`], [`TexelMap::gutter`]), in its order: what a bake
    /// gives up while the table is alive. `None` for a dense table.
    pub fn map_pixels(&self) -> Option<MapPixels> {
        let Storage::Ranked { blocks, gutter_texels } = &self.storage else { return None };
        let w = self.rect.width() as u32;
        let texels = blocks.iter().map(|b| b.texels.count_ones() as usize).sum();
        let mut pixel = Vec::with_capacity(texels);
        let mut gutter = Vec::with_capacity(gutter_texels.len());
        for (b, block) in blocks.iter().enumerate() {
            let (bx, by) = ((b as i64 % self.blocks_x) << 3, (b as i64 / self.blocks_x) << 3);
            let at = |m: u32| ((by + z_coordinate(m >> 1)) as u32) * w + (bx + z_coordinate(m)) as u32;
            for m in 0..64 {
                if block.texels >> m & 1 == 1 {
                    pixel.push(at(m));
                } else if block.gutter >> m & 1 == 1 {
                    gutter.push((at(m), gutter_texels[gutter.len()]));
                }
            }
        }
        Some(MapPixels { pixel, gutter })
    }
}

/// A map's [`TexelMap::pixel`] and [`TexelMap::gutter`], given back by a ranked table.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MapPixels {
    pub pixel: Vec<u32>,
    pub gutter: Vec<(u32, u32)>,
}

/// The ranked table of a whole-LOD map over `rect` (its pixels from (0, 0)), or `None` when
/// its texel ids do not follow the blocks or a pixel is listed twice.
fn ranked(map: &TexelMap, rect: PixelRect) -> Option<TexelTable> {
    let blocks_x = (rect.width() + 7) >> 3;
    let blocks_y = (rect.height() + 7) >> 3;
    let mut blocks = vec![RankedBlock::default(); (blocks_x * blocks_y) as usize];
    let w = map.width as i64;
    let place = |pixel: u32| {
        let (x, y) = (pixel as i64 % w, pixel as i64 / w);
        (((y >> 3) * blocks_x + (x >> 3)) as usize, z_index(x, y))
    };
    // Texels: ids must increase with (block, Z index), so each block's are consecutive.
    let mut last = None;
    for (i, &p) in map.pixel.iter().enumerate() {
        let (b, m) = place(p);
        if p as i64 >= w * rect.height() || last.is_some_and(|l| l >= (b, m)) {
            return None;
        }
        last = Some((b, m));
        let block = &mut blocks[b];
        if block.texels == 0 {
            block.first_texel = i as u32;
        }
        block.texels |= 1 << m;
    }
    // Gutter pixels, in the same order.
    let mut gutter: Vec<(usize, u32, u32)> = Vec::with_capacity(map.gutter.len());
    for &(p, texel) in &map.gutter {
        if p as i64 >= w * rect.height() {
            return None;
        }
        let (b, m) = place(p);
        gutter.push((b, m, texel));
    }
    gutter.sort_unstable_by_key(|&(b, m, _)| (b, m));
    let mut gutter_texels = Vec::with_capacity(gutter.len());
    for &(b, m, texel) in &gutter {
        let block = &mut blocks[b];
        if (block.texels | block.gutter) >> m & 1 == 1 {
            return None;
        }
        if block.gutter == 0 {
            block.first_gutter = gutter_texels.len() as u32;
        }
        block.gutter |= 1 << m;
        gutter_texels.push(texel);
    }
    Some(TexelTable {
        chart: None,
        rect,
        size: sides(rect),
        blocks_x,
        storage: Storage::Ranked { blocks, gutter_texels },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::texels::block_order;

    #[test]
    fn blocked_table_keeps_every_pixel_apart() {
        // Sizes and an origin that are not whole blocks, so ragged blocks count.
        let rect = PixelRect::new(5, 3, 18, 13);
        let mut t = TexelTable::new(Some(2), rect);
        for y in 3..13 {
            for x in 5..18 {
                t.set(x, y, (y * 100 + x) as u32);
            }
        }
        for y in 3..13 {
            for x in 5..18 {
                assert_eq!(t.get(x, y), (y * 100 + x) as u32);
            }
        }
        assert_eq!(t.get(4, 3), NO_TEXEL);
        assert_eq!(t.get(18, 12), NO_TEXEL);
        assert_eq!(t.dense_entries().iter().filter(|&&e| e != NO_TEXEL).count(), 13 * 10);
    }

    /// A map of `w`×`h` pixels whose covered pixels and gutters follow a fixed scramble, its
    /// texel ids in block order and its gutters too (as [`TexelMap::build`] makes them).
    fn scrambled_map(w: u32, h: u32) -> TexelMap {
        let mut map = TexelMap { width: w, height: h, ..TexelMap::default() };
        let mut gutter_sources = Vec::new();
        for p in block_order(w as usize, h as usize) {
            match (p as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15) >> 61 {
                0..=3 => {
                    map.face.push(0);
                    map.pixel.push(p as u32);
                }
                4 => gutter_sources.push(p as u32),
                _ => {}
            }
        }
        let n = map.pixel.len() as u32;
        map.gutter = gutter_sources.iter().map(|&p| (p, (p * 7) % n)).collect();
        map
    }

    #[test]
    fn ranked_table_reads_what_a_dense_one_holds() {
        // Ragged on both sides, a few hundred blocks.
        let map = scrambled_map(157, 93);
        assert!(map.pixel.len() > 5000 && map.gutter.len() > 1000, "{} {}", map.pixel.len(), map.gutter.len());
        let ranked = TexelTable::of_map(&map);
        assert!(matches!(ranked.storage, Storage::Ranked { .. }));
        let mut dense = TexelTable::new(None, ranked.rect);
        for (i, &p) in map.pixel.iter().enumerate() {
            dense.set((p % 157) as i64, (p / 157) as i64, i as u32);
        }
        for &(p, t) in &map.gutter {
            dense.set((p % 157) as i64, (p / 157) as i64, t);
        }
        for y in -2..96 {
            for x in -2..160 {
                assert_eq!(ranked.get(x, y), dense.get(x, y), "({x}, {y})");
            }
        }
        assert_eq!(ranked.dense_entries(), dense.dense_entries());
        assert_eq!(ranked.dense_len(), dense.dense_len());
        // The map's pixels and gutters come back as they were.
        assert_eq!(ranked.map_pixels(), Some(MapPixels { pixel: map.pixel.clone(), gutter: map.gutter.clone() }));
        // 24 B a block and 4 B a gutter pixel, against 4 B a pixel.
        assert_eq!(ranked.bytes(), 20 * 12 * 24 + map.gutter.len() * 4);
        assert_eq!(dense.bytes(), 20 * 12 * 64 * 4);
        assert_ne!(ranked.fingerprint(), TexelTable::of_map(&scrambled_map(157, 94)).fingerprint());
    }

    #[test]
    fn a_map_out_of_block_order_gets_a_dense_table() {
        let mut map = scrambled_map(40, 30);
        map.pixel.swap(10, 11);
        let t = TexelTable::of_map(&map);
        assert!(matches!(t.storage, Storage::Dense(_)));
        assert_eq!(t.get((map.pixel[10] % 40) as i64, (map.pixel[10] / 40) as i64), 10);
        assert_eq!(t.map_pixels(), None);
    }

    /// `any_in` gives the pixel-by-pixel answer for rectangles inside, across and outside the
    /// table, with and without entries.
    #[test]
    fn any_in_is_exact() {
        let rect = PixelRect::new(-5, 3, 60, 41);
        let mut table = TexelTable::new(None, rect);
        let mut rng = crate::sampling::Rng::new(3, 9);
        for k in 0..12 {
            let x = rect.x0 + (rng.next_f32() * rect.width() as f32) as i64 % rect.width();
            let y = rect.y0 + (rng.next_f32() * rect.height() as f32) as i64 % rect.height();
            table.set(x, y, k);
        }
        let mut yes = 0;
        for _ in 0..4000 {
            let x0 = -20 + (rng.next_f32() * 100.0) as i64;
            let y0 = -10 + (rng.next_f32() * 70.0) as i64;
            let (x1, y1) = (x0 + (rng.next_f32() * 12.0) as i64, y0 + (rng.next_f32() * 12.0) as i64);
            let holds = (y0..=y1).any(|y| (x0..=x1).any(|x| table.get(x, y) != NO_TEXEL));
            assert_eq!(table.any_in(x0, y0, x1, y1), holds, "({x0}, {y0})..=({x1}, {y1})");
            yes += holds as u32;
        }
        assert!(yes > 100 && yes < 3900, "{yes} of 4000 rectangles held entries");
        assert!(!table.any_in(100, 100, 120, 120));
        assert!(!table.any_in(-50, -50, -6, 60));
    }
}
