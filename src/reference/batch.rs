//! Parallel batches of irradiance queries.
//!
//! Workers take chunks of consecutive queries from the crate's work queue (dynamic load
//! balancing); query `i` always uses the random stream `(seed, i)`, so the results are the
//! same whatever the thread count or scheduling.

use std::time::Instant;

use glam::Vec3;

use super::tracer::{IrradianceEstimate, ReferenceTracer};
use crate::parallel::{available_threads, par_map_indices};
use crate::scene::Rgb;

/// What a batch cost.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize)]
pub struct TraceStats {
    /// Every ray cast: path segments, emitter and punctual-light shadow rays.
    pub rays: u64,
    /// Paths traced (queries × spp).
    pub paths: u64,
    /// Wall-clock time of the batch.
    pub seconds: f64,
}

impl TraceStats {
    /// Rays per second of wall-clock time (all threads together).
    pub fn rays_per_second(&self) -> f64 {
        if self.seconds > 0.0 { self.rays as f64 / self.seconds } else { 0.0 }
    }
}

impl ReferenceTracer<'_> {
    /// Worker threads a batch uses: the override, else the available parallelism.
    pub fn threads(&self) -> usize {
        self.options.threads.unwrap_or_else(available_threads).max(1)
    }

    /// E (W/m²) at every `(point, unit normal)` query with `spp` paths each; query `i` uses
    /// stream `(seed, i)`. `progress` is called from the workers with the number of queries
    /// finished so far (monotonic per call site, not necessarily in order across threads).
    pub fn irradiance_batch(
        &self,
        queries: &[(Vec3, Vec3)],
        spp: u32,
        seed: u64,
        progress: &(dyn Fn(usize) + Sync),
    ) -> (Vec<Rgb>, TraceStats) {
        let (est, stats) = self.irradiance_batch_estimates(queries, spp, seed, progress);
        (est.into_iter().map(|e| e.e).collect(), stats)
    }

    /// [`irradiance_batch`](Self::irradiance_batch) with standard errors and per-query ray counts.
    pub fn irradiance_batch_estimates(
        &self,
        queries: &[(Vec3, Vec3)],
        spp: u32,
        seed: u64,
        progress: &(dyn Fn(usize) + Sync),
    ) -> (Vec<IrradianceEstimate>, TraceStats) {
        let start = Instant::now();
        let n = queries.len();
        let threads = self.threads().min(n).max(1);
        let chunk = (n / (threads * 32)).clamp(1, 64);
        let results = par_map_indices(
            n,
            chunk,
            threads,
            |i| self.irradiance_estimate(queries[i].0, queries[i].1, spp, seed, i as u64),
            progress,
        );
        let rays = results.iter().map(|e| e.rays).sum();
        let stats = TraceStats { rays, paths: n as u64 * spp as u64, seconds: start.elapsed().as_secs_f64() };
        (results, stats)
    }
}
