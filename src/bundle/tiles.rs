//! The tile planner: which tiles of one bundle direction to render, at which bundle resolution
//! (paper Sect. 4.3, Eq. 1–3, and Appendix A, Program 1).
//!
//! A tile (i, x) is the 2^i × 2^i block of finest analysis pixels under pixel x of mip level i.
//! It needs `C_I(i,x) = A(i)·I(i,x)` rays (Eq. 1: area times the max-mipped importance, in rays
//! per unit area), and may use at most
//! `C_max(i,x) = min(W², min_{j=i..L} αN / F(j, x_j))` (Eq. 3, x_j the ancestor of x at level
//! j): the head-pointer buffer holds W² pixels and the node buffer N fragments, of which each
//! bundle pixel is predicted to take F, the average depth complexity. Coarse levels estimate F
//! with low variance and high bias, fine ones the other way round (paper Fig. 5), hence the
//! minimum over every ancestor. A tile with `C_I > C_max` is split into its four children
//! (unless it is already a finest pixel); otherwise it is rendered at
//! `res = ⌈√min(C_I, C_max)⌉`, never above `⌊√C_max⌋` (see [`bundle_resolution`]).
//!
//! The rule is implemented once and walked two ways: a plain recursive quadtree descent, and
//! the paper's single-pass form with one "thread" per finest pixel descending from the top,
//! where only the thread at a tile's corner emits it: the CPU twin of the compute shader.
//! Both return the tiles in Morton (Z) order of their corners, which keeps consecutive tiles
//! close together in the scene. [`TilePlanner::rays_needed`] and [`TilePlanner::ray_bound`]
//! evaluate Eq. 1 and Eq. 3 from scratch for any one tile, for checks.

use super::mips::{MipChain, Reduction};

/// α of Eq. 2–3: the paper's margin for a fragment-count estimate that is off by up to 10%.
pub const DEFAULT_ALPHA: f32 = 0.9;

/// Children of a tile, in Morton order: (0,0), (1,0), (0,1), (1,1).
const QUADRANTS: [(u32, u32); 4] = [(0, 0), (1, 0), (0, 1), (1, 1)];

/// Buffer sizes and scale of one bundle pass.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileParams {
    /// Side W of the head-pointer buffer: a tile has at most W×W bundle pixels.
    pub w: u32,
    /// Capacity N of the node buffer, in fragments.
    pub n: u64,
    /// Fraction of N the prediction may fill (α of Eq. 2–3), in (0, 1].
    pub alpha: f32,
    /// World area of one finest analysis pixel (perpendicular to the bundle direction), so a
    /// tile at level i covers A(i) = pixel_area · 4^i.
    pub pixel_area: f64,
}

impl TileParams {
    pub fn new(w: u32, n: u64, pixel_area: f64) -> Self {
        TileParams { w, n, alpha: DEFAULT_ALPHA, pixel_area }
    }

    /// A(i) = pixel_area · 4^i.
    pub fn tile_area(&self, level: i32) -> f64 {
        self.pixel_area * 4f64.powi(level)
    }

    /// W², the most bundle pixels a tile may have.
    pub fn head_buffer_pixels(&self) -> f64 {
        self.w as f64 * self.w as f64
    }

    /// αN, the fragments the prediction may fill.
    pub fn node_budget(&self) -> f64 {
        self.alpha as f64 * self.n as f64
    }

    fn validate(&self) -> Result<(), PlanError> {
        if self.w == 0 {
            return Err(PlanError::EmptyHeadBuffer);
        }
        if self.n == 0 {
            return Err(PlanError::EmptyNodeBuffer);
        }
        if !(self.alpha > 0.0 && self.alpha <= 1.0) {
            return Err(PlanError::AlphaOutOfRange(self.alpha));
        }
        if !(self.pixel_area.is_finite() && self.pixel_area > 0.0) {
            return Err(PlanError::InvalidPixelArea(self.pixel_area));
        }
        Ok(())
    }
}

/// How a bundle direction's R×R analysis window is cut into tiles.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TilingMode {
    /// One tile, the whole window, at bundle resolution W (no tiling baseline).
    None,
    /// k×k equal tiles, each at resolution W (the paper's uniform baseline); k a power of two,
    /// 1 ≤ k ≤ R.
    Uniform { k: u32 },
    /// Eq. 1–3.
    Adaptive,
}

/// One tile to render: the block of analysis pixels under pixel (x, y) of mip level `level`,
/// rendered as a `res`×`res` bundle.
///
/// Planned tiles have 0 ≤ level ≤ L. (A baker redoing an overflowed tile splits its pixel
/// grid, not the analysis grid: see `raster::Viewport::split`.)
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Tile {
    pub level: i32,
    pub x: u32,
    pub y: u32,
    pub res: u32,
}

/// A tile's square window in finest-analysis-pixel units (origin at the map's corner).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TileWindow {
    pub x: f64,
    pub y: f64,
    pub side: f64,
}

impl Tile {
    /// The window this tile covers, in finest analysis pixels. Exact: all values are dyadic.
    pub fn window(&self) -> TileWindow {
        let side = 2f64.powi(self.level);
        TileWindow { x: self.x as f64 * side, y: self.y as f64 * side, side }
    }

    /// World area of one of its bundle pixels, A(i)/res²: the `a_px` weight of the estimator.
    pub fn bundle_pixel_area(&self, params: &TileParams) -> f64 {
        params.tile_area(self.level) / (self.res as f64 * self.res as f64)
    }

    /// Position along the Z-order curve of the finest pixel at the tile's corner (planned
    /// tiles only: they never overlap, so no two share a key).
    pub fn morton_key(&self) -> u64 {
        let shift = self.level.max(0) as u32;
        interleave_bits(self.x << shift) | (interleave_bits(self.y << shift) << 1)
    }
}

/// Spreads the 32 bits of `v` to the even bits of a u64.
fn interleave_bits(v: u32) -> u64 {
    let mut v = v as u64;
    v = (v | (v << 16)) & 0x0000_ffff_0000_ffff;
    v = (v | (v << 8)) & 0x00ff_00ff_00ff_00ff;
    v = (v | (v << 4)) & 0x0f0f_0f0f_0f0f_0f0f;
    v = (v | (v << 2)) & 0x3333_3333_3333_3333;
    (v | (v << 1)) & 0x5555_5555_5555_5555
}

/// What planning found, beyond the tiles themselves. The split and undersampling counters are
/// only counted in [`TilingMode::Adaptive`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PlanStats {
    pub tiles: usize,
    /// Splits where the head-pointer buffer was the binding bound (C_I > W² ≤ the memory
    /// bound): the importance alone needed more than W×W pixels.
    pub splits_for_importance: usize,
    /// Splits where the node-buffer bound min_j αN/F was below W²: predicted overflow.
    /// Every split is counted exactly once, in one of the two counters.
    pub splits_for_memory: usize,
    /// Finest-level tiles with C_I > C_max, rendered at the bound instead: the importance
    /// there is not met.
    pub undersampled_tiles: usize,
}

/// The tiles of one bundle direction, in Morton order, and how they came about.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TilePlan {
    pub tiles: Vec<Tile>,
    pub stats: PlanStats,
}

/// Why a plan cannot be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("importance map is {importance}x{importance} but fragment-count map is {fragments}x{fragments}")]
    MapSizeMismatch { importance: u32, fragments: u32 },
    #[error("the importance map must be max-reduced and the fragment-count map average-reduced")]
    WrongReduction,
    #[error("head-pointer buffer side W must be at least 1")]
    EmptyHeadBuffer,
    #[error("node-buffer capacity N must be at least 1")]
    EmptyNodeBuffer,
    #[error("alpha {0} is outside (0, 1]")]
    AlphaOutOfRange(f32),
    #[error("pixel area {0} is not a positive finite number")]
    InvalidPixelArea(f64),
    #[error("uniform tiling needs k a power of two with 1 <= k <= {side}, got {k}")]
    InvalidUniformTiling { k: u32, side: u32 },
}

/// Plans the tiles of one bundle direction. See [`TilePlanner`].
pub fn plan_tiles(
    importance: &MipChain,
    fragments: &MipChain,
    params: TileParams,
    mode: TilingMode,
) -> Result<TilePlan, PlanError> {
    TilePlanner::new(importance, fragments, params)?.plan(mode)
}

/// The verdict of Eq. 1–3 on one tile.
enum Verdict {
    /// Nothing to light-map there.
    Skip,
    Split(SplitReason),
    Emit {
        res: u32,
        undersampled: bool,
    },
}

enum SplitReason {
    Importance,
    Memory,
}

/// The analysis maps of one bundle direction and the buffer sizes to plan its tiles for.
#[derive(Clone, Copy, Debug)]
pub struct TilePlanner<'a> {
    importance: &'a MipChain,
    fragments: &'a MipChain,
    params: TileParams,
}

impl<'a> TilePlanner<'a> {
    /// `importance`: rays needed per unit area, max-mipped; `fragments`: fragments per
    /// analysis pixel, average-mipped; both R×R.
    pub fn new(importance: &'a MipChain, fragments: &'a MipChain, params: TileParams) -> Result<Self, PlanError> {
        params.validate()?;
        if importance.side() != fragments.side() {
            return Err(PlanError::MapSizeMismatch { importance: importance.side(), fragments: fragments.side() });
        }
        if importance.reduction() != Reduction::Max || fragments.reduction() != Reduction::Average {
            return Err(PlanError::WrongReduction);
        }
        Ok(TilePlanner { importance, fragments, params })
    }

    pub fn params(&self) -> &TileParams {
        &self.params
    }

    pub fn plan(&self, mode: TilingMode) -> Result<TilePlan, PlanError> {
        let top = self.importance.top_level();
        match mode {
            TilingMode::None => Ok(self.plan_grid(top)),
            TilingMode::Uniform { k } => {
                let side = self.importance.side();
                if !k.is_power_of_two() || k > side {
                    return Err(PlanError::InvalidUniformTiling { k, side });
                }
                Ok(self.plan_grid(top - k.trailing_zeros()))
            }
            TilingMode::Adaptive => Ok(self.plan_adaptive_recursive()),
        }
    }

    /// Eq. 1: C_I(i, x) = A(i)·I(i, x), the rays tile (level, x, y) needs.
    pub fn rays_needed(&self, level: u32, x: u32, y: u32) -> f64 {
        self.params.tile_area(level as i32) * self.importance.get(level, x, y) as f64
    }

    /// Eq. 3: C_max(i, x) = min(W², min_{j=i..L} αN / F(j, x_j)), the most rays tile
    /// (level, x, y) may use.
    pub fn ray_bound(&self, level: u32, x: u32, y: u32) -> f64 {
        let memory = (level..=self.importance.top_level())
            .map(|j| self.memory_bound(j, x >> (j - level), y >> (j - level)))
            .fold(f64::INFINITY, f64::min);
        self.params.head_buffer_pixels().min(memory)
    }

    /// Fragments predicted for the tile: res² · F(i, x), with F of the analysis pixel holding
    /// a sub-pixel tile (the finest estimate there is).
    ///
    /// # Panics
    /// If the tile lies outside the analysis window.
    pub fn predicted_nodes(&self, tile: &Tile) -> f64 {
        let (level, x, y) = if tile.level >= 0 {
            (tile.level as u32, tile.x, tile.y)
        } else {
            let depth = tile.level.unsigned_abs();
            (0, tile.x >> depth, tile.y >> depth)
        };
        let res = tile.res as f64;
        res * res * self.fragments.get(level, x, y) as f64
    }

    /// Eq. 1–3 as a plain recursive quadtree descent from the top.
    pub fn plan_adaptive_recursive(&self) -> TilePlan {
        let mut plan = PlanBuilder::default();
        self.descend(self.importance.top_level(), 0, 0, f64::INFINITY, &mut plan);
        plan.finish()
    }

    /// Eq. 1–3 the way Program 1 runs on the GPU: one thread per finest pixel descends from the
    /// top, carrying the running minimum of Eq. 3; a tile is emitted (and a split counted) only
    /// by the thread at its corner, so each appears once although many threads evaluate it.
    pub fn plan_adaptive_per_pixel(&self) -> TilePlan {
        let mut plan = PlanBuilder::default();
        let side = self.importance.side();
        for py in 0..side {
            for px in 0..side {
                self.pixel_thread(px, py, &mut plan);
            }
        }
        plan.finish()
    }

    fn pixel_thread(&self, px: u32, py: u32, plan: &mut PlanBuilder) {
        // Program 1 prints this update as `Cmax = min(CI, αN/F)`: a typo, since Eq. 3 takes
        // the running minimum over levels j = i..L, i.e. `Cmax = min(Cmax, αN/F)`.
        let mut memory = f64::INFINITY;
        for level in (0..=self.importance.top_level()).rev() {
            let (x, y) = (px >> level, py >> level);
            let at_corner = x << level == px && y << level == py;
            memory = memory.min(self.memory_bound(level, x, y));
            match self.judge(level, x, y, memory) {
                Verdict::Split(reason) => {
                    if at_corner {
                        plan.count_split(reason);
                    }
                }
                Verdict::Skip => return,
                Verdict::Emit { res, undersampled } => {
                    if at_corner {
                        plan.emit(Tile { level: level as i32, x, y, res }, undersampled);
                    }
                    return;
                }
            }
        }
    }

    fn descend(&self, level: u32, x: u32, y: u32, ancestors: f64, plan: &mut PlanBuilder) {
        let memory = ancestors.min(self.memory_bound(level, x, y));
        match self.judge(level, x, y, memory) {
            Verdict::Skip => {}
            Verdict::Emit { res, undersampled } => plan.emit(Tile { level: level as i32, x, y, res }, undersampled),
            Verdict::Split(reason) => {
                plan.count_split(reason);
                for (dx, dy) in QUADRANTS {
                    self.descend(level - 1, 2 * x + dx, 2 * y + dy, memory, plan);
                }
            }
        }
    }

    /// αN / F(level, x, y); +∞ where no fragment was counted (no memory bound from there).
    fn memory_bound(&self, level: u32, x: u32, y: u32) -> f64 {
        self.params.node_budget() / self.fragments.get(level, x, y) as f64
    }

    /// The subdivision rule of Sect. 4.3 for tile (level, x, y), given the running minimum of
    /// αN/F over it and its ancestors. Splits iff C_I > C_max (Eq. 3; Program 1's `CI < Cmax`
    /// test would also split on equality, the text does not).
    fn judge(&self, level: u32, x: u32, y: u32, memory: f64) -> Verdict {
        let rays = self.rays_needed(level, x, y);
        if rays <= 0.0 {
            return Verdict::Skip;
        }
        let head = self.params.head_buffer_pixels();
        let bound = head.min(memory);
        if rays > bound && level > 0 {
            let reason = if memory < head { SplitReason::Memory } else { SplitReason::Importance };
            return Verdict::Split(reason);
        }
        Verdict::Emit { res: bundle_resolution(rays, bound), undersampled: rays > bound }
    }

    /// Every tile of one level with any importance, at bundle resolution W.
    fn plan_grid(&self, level: u32) -> TilePlan {
        let mut plan = PlanBuilder::default();
        let side = self.importance.level_side(level);
        for y in 0..side {
            for x in 0..side {
                if self.importance.get(level, x, y) > 0.0 {
                    plan.emit(Tile { level: level as i32, x, y, res: self.params.w }, false);
                }
            }
        }
        plan.finish()
    }
}

/// The side of a tile's bundle: ⌈√min(C_I, C_max)⌉, but never above ⌊√C_max⌋ and never below 1.
///
/// Rounding up alone could break the memory bound by up to a row and a column (C_max = 10.5
/// would give 4×4 = 16 pixels, 52% over the node budget): the cap keeps res² ≤ C_max, so the
/// predicted nodes res²·F stay within αN, as Eq. 3 promises. The price is that a tile whose
/// C_I sits within one rounding step below C_max gets ⌊√C_max⌋² < C_I rays (at most a factor
/// (k/(k+1))² short). A single pixel is the least a non-empty tile can have, even if one pixel
/// is predicted to exceed the budget (C_max < 1).
pub fn bundle_resolution(rays: f64, bound: f64) -> u32 {
    let wanted = rays.min(bound).sqrt().ceil();
    let allowed = bound.sqrt().floor();
    wanted.min(allowed).max(1.0) as u32
}

/// Collects emitted tiles and counters in whatever order a traversal produces them.
#[derive(Default)]
struct PlanBuilder {
    plan: TilePlan,
}

impl PlanBuilder {
    fn emit(&mut self, tile: Tile, undersampled: bool) {
        self.plan.tiles.push(tile);
        self.plan.stats.undersampled_tiles += undersampled as usize;
    }

    fn count_split(&mut self, reason: SplitReason) {
        match reason {
            SplitReason::Importance => self.plan.stats.splits_for_importance += 1,
            SplitReason::Memory => self.plan.stats.splits_for_memory += 1,
        }
    }

    fn finish(mut self) -> TilePlan {
        self.plan.tiles.sort_by_key(Tile::morton_key);
        self.plan.stats.tiles = self.plan.tiles.len();
        self.plan
    }
}

#[cfg(test)]
mod tests;
