//! The adaptive ray-bundle baker's pure-Rust building blocks (Tokuyoshi et al. 2013): the
//! unit-testable specification that the GPU passes are later held equal to.
//!
//! Per bundle direction ω the baker
//! 1. takes ω and the pixel-grid jitter from [`directions::BundleDirections`]: a progressive,
//!    stratified sequence of lines (ω and −ω are one bundle, pdf 1/(2π) per hemisphere);
//! 2. rasterises an R×R analysis pass along ω into an importance map (rays needed per unit
//!    area, reduced by max) and a fragment-count map (depth complexity, reduced by average),
//!    whose chains down to 1×1 are [`mips::MipChain`]s;
//! 3. plans the tiles of that direction with [`tiles::TilePlanner`] (Eq. 1–3, Program 1):
//!    each tile gets a bundle resolution that meets its importance while its predicted
//!    per-pixel linked-list nodes fit the node buffer.
//!
//! Nothing here touches the GPU.

pub mod directions;
pub mod emitters;
pub mod estimator;
pub mod mips;
pub mod progressive;
pub mod raster;
pub mod stats;
pub mod tiles;
