//! CPU reference path tracer: the ground truth every other estimate is tested against.
//!
//! * [`bvh`]: binned-SAH BVH2 over a [`SceneGeometry`](crate::scene::SceneGeometry)
//!   (closest hit, any hit, closest point; alpha-masked triangles cut out). Pure and reusable.
//! * [`emitters`]: emissive triangles sampled by power, with the densities MIS needs.
//! * [`tracer`]: [`ReferenceTracer`], irradiance E (W/m²) at a surface point by path tracing
//!   with next-event estimation and MIS at every vertex; its docs state the conventions
//!   (sidedness, emission, lights, sky, ray offset ε).
//! * [`compare`]: [`RelativeRmsError`], the error figure against a noisy reference.
//! * [`batch`]: many queries on worker threads, independent of thread count.
//! * [`scenes`]: synthetic scenes for tests and benchmarks.
//!
//! Throughput: `livebake bench --only reference`.

mod alpha;
pub mod batch;
pub mod bvh;
mod bvh_build;
pub mod compare;
pub mod emitters;
pub mod environment;
pub mod punctual;
pub mod scenes;
pub mod tracer;
mod triangle;

#[cfg(test)]
mod tests;

pub use alpha::AlphaMasks;
pub use batch::TraceStats;
pub use bvh::{Bvh, Hit, Nearest};
pub use compare::RelativeRmsError;
pub use emitters::{EmitterSample, EmitterTable};
pub use tracer::{IrradianceEstimate, ReferenceTracer, TracerOptions, ray_epsilon};
