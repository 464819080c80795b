//! Command-line interface: argument parsing and the subcommands. A stable interface: scripts
//! depend on the option names and output files.

mod bake;
mod bench;
mod converge;
mod options;
mod probe;
mod progress;
mod run;
mod serve;
mod shard;
mod view;

use std::path::PathBuf;

use anyhow::Result;
use clap::{Parser, Subcommand};

pub use converge::NotConverged;
pub use options::SceneOptions;

/// Global-illumination light maps for glTF scenes.
#[derive(Parser, Debug)]
#[command(name = "livebake", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
    /// Only print errors (no progress bars, no summary).
    #[arg(short, long, global = true)]
    quiet: bool,
    /// More log output (-v: debug, -vv: trace). RUST_LOG overrides.
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Bake a scene's light maps: DIR/lightmap_lodK.exr (irradiance, W/m²), DIR/lightmap_lodK.png
    /// (tone-mapped outgoing radiance) and DIR/report.json.
    Bake {
        /// glTF 2.0 scene (.gltf or .glb).
        scene: PathBuf,
        #[command(flatten)]
        outputs: Outputs,
        /// Bake LOD 0 in R bounce rounds instead of one progressive pass: round 1 holds the
        /// direct light, each further round reads the one before (one bounce a round). What
        /// direction shards merged round by round equal (docs/SHARDS.md).
        #[arg(long, value_name = "R")]
        bounce_rounds: Option<u32>,
        /// Bake only share I of N (from 0) of one bounce round's directions and write its
        /// sums to DIR/shard-IIII-of-NNNN.lbshard for `livebake merge` (docs/SHARDS.md).
        #[arg(long, value_name = "I/N", value_parser = livebake::shard::parse_share)]
        shard: Option<(u32, u32)>,
        /// With --shard: the merged state of the previous round (its merge's
        /// DIR/merged.lbshard); this shard bakes the next round. Without it, round 1.
        #[arg(long, value_name = "FILE", requires = "shard")]
        previous: Option<PathBuf>,
        /// With --shard: the bake's layout file (its atlas and texel map), read when it is
        /// this bake's, else made here and written there for the shards and merges after
        /// (docs/SHARDS.md). Give every shard and merge of a bake the same FILE.
        #[arg(long, value_name = "FILE", requires = "shard")]
        layout: Option<PathBuf>,
        /// Also write a static web page showing the finest baked light map (open
        /// DIR/index.html?static from any file server or a headset's browser; docs/SERVE.md),
        /// with the scene exported as --export-gltf does (DIR/scene.gltf).
        #[arg(long, value_name = "DIR")]
        export_web: Option<PathBuf>,
        /// With --shard: what a share is a share of. `directions`: every texel, share I of
        /// the round's batches; `regions`: share I of LOD 0's texels (whole charts), every
        /// batch, for scenes whose texels exceed one machine's memory (docs/SHARDS.md).
        #[arg(long, value_name = "KIND", value_enum, default_value_t = shard::ShardBy::Directions, requires = "shard")]
        shard_by: shard::ShardBy,
        #[command(flatten)]
        options: SceneOptions,
    },
    /// Merge direction shards (`bake --shard`) into what one bake writes: DIR/lightmap_lod0.exr,
    /// .png and report.json (and with --export-gltf the export), plus DIR/merged.lbshard for
    /// the next round's shards. Refuses shards that do not belong together, a missing share
    /// or one given twice.
    Merge {
        /// The shard files (DIR/shard-*), every share of one round.
        #[arg(required = true)]
        shards: Vec<PathBuf>,
        /// The bake's layout file (`bake --shard … --layout FILE`): read when it is this
        /// bake's, else made here and written there.
        #[arg(long, value_name = "FILE")]
        layout: Option<PathBuf>,
        #[command(flatten)]
        outputs: Outputs,
    },
    /// Irradiance at surface points given in a JSON file.
    Probe {
        /// glTF 2.0 scene (.gltf or .glb).
        scene: PathBuf,
        /// Input points: {"points":[{"p":[x,y,z],"n":[x,y,z]}, ...]}.
        #[arg(long)]
        points: PathBuf,
        /// Output JSON (the input list with "E":[r,g,b] added); stdout when absent.
        #[arg(long)]
        out: Option<PathBuf>,
        #[command(flatten)]
        options: SceneOptions,
    },
    /// Look at a scene in a window, lit by its light map as it bakes (keys in the title).
    View {
        /// glTF 2.0 scene (.gltf or .glb).
        scene: PathBuf,
        #[command(flatten)]
        view: view::ViewOptions,
        #[command(flatten)]
        options: SceneOptions,
    },
    /// Serve the live runtime to a browser or a WebXR headset: a page drawing the scene
    /// with its light map, refined where the viewer looks, hot reloads pushed
    /// (docs/SERVE.md). Binds 127.0.0.1 unless --host is given (then with an access token).
    Serve {
        /// glTF 2.0 scene (.gltf or .glb).
        scene: PathBuf,
        #[command(flatten)]
        serve: serve::ServeOptions,
        #[command(flatten)]
        options: SceneOptions,
    },
    /// Bake LOD 0 progressively and measure its error against a reference as it goes: relative
    /// RMS error at doubling direction counts in DIR/convergence.json, .csv and .png. Exit
    /// status 0 when --until is reached within --budget, 3 when not, 1 on errors. --samples N
    /// is the most directions (default 2^20: hours, the budget ends the run).
    Converge {
        /// glTF 2.0 scene (.gltf or .glb).
        scene: PathBuf,
        #[command(flatten)]
        options: SceneOptions,
        #[command(flatten)]
        converge: converge::ConvergeOptions,
    },
    /// The live runtime, headless: LOD 0 at first light, then cells near the camera refined
    /// and swapped to finer LODs; events as JSON lines; at the end the light maps as shown
    /// (DIR/lightmap_lodK.exr), DIR/cells.json and DIR/report.json.
    Run {
        /// glTF 2.0 scene (.gltf or .glb).
        scene: PathBuf,
        #[command(flatten)]
        options: SceneOptions,
        #[command(flatten)]
        run: run::RunOptions,
    },
    /// Measure: load and unwrap/pack, reference rays/s, startup bake, bundle throughput,
    /// convergence against Mitsuba and Cycles, tiling modes, the viewer, the live runtime and
    /// hot reload. Writes JSON (medians and ratios from one run).
    Bench {
        /// Output JSON.
        #[arg(long, default_value = "bench.json")]
        out: PathBuf,
        /// Only these sections, comma-separated (an unknown name is refused with the list of
        /// them); every one when not given.
        #[arg(long, value_delimiter = ',')]
        only: Vec<String>,
        /// Smaller sample sets and fewer repeats (a smoke run, not a measurement).
        #[arg(long)]
        quick: bool,
    },
}

/// Where `bake` and `merge` write, and the memory they may hold.
#[derive(clap::Args, Debug)]
struct Outputs {
    /// Output directory (created if missing).
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Also write a copy of the scene with the finest baked light map attached, for other
    /// engines (TEXCOORD_1 + MOZ_lightmap; OUT.bin, OUT.lightmap.exr and OUT.lightmap.png
    /// beside it).
    #[arg(long, value_name = "OUT.gltf")]
    export_gltf: Option<PathBuf>,
    /// Most memory the bake (or merge) may hold (e.g. 8G, 512M; K/M/G/T are powers of 1024),
    /// checked against an estimate before the texel maps are built. Default: 3/4 of RAM.
    #[arg(long, value_name = "BYTES", value_parser = livebake::bake::memory::parse_bytes)]
    memory_limit: Option<u64>,
}

/// The scene baked when livebake runs without arguments.
pub fn default_scene() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/assets/cornell_box/cornellBox-2.79-Cycles-gltf.gltf"))
}

pub fn run() -> Result<()> {
    // A shard stores its command line in its file (the merge remakes the bake from it).
    let raw_args: Vec<std::ffi::OsString> = std::env::args_os().collect();
    let cli = Cli::parse();
    init_logging(cli.quiet, cli.verbose);
    let ui = progress::Ui::new(cli.quiet);
    match cli.command {
        None => run_default(&ui),
        Some(Command::Run { scene, options, run }) => run::run(&scene, &options, &run, &ui),
        Some(Command::Bake {
            scene,
            outputs,
            bounce_rounds,
            shard,
            previous,
            layout,
            export_web,
            shard_by,
            options,
        }) => {
            let Outputs { out, export_gltf, memory_limit } = outputs;
            let Some(share) = shard else {
                let exports = bake::Exports { gltf: export_gltf.as_deref(), web: export_web.as_deref() };
                return bake::run(&scene, &out, exports, memory_limit, bounce_rounds, &options, &ui);
            };
            if export_gltf.is_some() || export_web.is_some() {
                anyhow::bail!(
                    "--export-gltf and --export-web are the merge's (`livebake merge … --export-gltf`), not a shard's"
                );
            }
            if bounce_rounds.is_some() {
                anyhow::bail!(
                    "a shard bakes one bounce round (round 1, or the one after --previous): --bounce-rounds is for a bake on one machine"
                );
            }
            let request =
                shard::ShardRequest { share, previous: previous.as_deref(), by: shard_by, layout: layout.as_deref() };
            shard::bake(&scene, &out, request, memory_limit, &options, &raw_args, &ui)
        }
        Some(Command::Merge { shards, layout, outputs: Outputs { out, export_gltf, memory_limit } }) => {
            shard::merge(&shards, &out, export_gltf.as_deref(), layout.as_deref(), memory_limit, &ui)
        }
        Some(Command::Probe { scene, points, out, options }) => {
            probe::run(&scene, &points, out.as_deref(), &options, &ui)
        }
        Some(Command::View { scene, view, options }) => view::run(&scene, &view, &options, &ui).map(|_| ()),
        Some(Command::Serve { scene, serve, options }) => serve::run(&scene, &serve, &options, &ui),
        Some(Command::Converge { scene, options, converge }) => converge::run(&scene, &options, &converge, &ui),
        Some(Command::Bench { out, only, quick }) => bench::command(&out, &only, quick, &ui),
    }
}

/// `livebake` without arguments: the viewer on the default scene when a display is there
/// (`DISPLAY` or `WAYLAND_DISPLAY` set and a window opens), else the headless runtime for
/// 3 s after first light into `./out`. A display that cannot be used is one warning, then
/// the headless run.
fn run_default(ui: &progress::Ui) -> Result<()> {
    let scene = default_scene();
    let options = SceneOptions::default();
    let has_display = ["DISPLAY", "WAYLAND_DISPLAY"].iter().any(|v| std::env::var_os(v).is_some_and(|d| !d.is_empty()));
    if has_display {
        let opened = livebake::viewer::ViewerLoop::open()
            .map_err(anyhow::Error::from)
            .and_then(|display| view::run_on(Some(display), &scene, &view::ViewOptions::default(), &options, ui));
        match opened {
            Ok(_) => return Ok(()),
            Err(e) if e.downcast_ref::<livebake::viewer::ViewerError>().is_some_and(|v| v.is_open_failure()) => {
                tracing::warn!("{e:#}; running headless instead");
            }
            Err(e) => return Err(e),
        }
    }
    run::run(&scene, &options, &run::RunOptions { seconds: 3.0, ..Default::default() }, ui)
}

fn init_logging(quiet: bool, verbose: u8) {
    use tracing_subscriber::EnvFilter;
    let level = match (quiet, verbose) {
        (true, _) => "error",
        (false, 0) => "warn,livebake=info",
        (false, 1) => "debug",
        _ => "trace",
    };
    let filter = EnvFilter::try_from_default_env().unwrap_or_else(|_| EnvFilter::new(level));
    let _ =
        tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_target(false).try_init();
}
