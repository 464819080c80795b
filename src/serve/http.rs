//! The HTTP side: one request per connection (`Connection: close`), read with a size cap
//! and a timeout, parsed by `httparse`. What is served: the page's own files (compiled in),
//! the scene's own files (the glTF and the buffers and images it names, read through the
//! loader's confinement, `scene::gltf::read_regular` under the scene folder's scope), a
//! status document, and the socket's upgrade. Everything else is 404; a request without the
//! access token (when one is set) is 403.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::time::Duration;

use crate::scene::gltf::{FileScope, LoadOptions, external_files, read_regular};

/// The page's files, compiled into the binary.
pub const PAGE_FILES: &[(&str, &str, &[u8])] = &[
    ("/", "text/html; charset=utf-8", include_bytes!("../../web/index.html")),
    ("/index.html", "text/html; charset=utf-8", include_bytes!("../../web/index.html")),
    ("/livebake.js", "text/javascript; charset=utf-8", include_bytes!("../../web/livebake.js")),
    ("/shaders.js", "text/javascript; charset=utf-8", include_bytes!("../../web/shaders.js")),
    ("/lightmap.js", "text/javascript; charset=utf-8", include_bytes!("../../web/lightmap.js")),
    ("/socket.js", "text/javascript; charset=utf-8", include_bytes!("../../web/socket.js")),
];

/// Headers that make the page cross-origin isolated (`SharedArrayBuffer` allowed).
pub const ISOLATION: [&str; 2] =
    ["Cross-Origin-Opener-Policy: same-origin", "Cross-Origin-Embedder-Policy: require-corp"];

/// Largest request head read.
const MAX_HEAD: usize = 16 * 1024;
/// Largest scene file served (a glTF's buffers and images are bounded by the loader's own
/// limits; this caps what one request reads).
const MAX_SCENE_FILE: u64 = 1 << 30;
/// Name of the cookie holding the access token.
pub const TOKEN_COOKIE: &str = "livebake_token";

/// A parsed request head.
#[derive(Debug)]
pub struct Request {
    pub method: String,
    /// The path, without the query.
    pub path: String,
    pub query: String,
    pub headers: Vec<(String, String)>,
}

impl Request {
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers.iter().find(|(n, _)| n.eq_ignore_ascii_case(name)).map(|(_, v)| v.as_str())
    }

    /// The value of query parameter `name`.
    pub fn query_param(&self, name: &str) -> Option<&str> {
        self.query.split('&').filter_map(|kv| kv.split_once('=')).find(|(k, _)| *k == name).map(|(_, v)| v)
    }

    fn cookie(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .filter(|(n, _)| n.eq_ignore_ascii_case("cookie"))
            .flat_map(|(_, v)| v.split(';'))
            .filter_map(|c| c.trim().split_once('='))
            .find(|(k, _)| *k == name)
            .map(|(_, v)| v)
    }

    /// Whether the request carries `token` (query `?token=` or the cookie); always with none.
    pub fn has_token(&self, token: Option<&str>) -> bool {
        let Some(token) = token else { return true };
        [self.query_param("token"), self.cookie(TOKEN_COOKIE)].into_iter().flatten().any(|t| same(t, token))
    }
}

/// Compares without stopping at the first difference (no timing hint at the token's prefix).
fn same(a: &str, b: &str) -> bool {
    a.len() == b.len() && a.bytes().zip(b.bytes()).fold(0u8, |d, (x, y)| d | (x ^ y)) == 0
}

#[derive(Debug, thiserror::Error)]
pub enum HttpError {
    #[error("cannot read the request: {0}")]
    Io(#[from] std::io::Error),
    #[error("the request head is longer than {MAX_HEAD} bytes")]
    TooLong,
    #[error("malformed request: {0}")]
    Malformed(String),
}

/// Reads and parses one request head from `stream` (10 s at most).
pub fn read_request(stream: &mut TcpStream) -> Result<Request, HttpError> {
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut buf = Vec::with_capacity(1024);
    let mut chunk = [0u8; 1024];
    loop {
        let n = stream.read(&mut chunk)?;
        if n == 0 {
            return Err(HttpError::Malformed("connection closed before the head ended".into()));
        }
        buf.extend_from_slice(&chunk[..n]);
        let mut headers = [httparse::EMPTY_HEADER; 64];
        let mut req = httparse::Request::new(&mut headers);
        match req.parse(&buf) {
            Ok(httparse::Status::Complete(_)) => {
                let target = req.path.unwrap_or("/");
                let (path, query) = target.split_once('?').unwrap_or((target, ""));
                return Ok(Request {
                    method: req.method.unwrap_or("").to_string(),
                    path: path.to_string(),
                    query: query.to_string(),
                    headers: req
                        .headers
                        .iter()
                        .map(|h| (h.name.to_string(), String::from_utf8_lossy(h.value).into_owned()))
                        .collect(),
                });
            }
            Ok(httparse::Status::Partial) if buf.len() < MAX_HEAD => {}
            Ok(httparse::Status::Partial) => return Err(HttpError::TooLong),
            Err(e) => return Err(HttpError::Malformed(e.to_string())),
        }
    }
}

/// Writes a whole response and closes.
pub fn respond(
    stream: &mut TcpStream,
    status: &str,
    content_type: &str,
    extra: &[String],
    body: &[u8],
    head_only: bool,
) {
    let mut head = format!(
        "HTTP/1.1 {status}\r\nContent-Type: {content_type}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\nConnection: close\r\n",
        body.len()
    );
    for h in extra {
        head.push_str(h);
        head.push_str("\r\n");
    }
    head.push_str("\r\n");
    let _ = stream.write_all(head.as_bytes());
    if !head_only {
        let _ = stream.write_all(body);
    }
    let _ = stream.flush();
}

pub fn refuse(stream: &mut TcpStream, status: &str) {
    respond(stream, status, "text/plain; charset=utf-8", &[], status.as_bytes(), false);
}

/// Percent-decodes a URL path; `None` when it is not valid UTF-8 or an escape is broken.
pub fn percent_decode(s: &str) -> Option<String> {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%' {
            let hex = std::str::from_utf8(b.get(i + 1..i + 3)?).ok()?;
            out.push(u8::from_str_radix(hex, 16).ok()?);
            i += 3;
        } else {
            out.push(b[i]);
            i += 1;
        }
    }
    String::from_utf8(out).ok()
}

/// Why a scene file is not served.
#[derive(Debug, PartialEq, Eq)]
pub enum SceneFileRefusal {
    /// Not one of the scene's files (404).
    NotFound,
    /// Names a place outside the scene's folder, or the file really is outside (403).
    Outside,
}

/// The bytes of the scene file that `relative` (the URL path after `/scene/`, decoded)
/// names: the scene's own file or one that its document refers to (buffers, images), read
/// only when its real path lies in the scene's folder.
pub fn scene_file(scene_path: &Path, relative: &str) -> Result<Vec<u8>, SceneFileRefusal> {
    let dir = scene_path.parent().unwrap_or(Path::new("."));
    let scope = FileScope::new(dir, false);
    let rel = Path::new(relative);
    if relative.is_empty() || relative.contains('\0') || scope.admits_text(rel).is_err() {
        return Err(SceneFileRefusal::Outside);
    }
    let wanted = normalise(&dir.join(rel));
    let doc =
        read_regular(scene_path, Some(&scope), 0, MAX_SCENE_FILE, None).map_err(|_| SceneFileRefusal::NotFound)?;
    let mut allowed = vec![normalise(scene_path)];
    if let Ok(files) = external_files(scene_path, &doc, &LoadOptions::default()) {
        allowed.extend(files.into_iter().map(|f| normalise(&f.path)));
    }
    if !allowed.contains(&wanted) {
        return Err(SceneFileRefusal::NotFound);
    }
    if wanted == normalise(scene_path) {
        return Ok(doc);
    }
    read_regular(&wanted, Some(&scope), 0, MAX_SCENE_FILE, None).map_err(|e| match e {
        crate::scene::gltf::FileError::Refused(_) => SceneFileRefusal::Outside,
        _ => SceneFileRefusal::NotFound,
    })
}

/// `a/./b/../c` as `a/c` (by text: the real path is checked when the file is opened).
fn normalise(p: &Path) -> PathBuf {
    let mut out = PathBuf::new();
    for c in p.components() {
        match c {
            std::path::Component::CurDir => {}
            std::path::Component::ParentDir => {
                out.pop();
            }
            other => out.push(other),
        }
    }
    out
}

/// A guess of a scene file's type from its name.
pub fn content_type(path: &str) -> &'static str {
    let lower = path.to_ascii_lowercase();
    match lower.rsplit('.').next() {
        Some("gltf") => "model/gltf+json",
        Some("glb") => "model/gltf-binary",
        Some("png") => "image/png",
        Some("jpg") | Some("jpeg") => "image/jpeg",
        _ => "application/octet-stream",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_come_from_the_query_or_the_cookie() {
        let req = |query: &str, cookie: Option<&str>| Request {
            method: "GET".into(),
            path: "/".into(),
            query: query.into(),
            headers: cookie.map(|c| vec![("Cookie".to_string(), c.to_string())]).unwrap_or_default(),
        };
        assert!(req("", None).has_token(None));
        assert!(!req("", None).has_token(Some("abc")));
        assert!(req("x=1&token=abc", None).has_token(Some("abc")));
        assert!(!req("token=abd", None).has_token(Some("abc")));
        assert!(!req("token=ab", None).has_token(Some("abc")));
        assert!(req("", Some("a=b; livebake_token=abc")).has_token(Some("abc")));
    }

    #[test]
    fn percent_decoding_refuses_broken_escapes() {
        assert_eq!(percent_decode("a%20b").as_deref(), Some("a b"));
        assert_eq!(percent_decode("%2e%2e/x").as_deref(), Some("../x"));
        assert_eq!(percent_decode("%zz"), None);
        assert_eq!(percent_decode("%4"), None);
    }
}
