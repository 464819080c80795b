// The page's shaders (web/livebake.js): the light map's GLSL twin of the viewer's
// shaders/lightmap.inc.wgsl and surface.wgsl's lit view.

// Columns of the integer textures holding the page tables and the cells' LODs.
export const TABLE_W = 4096;
// Pages a row of the pool texture holds.
export const POOL_COLUMNS = 64;

// The tone curve and sRGB encoding (common.inc.wgsl's), shared by both programs below.
const TONE_CURVE = `
vec3 toneMap(vec3 exposed) { return vec3(1.0) - exp(-max(exposed, vec3(0.0))); }

vec3 srgb_encode(vec3 c) {
  vec3 lo = c * 12.92;
  vec3 hi = 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055;
  return mix(hi, lo, vec3(lessThanEqual(c, vec3(0.0031308))));
}`;

export const VERTEX_SHADER = `#version 300 es
layout(location = 0) in vec3 position;
layout(location = 1) in vec2 uv0;
layout(location = 2) in vec2 lightmapFront;
layout(location = 3) in vec2 lightmapBack;
layout(location = 4) in vec4 color;
uniform mat4 viewProj;
out vec3 world;
out vec2 vUv0;
out vec2 vFront;
out vec2 vBack;
out vec4 vColor;
void main() {
  gl_Position = viewProj * vec4(position, 1.0);
  world = position;
  vUv0 = uv0;
  vFront = lightmapFront;
  vBack = lightmapBack;
  vColor = color;
}`;

// The twin of shaders/lightmap.inc.wgsl and surface.wgsl's lit view.
// With the punctual layer (layers = 2) or without: the page draws with the one-layer program
// while the punctual layer holds no page (a scene without punctual lights), which reads zero
// there. A branch on a uniform would not do: under software GL (SwiftShader) the empty layer
// still cost about a third of the frame behind one, and as much behind a loop.
// `kind`, as surface.wgsl's entry points:
// - "opaque";
// - "cutOut", a MASK material's program: fragments whose alpha is below `alphaCutoff` are
//   discarded (a program of its own: a discard costs every fragment its early depth test);
// - "sheetFilter" and "sheetLight", a see-through sheet's two draws (BLEND or transmission):
//   what lies behind × the light the sheet lets through, then plus its own.
// With `hdr`, the program writes exposed linear radiance into a float target that
// TONE_MAP_SHADER then puts on screen (a scene with sheets: their sums must be taken before
// the tone curve); without, it tone-maps and encodes itself (every other scene: one pass).
export const SHEET_KINDS = ["sheetFilter", "sheetLight"];
export const fragmentShader = (layers, kind = "opaque", hdr = false) => `#version 300 es
${layers > 1 ? "#define PUNCTUAL_LAYER" : ""}
${kind === "cutOut" ? "#define CUT_OUT" : ""}
${SHEET_KINDS.includes(kind) ? "#define SHEET" : ""}
${kind === "sheetFilter" ? "#define SHEET_FILTER" : ""}
${hdr ? "#define HDR_OUT" : ""}
precision highp float;
precision highp int;
precision highp usampler2D;
const float PI = 3.14159265358979;
const int PAGE_SIDE = 16;
const int PAGE_SHIFT = 4;
const uint NO_PAGE = 0xffffffffu;
const uint MAX_LODS = 8u;
const uint TABLE_W = ${TABLE_W}u;
const uint TABLE_SHIFT = ${Math.log2(TABLE_W)}u;
const uint POOL_SHIFT = ${Math.log2(POOL_COLUMNS)}u;
uniform sampler2D pool;
uniform usampler2D pageTable;
uniform usampler2D cellLod;
uniform sampler2D baseColorTexture;
uniform sampler2D emissiveTexture;
uniform sampler2D transmissionTexture;
uniform vec3 gridOrigin;
uniform float cellSize;
uniform uvec3 gridDims;
uniform uint lodCount;
uniform float blendBand;
uniform uint cellCount;
uniform uvec4 levels[16]; // pages_x, pages_y, table offset (layer * MAX_LODS + lod)
uniform vec4 baseColor;
uniform vec3 emission;
uniform float alphaCutoff;
uniform bool blendMode;
uniform float transmission;
uniform float exposure;
in vec3 world;
in vec2 vUv0;
in vec2 vFront;
in vec2 vBack;
in vec4 vColor;
out vec4 colour;

// TABLE_W, POOL_COLUMNS and PAGE_SIDE are powers of two: shifts and masks, not integer
// divisions.
uint tableEntry(uint i) { return texelFetch(pageTable, ivec2(int(i & (TABLE_W - 1u)), int(i >> TABLE_SHIFT)), 0).r; }
uint cellEntry(uint i) { return texelFetch(cellLod, ivec2(int(i & (TABLE_W - 1u)), int(i >> TABLE_SHIFT)), 0).r; }

// One pixel of a LOD of a layer (level: its page table's pages_x, pages_y, offset): (E, 1)
// when published, 0 outside the page table, in a missing page or where nothing was published.
vec4 lm_tap(uvec4 level, ivec2 px) {
  if (px.x < 0 || px.y < 0) return vec4(0.0);
  ivec2 page = px >> PAGE_SHIFT;
  if (uint(page.x) >= level.x || uint(page.y) >= level.y) return vec4(0.0);
  uint slot = tableEntry(level.z + uint(page.y) * level.x + uint(page.x));
  if (slot == NO_PAGE) return vec4(0.0);
  ivec2 origin = ivec2(int(slot & ((1u << POOL_SHIFT) - 1u)), int(slot >> POOL_SHIFT)) * PAGE_SIDE;
  vec4 t = texelFetch(pool, origin + (px & (PAGE_SIDE - 1)), 0);
  if (t.a > 0.0) return vec4(t.rgb, 1.0);
  return vec4(0.0);
}

vec3 lm_value(uint layer, uint lod, vec2 uv) {
  int k = int(min(lod, lodCount - 1u));
  for (; k >= 0; k--) {
    vec2 p = uv * float(1u << uint(k)) - vec2(0.5);
    vec2 p0 = floor(p);
    vec2 f = p - p0;
    ivec2 i0 = ivec2(p0);
    uvec4 level = levels[layer * MAX_LODS + uint(k)];
    vec4 t00 = lm_tap(level, i0);
    vec4 t10 = lm_tap(level, i0 + ivec2(1, 0));
    vec4 t01 = lm_tap(level, i0 + ivec2(0, 1));
    vec4 t11 = lm_tap(level, i0 + ivec2(1, 1));
    float w00 = (1.0 - f.x) * (1.0 - f.y) * t00.a;
    float w10 = f.x * (1.0 - f.y) * t10.a;
    float w01 = (1.0 - f.x) * f.y * t01.a;
    float w11 = f.x * f.y * t11.a;
    float wsum = w00 + w10 + w01 + w11;
    if (wsum > 0.0) return (t00.rgb * w00 + t10.rgb * w10 + t01.rgb * w01 + t11.rgb * w11) / wsum;
  }
  return vec3(0.0);
}

uvec3 lm_cell_coords(vec3 p) {
  vec3 q = floor((p - gridOrigin) / cellSize);
  return uvec3(clamp(q, vec3(0.0), vec3(gridDims - uvec3(1u))));
}

uint lm_cell_index(uvec3 c) { return c.x + gridDims.x * (c.y + gridDims.y * c.z); }

// The neighbour n across one face of the cell, d metres from it: how much of its coarser
// level blends in (w), and that level (kLow).
void lm_neighbour(uint lods, uint k, uvec3 n, float d, inout float w, inout uint kLow) {
  if (d >= blendBand) return;
  uint kn = cellEntry(lods + lm_cell_index(n));
  float band = blendBand / float(1u << kn);
  if (kn >= k || d >= band) return;
  w = max(w, clamp(1.0 - max(d, 0.0) / band, 0.0, 1.0));
  kLow = min(kLow, kn);
}

// Ifs that most pixels do not take are loops run once or never: software GL (SwiftShader)
// runs an if's body under a lane mask even when no pixel of the group takes it, but skips a
// loop that no pixel enters (measured: a sixth of the frame). On a GPU the two are the same.
vec3 lm_layer_irradiance(uint layer, uvec3 c, vec3 p, vec2 uv) {
  uint lods = layer * cellCount;
  uint k = cellEntry(lods + lm_cell_index(c));
  vec3 base = lm_value(layer, k, uv);
  vec3 lo = gridOrigin + vec3(c) * cellSize;
  vec3 below = p - lo;
  vec3 above = lo + vec3(cellSize) - p;
  // Within the band of a face of the cell: a neighbour may blend in.
  float nearest = min(min(below.x, below.y), min(below.z, min(above.x, min(above.y, above.z))));
  bool near = k > 0u && blendBand > 0.0 && nearest < blendBand;
  float w = 0.0;
  uint kLow = k;
  for (int once = 0; once < (near ? 1 : 0); once++) {
    if (c.x > 0u) lm_neighbour(lods, k, c - uvec3(1u, 0u, 0u), below.x, w, kLow);
    if (c.x + 1u < gridDims.x) lm_neighbour(lods, k, c + uvec3(1u, 0u, 0u), above.x, w, kLow);
    if (c.y > 0u) lm_neighbour(lods, k, c - uvec3(0u, 1u, 0u), below.y, w, kLow);
    if (c.y + 1u < gridDims.y) lm_neighbour(lods, k, c + uvec3(0u, 1u, 0u), above.y, w, kLow);
    if (c.z > 0u) lm_neighbour(lods, k, c - uvec3(0u, 0u, 1u), below.z, w, kLow);
    if (c.z + 1u < gridDims.z) lm_neighbour(lods, k, c + uvec3(0u, 0u, 1u), above.z, w, kLow);
  }
  // Next to a coarser neighbour: its level blends in.
  for (int once = 0; once < (kLow < k ? 1 : 0); once++) base = base * (1.0 - w) + lm_value(layer, kLow, uv) * w;
  return base;
}

${TONE_CURVE}

void main() {
  vec4 baseSample = baseColor * texture(baseColorTexture, vUv0) * vColor;
  float alpha = baseSample.a;
#ifdef CUT_OUT
  if (alpha < alphaCutoff) discard;
#endif
  vec3 albedo = clamp(baseSample.rgb, vec3(0.0), vec3(1.0));
#ifdef SHEET
  // Material::sheet: coverage (BLEND: alpha; MASK: whole where alpha reaches the cutoff;
  // OPAQUE, cutoff 0: whole) and transmission t.
  float coverage = blendMode ? clamp(alpha, 0.0, 1.0) : (alpha >= alphaCutoff ? 1.0 : 0.0);
  float t = clamp(transmission * texture(transmissionTexture, vUv0).r, 0.0, 1.0);
  vec3 passes = vec3(1.0 - coverage) + albedo * (coverage * t);
  vec3 reflectance = albedo * (coverage * (1.0 - t));
#else
  vec3 reflectance = albedo;
#endif
#ifdef SHEET_FILTER
  colour = vec4(passes, 1.0);
#else
  vec3 emitted = emission * texture(emissiveTexture, vUv0).rgb;
  vec2 uv = gl_FrontFacing ? vFront : vBack;
  vec3 irradiance = vec3(0.0);
  if (uv.x >= 0.0) {
    uvec3 c = lm_cell_coords(world);
    irradiance = lm_layer_irradiance(0u, c, world, uv);
#ifdef PUNCTUAL_LAYER
    irradiance += lm_layer_irradiance(1u, c, world, uv);
#endif
  }
  vec3 radiance = reflectance * irradiance / PI + emitted;
#ifdef HDR_OUT
  colour = vec4(radiance * exposure, 1.0);
#else
  colour = vec4(srgb_encode(toneMap(radiance * exposure)), 1.0);
#endif
#endif
}`;

// The twin of shaders/tone_map.wgsl: the float target's exposed radiance through the tone
// curve, encoded, pixel for pixel (drawn as one triangle over the viewport).
export const TONE_MAP_VERTEX_SHADER = `#version 300 es
void main() {
  vec2 p = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2));
  gl_Position = vec4(p * 2.0 - 1.0, 0.0, 1.0);
}`;

export const TONE_MAP_SHADER = `#version 300 es
precision highp float;
uniform sampler2D radiance;
out vec4 colour;
${TONE_CURVE}
void main() {
  colour = vec4(srgb_encode(toneMap(texelFetch(radiance, ivec2(gl_FragCoord.xy), 0).rgb)), 1.0);
}`;

// The twin of surface.wgsl's vs_sky/fs_sky: the sky picture (scene::SkyPicture, RGBA32F, row
// 0 up) where no surface is, one triangle at the far plane drawn after the opaque surfaces.
// With `hdr` it writes exposed radiance into the float target, else tone-mapped and encoded.
export const SKY_VERTEX_SHADER = `#version 300 es
out vec2 ndc;
void main() {
  ndc = vec2(float((gl_VertexID << 1) & 2), float(gl_VertexID & 2)) * 2.0 - 1.0;
  gl_Position = vec4(ndc, 1.0, 1.0);
}`;

export const skyShader = (hdr) => `#version 300 es
${hdr ? "#define HDR_OUT" : ""}
precision highp float;
precision highp int;
const float PI = 3.14159265358979;
const float TAU = 6.28318530717959;
uniform sampler2D skyPicture;
uniform mat4 invViewProj;
uniform float exposure;
in vec2 ndc;
out vec4 colour;
${TONE_CURVE}

vec3 skyTap(ivec2 size, int x, int y) {
  return texelFetch(skyPicture, ivec2(((x % size.x) + size.x) % size.x, clamp(y, 0, size.y - 1)), 0).rgb;
}

void main() {
  // Two points on the pixel's line of sight (WebGL clip depths -0.5 and 0.5): its direction.
  vec4 near = invViewProj * vec4(ndc, -0.5, 1.0);
  vec4 far = invViewProj * vec4(ndc, 0.5, 1.0);
  vec3 d = normalize(far.xyz / far.w - near.xyz / near.w);
  ivec2 size = textureSize(skyPicture, 0);
  vec2 uv = vec2(0.5 + atan(d.x, -d.z) / TAU, acos(clamp(d.y, -1.0, 1.0)) / PI);
  vec2 p = uv * vec2(size) - 0.5;
  vec2 p0 = floor(p);
  vec2 f = p - p0;
  ivec2 i0 = ivec2(p0);
  vec3 top = mix(skyTap(size, i0.x, i0.y), skyTap(size, i0.x + 1, i0.y), f.x);
  vec3 bottom = mix(skyTap(size, i0.x, i0.y + 1), skyTap(size, i0.x + 1, i0.y + 1), f.x);
  vec3 radiance = mix(top, bottom, f.y);
#ifdef HDR_OUT
  colour = vec4(radiance * exposure, 1.0);
#else
  colour = vec4(srgb_encode(toneMap(radiance * exposure)), 1.0);
#endif
}`;
