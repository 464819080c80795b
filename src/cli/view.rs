//! `livebake view SCENE`: the scene in a window, lit by the live runtime's light map: LOD 0
//! at first light, then the cells in view refined in the background.

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::{Args, ValueEnum};
use glam::Vec3;
use livebake::gpu::layout::ViewMode;
use livebake::viewer::camera::parse_pose;
use livebake::viewer::{DrawSettings, RuntimeLight, ViewerLoop, ViewerOptions, ViewerReport};
use livebake::watch::WatchConfig;

use super::SceneOptions;
use super::progress::Ui;
use super::run::{RuntimeOptions, runtime_config};

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum View {
    Lit,
    CellLod,
    CellGrid,
    Irradiance,
    TexelChecker,
}

impl From<View> for ViewMode {
    fn from(v: View) -> ViewMode {
        match v {
            View::Lit => ViewMode::Lit,
            View::CellLod => ViewMode::CellLod,
            View::CellGrid => ViewMode::CellGrid,
            View::Irradiance => ViewMode::Irradiance,
            View::TexelChecker => ViewMode::TexelChecker,
        }
    }
}

#[derive(Args, Debug, Clone)]
pub struct ViewOptions {
    /// Write the last frame to this PNG and exit (after --frames lit frames, default 1).
    #[arg(long, value_name = "PATH.png")]
    pub screenshot: Option<PathBuf>,
    /// Exit after this many frames drawn with light (counted from the first lit frame).
    #[arg(long, value_name = "N")]
    pub frames: Option<u32>,
    /// Start pose: eye and target, metres.
    #[arg(long, value_name = "EX,EY,EZ,TX,TY,TZ", value_parser = parse_pose, allow_hyphen_values = true)]
    pub camera: Option<(Vec3, Vec3)>,
    /// Side-by-side stereo (left eye on the left).
    #[arg(long)]
    pub stereo: bool,
    /// Interpupillary distance for --stereo, metres.
    #[arg(long, value_name = "M", default_value_t = 0.063)]
    pub ipd: f32,
    /// Radiance scale before the tone curve (also +/- in the window). Default: from the
    /// first light map shown (1.5 over its 99th-percentile E/π).
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Window size in pixels.
    #[arg(long, value_name = "WxH", default_value = "1280x720", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Write the run's figures here as JSON (frames, lit frame ms median/p99, first lit frame).
    #[arg(long, value_name = "PATH.json")]
    pub stats: Option<PathBuf>,
    /// What to show first (keys 1-5 switch).
    #[arg(long, value_enum, default_value_t = View::Lit)]
    pub view: View,
    /// Do not watch the scene's files (by default every good save is reloaded into the
    /// running view; the title shows the last reload's milliseconds and the last error).
    #[arg(long)]
    pub no_watch: bool,
    /// Most light-map pages (16×16 texels, 4 KiB each) the GPU may hold; the runtime keeps
    /// the shown map within it, and where a level does not fit a coarser one is shown
    /// (default: as many as the device's largest texture holds).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub gpu_pages: Option<u32>,
    #[command(flatten)]
    pub runtime: RuntimeOptions,
}

/// What `livebake` without arguments opens: the command-line defaults (a test holds them equal).
impl Default for ViewOptions {
    fn default() -> Self {
        ViewOptions {
            screenshot: None,
            frames: None,
            camera: None,
            stereo: false,
            ipd: 0.063,
            exposure: None,
            size: (1280, 720),
            stats: None,
            view: View::Lit,
            no_watch: false,
            gpu_pages: None,
            runtime: RuntimeOptions::default(),
        }
    }
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s.split_once('x').ok_or_else(|| format!("expected WIDTHxHEIGHT, got {s:?}"))?;
    let parse = |v: &str| v.trim().parse::<u32>().ok().filter(|&n| (16..=8192).contains(&n));
    match (parse(w), parse(h)) {
        (Some(w), Some(h)) => Ok((w, h)),
        _ => Err(format!("expected WIDTHxHEIGHT with sides of 16 to 8192 pixels, got {s:?}")),
    }
}

/// Opens the viewer on `scene_path`; returns when the window closes (or the screenshot is written).
pub fn run(scene_path: &Path, view: &ViewOptions, options: &SceneOptions, ui: &Ui) -> Result<ViewerReport> {
    run_on(None, scene_path, view, options, ui)
}

/// [`run`] on a display connection already made (`None`: made here, once the scene loaded
/// and before the runtime starts, so that a missing display costs no bake).
pub fn run_on(
    display: Option<ViewerLoop>,
    scene_path: &Path,
    view: &ViewOptions,
    options: &SceneOptions,
    ui: &Ui,
) -> Result<ViewerReport> {
    let launched = Instant::now();
    if let Some(e) = view.exposure
        && !(e.is_finite() && e > 0.0)
    {
        anyhow::bail!("--exposure must be a positive number, got {e}");
    }
    if !(view.ipd.is_finite() && view.ipd >= 0.0) {
        anyhow::bail!("--ipd must be a non-negative number of metres, got {}", view.ipd);
    }
    if view.frames == Some(0) {
        anyhow::bail!("--frames must be at least 1");
    }
    let config = runtime_config(options, &view.runtime)?;
    let (scene, _, spec) = super::bake::load_scene_with(scene_path, options, None)?;
    let display = match display {
        Some(d) => d,
        None => ViewerLoop::open()?,
    };
    let surroundings = scene.surroundings();
    // --camera is in the file's coordinates.
    let pose = view.camera.map(|p| scene.pose_to_scene(p));
    let mut runtime = super::run::start_runtime(scene, config, options.backend)
        .with_context(|| format!("cannot start the runtime on {}", scene_path.display()))?;
    if !view.no_watch {
        let watch = WatchConfig { surroundings, load: options.load_options(None), ..WatchConfig::default() };
        runtime.watch(scene_path, watch).with_context(|| format!("cannot watch {}", scene_path.display()))?;
    }
    let mut source = RuntimeLight::new(runtime).with_sun(spec);
    let viewer = ViewerOptions {
        pose,
        settings: DrawSettings {
            view_mode: view.view.into(),
            exposure: view.exposure.unwrap_or(1.0),
            stereo_ipd: view.stereo.then_some(view.ipd),
        },
        size: view.size,
        frames: view.frames.or(view.screenshot.is_some().then_some(1)),
        screenshot: view.screenshot.clone(),
        launched,
        auto_exposure: view.exposure.is_none(),
        gpu_pages: view.gpu_pages,
    };
    let report = display.run(&mut source, viewer, None)?;
    if let Some(path) = &view.stats {
        livebake::output::write_json(path, &report.to_json())
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some(path) = &view.screenshot {
        ui.say(format!("wrote {}", path.display()));
    }
    if let Some(s) = report.first_lit_frame_seconds {
        ui.say(format!("{} frames on {}; first lit frame {:.2} s after launch", report.frames, report.adapter, s));
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_options_are_the_command_line_defaults() {
        // `livebake` with no arguments must view as `livebake view SCENE` does.
        #[derive(clap::Parser)]
        struct Wrap {
            #[command(flatten)]
            view: ViewOptions,
        }
        let parsed = <Wrap as clap::Parser>::parse_from(["livebake"]).view;
        assert_eq!(format!("{parsed:?}"), format!("{:?}", ViewOptions::default()));
        let no_watch = <Wrap as clap::Parser>::parse_from(["livebake", "--no-watch"]).view;
        assert!(no_watch.no_watch && !parsed.no_watch);
    }

    #[test]
    fn size_parses_and_refuses_nonsense() {
        assert_eq!(parse_size("640x480").unwrap(), (640, 480));
        assert!(parse_size("640").is_err());
        assert!(parse_size("0x480").is_err());
        assert!(parse_size("axb").is_err());
    }
}
