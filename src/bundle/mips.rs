//! Mip chains of the analysis maps (paper Sect. 4.1–4.2).
//!
//! An R×R map (R a power of two) and its reductions down to 1×1. Level 0 is the finest (R×R)
//! and level L = log2 R is the single top pixel: the paper's indexing, so that a tile at level
//! i covers 2^i × 2^i finest pixels. The importance map is reduced by **max** (a tile must be
//! sampled as densely as its densest texel needs), the fragment-count map by **average** (the
//! expected depth complexity of a bundle pixel anywhere in the tile).

/// How four pixels of a level become one pixel of the next coarser level.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reduction {
    /// Importance map: the maximum of the four.
    Max,
    /// Fragment-count map: the mean of the four (what `GenerateMips` computes).
    Average,
}

impl Reduction {
    fn reduce(self, a: f32, b: f32, c: f32, d: f32) -> f32 {
        match self {
            Reduction::Max => a.max(b).max(c.max(d)),
            Reduction::Average => ((a + b) + (c + d)) * 0.25,
        }
    }
}

/// Why a map cannot become a [`MipChain`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MipError {
    #[error("map side {side} is not a power of two")]
    NotPowerOfTwo { side: u32 },
    #[error("a {side}x{side} map needs {expected} values, got {actual}")]
    LengthMismatch { side: u32, expected: usize, actual: usize },
    /// Both analysis maps hold counts or densities: a negative or non-finite value is a bug
    /// upstream, and NaN would silently win or lose every comparison of the planner.
    #[error("value {value} at index {index} is not a finite non-negative number")]
    InvalidValue { index: usize, value: f32 },
}

/// A square map and its whole reduction chain; `levels[i]` is `(R >> i)²` values, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct MipChain {
    reduction: Reduction,
    side: u32,
    levels: Vec<Vec<f32>>,
}

impl MipChain {
    /// Builds the chain of the `side`×`side` row-major map `finest`.
    pub fn new(side: u32, finest: Vec<f32>, reduction: Reduction) -> Result<Self, MipError> {
        validate(side, &finest)?;
        let top_level = side.trailing_zeros();
        let mut levels = Vec::with_capacity(top_level as usize + 1);
        levels.push(finest);
        for level in 1..=top_level {
            let finer = &levels[level as usize - 1];
            let coarser = reduce_level(finer, side >> (level - 1), reduction);
            levels.push(coarser);
        }
        Ok(MipChain { reduction, side, levels })
    }

    /// Importance map: max-reduced.
    pub fn max_mips(side: u32, finest: Vec<f32>) -> Result<Self, MipError> {
        Self::new(side, finest, Reduction::Max)
    }

    /// Fragment-count map: average-reduced.
    pub fn average_mips(side: u32, finest: Vec<f32>) -> Result<Self, MipError> {
        Self::new(side, finest, Reduction::Average)
    }

    pub fn reduction(&self) -> Reduction {
        self.reduction
    }

    /// R, the side of level 0.
    pub fn side(&self) -> u32 {
        self.side
    }

    /// L = log2 R, the level of the single top pixel.
    pub fn top_level(&self) -> u32 {
        self.levels.len() as u32 - 1
    }

    /// Side of `level` (≤ L), R >> level.
    pub fn level_side(&self, level: u32) -> u32 {
        self.side >> level
    }

    /// The row-major values of `level`.
    pub fn level(&self, level: u32) -> &[f32] {
        &self.levels[level as usize]
    }

    /// Pixel (x, y) of `level`.
    ///
    /// # Panics
    /// If `level > L` or (x, y) lies outside that level: callers index within the chain they
    /// built, so this is a programming error, like slice indexing.
    pub fn get(&self, level: u32, x: u32, y: u32) -> f32 {
        assert!(level <= self.top_level(), "level {level} above the top level {}", self.top_level());
        let side = self.level_side(level);
        assert!(x < side && y < side, "pixel ({x}, {y}) outside the {side}x{side} level {level}");
        self.levels[level as usize][y as usize * side as usize + x as usize]
    }
}

fn validate(side: u32, finest: &[f32]) -> Result<(), MipError> {
    if !side.is_power_of_two() {
        return Err(MipError::NotPowerOfTwo { side });
    }
    let expected = side as usize * side as usize;
    if finest.len() != expected {
        return Err(MipError::LengthMismatch { side, expected, actual: finest.len() });
    }
    match finest.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        Some(index) => Err(MipError::InvalidValue { index, value: finest[index] }),
        None => Ok(()),
    }
}

/// One reduction step: a `finer_side`² level to a `(finer_side / 2)`² level.
fn reduce_level(finer: &[f32], finer_side: u32, reduction: Reduction) -> Vec<f32> {
    let side = (finer_side / 2) as usize;
    let finer_side = finer_side as usize;
    let mut coarser = Vec::with_capacity(side * side);
    for y in 0..side {
        let row0 = &finer[2 * y * finer_side..][..finer_side];
        let row1 = &finer[(2 * y + 1) * finer_side..][..finer_side];
        for x in 0..side {
            let (x0, x1) = (2 * x, 2 * x + 1);
            coarser.push(reduction.reduce(row0[x0], row0[x1], row1[x0], row1[x1]));
        }
    }
    coarser
}

#[cfg(test)]
mod tests {
    use super::*;

    /// 4×4 map, rows top to bottom:
    ///  1  2 | 0  0
    ///  3  4 | 0  8
    ///  ----------
    ///  5  0 | 1  1
    ///  0  7 | 1  1
    fn four_by_four() -> Vec<f32> {
        vec![
            1.0, 2.0, 0.0, 0.0, //
            3.0, 4.0, 0.0, 8.0, //
            5.0, 0.0, 1.0, 1.0, //
            0.0, 7.0, 1.0, 1.0,
        ]
    }

    #[test]
    fn max_chain_of_a_hand_built_map() {
        let m = MipChain::max_mips(4, four_by_four()).unwrap();
        assert_eq!(m.top_level(), 2);
        assert_eq!(m.level(1), &[4.0, 8.0, 7.0, 1.0]);
        assert_eq!(m.level(2), &[8.0]);
        assert_eq!(m.get(1, 1, 0), 8.0);
        assert_eq!(m.get(1, 0, 1), 7.0);
        assert_eq!(m.get(0, 3, 1), 8.0);
        assert_eq!(m.reduction(), Reduction::Max);
    }

    #[test]
    fn average_chain_of_a_hand_built_map() {
        let m = MipChain::average_mips(4, four_by_four()).unwrap();
        assert_eq!(m.level(1), &[2.5, 2.0, 3.0, 1.0]);
        assert_eq!(m.level(2), &[2.125]);
        // The mean of the whole map is the top pixel whatever the reduction order.
        let mean = four_by_four().iter().sum::<f32>() / 16.0;
        assert_eq!(m.get(2, 0, 0), mean);
    }

    #[test]
    fn level_sides_halve_down_to_one() {
        let m = MipChain::average_mips(8, vec![1.0; 64]).unwrap();
        let sides: Vec<u32> = (0..=m.top_level()).map(|l| m.level_side(l)).collect();
        assert_eq!(sides, vec![8, 4, 2, 1]);
        assert_eq!(m.side(), 8);
        assert!((0..=3).all(|l| m.level(l).iter().all(|&v| v == 1.0)));
    }

    #[test]
    fn one_by_one_map_is_its_own_top() {
        let m = MipChain::max_mips(1, vec![3.5]).unwrap();
        assert_eq!(m.top_level(), 0);
        assert_eq!(m.get(0, 0, 0), 3.5);
    }

    #[test]
    fn max_chain_top_is_the_global_max_and_average_top_the_global_mean() {
        let side = 32u32;
        let mut rng = crate::sampling::Rng::new(11, 0);
        let data: Vec<f32> = (0..side * side).map(|_| (rng.next_u32() % 17) as f32).collect();
        let max = MipChain::max_mips(side, data.clone()).unwrap();
        let avg = MipChain::average_mips(side, data.clone()).unwrap();
        let global_max = data.iter().cloned().fold(0.0f32, f32::max);
        let global_mean = data.iter().map(|&v| v as f64).sum::<f64>() / data.len() as f64;
        assert_eq!(max.get(5, 0, 0), global_max);
        // Integers up to 16 over ≤ 1024 pixels: every partial mean is a dyadic fraction that
        // f32 holds exactly, so the average chain is exact too.
        assert_eq!(avg.get(5, 0, 0) as f64, global_mean);
    }

    #[test]
    fn rejects_sides_that_are_not_powers_of_two() {
        for side in [0u32, 3, 6, 12] {
            let n = (side * side) as usize;
            assert_eq!(MipChain::max_mips(side, vec![0.0; n]), Err(MipError::NotPowerOfTwo { side }));
        }
    }

    #[test]
    fn rejects_data_of_the_wrong_length() {
        assert_eq!(
            MipChain::average_mips(4, vec![0.0; 15]),
            Err(MipError::LengthMismatch { side: 4, expected: 16, actual: 15 })
        );
    }

    #[test]
    fn rejects_negative_and_non_finite_values() {
        let mut data = vec![1.0; 4];
        data[2] = -1.0;
        assert_eq!(MipChain::max_mips(2, data), Err(MipError::InvalidValue { index: 2, value: -1.0 }));
        let mut data = vec![1.0; 4];
        data[3] = f32::INFINITY;
        assert!(matches!(MipChain::average_mips(2, data), Err(MipError::InvalidValue { index: 3, .. })));
        let mut data = vec![1.0; 4];
        data[0] = f32::NAN;
        assert!(matches!(MipChain::average_mips(2, data), Err(MipError::InvalidValue { index: 0, .. })));
    }

    #[test]
    #[should_panic(expected = "outside")]
    fn get_outside_a_level_panics() {
        let m = MipChain::max_mips(4, vec![0.0; 16]).unwrap();
        m.get(1, 2, 0);
    }
}
