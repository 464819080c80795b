//! Options every scene command shares. Same options, same result.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::{Args, ValueEnum};

use livebake::atlas::AtlasConfig;
use livebake::bake::{BackendKind, BakeConfig};
use livebake::bundle::tiles::TilingMode;
use livebake::bundle::{BundleConfig, Lanes};
use livebake::scene::daylight::DaylightOptions;
use livebake::scene::environment::{EnvironmentOptions, load_environment};
use livebake::scene::sun::{Instant, SunPosition, parse_time};
use livebake::scene::{DEFAULT_MAX_TEXTURE_PIXELS, LoadOptions, Rgb, SunPlacement, SurroundingsSpec};

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum Backend {
    /// Adaptive ray bundles on the CPU (fast; the default).
    Cpu,
    /// Adaptive ray bundles on the GPU (Vulkan; Mesa's lavapipe where there is no GPU).
    Gpu,
    /// The GPU on a hardware adapter; on a software one the faster of cpu and gpu, measured
    /// once and remembered.
    Auto,
    /// Per-texel (or per-point) CPU path tracing: the ground truth.
    Reference,
}

/// Most worker threads: each has its own stack and scratch buffers, threads beyond the cores
/// only wait, and tens of thousands make the OS refuse to start them (the process aborts).
pub const MAX_THREADS: usize = 1024;

#[derive(Args, Debug, Clone)]
pub struct SceneOptions {
    /// Light-map texel size at LOD 0, metres. Default: from a budget of --texel-budget texels.
    // Negative numbers are taken as values so that `--texel-size -1` is refused with a
    // message about the texel size rather than as an unknown flag `-1`.
    #[arg(long, value_name = "M", allow_negative_numbers = true)]
    pub texel_size: Option<f32>,
    /// LOD-0 texel budget used when --texel-size is not given (bake: 500000; run: 40000, small
    /// enough for first light within a second).
    #[arg(long, value_name = "N")]
    pub texel_budget: Option<u64>,
    /// Light-map LODs (LOD k has 2^k times LOD 0's resolution). bake: how many to bake
    /// (default 1); run: the most the runtime refines to (default: enough for ~2 cm texels).
    #[arg(long, value_name = "K")]
    pub lods: Option<u32>,
    /// Samples: bundle directions for the bundle backends (default 256; converge: the most, default
    /// 2^20, hours); paths per texel (bake, default 16) or per point (probe, default 1024) for the
    /// reference backend.
    #[arg(long, value_name = "N")]
    pub samples: Option<u32>,
    /// Uniform sky radiance W/(sr·m²) seen by rays leaving the scene (default: none; but a
    /// scene with no light of its own, given no --sky, --sun, --environment or --sky-model,
    /// gets a white sky of 1 W/(sr·m²), and a warning).
    #[arg(long, value_name = "R,G,B", value_parser = parse_rgb, allow_hyphen_values = true)]
    pub sky: Option<Rgb>,
    #[command(flatten)]
    pub outdoors: OutdoorOptions,
    /// Estimator that computes irradiance.
    #[arg(long, value_enum, default_value_t = Backend::Cpu)]
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
    /// Let the scene read buffer and image files outside its folder (URIs with `..` leading
    /// out, absolute paths, symbolic links pointing out). Without it such a URI is refused.
    #[arg(long)]
    pub allow_outside_files: bool,
    /// Most pixels one texture may have, read from the image's header before it is decoded;
    /// a larger texture is refused.
    #[arg(long, value_name = "N", default_value_t = DEFAULT_MAX_TEXTURE_PIXELS)]
    pub max_texture_pixels: u64,
    #[command(flatten)]
    pub bundle: BundleOptions,
}

/// Light from around the scene: an environment map, the sun, a physical sky.
#[derive(Args, Debug, Clone)]
pub struct OutdoorOptions {
    /// Equirectangular environment map (.hdr or .exr), radiance W/(sr·m²) seen by rays leaving
    /// the scene (u = 0.5 + atan2(x, −z)/2π, v = acos(y)/π, row 0 up, the centre −Z).
    #[arg(long, value_name = "FILE")]
    pub environment: Option<PathBuf>,
    /// Multiplies the environment map.
    #[arg(long, value_name = "S", default_value_t = 1.0, allow_negative_numbers = true)]
    pub environment_scale: f32,
    /// Turns the environment map about +Y, degrees (positive: counter-clockwise seen from above).
    #[arg(long, value_name = "DEG", default_value_t = 0.0, allow_negative_numbers = true)]
    pub environment_rotation: f32,
    /// What becomes of a sun in the environment map: `split` (its brightest compact region is
    /// a directional light, the rest the sky) or `keep` (all of it is sky).
    #[arg(long, value_enum, default_value_t = EnvironmentSun::Split)]
    pub environment_sun: EnvironmentSun,
    /// The sun: elevation and azimuth in degrees (azimuth from −Z toward +X: −Z north, +X
    /// east) and its irradiance in W/m² (default: a clear sky's at --turbidity).
    #[arg(long, value_name = "ELEVATION,AZIMUTH[,IRRADIANCE]", value_parser = parse_sun, allow_hyphen_values = true)]
    pub sun: Option<(SunPosition, Option<f32>)>,
    /// A sun study: latitude and longitude in degrees (north, east positive), with --time.
    #[arg(long, value_name = "LAT,LON", value_parser = parse_location, allow_hyphen_values = true)]
    pub location: Option<(f64, f64)>,
    /// A sun study's date and time, ISO 8601 with an offset (2026-06-21T12:00:00Z).
    #[arg(long, value_name = "ISO-8601", value_parser = parse_time)]
    pub time: Option<Instant>,
    /// A physical sky lit by the sun (--sun, or --location and --time): `preetham`.
    #[arg(long, value_enum)]
    pub sky_model: Option<SkyModel>,
    /// Atmospheric turbidity of the sky model and the clear-sky sun (2: very clear, 10: hazy).
    #[arg(long, value_name = "T", default_value_t = DaylightOptions::default().turbidity)]
    pub turbidity: f64,
    /// Albedo of the ground the sky model puts below the horizon.
    #[arg(long, value_name = "A", default_value_t = DaylightOptions::default().ground_albedo)]
    pub ground_albedo: f64,
}

impl Default for OutdoorOptions {
    fn default() -> Self {
        OutdoorOptions {
            environment: None,
            environment_scale: 1.0,
            environment_rotation: 0.0,
            environment_sun: EnvironmentSun::Split,
            sun: None,
            location: None,
            time: None,
            sky_model: None,
            turbidity: DaylightOptions::default().turbidity,
            ground_albedo: DaylightOptions::default().ground_albedo,
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum EnvironmentSun {
    Split,
    Keep,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum SkyModel {
    /// Preetham, Shirley & Smits 1999.
    Preetham,
}

fn parse_numbers(s: &str, least: usize, most: usize, what: &str) -> Result<Vec<f64>, String> {
    let values: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|_| format!("{what}: {p:?} is not a number")))
        .collect::<Result<_, _>>()?;
    if values.len() < least || values.len() > most || values.iter().any(|v| !v.is_finite()) {
        return Err(format!("{what}: expected {least} to {most} finite numbers separated by commas, got {s:?}"));
    }
    Ok(values)
}

fn parse_sun(s: &str) -> Result<(SunPosition, Option<f32>), String> {
    let v = parse_numbers(s, 2, 3, "--sun ELEVATION,AZIMUTH[,IRRADIANCE]")?;
    if !(-90.0..=90.0).contains(&v[0]) {
        return Err(format!("--sun: elevation must be between -90 and 90 degrees, got {}", v[0]));
    }
    if v.get(2).is_some_and(|e| *e < 0.0) {
        return Err(format!("--sun: irradiance must be ≥ 0 W/m², got {}", v[2]));
    }
    Ok((SunPosition { elevation: v[0], azimuth: v[1].rem_euclid(360.0) }, v.get(2).map(|e| *e as f32)))
}

fn parse_location(s: &str) -> Result<(f64, f64), String> {
    let v = parse_numbers(s, 2, 2, "--location LAT,LON")?;
    if !(-90.0..=90.0).contains(&v[0]) || !(-180.0..=180.0).contains(&v[1]) {
        return Err(format!("--location: latitude in [-90, 90] and longitude in [-180, 180] degrees, got {s:?}"));
    }
    Ok((v[0], v[1]))
}

impl OutdoorOptions {
    /// How the surroundings are made: the environment map loaded (its sun split off unless
    /// `keep`), the sun placed, the options checked against each other.
    pub fn spec(&self, sky: Rgb, load: &LoadOptions) -> Result<SurroundingsSpec> {
        if self.sun.is_some() && (self.location.is_some() || self.time.is_some()) {
            bail!("--sun and --location/--time both place the sun: give one of them");
        }
        if self.location.is_some() != self.time.is_some() {
            bail!("a sun study needs both --location and --time");
        }
        if self.environment.is_some() && self.sky_model.is_some() {
            bail!("--environment and --sky-model are both the sky: give one of them");
        }
        if sky.max_element() > 0.0 && (self.environment.is_some() || self.sky_model.is_some()) {
            bail!("--sky and --environment/--sky-model are both the sky: give one of them");
        }
        let daylight = DaylightOptions { turbidity: self.turbidity, ground_albedo: self.ground_albedo };
        daylight.validate().map_err(anyhow::Error::msg)?;
        let sun = match (self.sun, self.location, self.time) {
            (Some((p, _)), _, _) => Some(SunPlacement::Fixed(p)),
            (None, Some((latitude, longitude)), Some(time)) => Some(SunPlacement::Study { latitude, longitude, time }),
            _ => None,
        };
        let mut spec = SurroundingsSpec {
            sky,
            sun,
            sun_irradiance: self.sun.and_then(|(_, e)| e).map(Rgb::splat),
            daylight: self.sky_model.map(|SkyModel::Preetham| daylight),
            turbidity: self.turbidity,
            ..SurroundingsSpec::default()
        };
        if let Some(path) = &self.environment {
            let options = EnvironmentOptions {
                scale: self.environment_scale,
                rotation_degrees: self.environment_rotation,
                max_pixels: load.max_texture_pixels,
                memory_limit: load.texture_memory_limit,
            };
            let map = load_environment(path, &options).context("--environment")?;
            if self.environment_sun == EnvironmentSun::Keep {
                spec.environment = Some(std::sync::Arc::new(map));
            } else {
                let (map, sun, _) = SurroundingsSpec::take_sun_from(map);
                spec.environment = Some(map);
                spec.environment_sun = sun;
            }
        }
        Ok(spec)
    }
}

/// Ray-bundle parameters (paper notation: W, N, α, R).
#[derive(Args, Debug, Clone)]
pub struct BundleOptions {
    /// Tiling of each bundle direction: adaptive (Eq. 1–3), uniform:K (K×K tiles at W×W),
    /// or none (one W×W bundle).
    #[arg(long, default_value = "adaptive", value_parser = parse_tiling)]
    pub tiling: TilingMode,
    /// Analysis map side R (power of two).
    #[arg(long, value_name = "R", default_value_t = BundleConfig::default().analysis_res)]
    pub analysis_res: u32,
    /// Head-pointer buffer side W: most bundle pixels per tile side.
    #[arg(long, value_name = "W", default_value_t = BundleConfig::default().head_side)]
    pub head_side: u32,
    /// Node-buffer capacity N: most fragments per tile.
    #[arg(long, value_name = "N", default_value_t = BundleConfig::default().node_capacity)]
    pub nodes: u64,
    /// α of Eq. 2–3: share of N the prediction may fill.
    #[arg(long, default_value_t = BundleConfig::default().alpha)]
    pub alpha: f32,
    /// Bundle pixels per texel side.
    #[arg(long, default_value_t = BundleConfig::default().oversampling)]
    pub oversampling: f32,
    /// Light-pass directions per global direction per small emitter.
    #[arg(long, default_value_t = BundleConfig::default().light_directions)]
    pub light_directions: u32,
    /// Accumulation lanes: `auto` (one for a LOD of 2^20 texels or more, else two) or a
    /// count. Each holds its own sums, 16 B a texel (28 with small emitters); results depend
    /// on it, not on --threads.
    #[arg(long, default_value_t = BundleConfig::default().lanes)]
    pub lanes: Lanes,
}

impl Default for BundleOptions {
    fn default() -> Self {
        let d = BundleConfig::default();
        BundleOptions {
            tiling: d.tiling,
            analysis_res: d.analysis_res,
            head_side: d.head_side,
            nodes: d.node_capacity,
            alpha: d.alpha,
            oversampling: d.oversampling,
            light_directions: d.light_directions,
            lanes: d.lanes,
        }
    }
}

fn parse_tiling(s: &str) -> Result<TilingMode, String> {
    match s {
        "adaptive" => Ok(TilingMode::Adaptive),
        "none" => Ok(TilingMode::None),
        _ => match s.strip_prefix("uniform:").map(str::parse::<u32>) {
            Some(Ok(k)) if k.is_power_of_two() => Ok(TilingMode::Uniform { k }),
            _ => Err(format!("expected adaptive, none or uniform:K with K a power of two, got {s:?}")),
        },
    }
}

/// What `livebake` without arguments uses: the same values as the command-line defaults above
/// (a test holds them equal).
impl Default for SceneOptions {
    fn default() -> Self {
        SceneOptions {
            texel_size: None,
            texel_budget: None,
            lods: None,
            samples: None,
            sky: None,
            outdoors: OutdoorOptions::default(),
            backend: Backend::Cpu,
            seed: 0,
            threads: None,
            no_uv1: false,
            allow_outside_files: false,
            max_texture_pixels: DEFAULT_MAX_TEXTURE_PIXELS,
            bundle: BundleOptions::default(),
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
    /// How the scene is loaded: the files it may read and its textures' limits, their
    /// decoded pixels held to `memory_limit` (`--memory-limit`; default 3/4 of the machine's
    /// memory, the bake's own guard).
    pub fn load_options(&self, memory_limit: Option<u64>) -> LoadOptions {
        LoadOptions {
            allow_outside_files: self.allow_outside_files,
            max_texture_pixels: self.max_texture_pixels,
            texture_memory_limit: Some(livebake::bake::memory::memory_limit(memory_limit).0),
            ..LoadOptions::default()
        }
    }

    /// The bake config; `default_samples(backend)` gives the sample count when --samples is absent.
    pub fn bake_config(&self, default_samples: impl Fn(Backend) -> u32) -> Result<BakeConfig> {
        if let Some(t) = self.texel_size
            && (!t.is_finite() || t <= 0.0)
        {
            bail!("--texel-size must be a positive number of metres, got {t}");
        }
        if self.texel_budget == Some(0) {
            bail!("--texel-budget must be at least 1");
        }
        if let Some(n) = self.threads
            && !(1..=MAX_THREADS).contains(&n)
        {
            bail!("--threads must be between 1 and {MAX_THREADS}, got {n}");
        }
        Ok(BakeConfig {
            atlas: AtlasConfig {
                texel_size: self.texel_size,
                texel_budget: self.texel_budget.unwrap_or(AtlasConfig::default().texel_budget),
                use_uv1: !self.no_uv1,
                ..AtlasConfig::default()
            },
            lods: self.lods.unwrap_or(1),
            samples: self.samples.unwrap_or_else(|| default_samples(self.backend)),
            backend: match self.backend {
                Backend::Reference => BackendKind::Reference,
                Backend::Cpu => BackendKind::Cpu,
                Backend::Gpu => BackendKind::Gpu,
                Backend::Auto => BackendKind::Auto,
            },
            seed: self.seed,
            bundle: BundleConfig {
                tiling: self.bundle.tiling,
                analysis_res: self.bundle.analysis_res,
                head_side: self.bundle.head_side,
                node_capacity: self.bundle.nodes,
                alpha: self.bundle.alpha,
                oversampling: self.bundle.oversampling,
                light_directions: self.bundle.light_directions,
                lanes: self.bundle.lanes,
                ..BundleConfig::default()
            },
            threads: self.threads,
            memory_limit: None,
            keep_texel_positions: true,
            bounce_rounds: None,
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

    #[test]
    fn default_options_are_the_command_line_defaults() {
        // `livebake` with no arguments must bake as `livebake bake SCENE` does.
        #[derive(clap::Parser)]
        struct Wrap {
            #[command(flatten)]
            options: SceneOptions,
        }
        let parsed = <Wrap as clap::Parser>::parse_from(["livebake"]).options;
        assert_eq!(format!("{parsed:?}"), format!("{:?}", SceneOptions::default()));
    }

    #[test]
    fn tiling_parses_the_three_modes() {
        assert_eq!(parse_tiling("adaptive").unwrap(), TilingMode::Adaptive);
        assert_eq!(parse_tiling("none").unwrap(), TilingMode::None);
        assert_eq!(parse_tiling("uniform:4").unwrap(), TilingMode::Uniform { k: 4 });
        assert!(parse_tiling("uniform:3").is_err());
        assert!(parse_tiling("fast").is_err());
    }
}
