//! livebake: global-illumination light maps for glTF scenes.
//!
//! Pure-Rust parts (no GPU): [`scene`] (glTF import), [`atlas`] (light-map UVs, packing,
//! per-LOD texel maps), [`lod`], [`reference`] (CPU reference path tracer), [`bake`] (bake
//! driver and backends), [`output`] (EXR/PNG/JSON), [`probe`] (irradiance at surface points).

pub mod atlas;
pub mod bundle;
pub mod lod;
pub mod reference;
pub mod sampling;
pub mod scene;

pub use glam;
