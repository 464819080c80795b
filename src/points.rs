//! Point files: `{"points":[{"p":[x,y,z],"n":[x,y,z]}, ...]}` in, the same list out with
//! `"E":[r,g,b]` (or `"error"`) added to each point. Shared by `probe`, `run --points`,
//! `converge` and the benches.
//!
//! Both directions stream: reading keeps each point's query (24 B) and nothing of the
//! document, and is refused past [`MAX_POINTS`]; writing reads the file again, one point at a
//! time, and writes it back with its result and every field the user gave. So a file costs
//! its queries and results (~50 MB at the most), never a document tree of it (a 250 MB file
//! of 10 million points had taken 11 GB).

use std::fmt;
use std::io::{BufReader, Write};
use std::marker::PhantomData;
use std::path::{Path, PathBuf};

use glam::{DVec3, Vec3};
use serde::Deserialize;
use serde::de::{self, DeserializeSeed, Deserializer, MapAccess, SeqAccess, Visitor};
use serde_json::{Map, Value, json};

use crate::output::OutputError;
use crate::probe::ProbeError;
use crate::reference::RelativeRmsError;
use crate::scene::Rgb;

/// Why a points file could not be read or written back.
#[derive(Debug, thiserror::Error)]
pub enum PointsError {
    #[error("cannot read points file {}: {source}", path.display())]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{}: {message} ({})", path.display(), FORMAT)]
    Format { path: PathBuf, message: String },
    #[error("{} is not valid JSON: {message}", path.display())]
    Json { path: PathBuf, message: String },
    #[error("in reference {}: {source}", path.display())]
    Reference { path: PathBuf, source: Box<PointsError> },
    #[error(
        "{non_finite} of {total} points have non-finite irradiance (the light overflowed f32); nothing was written"
    )]
    NonFinite { non_finite: usize, total: usize },
    #[error(transparent)]
    Output(#[from] OutputError),
    #[error("cannot write the points to standard output: {0}")]
    Stdout(std::io::Error),
}

/// Most points a points file may hold: a dense probe grid (references have hundreds).
pub const MAX_POINTS: usize = 1 << 20;

/// A query point (in the scene's frame: [`crate::scene::Scene::origin`]) and the normal of the
/// side it asks about.
#[derive(Clone, Copy, Debug)]
pub struct Query {
    pub p: Vec3,
    pub n: Vec3,
}

/// A query as a file gives it: its point in the file's coordinates, kept in `f64` until the
/// scene's origin is taken off (a point kilometres out keeps its millimetres).
#[derive(Clone, Copy, Debug)]
struct FileQuery {
    p: DVec3,
    n: Vec3,
}

impl FileQuery {
    fn in_frame(self, origin: DVec3) -> Query {
        Query { p: (self.p - origin).as_vec3(), n: self.n }
    }
}

/// The fields of a point that are read; every other one is skipped while reading (and kept
/// when writing back).
#[derive(Deserialize)]
struct RawPoint {
    p: Option<Value>,
    n: Option<Value>,
    #[serde(rename = "E")]
    e: Option<Value>,
    #[serde(rename = "E_stderr")]
    e_stderr: Option<Value>,
    error: Option<Value>,
}

/// `"key": [a, b, c]` of a point; `None` when the point has no such key.
fn triple(value: Option<&Value>, key: &str, index: usize) -> Result<Option<DVec3>, String> {
    let Some(value) = value else { return Ok(None) };
    let numbers: Option<Vec<f64>> = value.as_array().and_then(|a| a.iter().map(Value::as_f64).collect());
    match numbers.as_deref() {
        Some(&[a, b, c]) => Ok(Some(DVec3::new(a, b, c))),
        _ => Err(format!("point {index}: \"{key}\" must be three numbers, got {value}")),
    }
}

fn vec3(value: Option<&Value>, key: &str, index: usize) -> Result<Vec3, String> {
    let v = triple(value, key, index)?.ok_or_else(|| format!("point {index}: missing \"{key}\": [x, y, z]"))?;
    Ok(v.as_vec3())
}

/// What one point of a file becomes.
trait FromPoint: Sized {
    fn from_point(raw: RawPoint, index: usize) -> Result<Self, String>;
}

impl FromPoint for FileQuery {
    fn from_point(raw: RawPoint, index: usize) -> Result<Self, String> {
        let p =
            triple(raw.p.as_ref(), "p", index)?.ok_or_else(|| format!("point {index}: missing \"p\": [x, y, z]"))?;
        Ok(FileQuery { p, n: vec3(raw.n.as_ref(), "n", index)? })
    }
}

/// A reference point: the query, E and its standard error.
struct ReferencePoint {
    query: FileQuery,
    e: DVec3,
    stderr: DVec3,
}

impl FromPoint for ReferencePoint {
    fn from_point(raw: RawPoint, index: usize) -> Result<Self, String> {
        let e = triple(raw.e.as_ref(), "E", index)?.ok_or_else(|| match &raw.error {
            Some(why) => format!("point {index} has no \"E\" (the reference reports {why})"),
            None => format!("point {index}: missing \"E\": [r, g, b]"),
        })?;
        let stderr = triple(raw.e_stderr.as_ref(), "E_stderr", index)?.unwrap_or(DVec3::ZERO);
        let query = FileQuery::from_point(raw, index)?;
        Ok(ReferencePoint { query, e, stderr })
    }
}

/// The `points` array, read one element at a time.
struct PointList<T>(Vec<T>);

impl<'de, T: FromPoint> Deserialize<'de> for PointList<T> {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct List<T>(PhantomData<T>);
        impl<'de, T: FromPoint> Visitor<'de> for List<T> {
            type Value = PointList<T>;
            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a list of points")
            }
            fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Self::Value, A::Error> {
                let mut out = Vec::new();
                while let Some(raw) = seq.next_element::<RawPoint>()? {
                    if out.len() == MAX_POINTS {
                        return Err(de::Error::custom(format!(
                            "more than {MAX_POINTS} points, the most a points file may hold"
                        )));
                    }
                    out.push(T::from_point(raw, out.len()).map_err(de::Error::custom)?);
                }
                Ok(PointList(out))
            }
        }
        deserializer.deserialize_seq(List(PhantomData))
    }
}

/// The document: its `points`, every other field skipped.
#[derive(Deserialize)]
#[serde(bound = "T: FromPoint")]
struct PointsDoc<T> {
    points: PointList<T>,
}

const FORMAT: &str = "expected {\"points\": [{\"p\": [x,y,z], \"n\": [x,y,z]}, ...]}";

fn read_list<T: FromPoint>(path: &Path) -> Result<Vec<T>, PointsError> {
    let file = std::fs::File::open(path).map_err(|source| PointsError::Read { path: path.to_path_buf(), source })?;
    let mut de = serde_json::Deserializer::from_reader(BufReader::new(file));
    let doc = PointsDoc::<T>::deserialize(&mut de).and_then(|d| de.end().map(|()| d));
    match doc {
        Ok(doc) => Ok(doc.points.0),
        Err(e) if e.is_data() => Err(PointsError::Format { path: path.to_path_buf(), message: e.to_string() }),
        Err(e) if e.is_io() => {
            Err(PointsError::Read { path: path.to_path_buf(), source: std::io::Error::other(e.to_string()) })
        }
        Err(e) => Err(PointsError::Json { path: path.to_path_buf(), message: e.to_string() }),
    }
}

/// A points file: where it is (its points are written back from it) and its points, in the
/// file's coordinates.
pub struct PointsFile {
    pub path: PathBuf,
    points: Vec<FileQuery>,
}

impl PointsFile {
    /// The queries in the frame of a scene whose origin is `origin`
    /// ([`crate::scene::Scene::origin`]).
    pub fn queries(&self, origin: DVec3) -> Vec<Query> {
        self.points.iter().map(|q| q.in_frame(origin)).collect()
    }
}

pub fn read_points(path: &Path) -> Result<PointsFile, PointsError> {
    Ok(PointsFile { path: path.to_path_buf(), points: read_list(path)? })
}

/// A reference as read, its points in the file's coordinates: [`ReferenceFile::in_frame`]
/// places them in a scene's.
pub struct ReferenceFile {
    points: Vec<ReferencePoint>,
}

impl ReferenceFile {
    /// The reference with its points in the frame of a scene whose origin is `origin`
    /// ([`crate::scene::Scene::origin`]).
    pub fn in_frame(&self, origin: DVec3) -> ReferencePoints {
        let list = &self.points;
        ReferencePoints {
            queries: list.iter().map(|r| r.query.in_frame(origin)).collect(),
            e: list.iter().map(|r| r.e).collect(),
            stderr: list.iter().map(|r| r.stderr).collect(),
        }
    }
}

/// A reference in probe's output format: points with `"E"` (W/m²) and optionally
/// `"E_stderr"` (its 1σ Monte Carlo error; 0 when absent), e.g. from the Mitsuba tool.
pub struct ReferencePoints {
    pub queries: Vec<Query>,
    pub e: Vec<DVec3>,
    pub stderr: Vec<DVec3>,
}

pub fn read_reference(path: &Path) -> Result<ReferenceFile, PointsError> {
    let points = read_list(path)
        .map_err(|source| PointsError::Reference { path: path.to_path_buf(), source: Box::new(source) })?;
    Ok(ReferenceFile { points })
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

/// Writes the points file `points` back with each result added to its point (`"E"` or
/// `"error"`), to `out` (stdout when `None`), one point at a time; nothing is written when a
/// result is not finite.
pub fn write_results(
    points: &PointsFile,
    results: &[Result<Rgb, ProbeError>],
    out: Option<&Path>,
) -> Result<(), PointsError> {
    let non_finite = results.iter().filter(|r| r.as_ref().is_ok_and(|e| !e.is_finite())).count();
    if non_finite > 0 {
        return Err(PointsError::NonFinite { non_finite, total: results.len() });
    }
    let copy = |w: &mut dyn Write| copy_with_results(&points.path, results, w);
    match out {
        Some(path) => {
            crate::output::write_stream(path, |w| copy(w))?;
        }
        None => {
            let stdout = std::io::stdout();
            let mut w = std::io::BufWriter::new(stdout.lock());
            copy(&mut w).and_then(|()| w.flush()).map_err(PointsError::Stdout)?;
        }
    }
    Ok(())
}

/// Reads `path` again and writes it to `w` with the results added, one point in memory at a
/// time (the document's other fields as they are).
fn copy_with_results(path: &Path, results: &[Result<Rgb, ProbeError>], w: &mut dyn Write) -> std::io::Result<()> {
    let file = std::fs::File::open(path)?;
    let mut de = serde_json::Deserializer::from_reader(BufReader::new(file));
    let seed = DocumentCopy { results, out: w };
    seed.deserialize(&mut de)
        .and_then(|()| de.end())
        .map_err(|e| std::io::Error::other(format!("{} changed while it was read again: {e}", path.display())))
}

/// Copies the top-level object, the `points` list through [`PointsCopy`].
struct DocumentCopy<'a> {
    results: &'a [Result<Rgb, ProbeError>],
    out: &'a mut dyn Write,
}

fn io_error<E: de::Error>(e: std::io::Error) -> E {
    E::custom(e)
}

impl<'de> DeserializeSeed<'de> for DocumentCopy<'_> {
    type Value = ();
    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<(), D::Error> {
        deserializer.deserialize_map(self)
    }
}

impl<'de> Visitor<'de> for DocumentCopy<'_> {
    type Value = ();
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a points document")
    }
    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<(), A::Error> {
        let out = self.out;
        out.write_all(b"{").map_err(io_error)?;
        let mut first = true;
        while let Some(key) = map.next_key::<String>()? {
            let sep: &[u8] = if first { b"\n  " } else { b",\n  " };
            first = false;
            out.write_all(sep).map_err(io_error)?;
            serde_json::to_writer(&mut *out, &key).map_err(de::Error::custom)?;
            out.write_all(b": ").map_err(io_error)?;
            if key == "points" {
                map.next_value_seed(PointsCopy { results: self.results, out: &mut *out })?;
            } else {
                let value: Value = map.next_value()?;
                serde_json::to_writer(&mut *out, &value).map_err(de::Error::custom)?;
            }
        }
        out.write_all(b"\n}\n").map_err(io_error)
    }
}

/// Copies the `points` list, adding each point's result.
struct PointsCopy<'a> {
    results: &'a [Result<Rgb, ProbeError>],
    out: &'a mut dyn Write,
}

impl<'de> DeserializeSeed<'de> for PointsCopy<'_> {
    type Value = ();
    fn deserialize<D: Deserializer<'de>>(self, deserializer: D) -> Result<(), D::Error> {
        deserializer.deserialize_seq(self)
    }
}

impl<'de> Visitor<'de> for PointsCopy<'_> {
    type Value = ();
    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a list of points")
    }
    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<(), A::Error> {
        let out = self.out;
        out.write_all(b"[").map_err(io_error)?;
        let mut k = 0;
        while let Some(mut point) = seq.next_element::<Map<String, Value>>()? {
            let result = self.results.get(k).ok_or_else(|| de::Error::custom("it has more points than were read"))?;
            match result {
                Ok(e) => point.insert("E".into(), json!([e.x, e.y, e.z])),
                Err(err) => point.insert("error".into(), json!(err.to_string())),
            };
            out.write_all(if k == 0 { b"\n    " } else { b",\n    " }).map_err(io_error)?;
            serde_json::to_writer(&mut *out, &point).map_err(de::Error::custom)?;
            k += 1;
        }
        if k != self.results.len() {
            return Err(de::Error::custom("it has fewer points than were read"));
        }
        out.write_all(b"\n  ]").map_err(io_error)
    }
}
