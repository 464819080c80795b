//! GPU code (wgpu): the shared device, WGSL shaders and their `#[repr(C)]` mirrors, and the
//! viewer's passes, one file per pass.
//!
//! - [`bundle_analysis`], [`bundle_mips`]: the GPU bundle backend's analysis raster and mip
//!   passes (twins of `cpu::analysis` and `bundle::mips`); [`bundle_tiles`]: Program 1
//!   (twin of `bundle::tiles::TilePlanner`); [`bundle_lists`]: per-tile linked lists with
//!   overflow split-and-redo; [`bundle_resolve`]: the per-pixel exchange into fixed-point
//!   texel sums (twin of `cpu::fragments` + `bundle::estimator`); [`bundle_backend`]: the
//!   backend itself (`BundleBackend`) and its provider.
//! - [`choice`]: what `--backend auto` picks, measured once per adapter.
//! - [`pass`]: set-up the bundle passes share (buffer layouts, the attachment-less raster).
//! - [`device`]: adapter and device selection, shared by everything on the GPU.
//! - [`shader`]: the WGSL files under `shaders/` and the include preprocessor.
//! - [`layout`]: the structs uploaded to the GPU, checked against the shaders in tests.
//! - [`lightmap`]: the shown light map's GPU mirror (partial page uploads).
//! - [`scene`]: the scene's triangles, materials and textures on the GPU.
//! - [`surface`]: the surface pass (albedo × E/π + emission, debug views).
//! - [`surface_radiance`]: what surfaces outside a cell bake's target show its bundles (the
//!   shown map's mirror and the scene's materials, read by the resolve).
//! - [`probe`]: a compute pass evaluating the light map's sampling function at points.
//! - [`target`]: render targets and read-back to images.

pub mod bundle_analysis;
pub mod bundle_backend;
pub mod bundle_lists;
pub mod bundle_mips;
pub mod bundle_resolve;
pub mod bundle_tiles;
pub mod choice;
pub mod device;
pub mod layout;
pub mod lightmap;
pub mod pass;
pub mod probe;
pub mod scene;
pub mod shader;
pub mod sky;
pub mod surface;
pub mod surface_radiance;
pub mod target;
pub mod tone_map;

pub use bundle_backend::{GpuBundleBackend, GpuProvider};
pub use device::{GpuContext, GpuError};
