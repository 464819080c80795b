//! Point files: `{"points":[{"p":[x,y,z],"n":[x,y,z]}, ...]}` in, the same list out with
//! `"E":[r,g,b]` (or `"error"`) added to each point. Shared by `probe`, `run --points` and
//! `converge`.

use std::path::Path;

use anyhow::{Context, Result, bail};
use glam::Vec3;
use serde_json::{Value, json};

use livebake::probe::ProbeError;
use livebake::scene::Rgb;

use super::progress::Ui;

/// A query point and the normal of the side it asks about.
pub struct Query {
    pub p: Vec3,
    pub n: Vec3,
}

fn vec3_field(point: &Value, key: &str, index: usize) -> Result<Vec3> {
    let arr = point
        .get(key)
        .and_then(Value::as_array)
        .with_context(|| format!("point {index}: missing \"{key}\": [x, y, z]"))?;
    let vals: Vec<f64> = arr.iter().filter_map(Value::as_f64).collect();
    if arr.len() != 3 || vals.len() != 3 {
        bail!("point {index}: \"{key}\" must be three numbers, got {}", Value::Array(arr.clone()));
    }
    Ok(Vec3::new(vals[0] as f32, vals[1] as f32, vals[2] as f32))
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

/// Adds each result to its point and writes the document to `out` (stdout when `None`).
pub fn write_results(doc: &mut Value, results: &[Result<Rgb, ProbeError>], out: Option<&Path>, ui: &Ui) -> Result<()> {
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
