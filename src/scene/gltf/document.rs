//! From file bytes to a validated glTF JSON document: GLB container parsing (our own code, so a
//! lying header is an error, not a panic), JSON deserialisation, glTF version and
//! `extensionsRequired` checks, and the `gltf-json` validator.

use std::path::Path;

use ::gltf::json;

use super::LoadError;

/// GLB chunk types (little-endian u32 of "JSON" and "BIN\0").
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;
const GLB_HEADER: usize = 12;
const CHUNK_HEADER: usize = 8;

/// Extensions livebake reads and honours, so a file may require them.
pub(super) const SUPPORTED_REQUIRED: &[&str] = &[
    "KHR_lights_punctual",
    "KHR_materials_emissive_strength",
    "KHR_materials_pbrSpecularGlossiness",
    "KHR_materials_transmission",
    "KHR_mesh_quantization",
    "KHR_texture_transform",
    "EXT_mesh_gpu_instancing",
];

/// Extensions livebake does not read that do not change what a Lambertian light-map baker
/// sees: a file using them (besides those it reads) is not warned about.
const HARMLESS_UNREAD: &[&str] = &[
    "KHR_materials_specular",
    "KHR_materials_ior",
    "KHR_materials_clearcoat",
    "KHR_materials_sheen",
    "KHR_materials_variants",
    "KHR_texture_basisu",
    "EXT_texture_webp",
    "MSFT_texture_dds",
];

fn is_read_or_harmless(extension: &str) -> bool {
    SUPPORTED_REQUIRED.contains(&extension) || HARMLESS_UNREAD.contains(&extension)
}

/// The parsed document and, for a GLB, its BIN chunk.
pub(super) struct Parsed<'a> {
    pub root: json::Root,
    /// The JSON text as written (the JSON chunk of a GLB), for writers that copy parts of it.
    pub json_text: &'a [u8],
    pub bin: Option<&'a [u8]>,
    pub is_glb: bool,
    /// Extensions in `extensionsUsed` that livebake ignores and that may change the look.
    pub ignored_extensions: Vec<String>,
}

pub(super) fn parse<'a>(file: &Path, bytes: &'a [u8]) -> Result<Parsed<'a>, LoadError> {
    let (json_bytes, bin, is_glb) = split_container(file, bytes)?;
    let root = deserialize(file, json_bytes, is_glb)?;
    check_version(file, &root)?;
    check_required_extensions(file, &root)?;
    validate(file, &root)?;
    let ignored_extensions = root.extensions_used.iter().filter(|e| !is_read_or_harmless(e)).cloned().collect();
    Ok(Parsed { root, json_text: json_bytes, bin, is_glb, ignored_extensions })
}

/// JSON text, BIN chunk (GLB only) and whether the file is a GLB.
type Container<'a> = (&'a [u8], Option<&'a [u8]>, bool);

fn split_container<'a>(file: &Path, bytes: &'a [u8]) -> Result<Container<'a>, LoadError> {
    if bytes.is_empty() {
        return Err(LoadError::NotGltf { file: file.into(), reason: "the file is empty".into() });
    }
    if bytes.starts_with(b"glTF") {
        let (json, bin) = split_glb(file, bytes)?;
        return Ok((json, bin, true));
    }
    let text = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
    match text.iter().find(|b| !b.is_ascii_whitespace()) {
        Some(b'{') => Ok((text, None, false)),
        Some(_) => Err(LoadError::NotGltf {
            file: file.into(),
            reason: format!(
                "it starts with {} instead of a JSON object '{{' or the GLB magic 'glTF'",
                escape_prefix(bytes)
            ),
        }),
        None => Err(LoadError::NotGltf { file: file.into(), reason: "the file holds only whitespace".into() }),
    }
}

fn escape_prefix(bytes: &[u8]) -> String {
    let head: Vec<u8> = bytes.iter().copied().take(8).collect();
    format!("\"{}\"", head.escape_ascii())
}

fn u32_at(bytes: &[u8], offset: usize) -> Option<u32> {
    let end = offset.checked_add(4)?;
    Some(u32::from_le_bytes(bytes.get(offset..end)?.try_into().ok()?))
}

/// GLB: 12-byte header (magic, version, total length), a JSON chunk, an optional BIN chunk;
/// chunks of other types are skipped as the spec asks.
fn split_glb<'a>(file: &Path, bytes: &'a [u8]) -> Result<(&'a [u8], Option<&'a [u8]>), LoadError> {
    let glb_err = |message: String| LoadError::Glb { file: file.into(), message };
    let (Some(version), Some(length)) = (u32_at(bytes, 4), u32_at(bytes, 8)) else {
        return Err(glb_err(format!("the file has {} bytes, fewer than the 12-byte GLB header", bytes.len())));
    };
    if version != 2 {
        return Err(LoadError::Unsupported {
            file: file.into(),
            what: format!("GLB container version {version} (livebake reads glTF 2.0, GLB version 2)"),
        });
    }
    let length = length as usize;
    if length > bytes.len() {
        return Err(glb_err(format!(
            "the header says the file has {length} bytes but it has {} (truncated?)",
            bytes.len()
        )));
    }
    let mut pos = GLB_HEADER;
    let mut json = None;
    let mut bin = None;
    while pos < length {
        let (Some(chunk_len), Some(chunk_type)) = (u32_at(bytes, pos), u32_at(bytes, pos + 4)) else {
            return Err(glb_err(format!("chunk header at byte {pos} is cut off by the end of the file")));
        };
        let start = pos + CHUNK_HEADER;
        let end = start.checked_add(chunk_len as usize).filter(|&e| e <= length).ok_or_else(|| {
            glb_err(format!(
                "chunk at byte {pos} claims {chunk_len} bytes but only {} remain",
                length.saturating_sub(start)
            ))
        })?;
        let data = bytes.get(start..end).ok_or_else(|| glb_err(format!("chunk at byte {pos} is out of range")))?;
        match (chunk_type, json.is_some()) {
            (CHUNK_JSON, false) => json = Some(data),
            (_, false) => return Err(glb_err("the first chunk is not the JSON chunk".into())),
            (CHUNK_JSON, true) => return Err(glb_err(format!("second JSON chunk at byte {pos}"))),
            (CHUNK_BIN, true) if bin.is_none() => bin = Some(data),
            _ => {} // unknown chunk types (and further BIN chunks) are ignored
        }
        pos = end;
    }
    let json = json.ok_or_else(|| glb_err("no JSON chunk".into()))?;
    Ok((json, bin))
}

fn deserialize(file: &Path, json_text: &[u8], is_glb: bool) -> Result<json::Root, LoadError> {
    json::deserialize::from_slice::<json::Root>(json_text).map_err(|e| {
        let full = e.to_string();
        let position = format!(" at line {} column {}", e.line(), e.column());
        let mut message = full.strip_suffix(&position).unwrap_or(&full).to_string();
        if e.is_eof() {
            message.push_str(" (the file looks truncated)");
        }
        if is_glb {
            message.push_str(" (in the GLB JSON chunk)");
        }
        LoadError::Json { file: file.into(), line: e.line(), column: e.column(), message }
    })
}

fn check_version(file: &Path, root: &json::Root) -> Result<(), LoadError> {
    let major = |v: &str| v.split('.').next().and_then(|m| m.trim().parse::<u32>().ok());
    let unsupported = |what: String| LoadError::Unsupported { file: file.into(), what };
    match major(&root.asset.version) {
        Some(2) => {}
        _ => {
            return Err(unsupported(format!("glTF version '{}' (livebake reads glTF 2.x)", root.asset.version)));
        }
    }
    if let Some(min) = &root.asset.min_version {
        if major(min) != Some(2) || min.trim() != "2.0" {
            return Err(unsupported(format!("the file needs glTF {min} (asset.minVersion); livebake reads 2.0")));
        }
    }
    Ok(())
}

fn check_required_extensions(file: &Path, root: &json::Root) -> Result<(), LoadError> {
    let unsupported: Vec<&str> =
        root.extensions_required.iter().map(String::as_str).filter(|e| !SUPPORTED_REQUIRED.contains(e)).collect();
    if unsupported.is_empty() {
        return Ok(());
    }
    let compressed = unsupported
        .iter()
        .any(|e| matches!(*e, "KHR_draco_mesh_compression" | "EXT_meshopt_compression" | "KHR_meshopt_compression"));
    let hint = if compressed { "; re-export the file without mesh compression" } else { "" };
    Err(LoadError::Unsupported {
        file: file.into(),
        what: format!(
            "extensionsRequired lists {} which livebake does not support (supported: {}){hint}",
            unsupported.join(", "),
            SUPPORTED_REQUIRED.join(", ")
        ),
    })
}

/// Runs the `gltf-json` validator, minus two of its rules that disagree with the spec or with
/// what we support: accessors without `bufferView` (valid glTF: all zeros, maybe with sparse
/// values) and `extensionsRequired` (checked above, against our own list).
fn validate(file: &Path, root: &json::Root) -> Result<(), LoadError> {
    use json::validation::{Error as VError, Validate};
    precheck_position_indices(file, root)?;
    let mut errors: Vec<String> = Vec::new();
    root.validate(root, json::Path::new, &mut |path, error| {
        let path = path();
        let p = path.as_str();
        let zeros_accessor = p.starts_with("accessors[") && p.ends_with("].bufferView") && error == VError::Missing;
        if zeros_accessor || p.starts_with("extensionsRequired") {
            return;
        }
        errors.push(format!("{p}: {}", describe(error)));
    });
    if errors.is_empty() {
        return Ok(());
    }
    const SHOWN: usize = 8;
    let more = if errors.len() > SHOWN { format!(" (and {} more)", errors.len() - SHOWN) } else { String::new() };
    errors.truncate(SHOWN);
    Err(LoadError::Invalid { file: file.into(), message: format!("{}{more}", errors.join("; ")) })
}

fn describe(e: json::validation::Error) -> &'static str {
    use json::validation::Error as VError;
    match e {
        VError::IndexOutOfBounds => "index out of bounds",
        VError::Invalid => "invalid value",
        VError::Missing => "missing",
        VError::Oversize => "size exceeds the limits of this machine",
        VError::Unsupported => "unsupported",
    }
}

/// `gltf-json`'s primitive validation indexes `accessors[POSITION]` before checking that the
/// index exists; check it first so a bad index is an error, not a panic.
fn precheck_position_indices(file: &Path, root: &json::Root) -> Result<(), LoadError> {
    use json::mesh::Semantic;
    use json::validation::Checked;
    for (m, mesh) in root.meshes.iter().enumerate() {
        for (p, prim) in mesh.primitives.iter().enumerate() {
            if let Some(index) = prim.attributes.get(&Checked::Valid(Semantic::Positions)) {
                if index.value() >= root.accessors.len() {
                    return Err(LoadError::Invalid {
                        file: file.into(),
                        message: format!(
                            "meshes[{m}].primitives[{p}].attributes[\"POSITION\"]: accessor {} does not exist ({} accessors)",
                            index.value(),
                            root.accessors.len()
                        ),
                    });
                }
            }
        }
    }
    Ok(())
}
