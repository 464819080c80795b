//! `livebake bench`: the measurements the issues ask for, written as JSON. Medians and ratios
//! are measured side by side in one run; nothing here is a pass/fail test. `cargo bench`
//! (`benches/livebake.rs`) runs this command of the release binary, so one implementation
//! serves both. A front end like the other commands: it drives the library's public API and
//! reports failures with context (`anyhow`).

mod atlas;
mod bake_memory;
mod cell_bakes;
mod convergence;
mod gpu_backend;
mod instanced;
mod reference;
mod reload;
mod runtime;
mod runtime_large;
mod runtime_real;
mod scale_out;
mod serve;
mod startup;
mod throughput;
mod tiling;
mod viewer;

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

use anyhow::{Context, Result};
use serde_json::{Value, json};

use livebake::plot;

use super::progress::Ui;

/// Embree's incoherent rays/s per core on this kind of machine: the anchor of the issues'
/// throughput targets.
pub const EMBREE_RAYS_PER_CORE: f64 = 2.3e6;

pub fn assets() -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/assets"))
}

/// Where the benches' lines go: the command's progress display, or standard output under
/// `cargo bench`.
pub trait Narrator: Sync {
    /// A line of the summary.
    fn line(&self, line: &str);
    /// A status shown beside the current phase, replaced by the next one.
    fn status(&self, _line: &str) {}
}

impl dyn Narrator + '_ {
    pub fn say(&self, line: impl AsRef<str>) {
        self.line(line.as_ref())
    }
}

/// What a bench section is given.
pub struct Bench<'a> {
    /// Trade precision for time (smaller sample sets, fewer repeats): a smoke run.
    pub quick: bool,
    pub ui: &'a dyn Narrator,
    /// The `livebake` binary, for the sections that time whole commands.
    pub livebake: &'a Path,
    /// The report being written; pictures go beside it.
    out: &'a Path,
    section: &'static str,
    /// The file name of the section's plot, once drawn.
    plot: Mutex<Option<String>>,
}

impl Bench<'_> {
    /// Draws the section's relative error against time (`series`: seconds since the runtime or
    /// the whole-scene bake started, error; `target`: a goal line) as a PNG beside the report
    /// (`bench.json` → `bench.SECTION.png`), named in the report's `plots`.
    pub fn plot_error(&self, title: &str, series: &[plot::Series], target: Option<f64>) -> Result<()> {
        let stem = self.out.file_stem().map_or("bench".into(), |s| s.to_string_lossy());
        let file = format!("{stem}.{}.png", self.section);
        let path = self.out.with_file_name(&file);
        let x_desc = "seconds since the runtime (or the whole-scene bake) started";
        let image = plot::error_curves(title, x_desc, series, target)?;
        livebake::output::write_rgb8_png(&path, image)?;
        self.ui.say(format!("  wrote {}", path.display()));
        *self.plot.lock().map_err(|_| anyhow::anyhow!("a section's plot lock was poisoned"))? = Some(file);
        Ok(())
    }
}

/// One bench section.
type Section = fn(&Bench) -> Result<Value>;

/// The benches, in the order they run.
pub const SECTIONS: [(&str, Section); 18] = [
    ("atlas", atlas::run),
    ("reference", reference::run),
    ("startup", startup::run),
    ("throughput", throughput::run),
    ("convergence", convergence::run),
    ("tiling", tiling::run),
    ("gpu_backend", gpu_backend::run),
    ("viewer", viewer::run),
    ("runtime", runtime::run),
    ("runtime_real", runtime_real::run),
    ("cell_bakes", cell_bakes::run),
    ("runtime_large", runtime_large::run),
    ("runtime_large_overcast", runtime_large::run_overcast),
    ("instanced_1m", instanced::run),
    ("bake_memory", bake_memory::run),
    ("reload", reload::run),
    ("scale_out", scale_out::run),
    ("serve", serve::run),
];

/// Runs `f` `runs` times and returns the median of its results (seconds or rates).
pub fn median(runs: usize, mut f: impl FnMut() -> Result<f64>) -> Result<f64> {
    let mut v = (0..runs.max(1)).map(|_| f()).collect::<Result<Vec<f64>>>()?;
    v.sort_by(f64::total_cmp);
    Ok(v[v.len() / 2])
}

/// (seconds, error) of a curve as the reports write it: `[{"seconds": s, "error": e, ...}]`.
pub fn curve_points(curve: &Value) -> Vec<(f64, f64)> {
    let points = curve.as_array().map(Vec::as_slice).unwrap_or_default();
    points.iter().filter_map(|c| Some((c["seconds"].as_f64()?, c["error"].as_f64()?))).collect()
}

pub fn seconds(t: Instant) -> f64 {
    t.elapsed().as_secs_f64()
}

/// Refuses a section name that is not one of [`SECTIONS`].
pub fn check_sections(only: &[String]) -> Result<()> {
    if let Some(unknown) = only.iter().find(|s| !SECTIONS.iter().any(|(name, _)| name == s)) {
        let names: Vec<&str> = SECTIONS.iter().map(|(name, _)| *name).collect();
        anyhow::bail!("unknown bench section {unknown:?} (sections: {})", names.join(", "));
    }
    Ok(())
}

/// Runs the sections named in `only` (every one when empty) and writes their report to `out`.
/// `livebake` is the binary the whole-command sections run.
pub fn run(out: &Path, only: &[String], quick: bool, livebake: &Path, ui: &dyn Narrator) -> Result<()> {
    check_sections(only)?;
    let mut report = json!({
        "livebake_version": env!("CARGO_PKG_VERSION"),
        "threads": livebake::parallel::available_threads(),
        "quick": quick,
    });
    for (section, measure) in SECTIONS {
        if !only.is_empty() && !only.iter().any(|s| s == section) {
            continue;
        }
        ui.say(format!("bench {section} ..."));
        let t = Instant::now();
        let bench = Bench { quick, ui, livebake, out, section, plot: Mutex::new(None) };
        let value = measure(&bench).with_context(|| format!("bench {section}"))?;
        ui.say(format!("  {}", serde_json::to_string(&value)?));
        ui.say(format!("  ({:.1} s)", seconds(t)));
        report[section] = value;
        if let Some(file) = bench.plot.into_inner().ok().flatten() {
            report["plots"][section] = file.into();
        }
    }
    livebake::output::write_json(out, &report).with_context(|| format!("cannot write {}", out.display()))?;
    ui.say(format!("wrote {}", out.display()));
    Ok(())
}

impl Narrator for Ui {
    fn line(&self, line: &str) {
        self.say(line)
    }

    fn status(&self, line: &str) {
        Ui::status(self, line)
    }
}

/// `livebake bench`: the sections behind the command's progress display, timing this binary
/// where a section runs whole commands.
pub fn command(out: &Path, only: &[String], quick: bool, ui: &Ui) -> Result<()> {
    let livebake = std::env::current_exe().context("cannot find the livebake binary")?;
    run(out, only, quick, &livebake, ui)
}
