//! Atlas pixel → texel lookup tables: what a bundle fragment's light-map UV is turned into.

use super::raster::PixelRect;
use super::texels::{NO_TEXEL, TexelMap};

/// A dense lookup over a rectangle of LOD pixels, stored in 8×8-pixel blocks (row-major
/// blocks, row-major pixels inside): a bundle span walks a line across the atlas in any
/// direction, and blocks keep the entries it reads next to each other far more often than
/// rows do. Entries are texel ids (a gutter pixel holds the id of the texel it copies, so a
/// fragment whose UV rounds a hair outside its chart's covered pixels still finds its own
/// chart's texel), or [`NO_TEXEL`].
#[derive(Clone, Debug)]
pub struct TexelTable {
    /// The chart whose faces this table serves; `None` for a whole-LOD table serving all.
    pub chart: Option<u32>,
    pub rect: PixelRect,
    blocks_x: i64,
    entries: Vec<u32>,
}

impl TexelTable {
    pub fn new(chart: Option<u32>, rect: PixelRect) -> Self {
        let blocks_x = (rect.width() + 7) >> 3;
        let blocks_y = (rect.height() + 7) >> 3;
        TexelTable { chart, rect, blocks_x, entries: vec![NO_TEXEL; (blocks_x * blocks_y * 64) as usize] }
    }

    /// The table of a whole-LOD texel map: every texel and gutter pixel, for all charts.
    pub fn of_map(map: &TexelMap) -> Self {
        let mut t = TexelTable::new(None, PixelRect::new(0, 0, map.width as i64, map.height as i64));
        let w = map.width;
        for (&pixel, texel) in map.pixel.iter().zip(0..).chain(map.gutter.iter().map(|(p, t)| (p, *t))) {
            t.set((pixel % w) as i64, (pixel / w) as i64, texel);
        }
        t
    }

    #[inline(always)]
    fn index(&self, x: i64, y: i64) -> usize {
        let (x, y) = (x - self.rect.x0, y - self.rect.y0);
        (((y >> 3) * self.blocks_x + (x >> 3)) << 6 | (y & 7) << 3 | (x & 7)) as usize
    }

    /// The entry of LOD pixel `(x, y)`; [`NO_TEXEL`] outside the table.
    #[inline(always)]
    pub fn get(&self, x: i64, y: i64) -> u32 {
        if self.rect.contains(x, y) { self.entries[self.index(x, y)] } else { NO_TEXEL }
    }

    pub fn set(&mut self, x: i64, y: i64, v: u32) {
        let i = self.index(x, y);
        self.entries[i] = v;
    }

    /// The entries in their storage order (8×8 blocks, row-major blocks; see `index`), for
    /// uploads: entry of (x, y) is at `((y' >> 3)·blocks_x + (x' >> 3)) << 6 | (y' & 7) << 3 |
    /// (x' & 7)` with (x', y') relative to the rect's corner.
    pub fn entries(&self) -> &[u32] {
        &self.entries
    }

    /// 8×8 blocks per row of the entries.
    pub fn blocks_x(&self) -> i64 {
        self.blocks_x
    }

    pub fn bytes(&self) -> usize {
        self.entries.len() * 4
    }
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(t.entries.iter().filter(|&&e| e != NO_TEXEL).count(), 13 * 10);
    }
}
