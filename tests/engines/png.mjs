// Test helpers for the engine checks: a PNG decoder (8-bit RGB/RGBA, non-interlaced: what
// livebake writes) with Node's zlib, the sRGB decoding curve, and bilinear filtering with
// clamp-to-edge (what a GPU sampler with LINEAR/CLAMP_TO_EDGE does on sRGB textures:
// decode each texel, then filter).
import zlib from "zlib";

export function decodePng(bytes) {
  const sig = Buffer.from([0x89, 0x50, 0x4e, 0x47, 0x0d, 0x0a, 0x1a, 0x0a]);
  if (!bytes.subarray(0, 8).equals(sig)) throw new Error("not a PNG");
  let pos = 8;
  let width = 0, height = 0, channels = 0;
  const idat = [];
  while (pos < bytes.length) {
    const len = bytes.readUInt32BE(pos);
    const type = bytes.toString("latin1", pos + 4, pos + 8);
    const data = bytes.subarray(pos + 8, pos + 8 + len);
    if (type === "IHDR") {
      width = data.readUInt32BE(0);
      height = data.readUInt32BE(4);
      const [depth, colour, , , interlace] = data.subarray(8, 13);
      channels = { 2: 3, 6: 4 }[colour];
      if (depth !== 8 || !channels || interlace !== 0) throw new Error(`unsupported PNG (depth ${depth}, colour ${colour})`);
    } else if (type === "IDAT") {
      idat.push(data);
    }
    pos += 12 + len;
  }
  const raw = zlib.inflateSync(Buffer.concat(idat));
  const stride = width * channels;
  const out = new Uint8Array(height * stride);
  for (let y = 0; y < height; y++) {
    const filter = raw[y * (stride + 1)];
    const line = raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1));
    for (let i = 0; i < stride; i++) {
      const a = i >= channels ? out[y * stride + i - channels] : 0;
      const b = y > 0 ? out[(y - 1) * stride + i] : 0;
      const c = i >= channels && y > 0 ? out[(y - 1) * stride + i - channels] : 0;
      const p = a + b - c;
      const [pa, pb, pc] = [Math.abs(p - a), Math.abs(p - b), Math.abs(p - c)];
      const paeth = pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
      const pred = [0, a, b, (a + b) >> 1, paeth][filter];
      out[y * stride + i] = (line[i] + pred) & 0xff;
    }
  }
  return { width, height, channels, data: out };
}

export const srgbDecode = (v) => (v <= 0.04045 ? v / 12.92 : Math.pow((v + 0.055) / 1.055, 2.4));

export function bilinearSrgb(img, u, v) {
  const x = u * img.width - 0.5, y = v * img.height - 0.5;
  const x0 = Math.floor(x), y0 = Math.floor(y);
  const fx = x - x0, fy = y - y0;
  const texel = (px, py) => {
    px = Math.min(Math.max(px, 0), img.width - 1);
    py = Math.min(Math.max(py, 0), img.height - 1);
    const o = (py * img.width + px) * img.channels;
    return [0, 1, 2].map((c) => srgbDecode(img.data[o + c] / 255));
  };
  const [a, b, c, d] = [texel(x0, y0), texel(x0 + 1, y0), texel(x0, y0 + 1), texel(x0 + 1, y0 + 1)];
  return [0, 1, 2].map((k) => a[k] * (1 - fx) * (1 - fy) + b[k] * fx * (1 - fy) + c[k] * (1 - fx) * fy + d[k] * fx * fy);
}

// Index of each triangle by its corner positions: "x,y,z|x,y,z|x,y,z" sorted.
const key = (p) => p.map((q) => q.join(",")).sort().join("|");

// For each sample {mesh, primitive, corners: [[x,y,z]×3], weights: [w×3]}: the interpolated
// light-map UV the engine has for that point, found through `lookup(mesh, primitive)` →
// {positions, uvs, indices} (flat arrays of the engine's vertex data).
export function samplePoints(samples, lookup) {
  const cache = new Map();
  return samples.map((s) => {
    const id = `${s.mesh}/${s.primitive}`;
    if (!cache.has(id)) {
      const g = lookup(s.mesh, s.primitive);
      if (!g) throw new Error(`no engine mesh for glTF mesh ${s.mesh} primitive ${s.primitive}`);
      const byCorners = new Map();
      for (let t = 0; t < g.indices.length / 3; t++) {
        const vs = [0, 1, 2].map((k) => g.indices[3 * t + k]);
        byCorners.set(key(vs.map((v) => Array.from(g.positions.slice(3 * v, 3 * v + 3)))), vs);
      }
      cache.set(id, { g, byCorners });
    }
    const { g, byCorners } = cache.get(id);
    const corners = s.corners.map((c) => c.map(Math.fround));
    const vs = byCorners.get(key(corners));
    if (!vs) throw new Error(`triangle ${JSON.stringify(s.corners)} not found in the engine's mesh ${id}`);
    let u = 0, v = 0;
    for (const vi of vs) {
      const p = Array.from(g.positions.slice(3 * vi, 3 * vi + 3));
      const k = corners.findIndex((c) => c.every((x, i) => x === p[i]));
      u += s.weights[k] * g.uvs[2 * vi];
      v += s.weights[k] * g.uvs[2 * vi + 1];
    }
    return [u, v];
  });
}
