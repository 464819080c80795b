//! Writes small glTF files for the loader tests: a JSON document plus one binary buffer that
//! can be saved as `.gltf` + `.bin`, `.gltf` with a `data:` URI, or `.glb`.

#![allow(dead_code)]

pub mod shards;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use serde_json::{Value, json};

pub const FLOAT: u32 = 5126;
pub const U8: u32 = 5121;
pub const U16: u32 = 5123;
pub const U32: u32 = 5125;

pub struct Doc {
    pub json: Value,
    pub bin: Vec<u8>,
}

impl Default for Doc {
    fn default() -> Self {
        Self::new()
    }
}

impl Doc {
    pub fn new() -> Doc {
        Doc { json: json!({ "asset": { "version": "2.0" }, "scenes": [{ "nodes": [] }], "scene": 0 }), bin: Vec::new() }
    }

    /// Appends `value` to the top-level array `key` and returns its index.
    pub fn push(&mut self, key: &str, value: Value) -> usize {
        let obj = self.json.as_object_mut().unwrap();
        let arr = obj.entry(key).or_insert_with(|| json!([])).as_array_mut().unwrap();
        arr.push(value);
        arr.len() - 1
    }

    /// A bufferView over `bytes` (4-byte aligned in the buffer).
    pub fn view(&mut self, bytes: &[u8], stride: Option<usize>) -> usize {
        while self.bin.len() % 4 != 0 {
            self.bin.push(0);
        }
        let offset = self.bin.len();
        self.bin.extend_from_slice(bytes);
        let mut v = json!({ "buffer": 0, "byteOffset": offset, "byteLength": bytes.len() });
        if let Some(s) = stride {
            v["byteStride"] = json!(s);
        }
        self.push("bufferViews", v)
    }

    pub fn accessor(&mut self, view: Option<usize>, component: u32, ty: &str, count: usize, extra: Value) -> usize {
        let mut a = json!({ "componentType": component, "type": ty, "count": count });
        if let Some(v) = view {
            a["bufferView"] = json!(v);
        }
        if let Value::Object(extra) = extra {
            for (k, v) in extra {
                a[k] = v;
            }
        }
        self.push("accessors", a)
    }

    /// VEC3 float accessor with min/max (over the finite values, as the spec requires numbers).
    pub fn vec3(&mut self, data: &[[f32; 3]]) -> usize {
        let bytes: Vec<u8> = data.iter().flatten().flat_map(|f| f.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        let (min, max) = min_max(data);
        self.accessor(Some(view), FLOAT, "VEC3", data.len(), json!({ "min": min, "max": max }))
    }

    pub fn vec2(&mut self, data: &[[f32; 2]]) -> usize {
        let bytes: Vec<u8> = data.iter().flatten().flat_map(|f| f.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        self.accessor(Some(view), FLOAT, "VEC2", data.len(), json!({}))
    }

    pub fn indices_u16(&mut self, idx: &[u16]) -> usize {
        let bytes: Vec<u8> = idx.iter().flat_map(|i| i.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        self.accessor(Some(view), U16, "SCALAR", idx.len(), json!({}))
    }

    pub fn indices_u32(&mut self, idx: &[u32]) -> usize {
        let bytes: Vec<u8> = idx.iter().flat_map(|i| i.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        self.accessor(Some(view), U32, "SCALAR", idx.len(), json!({}))
    }

    pub fn indices_u8(&mut self, idx: &[u8]) -> usize {
        let view = self.view(idx, None);
        self.accessor(Some(view), U8, "SCALAR", idx.len(), json!({}))
    }

    /// A mesh with the given primitives, on a new root node with the given extra node
    /// properties (name, transform...). Returns the node index.
    pub fn mesh_node(&mut self, primitives: Vec<Value>, node: Value) -> usize {
        let mesh =
            self.push("meshes", json!({ "name": format!("mesh{}", self.count("meshes")), "primitives": primitives }));
        let mut n = node;
        n["mesh"] = json!(mesh);
        let index = self.push("nodes", n);
        self.add_root(index);
        index
    }

    pub fn add_root(&mut self, node: usize) {
        self.json["scenes"][0]["nodes"].as_array_mut().unwrap().push(json!(node));
    }

    pub fn count(&self, key: &str) -> usize {
        self.json.get(key).and_then(Value::as_array).map_or(0, Vec::len)
    }

    /// A triangle-list primitive from positions (and optional normals / indices).
    pub fn prim(&mut self, positions: &[[f32; 3]], normals: Option<&[[f32; 3]]>, indices: Option<&[u16]>) -> Value {
        let mut p = json!({ "attributes": { "POSITION": self.vec3(positions) } });
        if let Some(n) = normals {
            p["attributes"]["NORMAL"] = json!(self.vec3(n));
        }
        if let Some(i) = indices {
            p["indices"] = json!(self.indices_u16(i));
        }
        p
    }

    /// The document with buffer 0 pointing at `uri` (or the GLB BIN chunk if `None`).
    pub fn json_with_buffer(&self, uri: Option<String>) -> Value {
        let mut j = self.json.clone();
        if !self.bin.is_empty() {
            let mut b = json!({ "byteLength": self.bin.len() });
            if let Some(u) = uri {
                b["uri"] = json!(u);
            }
            j["buffers"] = json!([b]);
        }
        j
    }

    /// `<name>.gltf` + `<name>.bin`.
    pub fn write_gltf(&self, dir: &Path, name: &str) -> PathBuf {
        let bin_name = format!("{name}.bin");
        std::fs::write(dir.join(&bin_name), &self.bin).unwrap();
        let path = dir.join(format!("{name}.gltf"));
        let j = self.json_with_buffer(Some(bin_name));
        std::fs::write(&path, serde_json::to_vec_pretty(&j).unwrap()).unwrap();
        path
    }

    /// `<name>.gltf` with the buffer embedded as a base64 `data:` URI.
    pub fn write_data_uri(&self, dir: &Path, name: &str) -> PathBuf {
        let uri = format!("data:application/octet-stream;base64,{}", base64(&self.bin));
        let path = dir.join(format!("{name}.gltf"));
        std::fs::write(&path, serde_json::to_vec(&self.json_with_buffer(Some(uri))).unwrap()).unwrap();
        path
    }

    /// `<name>.glb`.
    pub fn write_glb(&self, dir: &Path, name: &str) -> PathBuf {
        let path = dir.join(format!("{name}.glb"));
        std::fs::write(&path, glb(&self.json_with_buffer(None), &self.bin)).unwrap();
        path
    }
}

fn min_max(data: &[[f32; 3]]) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::MAX; 3];
    let mut hi = [f32::MIN; 3];
    for p in data {
        for k in 0..3 {
            if p[k].is_finite() {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
    }
    if data.iter().all(|p| !p.iter().all(|c| c.is_finite())) {
        return ([0.0; 3], [0.0; 3]);
    }
    (lo, hi)
}

/// A GLB container: header, JSON chunk (space-padded), BIN chunk (zero-padded) if any.
pub fn glb(json: &Value, bin: &[u8]) -> Vec<u8> {
    let mut j = serde_json::to_vec(json).unwrap();
    while j.len() % 4 != 0 {
        j.push(b' ');
    }
    let mut b = bin.to_vec();
    while b.len() % 4 != 0 {
        b.push(0);
    }
    let total = 12 + 8 + j.len() + if b.is_empty() { 0 } else { 8 + b.len() };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(j.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&j);
    if !b.is_empty() {
        out.extend_from_slice(&(b.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&b);
    }
    out
}

pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut s = String::new();
    for c in bytes.chunks(3) {
        let n =
            (u32::from(c[0]) << 16) | (u32::from(*c.get(1).unwrap_or(&0)) << 8) | u32::from(*c.get(2).unwrap_or(&0));
        for k in 0..4 {
            if k <= c.len() {
                s.push(A[(n >> (18 - 6 * k) & 63) as usize] as char);
            } else {
                s.push('=');
            }
        }
    }
    s
}

/// A `w × h` RGBA PNG.
pub fn png(w: u32, h: u32, pixel: impl Fn(u32, u32) -> [u8; 4]) -> Vec<u8> {
    let img = image::RgbaImage::from_fn(w, h, |x, y| image::Rgba(pixel(x, y)));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png).unwrap();
    out.into_inner()
}

/// A cube `[0, s]³`: 4 vertices per face with the face's normal, CCW seen from outside.
pub fn cube(s: f32) -> (Vec<[f32; 3]>, Vec<[f32; 3]>, Vec<u16>) {
    let faces: [([f32; 3], [[f32; 3]; 4]); 6] = [
        ([-1.0, 0.0, 0.0], [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 1.0, 0.0]]),
        ([1.0, 0.0, 0.0], [[1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [1.0, 1.0, 1.0], [1.0, 0.0, 1.0]]),
        ([0.0, -1.0, 0.0], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 0.0, 1.0], [0.0, 0.0, 1.0]]),
        ([0.0, 1.0, 0.0], [[0.0, 1.0, 0.0], [0.0, 1.0, 1.0], [1.0, 1.0, 1.0], [1.0, 1.0, 0.0]]),
        ([0.0, 0.0, -1.0], [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [1.0, 0.0, 0.0]]),
        ([0.0, 0.0, 1.0], [[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.0, 1.0, 1.0]]),
    ];
    let (mut p, mut n, mut idx) = (Vec::new(), Vec::new(), Vec::new());
    for (normal, corners) in faces {
        let base = p.len() as u16;
        p.extend(corners.map(|c| c.map(|x| x * s)));
        n.extend([normal; 4]);
        idx.extend([base, base + 1, base + 2, base, base + 2, base + 3]);
    }
    (p, n, idx)
}

/// A `width × height` PNG of one-bit grey pixels, all black: a decompression bomb (a few
/// hundred kB that decode to `width × height` pixels). Written by hand: no encoder here
/// writes one-bit PNGs. The pixel rows (a filter byte and `width / 8` zero bytes each) are
/// one deflate block of fixed Huffman codes: a literal zero, then copies of 258 bytes at
/// distance 1.
pub fn png_bomb(width: u32, height: u32) -> Vec<u8> {
    let raw_len = height as u64 * (1 + width.div_ceil(8) as u64);
    let mut bits = BitWriter::default();
    bits.put(1, 1); // last block
    bits.put(1, 2); // fixed Huffman codes
    let (literal_zero, length_258, distance_1, end) = ((0x30, 8), (0xC5, 8), (0, 5), (0, 7));
    bits.code(literal_zero);
    let mut left = raw_len - 1;
    while left >= 258 {
        bits.code(length_258);
        bits.code(distance_1);
        left -= 258;
    }
    for _ in 0..left {
        bits.code(literal_zero);
    }
    bits.code(end);
    let mut zlib = vec![0x78, 0x01];
    zlib.extend(bits.finish());
    // Adler-32 of zeros: a stays 1, b adds it once a byte.
    let adler = ((raw_len % 65521) << 16 | 1) as u32;
    zlib.extend(adler.to_be_bytes());

    let mut out = b"\x89PNG\r\n\x1a\n".to_vec();
    let mut ihdr = Vec::new();
    ihdr.extend(width.to_be_bytes());
    ihdr.extend(height.to_be_bytes());
    ihdr.extend([1, 0, 0, 0, 0]); // bit depth 1, grey, deflate, adaptive filters, no interlace
    png_chunk(&mut out, b"IHDR", &ihdr);
    png_chunk(&mut out, b"IDAT", &zlib);
    png_chunk(&mut out, b"IEND", &[]);
    out
}

fn png_chunk(out: &mut Vec<u8>, kind: &[u8; 4], data: &[u8]) {
    out.extend((data.len() as u32).to_be_bytes());
    let start = out.len();
    out.extend(kind);
    out.extend(data);
    let crc = crc32(&out[start..]);
    out.extend(crc.to_be_bytes());
}

fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= b as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 { 0xEDB8_8320 ^ (crc >> 1) } else { crc >> 1 };
        }
    }
    !crc
}

/// Deflate's bit order: values least significant bit first, Huffman codes most significant
/// bit first.
#[derive(Default)]
struct BitWriter {
    bytes: Vec<u8>,
    acc: u64,
    count: u32,
}

impl BitWriter {
    fn put(&mut self, value: u32, n: u32) {
        self.acc |= (value as u64) << self.count;
        self.count += n;
        while self.count >= 8 {
            self.bytes.push(self.acc as u8);
            self.acc >>= 8;
            self.count -= 8;
        }
    }

    fn code(&mut self, (code, n): (u32, u32)) {
        self.put(code.reverse_bits() >> (32 - n), n);
    }

    fn finish(mut self) -> Vec<u8> {
        if self.count > 0 {
            self.bytes.push(self.acc as u8);
        }
        self.bytes
    }
}

// ---------------------------------------------------------------------------------------------
// the command, run as a process

/// Runs `livebake args…` in `cwd` (no RUST_LOG from the environment: default logging).
pub fn livebake(cwd: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_livebake"))
        .args(args)
        .current_dir(cwd)
        .env_remove("RUST_LOG")
        // No display: `livebake` without arguments runs headless.
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .output()
        .expect("cannot run livebake")
}

pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Runs and requires success; returns stdout.
#[track_caller]
pub fn ok(cwd: &Path, args: &[&str]) -> String {
    let out = livebake(cwd, args);
    let stderr = text(&out.stderr);
    assert!(out.status.success(), "livebake {args:?} failed ({}):\n{stderr}", out.status);
    assert!(!stderr.contains("panicked"), "{stderr}");
    text(&out.stdout)
}

/// Runs and requires failure with an `error:` line containing every one of `needles`
/// (case-insensitive), an exit code (not an abort) and no panic. Returns the exit code: 1, or
/// 2 for what the argument parser refuses.
#[track_caller]
pub fn fails(cwd: &Path, args: &[&str], needles: &[&str]) -> i32 {
    let out = livebake(cwd, args);
    let stderr = text(&out.stderr);
    assert!(!out.status.success(), "livebake {args:?} succeeded but should not have:\n{stderr}");
    assert!(!stderr.contains("panicked"), "livebake {args:?} panicked:\n{stderr}");
    let code = out.status.code().unwrap_or_else(|| panic!("livebake {args:?} was killed ({}):\n{stderr}", out.status));
    assert!(code == 1 || code == 2, "livebake {args:?} exited with {code}:\n{stderr}");
    let line = stderr
        .lines()
        .find(|l| l.starts_with("error:"))
        .unwrap_or_else(|| panic!("livebake {args:?}: no `error:` line in\n{stderr}"));
    for n in needles {
        assert!(line.to_lowercase().contains(&n.to_lowercase()), "livebake {args:?}: {line:?} does not mention {n:?}");
    }
    code
}

/// Bakes `scene` with `config`; on the GPU backend, checks that it really traced every
/// batch (it falls back to the CPU on a GPU error) and resolved every pixel.
pub fn bake(scene: &livebake::scene::Scene, config: &livebake::bake::BakeConfig) -> livebake::bake::BakeOutput {
    let progress = livebake::progress::NoProgress;
    let out = livebake::bake::bake(&std::sync::Arc::new(scene.clone()), config, &progress).expect("bake");
    if config.backend == livebake::bake::BackendKind::Gpu {
        assert_eq!(out.report.backend, "gpu");
        for lod in &out.report.lods {
            let pass = &lod.bundle.as_ref().expect("bundle report").stats.pass;
            assert_eq!((pass.cpu_fallback_batches, pass.unresolved_pixels), (0, 0));
        }
    }
    out
}
