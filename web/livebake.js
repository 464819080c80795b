// livebake's page: the scene lit by the live runtime's light map (docs/SERVE.md).
//
// WebGL 2 without a framework: the light map is the viewer's sparse page pyramid (a pool
// texture of 16×16-texel pages, a page table per layer and LOD, a shown LOD per cell and
// layer; web/lightmap.js), sampled by a GLSL twin of the viewer's shaders/lightmap.inc.wgsl,
// so that the page shows what `livebake view` shows. Each socket update writes exactly the pages it
// carries into the pool and the table entries and cell LODs it changes, as soon as it
// arrives (the socket lives in a worker, web/socket.js), outside the frame loop: one
// texSubImage2D per pool row of pages it touches, then a fence; the page acknowledges the
// update twice, once the upload calls returned and once the fence says the GPU did them.
// "Enter VR" opens a WebXR immersive-vr session: teleport (trigger, aiming at the floor)
// and snap turn (thumbstick left/right) on the controllers. On a desktop: the fly camera of
// `view` (drag to look, WASD/QE to move, wheel for speed).

import {
  fragmentShader, SHEET_KINDS, SKY_VERTEX_SHADER, skyShader, TONE_MAP_SHADER, TONE_MAP_VERTEX_SHADER,
  VERTEX_SHADER,
} from "./shaders.js";
import { LightMap } from "./lightmap.js";

// 4-byte words a vertex has in GEOMETRY (protocol.rs VERTEX_WORDS): 9 floats, then the
// vertex colour as 4 unorm16.
const VERTEX_WORDS = 11;
const SNAP_TURN = Math.PI / 6;
// The viewer's background (src/gpu/surface.rs: linear 0.02, 0.02, 0.025), sRGB-encoded as
// the page's framebuffer wants.
const srgb = (c) => (c <= 0.0031308 ? c * 12.92 : 1.055 * Math.pow(c, 1 / 2.4) - 0.055);
const CLEAR = [srgb(0.02), srgb(0.02), srgb(0.025)];
// The same background as exposed radiance in the float target (what the tone curve turns
// into 0.02, 0.02, 0.025).
const CLEAR_RADIANCE = [-Math.log(1 - 0.02), -Math.log(1 - 0.02), -Math.log(1 - 0.025)];

// ---------------------------------------------------------------- matrices (column-major)

function perspective(yfov, aspect, near, far) {
  const f = 1 / Math.tan(yfov / 2), nf = 1 / (near - far);
  return new Float32Array([f / aspect, 0, 0, 0, 0, f, 0, 0, 0, 0, (far + near) * nf, -1, 0, 0, 2 * far * near * nf, 0]);
}

function lookAt(eye, target, up) {
  const f = norm(sub(target, eye));
  const s = norm(cross(f, up));
  const u = cross(s, f);
  return new Float32Array([
    s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0,
    -dot(s, eye), -dot(u, eye), dot(f, eye), 1,
  ]);
}

function mul(a, b) {
  const o = new Float32Array(16);
  for (let c = 0; c < 4; c++)
    for (let r = 0; r < 4; r++) {
      let v = 0;
      for (let k = 0; k < 4; k++) v += a[k * 4 + r] * b[c * 4 + k];
      o[c * 4 + r] = v;
    }
  return o;
}

// The inverse of a column-major 4×4 matrix (Gauss–Jordan with partial pivoting, in doubles);
// the identity for a singular one.
function invert(m) {
  const a = Array.from({ length: 4 }, (_, r) => [0, 1, 2, 3].map((c) => m[c * 4 + r]).concat([0, 1, 2, 3].map((c) => (c === r ? 1 : 0))));
  for (let c = 0; c < 4; c++) {
    let p = c;
    for (let r = c + 1; r < 4; r++) if (Math.abs(a[r][c]) > Math.abs(a[p][c])) p = r;
    if (Math.abs(a[p][c]) < 1e-30) return new Float32Array([1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]);
    [a[c], a[p]] = [a[p], a[c]];
    const d = a[c][c];
    for (let k = 0; k < 8; k++) a[c][k] /= d;
    for (let r = 0; r < 4; r++) {
      if (r === c) continue;
      const f = a[r][c];
      for (let k = 0; k < 8; k++) a[r][k] -= f * a[c][k];
    }
  }
  const o = new Float32Array(16);
  for (let r = 0; r < 4; r++) for (let c = 0; c < 4; c++) o[c * 4 + r] = a[r][4 + c];
  return o;
}

const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const scale = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const norm = (a) => { const l = Math.hypot(a[0], a[1], a[2]) || 1; return [a[0] / l, a[1] / l, a[2] / l]; };

function compile(gl, type, source) {
  const s = gl.createShader(type);
  gl.shaderSource(s, source);
  gl.compileShader(s);
  if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
  return s;
}

function program(gl, vertex, fragment) {
  const p = gl.createProgram();
  gl.attachShader(p, compile(gl, gl.VERTEX_SHADER, vertex));
  gl.attachShader(p, compile(gl, gl.FRAGMENT_SHADER, fragment));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
  const u = {};
  const n = gl.getProgramParameter(p, gl.ACTIVE_UNIFORMS);
  for (let i = 0; i < n; i++) {
    const name = gl.getActiveUniform(p, i).name.replace(/\[0\]$/, "");
    u[name] = gl.getUniformLocation(p, gl.getActiveUniform(p, i).name);
  }
  return { program: p, u };
}

// ---------------------------------------------------------------- the scene on the GPU

function makeTexture(gl, width, height, pixels, srgb, wrap) {
  const t = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, t);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
  gl.texImage2D(gl.TEXTURE_2D, 0, srgb ? gl.SRGB8_ALPHA8 : gl.RGBA8, width, height, 0, gl.RGBA, gl.UNSIGNED_BYTE, pixels);
  const mode = { repeat: gl.REPEAT, mirrored_repeat: gl.MIRRORED_REPEAT, clamp_to_edge: gl.CLAMP_TO_EDGE };
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_S, mode[wrap?.[0]] ?? gl.REPEAT);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_WRAP_T, mode[wrap?.[1]] ?? gl.REPEAT);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR_MIPMAP_LINEAR);
  gl.generateMipmap(gl.TEXTURE_2D);
  return t;
}

// ---------------------------------------------------------------- the page

export function start(canvas, ui = {}) {
  const gl = canvas.getContext("webgl2", { antialias: false, xrCompatible: true, preserveDrawingBuffer: true });
  if (!gl) throw new Error("WebGL 2 is not available");
  // Surface programs by layers (1: the bundle layer alone, 2: both), kind and hdr
  // (fragmentShader), made when first drawn with: a scene without sheets never needs the
  // float-target ones.
  const shaders = new Map();
  function shader(layers, kind, hdr) {
    const key = `${layers} ${kind} ${hdr}`;
    let p = shaders.get(key);
    if (!p) {
      p = program(gl, VERTEX_SHADER, fragmentShader(layers, kind, hdr));
      shaders.set(key, p);
      if (state.scene) uploadUniformsOf(p);
    }
    return p;
  }
  const toneMap = program(gl, TONE_MAP_VERTEX_SHADER, TONE_MAP_SHADER);
  // The sky programs: [straight on screen, into the float target].
  const skyPrograms = [false, true].map((hdr) => program(gl, SKY_VERTEX_SHADER, skyShader(hdr)));
  // Rendering into RGBA16F needs this (core WebGL 2 only samples it). Without it a scene's
  // sheets are drawn as opaque surfaces (state.errors says so).
  const floatTargets = gl.getExtension("EXT_color_buffer_float");
  const white = makeTexture(gl, 1, 1, new Uint8Array([255, 255, 255, 255]), false);
  const params = new URLSearchParams(location.search);
  const state = {
    scene: null, vao: null, buffer: null, textures: [], lightmap: null,
    updates: 0, pagesWritten: 0, bytesUploaded: 0, uploadCalls: 0, fenced: 0, pendingFences: [], lastSeq: -1, fullSeen: 0, generation: 0,
    eye: [0, 0, 0], yaw: 0, pitch: 0, speed: 1, frames: 0, frameMs: [],
    xr: null, xrFrames: 0, lastViews: null, capture: null, socket: null, connected: false,
    scenesReceived: 0, errors: [],
  };
  const setStatus = (s) => { if (ui.status) ui.status.textContent = s; };

  function setStart(start) {
    state.eye = start.eye.slice();
    const f = norm(sub(start.target, start.eye));
    state.yaw = Math.atan2(f[0], -f[2]);
    state.pitch = Math.asin(Math.max(-1, Math.min(1, f[1])));
    state.speed = start.speed;
  }

  function forward() {
    const sy = Math.sin(state.yaw), cy = Math.cos(state.yaw), sp = Math.sin(state.pitch), cp = Math.cos(state.pitch);
    return [cp * sy, sp, -cp * cy];
  }

  function onScene(scene) {
    if (state.lightmap) state.lightmap.dispose();
    if (state.sky) { gl.deleteTexture(state.sky); state.sky = null; }
    state.skyUniform = null;
    for (const t of state.textures) if (t) gl.deleteTexture(t);
    state.scene = scene;
    // The batches each program draws (drawScene): opaque materials', MASK ones', then the
    // see-through sheets' (BLEND or transmission; Material::is_see_through).
    const sheet = (b) => scene.materials[b.material].blend || scene.materials[b.material].transmission > 0;
    const cutOut = (b) => scene.materials[b.material].alpha_cutoff != null;
    state.drawLists = {
      opaque: scene.batches.filter((b) => !sheet(b) && !cutOut(b)),
      cutOut: scene.batches.filter((b) => !sheet(b) && cutOut(b)),
      // Each with the centre of its corners' box (onGeometry): sheets are drawn farthest first.
      sheets: scene.batches.filter(sheet).map((b) => ({ ...b, centre: [0, 0, 0] })),
    };
    if (state.drawLists.sheets.length && !floatTargets) {
      state.errors.push("EXT_color_buffer_float is missing: see-through surfaces are drawn opaque");
      state.drawLists.opaque.push(...state.drawLists.sheets);
      state.drawLists.sheets = [];
    }
    state.textures = new Array(scene.textures.length).fill(null);
    state.lightmap = new LightMap(gl, scene);
    state.generation = scene.generation;
    state.scenesReceived++;
    if (!state.started) { setStart(scene.start); state.started = true; }
    uploadUniforms();
  }

  function onGeometry(buf) {
    const floats = new Float32Array(buf, 8);
    if (state.vao) { gl.deleteVertexArray(state.vao); gl.deleteBuffer(state.buffer); }
    state.vao = gl.createVertexArray();
    gl.bindVertexArray(state.vao);
    state.buffer = gl.createBuffer();
    gl.bindBuffer(gl.ARRAY_BUFFER, state.buffer);
    gl.bufferData(gl.ARRAY_BUFFER, floats, gl.STATIC_DRAW);
    const stride = VERTEX_WORDS * 4;
    [[0, 3, 0], [1, 2, 3], [2, 2, 5], [3, 2, 7]].forEach(([loc, n, off]) => {
      gl.enableVertexAttribArray(loc);
      gl.vertexAttribPointer(loc, n, gl.FLOAT, false, stride, off * 4);
    });
    gl.enableVertexAttribArray(4);
    gl.vertexAttribPointer(4, 4, gl.UNSIGNED_SHORT, true, stride, 9 * 4);
    gl.bindVertexArray(null);
    for (const b of state.drawLists?.sheets ?? []) {
      const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
      for (let v = b.first; v < b.first + b.count && (v + 1) * VERTEX_WORDS <= floats.length; v++) {
        for (let k = 0; k < 3; k++) {
          lo[k] = Math.min(lo[k], floats[v * VERTEX_WORDS + k]);
          hi[k] = Math.max(hi[k], floats[v * VERTEX_WORDS + k]);
        }
      }
      b.centre = [0, 1, 2].map((k) => (lo[k] <= hi[k] ? 0.5 * (lo[k] + hi[k]) : 0));
    }
  }

  // The sky picture (SKY message): RGBA f32 after a 12-byte header, for a scene whose sky is
  // not black (scene.sky gives its size).
  function onSky(buf) {
    const dv = new DataView(buf);
    const w = dv.getUint32(4, true), h = dv.getUint32(8, true);
    if (!state.scene?.sky || w !== state.scene.sky[0] || h !== state.scene.sky[1]) return;
    if (state.sky) gl.deleteTexture(state.sky);
    state.sky = null;
    const texels = new Float32Array(buf, 12, w * h * 4);
    // A uniform sky (every pixel the same): the frame is cleared to it, no sky is drawn (as
    // the viewer's SkyGpu::Uniform).
    state.skyUniform = texels.every((v, i) => v === texels[i & 3]) ? Array.from(texels.subarray(0, 3)) : null;
    if (state.skyUniform) return;
    state.sky = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, state.sky);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, w, h, 0, gl.RGBA, gl.FLOAT, texels);
  }

  function onTexture(buf) {
    const dv = new DataView(buf);
    const i = dv.getUint32(4, true), w = dv.getUint32(8, true), h = dv.getUint32(12, true);
    const info = state.scene?.textures[i];
    if (!info || w === 0 || h === 0) return;
    state.textures[i] = makeTexture(gl, w, h, new Uint8Array(buf, 16, w * h * 4), info.srgb, info.wrap);
  }

  // Applied as soon as it arrives (the socket's handler, not the frame loop).
  function onUpdate(buf) {
    if (!state.lightmap) return;
    const dv = new DataView(buf);
    const seq = dv.getUint32(4, true), generation = dv.getUint32(16, true);
    if (generation !== state.generation) return;
    const calls = state.lightmap.uploadCalls;
    const { pages, bytes } = state.lightmap.apply(buf);
    state.uploadCalls += state.lightmap.uploadCalls - calls;
    state.updates++;
    state.pagesWritten += pages;
    state.bytesUploaded += bytes;
    state.lastSeq = seq;
    if (dv.getUint8(1) & 1) state.fullSeen++;
    // The upload calls returned (stage 0); the GPU has done them once a fence placed after
    // them is signalled (stage 1): the server's publish-to-texture latency.
    ack(seq, 0);
    state.pendingFences.push({ seq, sync: gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0) });
    gl.flush();
    pollFences();
    if (state.onUpdate) state.onUpdate(buf);
  }

  function ack(seq, stage) {
    const b = new ArrayBuffer(16);
    const a = new DataView(b);
    a.setUint8(0, 2);
    a.setUint8(1, stage);
    a.setUint32(4, seq, true);
    a.setFloat64(8, performance.now(), true);
    send(b);
  }

  // WebGL updates a fence's status only between tasks: polled on timeouts while any is
  // pending (fences signal in order).
  let polling = false;
  function pollFences() {
    const f = state.pendingFences;
    while (f.length > 0 && gl.getSyncParameter(f[0].sync, gl.SYNC_STATUS) === gl.SIGNALED) {
      const { seq, sync } = f.shift();
      gl.deleteSync(sync);
      state.fenced++;
      ack(seq, 1);
    }
    if (f.length > 0 && !polling) {
      polling = true;
      setTimeout(() => { polling = false; pollFences(); }, 1);
    }
  }

  function send(buf) {
    if (state.socket && state.connected) state.socket.postMessage(buf, [buf]);
  }

  let lastPose = 0;
  function sendPose(eye, fwd, yfov, aspect, heightPx) {
    const now = performance.now();
    if (now - lastPose < 100) return;
    lastPose = now;
    const b = new ArrayBuffer(40);
    const d = new DataView(b);
    d.setUint8(0, 1);
    const target = add(eye, fwd);
    [...eye, ...target, yfov, aspect].forEach((v, i) => d.setFloat32(4 + 4 * i, v, true));
    d.setUint32(36, Math.max(1, Math.round(heightPx)), true);
    send(b);
    state.lastPoseSent = { eye: eye.slice(), target };
  }

  function connect() {
    if (params.has("static")) return loadStatic();
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const worker = new Worker(new URL("socket.js", import.meta.url));
    state.socket = worker;
    let shared = null;
    if (self.crossOriginIsolated) {
      shared = { data: new SharedArrayBuffer(RING_BYTES), state: new SharedArrayBuffer(4) };
      ring = { bytes: new Uint8Array(shared.data), state: new Int32Array(shared.state), read: 0 };
    }
    state.sharedRing = !!ring;
    worker.postMessage({ connect: `${proto}//${location.host}/socket${location.search}`, ring: shared });
    worker.onmessage = (ev) => {
      const m = ev.data;
      if (m.open) { state.connected = true; setStatus("waiting for first light…"); return; }
      if (m.closed) { state.connected = false; setStatus("disconnected"); return; }
      if (m.index !== undefined) posted.set(m.index, m);
      drain();
    };
  }

  // The socket's messages in the worker's order: posted ones, and those in the shared ring
  // (read here whenever the page runs: a message's task, a frame's start).
  const RING_BYTES = 16 << 20;
  let ring = null, nextIndex = 0;
  const posted = new Map();
  function ringRead(n) {
    const cap = ring.bytes.length, out = new Uint8Array(n);
    const first = Math.min(n, cap - ring.read);
    out.set(ring.bytes.subarray(ring.read, ring.read + first));
    out.set(ring.bytes.subarray(0, n - first), first);
    ring.read = (ring.read + n) % cap;
    return out;
  }
  function ringPeekIndex() {
    if (!ring || Atomics.load(ring.state, 0) === 0) return -1;
    const at = ring.read;
    const head = ringRead(4);
    ring.read = at;
    return new DataView(head.buffer).getUint32(0, true);
  }
  function drain() {
    for (;;) {
      let m = posted.get(nextIndex);
      if (m) posted.delete(nextIndex);
      else if (ringPeekIndex() === nextIndex) {
        const head = new DataView(ringRead(8).buffer);
        const n = head.getUint32(4, true), need = 8 + ((n + 3) & ~3);
        m = { binary: ringRead(n).buffer };
        ring.read = (ring.read + (need - 8 - n)) % ring.bytes.length;
        Atomics.sub(ring.state, 0, need);
      } else return;
      nextIndex++;
      handle(m);
    }
  }
  function handle(m) {
      try {
        if (m.text !== undefined) {
          const d = JSON.parse(m.text);
          if (d.type === "scene") onScene(d);
          return;
        }
        const kind = new Uint8Array(m.binary, 0, 1)[0];
        if (kind === 1) onGeometry(m.binary);
        else if (kind === 2) onTexture(m.binary);
        else if (kind === 3) onUpdate(m.binary);
        else if (kind === 4) onSky(m.binary);
        setStatus(`${state.updates} updates, ${state.pagesWritten} pages`);
      } catch (e) {
        state.errors.push(String(e));
        console.error(e);
      }
  }

  // --export-web: scene.json, geometry.bin, texture-N.bin and lightmap.bin beside the page.
  async function loadStatic() {
    const get = async (name) => { const r = await fetch(name); if (!r.ok) throw new Error(`${name}: ${r.status}`); return r; };
    onScene(await (await get("scene.json")).json());
    onGeometry(await (await get("geometry.bin")).arrayBuffer());
    for (let i = 0; i < state.scene.textures.length; i++) onTexture(await (await get(`texture-${i}.bin`)).arrayBuffer());
    if (state.scene.sky) onSky(await (await get("sky.bin")).arrayBuffer());
    onUpdate(await (await get("lightmap.bin")).arrayBuffer());
    setStatus("static export");
  }

  function uploadUniforms() {
    for (const p of shaders.values()) uploadUniformsOf(p);
  }
  function uploadUniformsOf(shader) {
    const s = state.scene, lm = state.lightmap, u = shader.u;
    gl.useProgram(shader.program);
    gl.uniform3fv(u.gridOrigin, s.grid.origin);
    gl.uniform1f(u.cellSize, s.grid.cell_size);
    gl.uniform3uiv(u.gridDims, s.grid.dims);
    gl.uniform1ui(u.lodCount, s.lods);
    gl.uniform1f(u.blendBand, s.blend_band);
    gl.uniform1ui(u.cellCount, lm.cellCount);
    gl.uniform4uiv(u.levels, lm.levels);
    gl.uniform1f(u.exposure, exposureOverride ?? s.exposure);
    gl.uniform1i(u.pool, 0);
    gl.uniform1i(u.pageTable, 1);
    gl.uniform1i(u.cellLod, 2);
    gl.uniform1i(u.baseColorTexture, 3);
    gl.uniform1i(u.emissiveTexture, 4);
    gl.uniform1i(u.transmissionTexture, 5);
  }
  let exposureOverride = params.has("exposure") ? Number(params.get("exposure")) : null;

  // The float target the surface programs write to when the scene has sheets (its depth
  // buffer beside it), of the drawn framebuffer's size.
  let radiance = null;
  function radianceTarget(width, height) {
    if (radiance && radiance.width === width && radiance.height === height) return radiance;
    if (radiance) { gl.deleteFramebuffer(radiance.fbo); gl.deleteTexture(radiance.tex); gl.deleteRenderbuffer(radiance.depth); }
    const tex = gl.createTexture();
    gl.bindTexture(gl.TEXTURE_2D, tex);
    gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA16F, width, height);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.NEAREST);
    gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.NEAREST);
    const depth = gl.createRenderbuffer();
    gl.bindRenderbuffer(gl.RENDERBUFFER, depth);
    gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT32F, width, height);
    const fbo = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, fbo);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, tex, 0);
    gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, depth);
    radiance = { fbo, tex, depth, width, height };
    return radiance;
  }

  // Draws the scene with `viewProj`, seen from `eye`, into `viewport` of `target` (a
  // framebuffer of `size` pixels; null: the canvas). A scene with see-through sheets is drawn
  // into the float target first (opaque surfaces, then the sheets farthest first, each scaling
  // what lies behind it and adding its own light), then tone-mapped into the viewport, as
  // `livebake view` does (src/gpu/surface.rs, tone_map.rs); any other scene straight in.
  function drawScene(viewProj, viewport, eye, target, size) {
    const s = state.scene, lm = state.lightmap;
    const hdr = Boolean(s && state.vao && state.drawLists.sheets.length);
    gl.bindFramebuffer(gl.FRAMEBUFFER, hdr ? radianceTarget(...size).fbo : target);
    gl.viewport(...viewport);
    gl.enable(gl.SCISSOR_TEST);
    gl.scissor(...viewport);
    const exposure = exposureOverride ?? s?.exposure ?? 1;
    const skyColour = (v) => (hdr ? v * exposure : srgb(1 - Math.exp(-v * exposure)));
    gl.clearColor(...(state.skyUniform ? state.skyUniform.map(skyColour) : hdr ? CLEAR_RADIANCE : CLEAR), 1);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    gl.disable(gl.SCISSOR_TEST);
    if (!s || !state.vao) return;
    gl.enable(gl.DEPTH_TEST);
    gl.depthFunc(gl.LESS);
    gl.frontFace(gl.CCW);
    gl.activeTexture(gl.TEXTURE0); gl.bindTexture(gl.TEXTURE_2D, lm.pool);
    gl.activeTexture(gl.TEXTURE1); gl.bindTexture(gl.TEXTURE_2D, lm.table.tex);
    gl.activeTexture(gl.TEXTURE2); gl.bindTexture(gl.TEXTURE_2D, lm.cells.tex);
    gl.bindVertexArray(state.vao);
    const layers = lm.layerPages[1] > 0 ? 2 : 1;
    const texture = (i) => (i != null && state.textures[i]) || white;
    const draw = (kind, batches) => {
      if (!batches.length) return;
      const p = shader(layers, kind, hdr), u = p.u;
      gl.useProgram(p.program);
      gl.uniformMatrix4fv(u.viewProj, false, viewProj);
      for (const b of batches) {
        const m = s.materials[b.material];
        gl.uniform4fv(u.baseColor, m.base_color);
        gl.uniform3fv(u.emission, m.emission);
        if (u.alphaCutoff) gl.uniform1f(u.alphaCutoff, m.alpha_cutoff ?? 0);
        if (u.blendMode) gl.uniform1i(u.blendMode, m.blend ? 1 : 0);
        if (u.transmission) gl.uniform1f(u.transmission, m.transmission);
        gl.activeTexture(gl.TEXTURE3);
        gl.bindTexture(gl.TEXTURE_2D, texture(m.base_color_texture));
        gl.activeTexture(gl.TEXTURE4);
        gl.bindTexture(gl.TEXTURE_2D, texture(m.emissive_texture));
        gl.activeTexture(gl.TEXTURE5);
        gl.bindTexture(gl.TEXTURE_2D, texture(m.transmission_texture));
        if (b.double_sided) gl.disable(gl.CULL_FACE);
        else { gl.enable(gl.CULL_FACE); gl.cullFace(gl.BACK); }
        gl.drawArrays(gl.TRIANGLES, b.first, b.count);
      }
    };
    // Opaque materials, then MASK ones with the program that cuts them out.
    draw("opaque", state.drawLists.opaque);
    draw("cutOut", state.drawLists.cutOut);
    if (state.sky) {
      // At the far plane, where the depth buffer was cleared: LEQUAL passes only where no
      // surface was drawn.
      const p = skyPrograms[hdr ? 1 : 0];
      gl.useProgram(p.program);
      gl.uniformMatrix4fv(p.u.invViewProj, false, invert(viewProj));
      gl.uniform1f(p.u.exposure, exposure);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, state.sky);
      gl.uniform1i(p.u.skyPicture, 0);
      gl.disable(gl.CULL_FACE);
      gl.depthFunc(gl.LEQUAL);
      gl.depthMask(false);
      gl.bindVertexArray(null);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      gl.bindVertexArray(state.vao);
      gl.depthMask(true);
      gl.depthFunc(gl.LESS);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, lm.pool);
    }
    if (hdr) {
      const far = (b) => { const d = sub(b.centre, eye); return dot(d, d); };
      const sheets = state.drawLists.sheets.slice().sort((a, b) => far(b) - far(a));
      // Sheets test depth but do not write it: what lies behind another sheet stays drawable.
      gl.depthMask(false);
      gl.enable(gl.BLEND);
      for (const b of sheets) {
        gl.blendFunc(gl.ZERO, gl.SRC_COLOR);
        draw(SHEET_KINDS[0], [b]);
        gl.blendFunc(gl.ONE, gl.ONE);
        draw(SHEET_KINDS[1], [b]);
      }
      gl.disable(gl.BLEND);
      gl.depthMask(true);
      gl.bindVertexArray(null);
      gl.bindFramebuffer(gl.FRAMEBUFFER, target);
      gl.disable(gl.DEPTH_TEST);
      gl.useProgram(toneMap.program);
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D, radiance.tex);
      gl.uniform1i(toneMap.u.radiance, 0);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      return;
    }
    gl.bindVertexArray(null);
  }

  // ------------------------------------------------------------ desktop: the fly camera
  const keys = new Set();
  addEventListener("keydown", (e) => keys.add(e.code));
  addEventListener("keyup", (e) => keys.delete(e.code));
  let drag = null;
  canvas.addEventListener("pointerdown", (e) => { drag = [e.clientX, e.clientY]; canvas.setPointerCapture(e.pointerId); });
  canvas.addEventListener("pointerup", () => { drag = null; });
  canvas.addEventListener("pointermove", (e) => {
    if (!drag) return;
    state.yaw += (e.clientX - drag[0]) * 0.003;
    state.pitch = Math.max(-1.55, Math.min(1.55, state.pitch - (e.clientY - drag[1]) * 0.003));
    drag = [e.clientX, e.clientY];
  });
  canvas.addEventListener("wheel", (e) => { state.speed *= Math.pow(1.25, -Math.sign(e.deltaY)); e.preventDefault(); }, { passive: false });

  let lastT = performance.now();
  function desktopFrame(t) {
    drain();
    pollFences();
    const dt = Math.min(0.1, (t - lastT) / 1000);
    lastT = t;
    if (!state.xr) {
      const f = forward(), r = norm(cross(f, [0, 1, 0]));
      const m = [0, 0, 0];
      if (keys.has("KeyW")) m[2] += 1;
      if (keys.has("KeyS")) m[2] -= 1;
      if (keys.has("KeyD")) m[0] += 1;
      if (keys.has("KeyA")) m[0] -= 1;
      if (keys.has("KeyE")) m[1] += 1;
      if (keys.has("KeyQ")) m[1] -= 1;
      const step = state.speed * dt;
      state.eye = add(state.eye, scale(add(add(scale(r, m[0]), [0, m[1], 0]), scale(f, m[2])), step));
      const w = Math.max(1, Math.round(canvas.clientWidth * devicePixelRatio));
      const h = Math.max(1, Math.round(canvas.clientHeight * devicePixelRatio));
      if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; }
      // At most one frame in flight: a slow GPU (software GL) queues frames otherwise, and
      // an update's upload waits behind all of them.
      if (state.frameFence && gl.getSyncParameter(state.frameFence, gl.SYNC_STATUS) === gl.SIGNALED) {
        gl.deleteSync(state.frameFence);
        state.frameFence = null;
      }
      if (state.scene && !state.frameFence) {
        const s = state.scene.start;
        const t0 = performance.now();
        const vp = mul(perspective(s.yfov, w / h, s.znear, s.zfar), lookAt(state.eye, add(state.eye, f), [0, 1, 0]));
        drawScene(vp, [0, 0, w, h], state.eye, null, [w, h]);
        countFrame(performance.now() - t0);
        state.frameFence = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
        sendPose(state.eye, f, s.yfov, w / h, h);
      }
    }
    requestAnimationFrame(desktopFrame);
  }

  function countFrame(ms) {
    state.frames++;
    state.frameMs.push(ms);
    if (state.frameMs.length >= 60) {
      const mean = state.frameMs.reduce((a, b) => a + b, 0) / state.frameMs.length;
      const b = new ArrayBuffer(16);
      const d = new DataView(b);
      d.setUint8(0, 3);
      d.setUint32(4, state.frameMs.length, true);
      d.setFloat64(8, mean, true);
      send(b);
      state.lastFrameMean = mean;
      state.frameMs = [];
    }
  }

  // ------------------------------------------------------------ WebXR
  // World = origin · local: the session's local space is placed at the start eye, facing
  // the start view (yaw only), and moved by teleports and snap turns. (Applied to the
  // matrices here rather than through an offset reference space.)
  function rotY(yaw) {
    // Rotation about +Y taking -Z to the view's forward (sin yaw, 0, -cos yaw).
    const c = Math.cos(yaw), s = Math.sin(yaw);
    return [[c, 0, -s], [0, 1, 0], [s, 0, c]]; // rows
  }
  const apply = (r, v) => [dot(r[0], v), dot(r[1], v), dot(r[2], v)];
  function originInverse() {
    const r = rotY(state.origin.yaw), p = state.origin.position;
    const t = [-dot([r[0][0], r[1][0], r[2][0]], p), -dot([r[0][1], r[1][1], r[2][1]], p), -dot([r[0][2], r[1][2], r[2][2]], p)];
    return new Float32Array([r[0][0], r[0][1], r[0][2], 0, r[1][0], r[1][1], r[1][2], 0, r[2][0], r[2][1], r[2][2], 0, t[0], t[1], t[2], 1]);
  }
  // A local-space point or direction in the world.
  const toWorld = (v) => add(apply(rotY(state.origin.yaw), v), state.origin.position);
  const dirToWorld = (v) => apply(rotY(state.origin.yaw), v);

  async function enterVR() {
    if (!navigator.xr) throw new Error("WebXR is not available");
    const session = await navigator.xr.requestSession("immersive-vr", { optionalFeatures: ["local-floor"] });
    await gl.makeXRCompatible();
    const scaleFactor = params.has("xrscale") ? Number(params.get("xrscale")) : 1;
    session.updateRenderState({
      baseLayer: new XRWebGLLayer(session, gl, { antialias: false, framebufferScaleFactor: scaleFactor }),
      depthNear: state.scene.start.znear,
      depthFar: state.scene.start.zfar,
    });
    const local = await session.requestReferenceSpace("local");
    state.xr = { session, space: local, turnHeld: new Set() };
    session.addEventListener("end", () => { state.xr = null; });
    session.addEventListener("selectend", (ev) => teleport(ev.frame, ev.inputSource));
    session.requestAnimationFrame(xrFrame);
    return session;
  }
  state.enterVR = enterVR;

  // Places the origin so that the head, where it is in the local space now, is at the
  // start eye facing the start view's yaw.
  function placeAtStart(localHead) {
    state.origin = { position: [0, 0, 0], yaw: state.yaw };
    state.origin.position = sub(state.eye, dirToWorld(localHead));
  }

  // Aims the controller's ray at the floor (the plane 1.6 m below the head) and moves the
  // viewer's feet where it hits.
  function teleport(frame, source) {
    if (!state.xr || !frame || !state.origin) return;
    const pose = frame.getPose(source.targetRaySpace, state.xr.space);
    const viewer = frame.getViewerPose(state.xr.space);
    if (!pose || !viewer) return;
    const m = pose.transform.matrix;
    const o = toWorld([m[12], m[13], m[14]]), d = dirToWorld([-m[8], -m[9], -m[10]]);
    const hp = viewer.transform.position;
    const head = toWorld([hp.x, hp.y, hp.z]);
    const floor = head[1] - 1.6;
    if (d[1] >= -1e-3) return;
    const hit = add(o, scale(d, (floor - o[1]) / d[1]));
    state.origin.position = add(state.origin.position, [hit[0] - head[0], 0, hit[2] - head[2]]);
    state.teleports = (state.teleports || 0) + 1;
  }

  function snapTurn(frame, viewer) {
    for (const source of state.xr.session.inputSources) {
      const axes = source.gamepad?.axes;
      if (!axes || axes.length < 4) continue;
      const x = axes[2];
      const held = state.xr.turnHeld;
      if (Math.abs(x) > 0.7 && !held.has(source.handedness)) {
        held.add(source.handedness);
        // Turn about the head: it stays where it is in the world.
        const hp = viewer.transform.position, local = [hp.x, hp.y, hp.z];
        const head = toWorld(local);
        state.origin.yaw += x > 0 ? SNAP_TURN : -SNAP_TURN;
        state.origin.position = sub(head, dirToWorld(local));
        state.snapTurns = (state.snapTurns || 0) + 1;
      } else if (Math.abs(x) < 0.3) held.delete(source.handedness);
    }
  }

  function xrFrame(t, frame) {
    const xr = state.xr;
    if (!xr) return;
    xr.session.requestAnimationFrame(xrFrame);
    try {
      // What arrived while the main thread was held (by the last frame's GPU work, in the
      // emulator) goes into the textures before this frame's draws.
      drain();
      pollFences();
      drawXR(frame);
    } catch (e) {
      if (state.errors.length < 10) state.errors.push(String(e && e.stack || e));
    }
  }

  function drawXR(frame) {
    const xr = state.xr;
    const pose = frame.getViewerPose(xr.space);
    const layer = xr.session.renderState.baseLayer;
    if (!pose || !state.scene) return;
    if (!state.origin) {
      const hp = pose.transform.position;
      placeAtStart([hp.x, hp.y, hp.z]);
    }
    snapTurn(frame, pose);
    const t0 = performance.now();
    const views = [];
    const inv = originInverse();
    for (const view of pose.views) {
      const vp = layer.getViewport(view);
      const viewport = [vp.x, vp.y, vp.width, vp.height];
      const m = view.transform.matrix;
      const position = toWorld([m[12], m[13], m[14]]);
      const size = [layer.framebufferWidth, layer.framebufferHeight];
      drawScene(mul(view.projectionMatrix, mul(view.transform.inverse.matrix, inv)), viewport, position, layer.framebuffer, size);
      views.push({
        eye: view.eye, viewport,
        position, forward: dirToWorld([-m[8], -m[9], -m[10]]), up: dirToWorld([m[4], m[5], m[6]]),
        projection: Array.from(view.projectionMatrix),
      });
    }
    // With ?finish the frame time includes the GPU's work (the bench), not only its submission.
    if (params.has("finish")) gl.finish();
    countFrame(performance.now() - t0);
    state.xrFrames++;
    state.lastViews = views;
    if (state.capture) {
      const c = state.capture;
      state.capture = null;
      const eyes = views.map((v) => {
        const [x, y, w, h] = v.viewport;
        const px = new Uint8Array(w * h * 4);
        gl.readPixels(x, y, w, h, gl.RGBA, gl.UNSIGNED_BYTE, px);
        return { ...v, width: w, height: h, pixels: px };
      });
      c(eyes);
    }
    const m = pose.transform.matrix;
    const p = views[0].projection;
    sendPose(toWorld([m[12], m[13], m[14]]), dirToWorld([-m[8], -m[9], -m[10]]), 2 * Math.atan(1 / p[5]), p[5] / p[0], views[0].viewport[3]);
  }

  // Test hooks: the page's state, and the pixels of each eye of the next XR frame.
  state.captureEyes = () => new Promise((resolve) => { state.capture = resolve; });
  window.livebake = state;

  if (ui.vrButton && navigator.xr) {
    navigator.xr.isSessionSupported("immersive-vr").then((ok) => {
      if (!ok) return;
      ui.vrButton.hidden = false;
      ui.vrButton.onclick = () => enterVR().catch((e) => setStatus(`VR: ${e.message}`));
    });
  }
  connect();
  requestAnimationFrame(desktopFrame);
  return state;
}
