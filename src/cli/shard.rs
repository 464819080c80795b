//! `livebake bake --shard I/N` and `livebake merge`: direction shards of a bounce-rounds bake
//! (docs/SHARDS.md). A shard file carries the job that made it (the scene's path and the
//! bake's options as given), so that the merge remakes the same atlas and checks, by the
//! scene's content hash and the options hash, that it merges what it thinks it does.

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Parser;
use serde::{Deserialize, Serialize};

use livebake::bake::bundle::BundleLodStats;
use livebake::bake::memory::described_limit;
use livebake::bake::report::LodReport;
use livebake::bake::rounds::add_round_stats;
use livebake::bake::{
    BackendStats, BakeOutput, BakeReport, BakedLod, bake_region_shard, bake_shard, check_finite, shard_layout,
};
use livebake::export::{ExportOptions, export_gltf};
use livebake::output::{irradiance_image, write_json, write_lightmaps};
use livebake::scene::{SceneGeometry, external_files};
use livebake::shard::layout::{Layout, LayoutPlace};
use livebake::shard::{
    self, MERGED_STATE, PreviousRound, ShardFile, ShardKind, ShardState, WordHash, check_set, read_header,
    region_placement, shard_file_name, write_state,
};

use super::SceneOptions;
use super::bake::{default_samples, load_scene};
use super::progress::Ui;

/// How to make the bake again: what every shard of a round shares.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct Job {
    /// The scene, an absolute path (the merge may run elsewhere on shared storage).
    scene: PathBuf,
    /// The bake's options as given after the scene (without --shard, --previous, --out,
    /// --threads, --memory-limit and the global flags).
    args: Vec<String>,
    /// Where they were given (relative paths in them, such as --environment, are from here).
    cwd: PathBuf,
}

/// A shard file's JSON: the job and what the shard measured.
#[derive(Serialize, Deserialize)]
struct JobRecord {
    job: Job,
    stats: BundleLodStats,
    seconds: f64,
}

/// The options of a stored job, parsed as `bake` parses them.
#[derive(Parser, Debug)]
#[command(name = "livebake bake", no_binary_name = true)]
struct StoredBake {
    scene: PathBuf,
    #[command(flatten)]
    options: SceneOptions,
}

/// Options left out of a stored job: with a value, and without.
const DROPPED_WITH_VALUE: [&str; 8] =
    ["--shard", "--shard-by", "--previous", "--layout", "--out", "--threads", "--memory-limit", "--export-gltf"];
const DROPPED_FLAGS: [&str; 4] = ["-q", "--quiet", "-v", "--verbose"];

impl Job {
    /// The job of this process's `bake` command line (`raw`: its arguments, program first),
    /// the scene `scene` as parsed.
    fn of_command_line(raw: &[OsString], scene: &Path) -> Result<Job> {
        let args: Vec<String> = raw
            .iter()
            .skip(1)
            .map(|a| a.to_str().map(str::to_string))
            .collect::<Option<_>>()
            .context("a shard's arguments must be UTF-8 (they are stored in its file)")?;
        let start = args.iter().position(|a| a == "bake").context("no `bake` in the command line")? + 1;
        let scene_given = scene.to_str().context("the scene path must be UTF-8")?;
        let mut kept = Vec::new();
        let mut scene_seen = false;
        let mut rest = args[start..].iter();
        while let Some(a) = rest.next() {
            if DROPPED_WITH_VALUE.contains(&a.as_str()) {
                rest.next();
            } else if DROPPED_WITH_VALUE.iter().any(|d| a.starts_with(&format!("{d}=")))
                || DROPPED_FLAGS.contains(&a.as_str())
                || (a.starts_with("-v") && a[1..].chars().all(|c| c == 'v'))
            {
            } else if !scene_seen && a == scene_given {
                scene_seen = true;
            } else {
                kept.push(a.clone());
            }
        }
        let cwd = std::env::current_dir().context("the current directory")?;
        let scene = std::path::absolute(scene).context("the scene's absolute path")?;
        Ok(Job { scene, args: kept, cwd })
    }

    /// The job's scene options, parsed as `bake` parses them, relative paths from its folder.
    fn options(&self) -> Result<SceneOptions> {
        let scene = self.scene.to_str().context("the stored scene path is not UTF-8")?;
        let argv = std::iter::once(scene.to_string()).chain(self.args.iter().cloned());
        let parsed = StoredBake::try_parse_from(argv).context("the shard's stored options do not parse")?;
        let mut options = parsed.options;
        if let Some(env) = &options.outdoors.environment {
            options.outdoors.environment = Some(self.cwd.join(env));
        }
        Ok(options)
    }
}

/// The options hash: every option that changes the result (what `bake` parsed, paths made
/// absolute; not --threads, which changes nothing). The debug form of the parsed options
/// holds them all, whatever options are added later.
fn options_hash(options: &SceneOptions) -> u64 {
    let mut o = options.clone();
    o.threads = None;
    let mut h = WordHash::new();
    h.update_str(concat!("livebake ", env!("CARGO_PKG_VERSION"), " bounce rounds"));
    h.update_str(&format!("{o:?}"));
    h.finish()
}

/// The scene's content hash: the document's bytes, each file it refers to (its URI and
/// bytes) and the environment map's bytes.
fn scene_hash(scene: &Path, options: &SceneOptions) -> Result<u64> {
    let mut h = WordHash::new();
    let bytes = std::fs::read(scene).with_context(|| format!("cannot read {}", scene.display()))?;
    h.update_str("scene");
    h.update(&(bytes.len() as u64).to_le_bytes());
    h.update(&bytes);
    let files = external_files(scene, &bytes, &options.load_options(None)).context("cannot list the scene's files")?;
    for f in files {
        let data = std::fs::read(&f.path).with_context(|| format!("cannot read {}", f.path.display()))?;
        h.update_str(&f.uri);
        h.update(&(data.len() as u64).to_le_bytes());
        h.update(&data);
    }
    if let Some(env) = &options.outdoors.environment {
        let data = std::fs::read(env).with_context(|| format!("cannot read {}", env.display()))?;
        h.update_str("environment");
        h.update(&data);
    }
    Ok(h.finish())
}

fn job_of(file: &ShardFile) -> Result<JobRecord> {
    serde_json::from_str(&file.job)
        .with_context(|| format!("{}: its job description is not valid", file.path.display()))
}

/// Opens a whole state (the previous round's merge) after checking it against this bake:
/// its header here, its checksum by [`PreviousRound::open`]; the round streams its sums.
fn read_previous(path: &Path, scene_hash: u64, options_hash: u64, memory_limit: Option<u64>) -> Result<PreviousRound> {
    let file = read_header(path)?;
    let h = &file.header;
    if h.count != 1 {
        bail!(
            "--previous {}: a share ({}/{}), not a merged round; give the merge's {MERGED_STATE}",
            path.display(),
            h.index,
            h.count
        );
    }
    if h.scene_hash != scene_hash {
        bail!("--previous {} was baked from another scene (or the scene's files changed since)", path.display());
    }
    if h.options_hash != options_hash {
        bail!("--previous {} was baked with other options", path.display());
    }
    if h.kind != ShardKind::Directions {
        bail!("--previous {}: a region shard, not a merged round; give the merge's {MERGED_STATE}", path.display());
    }
    Ok(PreviousRound::open(file, described_limit(memory_limit))?)
}

/// What a share is a share of (`--shard-by`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ShardBy {
    /// Every texel, share I of the round's batches.
    Directions,
    /// Share I of LOD 0's texels (whole charts), every batch.
    Regions,
}

/// What `--shard`, `--shard-by`, `--previous` and `--layout` ask for.
pub struct ShardRequest<'a> {
    pub share: (u32, u32),
    pub previous: Option<&'a Path>,
    pub by: ShardBy,
    pub layout: Option<&'a Path>,
}

/// `livebake bake SCENE --shard I/N [--previous STATE] --out DIR`.
pub fn bake(
    scene_path: &Path,
    out: &Path,
    ShardRequest { share, previous, by, layout }: ShardRequest,
    memory_limit: Option<u64>,
    options: &SceneOptions,
    raw_args: &[OsString],
    ui: &Ui,
) -> Result<()> {
    let job = Job::of_command_line(raw_args, scene_path)?;
    // What the merge will parse must be what this bake runs (relative paths as it reads them).
    let mut here = options.clone();
    if let Some(env) = &here.outdoors.environment {
        here.outdoors.environment = Some(job.cwd.join(env));
    }
    let hash = options_hash(&here);
    if options_hash(&job.options()?) != hash {
        bail!("the shard's options do not read back the same from its stored command line: {:?}", job.args);
    }
    let scene_hash = scene_hash(&job.scene, &here)?;
    let previous = previous.map(|p| read_previous(p, scene_hash, hash, memory_limit)).transpose()?;
    let round = previous.as_ref().map_or(1, |p| p.header().round + 1);
    let layout = layout.map(|path| LayoutPlace { path: path.to_path_buf(), scene_hash, options_hash: hash });
    let config = livebake::bake::BakeConfig { memory_limit, ..options.bake_config(default_samples)? };
    let (scene, _) = load_scene(scene_path, options, memory_limit)?;
    let t0 = Instant::now();
    let failed = || format!("cannot bake share {}/{} of {}", share.0, share.1, scene_path.display());
    let (estimate, report, regions) = match by {
        ShardBy::Directions => {
            let baked = bake_shard(&scene, &config, round, share, previous.as_ref(), layout.as_ref(), ui)
                .with_context(failed)?;
            (baked.estimate, baked.report, None)
        }
        ShardBy::Regions => {
            let baked = bake_region_shard(&scene, &config, round, share, previous.as_ref(), layout.as_ref(), ui)
                .with_context(failed)?;
            tracing::info!(
                texels = baked.texels.len(),
                lod_texels = baked.whole_texels,
                charts = baked.charts.len(),
                held_bytes = baked.held_bytes,
                expected_peak = baked.memory.bytes,
                peak_resident = livebake::bake::memory::peak_resident_bytes().unwrap_or(0),
                "region shard"
            );
            (baked.estimate, baked.report, Some((baked.charts, baked.whole_texels as u64)))
        }
    };
    let seconds = t0.elapsed().as_secs_f64();
    let stats = report.lods.first().and_then(|l| l.bundle.as_ref()).map(|b| b.stats.clone());
    let record = JobRecord { job, stats: stats.unwrap_or_default(), seconds };
    let mut state = ShardState::new(scene_hash, hash, 0, round, share, serde_json::to_string(&record)?, estimate);
    if let Some((charts, lod_texels)) = regions {
        state = state.of_regions(charts, lod_texels);
    }
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let path = out.join(shard_file_name(share.0, share.1));
    write_state(&path, &state)?;
    ui.say(format!(
        "livebake: {} share {}/{} of round {round} of {}: {} batches, {} texels, {seconds:.2} s",
        state.header.kind.name(),
        share.0,
        share.1,
        scene_path.display(),
        state.header.batches,
        state.header.texels
    ));
    ui.say(format!("  wrote {}", path.display()));
    Ok(())
}

/// `livebake merge FILES… --out DIR [--export-gltf OUT.gltf]`.
pub fn merge(
    files: &[PathBuf],
    out: &Path,
    export: Option<&Path>,
    layout: Option<&Path>,
    memory_limit: Option<u64>,
    ui: &Ui,
) -> Result<()> {
    let started = Instant::now();
    let headers = files.iter().map(|f| read_header(f)).collect::<Result<Vec<_>, _>>()?;
    // Shards of one bake may have been started from other folders or other copies of the
    // scene: the hashes decide (`check_set`), the first shard's job remakes the atlas.
    let records = headers.iter().map(job_of).collect::<Result<Vec<_>>>()?;
    let files = check_set(headers)?;
    let first = &files[0].header;
    let job = &records[0].job;
    let options = job.options()?;
    if options_hash(&options) != first.options_hash {
        bail!("the shards' options hash is not this livebake's for their stored options (another livebake version?)");
    }
    if scene_hash(&job.scene, &options)? != first.scene_hash {
        bail!("{}: the scene's files changed since the shards were baked", job.scene.display());
    }
    let config = livebake::bake::BakeConfig {
        memory_limit,
        keep_texel_positions: false,
        ..options.bake_config(default_samples)?
    };
    let (scene, load_seconds) = load_scene(&job.scene, &options, memory_limit)?;
    let geom = SceneGeometry::new(&scene);
    let place = layout.map(|path| LayoutPlace {
        path: path.to_path_buf(),
        scene_hash: first.scene_hash,
        options_hash: first.options_hash,
    });
    let (Layout { atlas, texels }, texel_seconds) =
        shard_layout(&scene, &geom, &config, place.as_ref()).context("cannot remake the shards' atlas")?;
    if texels.len() as u64 != first.lod_texels {
        bail!("the shards hold {} texels, this atlas {}: not the same bake", first.lod_texels, texels.len());
    }
    let placement = match first.kind {
        ShardKind::Directions => None,
        ShardKind::Regions => {
            let faces = &atlas.faces;
            let chart_of = |i: usize| faces[texels.face[i] as usize].chart;
            Some(region_placement(&files, texels.len(), atlas.charts.len(), chart_of)?)
        }
    };
    let estimate = shard::merge(&files, placement.as_deref(), described_limit(memory_limit))?;
    drop(placement);
    let irradiance = estimate.irradiance();
    check_finite(0, &irradiance)?;
    let mut stats = BundleLodStats::default();
    for r in &records {
        add_round_stats(&mut stats, &r.stats);
    }
    if first.kind == ShardKind::Regions {
        // Every region shard traced every direction of the round: the round's directions
        // are one shard's (the work, times and pass counters, stay summed).
        stats.directions = records[0].stats.directions;
        stats.batches = records[0].stats.batches;
        stats.light_directions_per_group = records[0].stats.light_directions_per_group;
    }
    // Texels no bundle reached, counted on the merged sums (a shard's own count is only of
    // its directions, or of its texels).
    stats.unsampled_texels = estimate.unsampled();
    let shard_seconds: f64 = records.iter().map(|r| r.seconds).sum();
    let backend_stats = BackendStats {
        samples_per_texel: config.samples,
        rays: stats.pass.covered_pixels,
        seconds: stats.bundle_seconds + stats.punctual_seconds,
    };
    let mut report = BakeReport::new(&scene, &atlas, &config);
    report.backend = config.backend.name();
    report.lods.push(LodReport::new(&texels, texel_seconds, &backend_stats, &irradiance, Some(stats.clone())));
    let mut baked = BakeOutput { atlas, lods: vec![BakedLod { texels, irradiance }], report };
    let t_write = Instant::now();
    let mut written = write_lightmaps(out, &baked)?;
    if let Some(gltf) = export {
        let export = ExportOptions { load: options.load_options(memory_limit) };
        let r = export_gltf(&scene, &baked.atlas, &irradiance_image(&baked.lods[0]), gltf, &export)
            .with_context(|| format!("cannot export {}", gltf.display()))?;
        written.extend([r.gltf, r.bin, r.hdr, r.png]);
    }
    // The merged round, for the next round's shards (`--previous`).
    let record = JobRecord { job: job.clone(), stats, seconds: shard_seconds };
    let state = ShardState::new(
        first.scene_hash,
        first.options_hash,
        first.lod,
        first.round,
        (0, 1),
        serde_json::to_string(&record)?,
        estimate,
    );
    let state_path = out.join(MERGED_STATE);
    write_state(&state_path, &state)?;
    written.push(state_path);
    baked.report.phases.load = load_seconds;
    baked.report.phases.write = t_write.elapsed().as_secs_f64();
    baked.report.total_seconds = started.elapsed().as_secs_f64();
    baked.report.memory.measure();
    baked.report.bytes_per_texel = baked.report.memory.measured_bytes_per_texel;
    let report_path = out.join("report.json");
    write_json(&report_path, &baked.report)?;
    ui.say(format!(
        "livebake: merged {} {} shares of round {} of {} ({} texels) in {:.2} s",
        files.len(),
        first.kind.name(),
        first.round,
        job.scene.display(),
        first.lod_texels,
        started.elapsed().as_secs_f64()
    ));
    for f in written.iter().chain([&report_path]) {
        ui.say(format!("  wrote {}", f.display()));
    }
    Ok(())
}
