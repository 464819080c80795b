//! Options every scene command shares. Same options, same result.

use anyhow::{Result, bail};
use clap::{Args, ValueEnum};

use livebake::atlas::AtlasConfig;
use livebake::bake::{BackendKind, BakeConfig};
use livebake::scene::Rgb;

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Backend {
    /// Per-texel (or per-point) CPU path tracing: the ground truth.
    Reference,
}

#[derive(Args, Debug, Clone)]
pub struct SceneOptions {
    /// Light-map texel size at LOD 0, metres. Default: from a budget of --texel-budget texels.
    #[arg(long, value_name = "M")]
    pub texel_size: Option<f32>,
    /// LOD-0 texel budget used when --texel-size is not given.
    #[arg(long, value_name = "N", default_value_t = 500_000)]
    pub texel_budget: u64,
    /// Number of light-map LODs to bake (LOD k has 2^k times LOD 0's resolution).
    #[arg(long, value_name = "K", default_value_t = 1)]
    pub lods: u32,
    /// Samples: paths per texel (bake) or per point (probe) for the reference backend.
    /// Default: 16 for bake, 1024 for probe.
    #[arg(long, value_name = "N")]
    pub samples: Option<u32>,
    /// Uniform sky radiance W/(sr·m²) seen by rays leaving the scene.
    #[arg(long, value_name = "R,G,B", default_value = "0,0,0", value_parser = parse_rgb)]
    pub sky: Rgb,
    /// Estimator that computes irradiance.
    #[arg(long, value_enum, default_value_t = Backend::Reference)]
    pub backend: Backend,
    /// Random seed.
    #[arg(long, value_name = "S", default_value_t = 0)]
    pub seed: u64,
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long, value_name = "N")]
    pub threads: Option<usize>,
    /// Ignore TEXCOORD_1 and unwrap every mesh.
    #[arg(long)]
    pub no_uv1: bool,
}

impl Default for SceneOptions {
    fn default() -> Self {
        SceneOptions {
            texel_size: None,
            texel_budget: 500_000,
            lods: 1,
            samples: None,
            sky: Rgb::ZERO,
            backend: Backend::Reference,
            seed: 0,
            threads: None,
            no_uv1: false,
        }
    }
}

fn parse_rgb(s: &str) -> Result<Rgb, String> {
    let parts: Vec<&str> = s.split(',').map(str::trim).collect();
    let vals: Vec<f32> = match parts.len() {
        1 => vec![parts[0].parse().map_err(|e| format!("{s:?}: {e}"))?; 3],
        3 => parts.iter().map(|p| p.parse::<f32>().map_err(|e| format!("{p:?}: {e}"))).collect::<Result<_, _>>()?,
        _ => return Err(format!("expected R,G,B or a single value, got {s:?}")),
    };
    if vals.iter().any(|v| !v.is_finite() || *v < 0.0) {
        return Err(format!("sky radiance must be finite and non-negative, got {s:?}"));
    }
    Ok(Rgb::new(vals[0], vals[1], vals[2]))
}

impl SceneOptions {
    pub fn bake_config(&self, default_samples: u32) -> Result<BakeConfig> {
        if let Some(t) = self.texel_size
            && (!t.is_finite() || t <= 0.0)
        {
            bail!("--texel-size must be a positive number of metres, got {t}");
        }
        if self.texel_budget == 0 {
            bail!("--texel-budget must be at least 1");
        }
        if self.threads == Some(0) {
            bail!("--threads must be at least 1");
        }
        Ok(BakeConfig {
            atlas: AtlasConfig {
                texel_size: self.texel_size,
                texel_budget: self.texel_budget,
                use_uv1: !self.no_uv1,
                ..AtlasConfig::default()
            },
            lods: self.lods,
            samples: self.samples.unwrap_or(default_samples),
            backend: match self.backend {
                Backend::Reference => BackendKind::Reference,
            },
            seed: self.seed,
            threads: self.threads,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sky_parses_triples_and_scalars_and_refuses_nonsense() {
        assert_eq!(parse_rgb("1,2,3").unwrap(), Rgb::new(1.0, 2.0, 3.0));
        assert_eq!(parse_rgb("0.5").unwrap(), Rgb::splat(0.5));
        assert!(parse_rgb("1,2").is_err());
        assert!(parse_rgb("-1,0,0").is_err());
        assert!(parse_rgb("nan,0,0").is_err());
        assert!(parse_rgb("a,b,c").is_err());
    }
}
