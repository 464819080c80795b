//! `--backend auto`: the GPU bundle backend on a hardware adapter; on a software adapter
//! (lavapipe, where the "GPU" is the same CPU cores) whichever of the two backends traced a
//! trial batch faster, measured once per adapter, driver and thread count and remembered in
//! the user's cache directory (`$XDG_CACHE_HOME/livebake/backend.json`, else
//! `~/.cache/livebake/backend.json`).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use super::device::GpuContext;

/// What `auto` resolved to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Chosen {
    Cpu,
    Gpu,
}

/// One remembered measurement.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Measured {
    pub adapter: String,
    pub driver: String,
    pub threads: usize,
    pub cpu_seconds: f64,
    pub gpu_seconds: f64,
    pub chosen: Chosen,
}

#[derive(Default, Serialize, Deserialize)]
struct Cache {
    measured: Vec<Measured>,
}

/// Where the choices are remembered; `None` when the machine has no home or cache dir.
pub fn cache_path() -> Option<PathBuf> {
    let base = std::env::var_os("XDG_CACHE_HOME")
        .filter(|v| !v.is_empty())
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").filter(|v| !v.is_empty()).map(|h| PathBuf::from(h).join(".cache")))?;
    Some(base.join("livebake").join("backend.json"))
}

fn key(gpu: &GpuContext, threads: usize) -> (String, String, usize) {
    (gpu.info.name.clone(), gpu.info.driver_info.clone(), threads)
}

/// The remembered choice for this adapter and thread count, if any.
pub fn remembered(gpu: &GpuContext, threads: usize, path: &std::path::Path) -> Option<Measured> {
    let text = std::fs::read_to_string(path).ok()?;
    let cache: Cache = serde_json::from_str(&text).ok()?;
    let (adapter, driver, threads) = key(gpu, threads);
    cache.measured.into_iter().find(|m| m.adapter == adapter && m.driver == driver && m.threads == threads)
}

/// Records a measurement (replacing an older one for the same key). Failing to write the
/// cache only costs a new measurement next time, so errors are logged, not returned.
pub fn remember(measured: &Measured, path: &std::path::Path) {
    let mut cache: Cache =
        std::fs::read_to_string(path).ok().and_then(|t| serde_json::from_str(&t).ok()).unwrap_or_default();
    cache
        .measured
        .retain(|m| !(m.adapter == measured.adapter && m.driver == measured.driver && m.threads == measured.threads));
    cache.measured.push(measured.clone());
    let write = || -> std::io::Result<()> {
        if let Some(dir) = path.parent() {
            std::fs::create_dir_all(dir)?;
        }
        // Written whole then renamed: a reader never sees half a file.
        let tmp = path.with_extension("json.tmp");
        std::fs::write(&tmp, serde_json::to_vec_pretty(&cache).map_err(std::io::Error::other)?)?;
        std::fs::rename(&tmp, path)
    };
    if let Err(e) = write() {
        tracing::warn!("cannot remember the backend choice in {}: {e}", path.display());
    }
}

/// The choice from a measurement: the faster backend.
pub fn from_times(gpu: &GpuContext, threads: usize, cpu_seconds: f64, gpu_seconds: f64) -> Measured {
    let (adapter, driver, threads) = key(gpu, threads);
    let chosen = if gpu_seconds < cpu_seconds { Chosen::Gpu } else { Chosen::Cpu };
    Measured { adapter, driver, threads, cpu_seconds, gpu_seconds, chosen }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_measurement_is_remembered_per_adapter_and_thread_count() {
        let gpu = GpuContext::headless().expect("a Vulkan adapter (lavapipe: mesa-vulkan-drivers)");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("livebake/backend.json");
        assert_eq!(remembered(&gpu, 2, &path), None);
        let slow_gpu = from_times(&gpu, 2, 1.0, 3.0);
        assert_eq!(slow_gpu.chosen, Chosen::Cpu);
        remember(&slow_gpu, &path);
        assert_eq!(remembered(&gpu, 2, &path), Some(slow_gpu));
        assert_eq!(remembered(&gpu, 1, &path), None, "another thread count is measured apart");
        let fast_gpu = from_times(&gpu, 2, 3.0, 1.0);
        assert_eq!(fast_gpu.chosen, Chosen::Gpu);
        remember(&fast_gpu, &path);
        assert_eq!(remembered(&gpu, 2, &path), Some(fast_gpu), "a new measurement replaces the old");
        std::fs::write(&path, "{ half a fi").unwrap();
        assert_eq!(remembered(&gpu, 2, &path), None, "a damaged cache is measured again");
    }
}
