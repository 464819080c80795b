//! `livebake serve SCENE`: the live runtime for a browser or a WebXR headset (docs/SERVE.md).

use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use glam::Vec3;
use livebake::serve::{ServeConfig, ServeStats, Server, random_token};
use livebake::viewer::camera::parse_pose;
use livebake::watch::WatchConfig;

use super::SceneOptions;
use super::progress::Ui;
use super::run::{RuntimeOptions, runtime_config};

#[derive(Args, Debug, Clone)]
pub struct ServeOptions {
    /// TCP port (0: any free one; the URL printed says which).
    #[arg(long, default_value_t = 8080)]
    pub port: u16,
    /// Listen on this address instead of 127.0.0.1 (e.g. 0.0.0.0 for a headset on the LAN).
    /// Then every request must carry the random access token of the URL printed.
    #[arg(long, value_name = "ADDR")]
    pub host: Option<IpAddr>,
    /// Start pose of the page: eye and target, metres (default: `view`'s).
    #[arg(long, value_name = "EX,EY,EZ,TX,TY,TZ", value_parser = parse_pose, allow_hyphen_values = true)]
    pub camera: Option<(Vec3, Vec3)>,
    /// Radiance scale before the tone curve (default: `view`'s, from the first light map).
    #[arg(long)]
    pub exposure: Option<f32>,
    /// Stop after this many seconds of serving (default: until Ctrl-C).
    #[arg(long, value_name = "S")]
    pub seconds: Option<f64>,
    /// Do not watch the scene's files (by default every good save reaches the pages).
    #[arg(long)]
    pub no_watch: bool,
    /// Write the run's figures here as JSON at the end (updates, bytes, latencies, frames).
    #[arg(long, value_name = "PATH.json")]
    pub stats: Option<PathBuf>,
    #[command(flatten)]
    pub runtime: RuntimeOptions,
}

pub fn run(scene_path: &Path, serve: &ServeOptions, options: &SceneOptions, ui: &Ui) -> Result<()> {
    if let Some(e) = serve.exposure
        && !(e.is_finite() && e > 0.0)
    {
        bail!("--exposure must be a positive number, got {e}");
    }
    if let Some(s) = serve.seconds
        && !(s.is_finite() && s >= 0.0)
    {
        bail!("--seconds must be a non-negative number, got {s}");
    }
    let config = runtime_config(options, &serve.runtime)?;
    let (scene, _, _) = super::bake::load_scene_with(scene_path, options, None)?;
    // A token whenever the address is chosen: --host opens the server beyond this machine.
    let token = serve.host.map(|_| random_token()).transpose()?;
    let addr = SocketAddr::new(serve.host.unwrap_or(IpAddr::V4(Ipv4Addr::LOCALHOST)), serve.port);
    let server = Server::bind(
        scene_path,
        ServeConfig {
            addr,
            token,
            exposure: serve.exposure,
            // --camera is in the file's coordinates.
            pose: serve.camera.map(|p| scene.pose_to_scene(p)),
            in_flight_bytes: livebake::serve::hub::IN_FLIGHT_BYTES,
        },
    )?;
    let surroundings = scene.surroundings();
    let mut runtime = super::run::start_runtime(scene, config, options.backend)
        .with_context(|| format!("cannot start the runtime on {}", scene_path.display()))?;
    if !serve.no_watch {
        let watch = WatchConfig { surroundings, load: options.load_options(None), ..WatchConfig::default() };
        runtime.watch(scene_path, watch).with_context(|| format!("cannot watch {}", scene_path.display()))?;
    }
    // Scripts read the URL from stdout (its one line).
    println!("{}", server.url());
    ui.say(format!("serving {} at {} (Ctrl-C ends)", scene_path.display(), server.url()));
    let interrupted = Arc::new(AtomicBool::new(false));
    let _ = signal_hook::flag::register(signal_hook::consts::SIGINT, interrupted.clone());
    let _ = signal_hook::flag::register(signal_hook::consts::SIGTERM, interrupted.clone());
    let started = Instant::now();
    let seconds = serve.seconds;
    let served = server.run(&runtime, |_: &ServeStats| {
        interrupted.load(Ordering::SeqCst) || seconds.is_some_and(|s| started.elapsed().as_secs_f64() >= s)
    });
    let shutdown = runtime.shutdown();
    let stats = served?;
    shutdown.context("the runtime failed")?;
    if let Some(path) = &serve.stats {
        livebake::output::write_json(path, &stats).with_context(|| format!("cannot write {}", path.display()))?;
    }
    ui.say(format!(
        "{} clients, {} updates ({} pages, {} bytes)",
        stats.clients_joined, stats.updates, stats.update_pages, stats.update_bytes
    ));
    Ok(())
}
