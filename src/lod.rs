//! The light-map LOD hierarchy: LOD k has resolution `base · 2^k` over one shared UV layout.

use serde::Serialize;

/// Resolutions of every light-map level over one atlas layout.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub struct LodHierarchy {
    /// LOD 0 (coarsest) resolution in texels.
    pub base_width: u32,
    pub base_height: u32,
    /// Number of levels (≥ 1).
    pub levels: u32,
}

impl LodHierarchy {
    pub fn new(base_width: u32, base_height: u32, levels: u32) -> Self {
        LodHierarchy { base_width, base_height, levels: levels.max(1) }
    }

    /// (width, height) of LOD `k`.
    pub fn resolution(&self, k: u32) -> (u32, u32) {
        (self.base_width << k, self.base_height << k)
    }

    /// Side of a LOD `k` texel in LOD-0 texels (1/2^k).
    pub fn texel_scale(&self, k: u32) -> f32 {
        1.0 / (1u32 << k) as f32
    }

    pub fn texel_count(&self, k: u32) -> u64 {
        let (w, h) = self.resolution(k);
        w as u64 * h as u64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_level_doubles() {
        let l = LodHierarchy::new(300, 200, 3);
        assert_eq!(l.resolution(0), (300, 200));
        assert_eq!(l.resolution(1), (600, 400));
        assert_eq!(l.resolution(2), (1200, 800));
        assert_eq!(l.texel_count(2), 4 * l.texel_count(1));
        assert_eq!(l.texel_scale(2), 0.25);
    }
}
