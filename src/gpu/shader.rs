//! WGSL sources (`shaders/`, compiled into the binary) and the include preprocessor.
//!
//! A line `#include "NAME.inc.wgsl"` is replaced by that file, itself preprocessed; every
//! include is pasted at most once per shader (the first time it is named), so two includes
//! may share a third and a cycle cannot recurse.

/// Every shader file: passes (`*.wgsl`) and includes (`*.inc.wgsl`). A test checks this list
/// against the `shaders/` folder and validates each pass with naga.
pub const SOURCES: &[(&str, &str)] = &[
    ("common.inc.wgsl", include_str!("../../shaders/common.inc.wgsl")),
    ("lightmap.inc.wgsl", include_str!("../../shaders/lightmap.inc.wgsl")),
    ("surface_radiance.inc.wgsl", include_str!("../../shaders/surface_radiance.inc.wgsl")),
    ("bundle_through.inc.wgsl", include_str!("../../shaders/bundle_through.inc.wgsl")),
    ("surface.wgsl", include_str!("../../shaders/surface.wgsl")),
    ("tone_map.wgsl", include_str!("../../shaders/tone_map.wgsl")),
    ("irradiance_probe.wgsl", include_str!("../../shaders/irradiance_probe.wgsl")),
    ("bundle_analysis.wgsl", include_str!("../../shaders/bundle_analysis.wgsl")),
    ("bundle_mips.wgsl", include_str!("../../shaders/bundle_mips.wgsl")),
    ("bundle_tiles.wgsl", include_str!("../../shaders/bundle_tiles.wgsl")),
    ("bundle_lists.wgsl", include_str!("../../shaders/bundle_lists.wgsl")),
    ("bundle_resolve.wgsl", include_str!("../../shaders/bundle_resolve.wgsl")),
    ("bundle_groups.wgsl", include_str!("../../shaders/bundle_groups.wgsl")),
];

/// The line of a pass that names its float type for host-precision arithmetic
/// (`bundle_tiles.wgsl`); [`source_f64`] rewrites it.
pub const REAL_F32: &str = "alias real = f32;";
const REAL_F64: &str = "alias real = f64;";

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum ShaderError {
    #[error("shader {0:?} is not one of livebake's shaders")]
    Unknown(String),
    #[error("shader {0:?} has no `alias real = f32;` line to make f64")]
    NoRealAlias(String),
    #[error("{file}:{line}: malformed #include (expected #include \"NAME.inc.wgsl\")")]
    BadInclude { file: String, line: usize },
}

/// The passes (not the includes): what gets compiled and validated.
pub fn passes() -> impl Iterator<Item = &'static str> {
    SOURCES.iter().map(|(name, _)| *name).filter(|n| !n.ends_with(".inc.wgsl"))
}

/// The source of `name` with its includes resolved.
pub fn source(name: &str) -> Result<String, ShaderError> {
    preprocess(name, &|n| SOURCES.iter().find(|(k, _)| *k == n).map(|(_, s)| *s))
}

/// [`source`] with `real` aliased to f64 (for devices with `SHADER_F64`): an error if the pass
/// has no [`REAL_F32`] line.
pub fn source_f64(name: &str) -> Result<String, ShaderError> {
    let text = source(name)?;
    if !text.lines().any(|l| l.trim() == REAL_F32) {
        return Err(ShaderError::NoRealAlias(name.to_string()));
    }
    Ok(text.lines().map(|l| if l.trim() == REAL_F32 { REAL_F64 } else { l }).collect::<Vec<_>>().join("\n"))
}

/// [`source`] over any file set (`lookup` gives a file's text by name).
pub fn preprocess<'a>(name: &str, lookup: &dyn Fn(&str) -> Option<&'a str>) -> Result<String, ShaderError> {
    let mut out = String::new();
    let mut seen = Vec::new();
    expand(name, lookup, &mut seen, &mut out)?;
    Ok(out)
}

fn expand<'a>(
    name: &str,
    lookup: &dyn Fn(&str) -> Option<&'a str>,
    seen: &mut Vec<String>,
    out: &mut String,
) -> Result<(), ShaderError> {
    seen.push(name.to_string());
    let text = lookup(name).ok_or_else(|| ShaderError::Unknown(name.to_string()))?;
    for (i, line) in text.lines().enumerate() {
        let Some(rest) = line.trim_start().strip_prefix("#include") else {
            out.push_str(line);
            out.push('\n');
            continue;
        };
        let bad = || ShaderError::BadInclude { file: name.to_string(), line: i + 1 };
        let included = rest.trim().strip_prefix('"').and_then(|r| r.strip_suffix('"')).ok_or_else(bad)?;
        if !included.ends_with(".inc.wgsl") {
            return Err(bad());
        }
        if !seen.iter().any(|s| s == included) {
            expand(included, lookup, seen, out)?;
        }
    }
    Ok(())
}

/// A shader module for pass `name` (errors: an unknown name; WGSL errors surface as wgpu
/// validation errors, which the shader tests rule out).
pub fn module(device: &wgpu::Device, name: &str) -> Result<wgpu::ShaderModule, ShaderError> {
    Ok(module_from(device, name, source(name)?))
}

/// A shader module for pass `name` from its (preprocessed, possibly rewritten) text.
pub fn module_from(device: &wgpu::Device, name: &str, text: String) -> wgpu::ShaderModule {
    device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(name),
        source: wgpu::ShaderSource::Wgsl(text.into()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn files<'a>(set: &'a [(&'a str, &'a str)]) -> impl Fn(&str) -> Option<&'a str> {
        move |n| set.iter().find(|(k, _)| *k == n).map(|(_, s)| *s)
    }

    #[test]
    fn includes_paste_once_and_cycles_stop() {
        let set = [
            ("a.wgsl", "A\n#include \"b.inc.wgsl\"\n#include \"c.inc.wgsl\"\nA2"),
            ("b.inc.wgsl", "B\n#include \"c.inc.wgsl\""),
            ("c.inc.wgsl", "C\n#include \"b.inc.wgsl\""),
        ];
        assert_eq!(preprocess("a.wgsl", &files(&set)).unwrap(), "A\nB\nC\nA2\n");
    }

    #[test]
    fn bad_includes_are_errors() {
        let set = [
            ("a.wgsl", "x\n#include b.inc.wgsl"),
            ("d.wgsl", "#include \"nope.inc.wgsl\""),
            ("e.wgsl", "#include \"e.wgsl\""),
        ];
        assert_eq!(preprocess("a.wgsl", &files(&set)), Err(ShaderError::BadInclude { file: "a.wgsl".into(), line: 2 }));
        assert_eq!(preprocess("d.wgsl", &files(&set)), Err(ShaderError::Unknown("nope.inc.wgsl".into())));
        assert!(matches!(preprocess("e.wgsl", &files(&set)), Err(ShaderError::BadInclude { .. })));
    }

    /// Every file in `shaders/` is in [`SOURCES`] (so none escapes validation), and every
    /// pass parses and validates with naga (all validation flags, default capabilities).
    #[test]
    fn every_shader_is_listed_and_validates_with_naga() {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/shaders");
        let mut on_disk: Vec<String> = std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.ends_with(".wgsl"))
            .collect();
        on_disk.sort();
        let mut listed: Vec<String> = SOURCES.iter().map(|(n, _)| n.to_string()).collect();
        listed.sort();
        assert_eq!(on_disk, listed);
        for name in passes() {
            let text = source(name).unwrap();
            let module =
                naga::front::wgsl::parse_str(&text).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&text)));
            naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::default())
                .validate(&module)
                .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(&text)));
            // Passes with a `real` alias also validate in their f64 form.
            if let Ok(text) = source_f64(name) {
                let module = naga::front::wgsl::parse_str(&text)
                    .unwrap_or_else(|e| panic!("{name} (f64): {}", e.emit_to_string(&text)));
                let caps = naga::valid::Capabilities::default() | naga::valid::Capabilities::FLOAT64;
                naga::valid::Validator::new(naga::valid::ValidationFlags::all(), caps)
                    .validate(&module)
                    .unwrap_or_else(|e| panic!("{name} (f64): {}", e.emit_to_string(&text)));
            }
        }
        assert!(source_f64("bundle_tiles.wgsl").is_ok());
        assert_eq!(source_f64("surface.wgsl"), Err(ShaderError::NoRealAlias("surface.wgsl".into())));
    }
}
