//! The texels an atlas's charts claim, one bit each, and the free places left: where an
//! update ([`super::update`]) puts the charts of a changed mesh without moving the others.

use super::pack::Footprint;

/// A rectangle of texels: top-left corner and size.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Rect {
    pub x: u32,
    pub y: u32,
    pub w: u32,
    pub h: u32,
}

impl Rect {
    pub fn contains(&self, o: &Rect) -> bool {
        o.x >= self.x && o.y >= self.y && o.x + o.w <= self.x + self.w && o.y + o.h <= self.y + self.h
    }
}

/// Occupied texels of an atlas, one bit each, for finding free space.
#[derive(Clone, Debug)]
pub struct FreeMap {
    width: u32,
    height: u32,
    words: usize,
    /// Row-major, `words` u64 per row; bit set = occupied.
    bits: Vec<u64>,
}

impl FreeMap {
    pub fn new(width: u32, height: u32) -> Self {
        let words = (width as usize).div_ceil(64);
        FreeMap { width, height, words, bits: vec![0; words * height as usize] }
    }

    /// Marks the footprint `f` with its rectangle's corner at `corner` occupied (clipped to
    /// the map).
    pub fn occupy_footprint(&mut self, corner: (u32, u32), f: &Footprint) {
        for y in 0..f.size.1.min(self.height.saturating_sub(corner.1)) {
            let row = (corner.1 + y) as usize * self.words;
            for x in 0..f.size.0.min(self.width.saturating_sub(corner.0)) {
                if f.get(x, y) {
                    let ax = corner.0 + x;
                    self.bits[row + ax as usize / 64] |= 1 << (ax % 64);
                }
            }
        }
    }

    /// Whether the footprint `f` fits with its rectangle's corner at `corner`: inside the map,
    /// on free texels only.
    pub fn fits(&self, corner: (u32, u32), f: &Footprint) -> bool {
        if corner.0 as u64 + f.size.0 as u64 > self.width as u64
            || corner.1 as u64 + f.size.1 as u64 > self.height as u64
        {
            return false;
        }
        (0..f.size.1).all(|y| {
            let row = (corner.1 + y) as usize * self.words;
            (0..f.size.0).all(|x| {
                let ax = corner.0 + x;
                !f.get(x, y) || self.bits[row + ax as usize / 64] & (1 << (ax % 64)) == 0
            })
        })
    }

    /// Per row, the bit mask of the columns `x` where `w` free texels start (`x..x + w`).
    fn starts(&self, w: u32) -> Vec<u64> {
        let words = self.words;
        let mut out = vec![0u64; self.bits.len()];
        let mut run = vec![0u64; words];
        let mut tmp = vec![0u64; words];
        for y in 0..self.height as usize {
            let row = &self.bits[y * words..(y + 1) * words];
            // Free bits, columns past the width cleared.
            for (k, r) in run.iter_mut().enumerate() {
                *r = !row[k];
                let lo = k as u32 * 64;
                if lo + 64 > self.width {
                    let valid = self.width.saturating_sub(lo);
                    *r &= if valid == 0 { 0 } else { u64::MAX >> (64 - valid) };
                }
            }
            // run[x] = free at x..x+len; double len until it reaches w, then top up.
            let mut len = 1u32;
            while len < w {
                let step = len.min(w - len);
                shift_down(&run, step, &mut tmp);
                for (r, t) in run.iter_mut().zip(&tmp) {
                    *r &= t;
                }
                len += step;
            }
            out[y * words..(y + 1) * words].copy_from_slice(&run);
        }
        out
    }

    /// The first free place for a `w × h` rectangle, scanning rows top to bottom and columns
    /// left to right.
    pub fn first_fit(&self, w: u32, h: u32) -> Option<(u32, u32)> {
        if w == 0 || h == 0 || w > self.width || h > self.height {
            return None;
        }
        let starts = self.starts(w);
        let words = self.words;
        let row = |y: u32| &starts[y as usize * words..(y as usize + 1) * words];
        let mut acc = vec![0u64; words];
        let mut y0 = 0;
        'scan: while y0 + h <= self.height {
            acc.copy_from_slice(row(y0));
            for k in 0..h {
                let r = row(y0 + k);
                if r.iter().all(|&b| b == 0) {
                    // No window containing this row fits.
                    y0 += k + 1;
                    continue 'scan;
                }
                let mut any = 0;
                for (a, b) in acc.iter_mut().zip(r) {
                    *a &= b;
                    any |= *a;
                }
                if any == 0 {
                    y0 += 1;
                    continue 'scan;
                }
            }
            let k = acc.iter().position(|&b| b != 0)?;
            return Some((k as u32 * 64 + acc[k].trailing_zeros(), y0));
        }
        None
    }
}

/// `out[x] = bits[x + s]` over a row of bits (zeros shifted in at the end).
fn shift_down(bits: &[u64], s: u32, out: &mut [u64]) {
    let (wq, r) = ((s / 64) as usize, s % 64);
    for (k, o) in out.iter_mut().enumerate() {
        let lo = bits.get(k + wq).copied().unwrap_or(0);
        let hi = bits.get(k + wq + 1).copied().unwrap_or(0);
        *o = if r == 0 { lo } else { (lo >> r) | (hi << (64 - r)) };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::atlas::pack::Orient;
    use crate::atlas::pack::tests::triangle;

    /// A footprint fits the free map where its claimed pixels are free, whatever lies under
    /// its unclaimed ones (brute force agrees); once placed, exactly its pixels are taken.
    #[test]
    fn free_map_fits_footprints_by_their_pixels() {
        let mut r = crate::sampling::Rng::new(9, 0);
        let mut m = FreeMap::new(70, 40);
        let mut taken = vec![false; 70 * 40];
        for k in 0..200 {
            let f = triangle(3 + (r.next_f64() * 12.0) as u32, 3 + (r.next_f64() * 12.0) as u32)
                .oriented(Orient::ALL[k % 4]);
            let corner = ((r.next_f64() * 70.0) as u32, (r.next_f64() * 40.0) as u32);
            let inside = corner.0 + f.size.0 <= 70 && corner.1 + f.size.1 <= 40;
            let brute = inside
                && (0..f.size.1).all(|y| {
                    (0..f.size.0).all(|x| !f.get(x, y) || !taken[((corner.1 + y) * 70 + corner.0 + x) as usize])
                });
            assert_eq!(m.fits(corner, &f), brute);
            if brute {
                m.occupy_footprint(corner, &f);
                for y in 0..f.size.1 {
                    for x in 0..f.size.0 {
                        if f.get(x, y) {
                            taken[((corner.1 + y) * 70 + corner.0 + x) as usize] = true;
                        }
                    }
                }
            }
        }
        assert!(taken.iter().filter(|&&t| t).count() > 500, "the map filled up");
        for y in 0..40 {
            for x in 0..70 {
                assert_eq!(m.fits((x, y), &Footprint::full((1, 1))), !taken[(y * 70 + x) as usize]);
            }
        }
    }

    #[test]
    fn free_map_finds_the_first_hole() {
        let mut m = FreeMap::new(130, 40);
        m.occupy_footprint((0, 0), &Footprint::full((130, 10)));
        m.occupy_footprint((0, 10), &Footprint::full((70, 30)));
        m.occupy_footprint((75, 10), &Footprint::full((55, 5)));
        // A 5-wide column free from row 10, a 60-wide region from row 15.
        assert_eq!(m.first_fit(5, 30), Some((70, 10)));
        assert_eq!(m.first_fit(6, 2), Some((70, 15)));
        assert_eq!(m.first_fit(60, 25), Some((70, 15)));
        assert_eq!(m.first_fit(61, 1), None);
        assert_eq!(m.first_fit(60, 26), None);
        assert!(m.fits((70, 15), &Footprint::full((60, 25))));
        assert!(!m.fits((69, 15), &Footprint::full((2, 2))));
        // Brute force agrees on random maps.
        let mut r = crate::sampling::Rng::new(5, 0);
        for _ in 0..40 {
            let mut m = FreeMap::new(150, 50);
            for _ in 0..30 {
                let (x, y) = ((r.next_f64() * 150.0) as u32, (r.next_f64() * 50.0) as u32);
                m.occupy_footprint(
                    (x, y),
                    &Footprint::full((1 + (r.next_f64() * 30.0) as u32, 1 + (r.next_f64() * 10.0) as u32)),
                );
            }
            for (w, h) in [(1, 1), (3, 7), (20, 4), (70, 2), (9, 9)] {
                let brute = (0..=50 - h)
                    .find_map(|y| (0..=150 - w).find(|&x| m.fits((x, y), &Footprint::full((w, h)))).map(|x| (x, y)));
                assert_eq!(m.first_fit(w, h), brute, "{w}×{h}");
            }
        }
    }
}
