//! The CPU bundle backend: the adaptive ray-bundle algorithm on worker threads, with the
//! same plan, node budget and estimator as the GPU backend.
//!
//! A batch of directions is split into a fixed number of lanes; each lane traces its
//! directions in order into its own hit sums, and the lanes are added in order. The sums
//! therefore do not depend on how many threads ran the lanes.

mod analysis;
mod direction;
mod fragments;
pub mod prepared;
pub mod punctual;
mod spheres;

use crate::bundle::emitters::EmitterGroup;
use crate::bundle::progressive::BatchSums;
use crate::bundle::stats::PassStats;
use crate::bundle::{BundleBackend, BundleConfig, DirectionJob};
use crate::parallel::par_map;
use crate::scene::Rgb;

use direction::{PassContext, Scratch, trace_direction};
pub use prepared::PreparedScene;

struct Lane {
    sums: BatchSums,
    scratch: Scratch,
}

pub struct CpuBundleBackend<'a> {
    ctx: PassContext<'a>,
    lanes: Vec<Lane>,
    threads: usize,
}

impl<'a> CpuBundleBackend<'a> {
    /// `light_pixel`: bundle pixel side of the light pass (metres).
    pub fn new(
        scene: &'a PreparedScene<'a>,
        config: &'a BundleConfig,
        groups: &'a [EmitterGroup],
        sky: Rgb,
        light_pixel: f32,
        threads: usize,
    ) -> Self {
        let texels = scene.texels.len();
        let lanes = (0..config.lanes.max(1))
            .map(|_| Lane { sums: BatchSums::new(texels), scratch: Scratch::default() })
            .collect();
        CpuBundleBackend {
            ctx: PassContext { scene, config, groups, sky, light_pixel },
            lanes,
            threads: threads.max(1),
        }
    }
}

impl BundleBackend for CpuBundleBackend<'_> {
    fn name(&self) -> &'static str {
        "cpu"
    }

    fn trace_batch(&mut self, batch: &[DirectionJob], source: &[Rgb], sums: &mut BatchSums) -> PassStats {
        let n_lanes = self.lanes.len();
        let ctx = &self.ctx;
        // Lane l traces directions l, l + n_lanes, ... in order into its own sums; lanes are
        // independent, so which worker runs which lane does not change the result.
        let lanes: Vec<(usize, &mut Lane)> = self.lanes.iter_mut().enumerate().collect();
        let stats = par_map(lanes, self.threads, |(l, lane)| {
            let mut stats = PassStats::default();
            for job in batch.iter().skip(l).step_by(n_lanes) {
                trace_direction(ctx, job, source, &mut lane.sums, &mut lane.scratch, &mut stats);
            }
            stats
        });
        let mut lane_sums: Vec<BatchSums> = self.lanes.iter_mut().map(|l| std::mem::take(&mut l.sums)).collect();
        sums.reduce_from(&mut lane_sums, self.threads);
        for (lane, s) in self.lanes.iter_mut().zip(lane_sums) {
            lane.sums = s;
        }
        let mut total = PassStats::default();
        for s in &stats {
            total.add(s);
        }
        total
    }
}
