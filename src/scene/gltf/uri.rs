//! glTF URIs: `data:` URIs (base64 or percent-encoded) and relative file references
//! (percent-decoded, resolved against the directory of the glTF file, and refused when
//! their text leaves it: [`FileScope::admits_text`]).

use std::path::{Path, PathBuf};

use super::files::{FileScope, Refusal};

/// Where the bytes behind a URI are.
#[derive(Debug, PartialEq)]
pub(super) enum UriSource {
    /// An embedded `data:` URI, already decoded.
    Data { mime: String, bytes: Vec<u8> },
    /// A local file, resolved against the glTF file's directory.
    File(PathBuf),
}

/// Why a URI cannot be used.
#[derive(Debug, PartialEq)]
pub(super) enum UriError {
    /// `data:` URI without the `,` that separates the header from the data.
    MalformedData,
    /// Invalid base64 at this byte offset of the data part.
    Base64 { offset: usize },
    /// A URI with a scheme other than `data:` (http, https, file...).
    Remote { scheme: String },
    /// A file path that leaves the scene's folder.
    Refused(Refusal),
}

impl std::fmt::Display for UriError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            UriError::MalformedData => write!(f, "malformed data URI (no ',' after the media type)"),
            UriError::Base64 { offset } => write!(f, "data URI has invalid base64 at offset {offset} of its data"),
            UriError::Remote { scheme } => {
                write!(f, "'{scheme}:' URIs are not supported (only relative file paths and data: URIs)")
            }
            UriError::Refused(r) => r.fmt(f),
        }
    }
}

/// Resolves `uri` (from a buffer or image) relative to `base_dir`, refusing a path whose
/// text leaves the folder `scope` keeps the scene in.
pub(super) fn resolve(base_dir: &Path, uri: &str, scope: &FileScope) -> Result<UriSource, UriError> {
    if let Some(scheme) = scheme_of(uri) {
        if scheme.eq_ignore_ascii_case("data") {
            return decode_data_uri(uri);
        }
        return Err(UriError::Remote { scheme: scheme.to_string() });
    }
    // Drop a query or fragment, then percent-decode ("my%20mesh.bin" → "my mesh.bin").
    let path_part = uri.split(['?', '#']).next().unwrap_or_default();
    let decoded = percent_decode(path_part);
    let decoded = PathBuf::from(String::from_utf8_lossy(&decoded).into_owned());
    scope.admits_text(&decoded).map_err(UriError::Refused)?;
    Ok(UriSource::File(base_dir.join(decoded)))
}

/// The local file a URI names, resolved as [`resolve`] does, `Ok(None)` for a `data:` URI or
/// a remote one (neither is a file on this machine), or why the file is out of `scope`
/// (its text, or where its symbolic links lead). Decodes nothing but the path.
pub(super) fn file_path(base_dir: &Path, uri: &str, scope: &FileScope) -> Result<Option<PathBuf>, Refusal> {
    if scheme_of(uri).is_some() {
        return Ok(None);
    }
    match resolve(base_dir, uri, scope) {
        Ok(UriSource::File(path)) => {
            scope.admits_path(&path)?;
            Ok(Some(path))
        }
        Err(UriError::Refused(r)) => Err(r),
        _ => Ok(None),
    }
}

/// The scheme of an absolute URI (`data`, `http`...), if `uri` has one. A single letter before
/// ':' is taken as a Windows drive, not a scheme.
fn scheme_of(uri: &str) -> Option<&str> {
    let colon = uri.find(':')?;
    let scheme = uri.get(..colon)?;
    let mut chars = scheme.chars();
    let first = chars.next()?;
    let valid = first.is_ascii_alphabetic() && chars.all(|c| c.is_ascii_alphanumeric() || "+-.".contains(c));
    (valid && scheme.len() >= 2).then_some(scheme)
}

/// `data:[<media type>][;base64],<data>`
fn decode_data_uri(uri: &str) -> Result<UriSource, UriError> {
    let rest = uri.get("data:".len()..).ok_or(UriError::MalformedData)?;
    let (header, data) = rest.split_once(',').ok_or(UriError::MalformedData)?;
    let (mime, is_base64) = match header.strip_suffix(";base64") {
        Some(m) => (m, true),
        None => (header, false),
    };
    let mime = mime.split(';').next().unwrap_or_default().to_string();
    let bytes = if is_base64 {
        // Base64 has no '%', but some writers percent-encode the padding.
        let text = percent_decode(data);
        base64_decode(&text).map_err(|offset| UriError::Base64 { offset })?
    } else {
        percent_decode(data)
    };
    Ok(UriSource::Data { mime, bytes })
}

/// Decodes `%XX` escapes; a malformed escape is kept as it is.
pub(super) fn percent_decode(s: &str) -> Vec<u8> {
    let bytes = s.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while let Some(&b) = bytes.get(i) {
        if b == b'%' {
            let hi = bytes.get(i + 1).and_then(|&c| hex_value(c));
            let lo = bytes.get(i + 2).and_then(|&c| hex_value(c));
            if let (Some(hi), Some(lo)) = (hi, lo) {
                out.push(hi << 4 | lo);
                i += 3;
                continue;
            }
        }
        out.push(b);
        i += 1;
    }
    out
}

fn hex_value(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'a'..=b'f' => Some(c - b'a' + 10),
        b'A'..=b'F' => Some(c - b'A' + 10),
        _ => None,
    }
}

/// Standard (and URL-safe) base64 with optional padding; ASCII whitespace is skipped.
/// Returns the offset of the first invalid byte on error.
pub(super) fn base64_decode(text: &[u8]) -> Result<Vec<u8>, usize> {
    let mut out = Vec::with_capacity(text.len() / 4 * 3 + 3);
    let mut acc: u32 = 0;
    let mut bits = 0u32;
    let mut padding = false;
    for (i, &c) in text.iter().enumerate() {
        let v = match c {
            b'A'..=b'Z' => c - b'A',
            b'a'..=b'z' => c - b'a' + 26,
            b'0'..=b'9' => c - b'0' + 52,
            b'+' | b'-' => 62,
            b'/' | b'_' => 63,
            b'=' => {
                padding = true;
                continue;
            }
            b' ' | b'\t' | b'\r' | b'\n' => continue,
            _ => return Err(i),
        };
        if padding {
            return Err(i); // data after '='
        }
        acc = (acc << 6) | u32::from(v);
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
            acc &= (1 << bits) - 1;
        }
    }
    // One leftover character carries 6 bits: less than a byte, so the text was cut short.
    if bits >= 6 {
        return Err(text.len());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_round_trips_known_vectors() {
        assert_eq!(base64_decode(b"").unwrap(), b"");
        assert_eq!(base64_decode(b"Zg==").unwrap(), b"f");
        assert_eq!(base64_decode(b"Zm8=").unwrap(), b"fo");
        assert_eq!(base64_decode(b"Zm9v").unwrap(), b"foo");
        assert_eq!(base64_decode(b"Zm9vYmFy").unwrap(), b"foobar");
        assert_eq!(base64_decode(b"Zm9vYg").unwrap(), b"foob"); // unpadded
        assert_eq!(base64_decode(b"AAEC/w==").unwrap(), [0, 1, 2, 255]);
        assert_eq!(base64_decode(b"AAEC_w==").unwrap(), [0, 1, 2, 255]); // URL-safe
        assert_eq!(base64_decode(b"Zm9v\nYmFy").unwrap(), b"foobar");
    }

    #[test]
    fn base64_rejects_garbage() {
        assert_eq!(base64_decode(b"Zm9v!mFy"), Err(4));
        assert_eq!(base64_decode(b"Zg==Zg"), Err(4));
        assert_eq!(base64_decode(b"Zm9vY"), Err(5));
    }

    fn anywhere() -> FileScope {
        FileScope::new(Path::new("/x"), true)
    }

    #[test]
    fn data_uris_decode() {
        let base = Path::new("/x");
        let resolve = |base: &Path, uri: &str| resolve(base, uri, &anywhere());
        assert_eq!(
            resolve(base, "data:application/octet-stream;base64,AAEC").unwrap(),
            UriSource::Data { mime: "application/octet-stream".into(), bytes: vec![0, 1, 2] }
        );
        assert_eq!(
            resolve(base, "data:text/plain,a%20b").unwrap(),
            UriSource::Data { mime: "text/plain".into(), bytes: b"a b".to_vec() }
        );
        assert_eq!(resolve(base, "data:;base64,AA*A"), Err(UriError::Base64 { offset: 2 }));
        assert_eq!(resolve(base, "data:nocomma"), Err(UriError::MalformedData));
    }

    #[test]
    fn file_uris_are_percent_decoded_and_relative() {
        let base = Path::new("/scenes/room");
        let scope = FileScope::new(base, false);
        let resolve = |base: &Path, uri: &str| resolve(base, uri, &scope);
        let file_path = |base: &Path, uri: &str| file_path(base, uri, &scope).unwrap();
        assert_eq!(resolve(base, "my%20mesh.bin").unwrap(), UriSource::File(PathBuf::from("/scenes/room/my mesh.bin")));
        assert_eq!(resolve(base, "tex/a.png?v=2").unwrap(), UriSource::File(PathBuf::from("/scenes/room/tex/a.png")));
        assert_eq!(percent_decode("100%"), b"100%");
        assert_eq!(percent_decode("%4g%41"), b"%4gA");
        assert!(matches!(resolve(base, "https://example.com/a.bin"), Err(UriError::Remote { .. })));
        assert_eq!(file_path(base, "tex/a%20b.png"), Some(PathBuf::from("/scenes/room/tex/a b.png")));
        assert_eq!(file_path(base, "data:;base64,AAEC"), None);
        assert_eq!(file_path(base, "https://example.com/a.bin"), None);
        // Percent-encoded dots climb out as well as written ones.
        assert_eq!(resolve(base, "%2e%2e/x.bin"), Err(UriError::Refused(Refusal::ParentEscape)));
        assert_eq!(resolve(base, "%2Fetc%2Fpasswd"), Err(UriError::Refused(Refusal::Absolute)));
    }
}
