//! Point files: `{"points":[{"p":[x,y,z],"n":[x,y,z]}, ...]}` in, the same list out with
//! `"E":[r,g,b]` (or `"error"`) added to each point. Shared by `probe`, `run --points` and
//! `converge`.

use std::path::Path;

use anyhow::{Context, Result, bail};
use glam::{DVec3, Vec3};
use serde_json::{Value, json};

use livebake::probe::ProbeError;
use livebake::reference::RelativeRmsError;
use livebake::scene::Rgb;

use super::progress::Ui;

/// A query point and the normal of the side it asks about.
#[derive(Clone, Copy, Debug)]
pub struct Query {
    pub p: Vec3,
    pub n: Vec3,
}

/// `"key": [a, b, c]` of a point; `None` when the point has no such key.
fn triple_field(point: &Value, key: &str, index: usize) -> Result<Option<DVec3>> {
    let Some(value) = point.get(key) else { return Ok(None) };
    let numbers: Option<Vec<f64>> = value.as_array().and_then(|a| a.iter().map(Value::as_f64).collect());
    match numbers.as_deref() {
        Some(&[a, b, c]) => Ok(Some(DVec3::new(a, b, c))),
        _ => bail!("point {index}: \"{key}\" must be three numbers, got {value}"),
    }
}

fn vec3_field(point: &Value, key: &str, index: usize) -> Result<Vec3> {
    let v = triple_field(point, key, index)?.with_context(|| format!("point {index}: missing \"{key}\": [x, y, z]"))?;
    Ok(v.as_vec3())
}

/// The document (kept to write back with every field the user gave) and its queries.
pub fn read_points(path: &Path) -> Result<(Value, Vec<Query>)> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read points file {}", path.display()))?;
    let doc: Value = serde_json::from_str(&text).with_context(|| format!("{} is not valid JSON", path.display()))?;
    let list = doc.get("points").and_then(Value::as_array).with_context(|| {
        format!("{}: expected {{\"points\": [{{\"p\": [x,y,z], \"n\": [x,y,z]}}, ...]}}", path.display())
    })?;
    let queries = list
        .iter()
        .enumerate()
        .map(|(i, pt)| Ok(Query { p: vec3_field(pt, "p", i)?, n: vec3_field(pt, "n", i)? }))
        .collect::<Result<Vec<_>>>()
        .with_context(|| format!("in {}", path.display()))?;
    Ok((doc, queries))
}

/// A reference in probe's output format: points with `"E"` (W/m²) and optionally
/// `"E_stderr"` (its 1σ Monte Carlo error; 0 when absent), e.g. from the Mitsuba tool.
pub struct ReferencePoints {
    pub queries: Vec<Query>,
    pub e: Vec<DVec3>,
    pub stderr: Vec<DVec3>,
}

pub fn read_reference(path: &Path) -> Result<ReferencePoints> {
    let (doc, queries) = read_points(path)?;
    let list = doc.get("points").and_then(Value::as_array).map(Vec::as_slice).unwrap_or_default();
    let mut reference = ReferencePoints { queries, e: Vec::new(), stderr: Vec::new() };
    for (i, pt) in list.iter().enumerate() {
        let (e, stderr) = reference_values(pt, i).with_context(|| format!("in reference {}", path.display()))?;
        reference.e.push(e);
        reference.stderr.push(stderr);
    }
    Ok(reference)
}

/// A reference point's E and its standard error.
fn reference_values(point: &Value, index: usize) -> Result<(DVec3, DVec3)> {
    let e = triple_field(point, "E", index)?.with_context(|| match point.get("error") {
        Some(why) => format!("point {index} has no \"E\" (the reference reports {why})"),
        None => format!("point {index}: missing \"E\": [r, g, b]"),
    })?;
    Ok((e, triple_field(point, "E_stderr", index)?.unwrap_or(DVec3::ZERO)))
}

impl ReferencePoints {
    /// Relative RMS error of the estimates `got(k)` at the points, the reference's own noise
    /// removed in quadrature ([`RelativeRmsError`]).
    pub fn relative_rms(&self, got: impl Fn(usize) -> DVec3) -> f64 {
        let mut error = RelativeRmsError::default();
        for (k, (e, stderr)) in self.e.iter().zip(&self.stderr).enumerate() {
            error.add(got(k), *e, *stderr);
        }
        error.value()
    }
}

/// Adds each result to its point and writes the document to `out` (stdout when `None`);
/// nothing is written when a result is not finite.
pub fn write_results(doc: &mut Value, results: &[Result<Rgb, ProbeError>], out: Option<&Path>, ui: &Ui) -> Result<()> {
    let non_finite = results.iter().filter(|r| r.as_ref().is_ok_and(|e| !e.is_finite())).count();
    if non_finite > 0 {
        bail!(
            "{non_finite} of {} points have non-finite irradiance (the light overflowed f32); nothing was written",
            results.len()
        );
    }
    if let Some(list) = doc.get_mut("points").and_then(Value::as_array_mut) {
        for (pt, r) in list.iter_mut().zip(results) {
            match r {
                Ok(e) => pt["E"] = json!([e.x, e.y, e.z]),
                Err(err) => pt["error"] = json!(err.to_string()),
            }
        }
    }
    match out {
        Some(path) => {
            livebake::output::write_json(path, doc)?;
            ui.say(format!("wrote {} ({} points)", path.display(), results.len()));
        }
        None => println!("{}", serde_json::to_string_pretty(doc)?),
    }
    Ok(())
}
