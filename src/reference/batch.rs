//! Parallel batches of irradiance queries on crossbeam scoped threads.
//!
//! Workers take chunks of consecutive queries from an atomic counter (dynamic load
//! balancing); query `i` always uses the random stream `(seed, i)`, so the results are the
//! same whatever the thread count or scheduling.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use glam::Vec3;

use super::tracer::{IrradianceEstimate, ReferenceTracer};
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

/// A chunk of finished queries: first index and their estimates.
type Chunk = (usize, Vec<IrradianceEstimate>);

impl ReferenceTracer<'_> {
    /// Worker threads a batch uses: the override, else the available parallelism.
    pub fn threads(&self) -> usize {
        self.options.threads.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get())).max(1)
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
        let next = AtomicUsize::new(0);
        let done = AtomicUsize::new(0);
        let worker = || {
            let mut out: Vec<Chunk> = Vec::new();
            loop {
                let begin = next.fetch_add(chunk, Ordering::Relaxed);
                if begin >= n {
                    return out;
                }
                let end = (begin + chunk).min(n);
                let est = (begin..end)
                    .map(|i| self.irradiance_estimate(queries[i].0, queries[i].1, spp, seed, i as u64))
                    .collect();
                out.push((begin, est));
                progress(done.fetch_add(end - begin, Ordering::Relaxed) + end - begin);
            }
        };
        let chunks: Vec<Vec<Chunk>> = crossbeam::thread::scope(|s| {
            let handles: Vec<_> = (0..threads).map(|_| s.spawn(|_| worker())).collect();
            handles.into_iter().map(|h| h.join().expect("reference tracer worker panicked")).collect()
        })
        .expect("reference tracer worker panicked");
        let mut results = vec![IrradianceEstimate { e: Rgb::ZERO, stderr: Rgb::ZERO, rays: 0 }; n];
        for (begin, est) in chunks.into_iter().flatten() {
            results[begin..begin + est.len()].copy_from_slice(&est);
        }
        let rays = results.iter().map(|e| e.rays).sum();
        let stats = TraceStats { rays, paths: n as u64 * spp as u64, seconds: start.elapsed().as_secs_f64() };
        (results, stats)
    }
}
