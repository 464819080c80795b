//! Reference backend: every texel's irradiance path-traced independently.

use crate::atlas::TexelMap;
use crate::progress::Progress;
use crate::reference::ReferenceTracer;
use crate::scene::{Rgb, Scene};

use super::{BackendStats, BakeConfig};

pub struct ReferenceBackend<'s> {
    tracer: ReferenceTracer<'s>,
    samples: u32,
    seed: u64,
}

impl<'s> ReferenceBackend<'s> {
    pub fn new(scene: &'s Scene, config: &BakeConfig) -> Self {
        ReferenceBackend {
            tracer: ReferenceTracer::new(scene).with_threads(config.threads),
            samples: config.samples,
            seed: config.seed,
        }
    }

    pub fn bake_lod(&self, texels: &TexelMap, progress: &dyn Progress) -> (Vec<Rgb>, BackendStats) {
        let queries: Vec<_> = texels.position.iter().copied().zip(texels.normal.iter().copied()).collect();
        progress.begin(&format!("LOD {} reference", texels.lod), queries.len() as u64);
        // Each LOD draws from its own seed so levels are independent estimates.
        let seed = crate::sampling::mix64(self.seed ^ ((texels.lod as u64) << 56));
        let (e, stats) =
            self.tracer.irradiance_batch(&queries, self.samples, seed, &|done| progress.reached(done as u64));
        progress.end();
        let stats = BackendStats { samples_per_texel: self.samples, rays: stats.rays, seconds: stats.seconds };
        (e, stats)
    }
}
