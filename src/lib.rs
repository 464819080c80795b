//! livebake: global-illumination light maps for glTF scenes.
//!
//! Pure-Rust parts (no GPU): [`scene`] (glTF import), [`atlas`] (light-map UVs, packing,
//! per-LOD texel maps), [`lod`], [`mod@reference`] (CPU reference path tracer), [`bundle`] (the
//! adaptive ray-bundle algorithm: directions, analysis mips, tile planner, estimator),
//! [`cpu`] (the CPU bundle backend), [`bake`] (bake driver), [`output`] (EXR/PNG/JSON),
//! [`probe`] (irradiance at surface points), [`export`] (glTF with the light map, for other
//! engines), [`watch`] (hot reload: file watching and scene diffs).

pub mod analytic;
pub mod atlas;
pub mod bake;
pub mod bundle;
pub mod cpu;
pub mod export;
pub mod gpu;
pub mod grid;
pub mod lod;
pub mod morton;
pub mod output;
pub mod parallel;
pub mod plot;
pub mod points;
pub mod probe;
pub mod progress;
pub mod reference;
pub mod runtime;
pub mod sampling;
pub mod scene;
pub mod serve;
pub mod shard;
pub mod viewer;
pub mod watch;

pub use glam;
