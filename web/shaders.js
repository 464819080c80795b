// The page's shaders (web/livebake.js): the light map's GLSL twin of the viewer's
// shaders/lightmap.inc.wgsl and surface.wgsl's lit view.

// Columns of the integer textures holding the page tables and the cells' LODs.
export const TABLE_W = 4096;

export const VERTEX_SHADER = `#version 300 es
layout(location = 0) in vec3 position;
layout(location = 1) in vec2 uv0;
layout(location = 2) in vec2 lightmapFront;
layout(location = 3) in vec2 lightmapBack;
uniform mat4 viewProj;
out vec3 world;
out vec2 vUv0;
out vec2 vFront;
out vec2 vBack;
void main() {
  gl_Position = viewProj * vec4(position, 1.0);
  world = position;
  vUv0 = uv0;
  vFront = lightmapFront;
  vBack = lightmapBack;
}`;

// The twin of shaders/lightmap.inc.wgsl and surface.wgsl's lit view.
export const FRAGMENT_SHADER = `#version 300 es
precision highp float;
precision highp int;
precision highp usampler2D;
const float PI = 3.14159265358979;
const int PAGE_SIDE = 16;
const uint NO_PAGE = 0xffffffffu;
const uint MAX_LODS = 8u;
const uint TABLE_W = ${TABLE_W}u;
uniform sampler2D pool;
uniform usampler2D pageTable;
uniform usampler2D cellLod;
uniform sampler2D baseColorTexture;
uniform sampler2D emissiveTexture;
uniform vec3 gridOrigin;
uniform float cellSize;
uniform uvec3 gridDims;
uniform uint lodCount;
uniform float blendBand;
uniform uint poolColumns;
uniform uint cellCount;
uniform uvec4 levels[16]; // pages_x, pages_y, table offset (layer * MAX_LODS + lod)
uniform vec4 baseColor;
uniform vec3 emission;
uniform float exposure;
in vec3 world;
in vec2 vUv0;
in vec2 vFront;
in vec2 vBack;
out vec4 colour;

uint tableEntry(uint i) { return texelFetch(pageTable, ivec2(int(i % TABLE_W), int(i / TABLE_W)), 0).r; }
uint cellEntry(uint i) { return texelFetch(cellLod, ivec2(int(i % TABLE_W), int(i / TABLE_W)), 0).r; }

vec4 lm_tap(uint layer, uint k, ivec2 px) {
  if (px.x < 0 || px.y < 0) return vec4(0.0);
  ivec2 page = px / PAGE_SIDE;
  uvec4 level = levels[layer * MAX_LODS + k];
  if (uint(page.x) >= level.x || uint(page.y) >= level.y) return vec4(0.0);
  uint slot = tableEntry(level.z + uint(page.y) * level.x + uint(page.x));
  if (slot == NO_PAGE) return vec4(0.0);
  ivec2 origin = ivec2(int(slot % poolColumns), int(slot / poolColumns)) * PAGE_SIDE;
  vec4 t = texelFetch(pool, origin + px % PAGE_SIDE, 0);
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
    vec4 t00 = lm_tap(layer, uint(k), i0);
    vec4 t10 = lm_tap(layer, uint(k), i0 + ivec2(1, 0));
    vec4 t01 = lm_tap(layer, uint(k), i0 + ivec2(0, 1));
    vec4 t11 = lm_tap(layer, uint(k), i0 + ivec2(1, 1));
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

vec3 lm_layer_irradiance(uint layer, uvec3 c, vec3 p, vec2 uv) {
  uint lods = layer * cellCount;
  uint k = cellEntry(lods + lm_cell_index(c));
  vec3 base = lm_value(layer, k, uv);
  vec3 lo = gridOrigin + vec3(c) * cellSize;
  if (k == 0u || blendBand <= 0.0) return base;
  float w = 0.0;
  uint kLow = k;
  bool nearCoarser = false;
  for (uint axis = 0u; axis < 3u; axis++) {
    for (uint side = 0u; side < 2u; side++) {
      uvec3 n = c;
      float d = 0.0;
      if (side == 0u) {
        if (c[axis] == 0u) continue;
        n[axis] = c[axis] - 1u;
        d = p[axis] - lo[axis];
      } else {
        if (c[axis] + 1u >= gridDims[axis]) continue;
        n[axis] = c[axis] + 1u;
        d = lo[axis] + cellSize - p[axis];
      }
      if (d >= blendBand) continue;
      uint kn = cellEntry(lods + lm_cell_index(n));
      float band = blendBand / float(1u << kn);
      if (kn >= k || d >= band) continue;
      w = max(w, clamp(1.0 - max(d, 0.0) / band, 0.0, 1.0));
      kLow = min(kLow, kn);
      nearCoarser = true;
    }
  }
  if (nearCoarser) return base * (1.0 - w) + lm_value(layer, kLow, uv) * w;
  return base;
}

vec3 srgb_encode(vec3 c) {
  vec3 lo = c * 12.92;
  vec3 hi = 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055;
  return mix(hi, lo, vec3(lessThanEqual(c, vec3(0.0031308))));
}

void main() {
  vec3 base = baseColor.rgb * texture(baseColorTexture, vUv0).rgb;
  vec3 albedo = clamp(base, vec3(0.0), vec3(1.0));
  vec3 emitted = emission * texture(emissiveTexture, vUv0).rgb;
  vec2 uv = gl_FrontFacing ? vFront : vBack;
  vec3 irradiance = vec3(0.0);
  if (uv.x >= 0.0) {
    uvec3 c = lm_cell_coords(world);
    irradiance = lm_layer_irradiance(0u, c, world, uv) + lm_layer_irradiance(1u, c, world, uv);
  }
  vec3 radiance = albedo * irradiance / PI + emitted;
  vec3 toned = vec3(1.0) - exp(-max(radiance * exposure, vec3(0.0)));
  colour = vec4(srgb_encode(toned), 1.0);
}`;
