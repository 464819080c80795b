//! Which bundle backend a bake runs on (`--backend cpu|gpu|auto`).

use std::sync::Arc;
use std::sync::atomic::AtomicBool;
use std::time::Instant;

use super::BackendKind;
use super::BakeError;
use crate::atlas::TexelMap;
use crate::bundle::progressive::BatchSums;
use crate::bundle::target::WholeLod;
use crate::bundle::{BackendProvider, BundleBackend, BundleScene, DirectionJob, JobSequence, SourceRadiance};
use crate::cpu::CpuProvider;
use crate::gpu::choice::{self, Chosen};
use crate::gpu::{GpuContext, GpuProvider};
use crate::scene::Rgb;

/// The backend `kind` names for `bundle` (not the reference tracer).
pub(super) fn bundle_backend(
    kind: BackendKind,
    bundle: &Arc<BundleScene>,
    threads: usize,
) -> Result<Box<dyn BundleBackend>, BakeError> {
    let unavailable = |e: &dyn std::fmt::Display| BakeError::Backend(e.to_string());
    let cpu = || -> Result<Box<dyn BundleBackend>, BakeError> {
        Ok(Box::new(CpuProvider::new().backend(bundle, threads).map_err(|e| unavailable(&e))?))
    };
    let gpu = |context: GpuContext| -> Result<Box<dyn BundleBackend>, BakeError> {
        Ok(Box::new(GpuProvider::new(context).backend(bundle, threads).map_err(|e| unavailable(&e))?))
    };
    match kind {
        BackendKind::Cpu | BackendKind::Reference => cpu(),
        BackendKind::Gpu => gpu(GpuContext::headless().map_err(|e| {
            BakeError::Backend(format!("{e} (--backend gpu needs a Vulkan adapter; --backend cpu needs none)"))
        })?),
        BackendKind::Auto => {
            let context = match GpuContext::headless() {
                Ok(c) => c,
                Err(e) => {
                    tracing::info!("--backend auto: no GPU ({e}); baking on the CPU");
                    return cpu();
                }
            };
            if !context.is_software() {
                tracing::info!("--backend auto: the GPU backend on {}", context.info.name);
                return gpu(context);
            }
            let path = choice::cache_path();
            let known = path.as_deref().and_then(|p| choice::remembered(&context, threads, p));
            let measured = match known {
                Some(m) => m,
                None => {
                    let mut on_cpu = cpu()?;
                    let mut on_gpu = gpu(context.clone())?;
                    let cpu_seconds = trial(bundle, &mut *on_cpu);
                    let gpu_seconds = trial(bundle, &mut *on_gpu);
                    let m = choice::from_times(&context, threads, cpu_seconds, gpu_seconds);
                    if let Some(p) = &path {
                        choice::remember(&m, p);
                    }
                    m
                }
            };
            tracing::info!(
                "--backend auto on the software adapter {}: {:?} (a trial batch took {:.2} s on the CPU backend, \
                 {:.2} s on the GPU backend)",
                measured.adapter,
                measured.chosen,
                measured.cpu_seconds,
                measured.gpu_seconds
            );
            match measured.chosen {
                Chosen::Cpu => cpu(),
                Chosen::Gpu => gpu(context),
            }
        }
    }
}

/// Seconds `backend` takes for one batch of four directions over the scene's LOD 0.
fn trial(bundle: &BundleScene, backend: &mut dyn BundleBackend) -> f64 {
    let texels = TexelMap::build(&bundle.scene, &bundle.geom, &bundle.atlas, 0);
    let whole = WholeLod::new(&bundle.atlas, &texels);
    let target = whole.target(&texels);
    let own = vec![Rgb::ZERO; texels.len()];
    let source = SourceRadiance { own: &own, foreign: None };
    let jobs = JobSequence::new(bundle.config.seed, bundle.emitters.small.len(), bundle.config.light_directions);
    let batch: Vec<DirectionJob> = (0..4).map(|i| jobs.job(i)).collect();
    let mut sums = BatchSums::default();
    let never = AtomicBool::new(false);
    let t = Instant::now();
    let _ = backend.trace_batch(&target, &batch, &source, &mut sums, &never);
    t.elapsed().as_secs_f64()
}
