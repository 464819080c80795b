//! The shown light map: an immutable snapshot of what the viewer displays.
//!
//! STAND-IN written on the `viewer` branch to the lead's specification (issue 10 brief);
//! replaced by main's `src/runtime/shown.rs` at the merge.

use std::sync::Arc;

use glam::{Vec2, Vec3};

use crate::grid::Grid;
use crate::scene::Rgb;

/// Pixels per page side.
pub const PAGE_SIDE: u32 = 64;

/// 64×64 pixels of one LOD, row-major: rgb = irradiance E (W/m²), a = 1 valid, 0 none.
#[derive(Clone, Debug)]
pub struct Page {
    pub id: u64,
    pub texels: Vec<[f32; 4]>,
}

#[derive(Clone, Debug)]
pub struct LodPages {
    pub pages_x: u32,
    pub pages_y: u32,
    pub pages: Vec<Option<Arc<Page>>>,
}

#[derive(Clone, Debug)]
pub struct ShownLightmap {
    pub grid: Grid,
    pub cell_lod: Vec<u8>,
    pub atlas_width: u32,
    pub atlas_height: u32,
    pub blend_band: f32,
    pub levels: Vec<LodPages>,
}

impl ShownLightmap {
    /// One pixel of LOD `k`: `(E, valid)`; outside the map or in a missing page: invalid.
    fn pixel(&self, k: usize, x: i64, y: i64) -> ([f32; 4], bool) {
        let level = &self.levels[k];
        let (w, h) = ((self.atlas_width as i64) << k, (self.atlas_height as i64) << k);
        if x < 0 || y < 0 || x >= w || y >= h {
            return ([0.0; 4], false);
        }
        let side = PAGE_SIDE as i64;
        let (px, py) = (x / side, y / side);
        if px >= level.pages_x as i64 || py >= level.pages_y as i64 {
            return ([0.0; 4], false);
        }
        match &level.pages[(py * level.pages_x as i64 + px) as usize] {
            Some(page) => {
                let t = page.texels[((y % side) * side + x % side) as usize];
                (t, t[3] > 0.0)
            }
            None => ([0.0; 4], false),
        }
    }

    /// Bilinear value of LOD `k` at LOD-0 atlas UV `uv`, falling back to coarser LODs where
    /// no tap is valid.
    fn value(&self, k: usize, uv: Vec2) -> Rgb {
        let mut k = k as i64;
        while k >= 0 {
            let p = uv * (1u32 << k) as f32 - Vec2::splat(0.5);
            let p0 = p.floor();
            let f = p - p0;
            let (x0, y0) = (p0.x as i64, p0.y as i64);
            let mut sum = Vec3::ZERO;
            let mut wsum = 0.0f32;
            for (dx, dy, w) in [
                (0, 0, (1.0 - f.x) * (1.0 - f.y)),
                (1, 0, f.x * (1.0 - f.y)),
                (0, 1, (1.0 - f.x) * f.y),
                (1, 1, f.x * f.y),
            ] {
                let (t, valid) = self.pixel(k as usize, x0 + dx, y0 + dy);
                if valid {
                    sum += Vec3::new(t[0], t[1], t[2]) * w;
                    wsum += w;
                }
            }
            if wsum > 0.0 {
                return sum / wsum;
            }
            k -= 1;
        }
        Rgb::ZERO
    }

    /// Irradiance (W/m²) the viewer shows at world position `p` with LOD-0 atlas UV `uv`.
    pub fn irradiance(&self, p: Vec3, uv: Vec2) -> Rgb {
        let c = self.grid.cell_coords(p);
        let k = self.cell_lod[self.grid.index(c)];
        let base = self.value(k as usize, uv);
        let lo = self.grid.origin + Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32) * self.grid.cell_size;
        let mut w = 0.0f32;
        let mut k_low = k;
        for axis in 0..3 {
            for dir in [-1i64, 1] {
                let n = c[axis] as i64 + dir;
                if n < 0 || n >= self.grid.dims[axis] as i64 {
                    continue;
                }
                let mut nc = c;
                nc[axis] = n as u32;
                let kn = self.cell_lod[self.grid.index(nc)];
                if kn >= k {
                    continue;
                }
                let d = if dir < 0 { p[axis] - lo[axis] } else { lo[axis] + self.grid.cell_size - p[axis] };
                if d < self.blend_band {
                    let wn = 1.0 - d / self.blend_band;
                    if wn > 0.0 {
                        w = w.max(wn);
                        k_low = k_low.min(kn);
                    }
                }
            }
        }
        if w > 0.0 { (1.0 - w) * base + w * self.value(k_low as usize, uv) } else { base }
    }
}
