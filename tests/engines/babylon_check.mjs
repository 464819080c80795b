// Loads an export with Babylon.js's glTF loader (NullEngine: no GPU in Node) and docs/EXPORT.md's
// MOZ_lightmap extension (babylon_moz_lightmap.mjs), and prints as JSON what Babylon then
// shades with: per sample point, π × level × (the lightmap texel, sRGB-decoded and filtered at
// the point's interpolated UV2), i.e. E if the PBR shader makes albedo × map × level; plus the
// material settings and the shader code that makes it so.
//   node babylon_check.mjs EXPORT.gltf SAMPLES.json
// Babylon fetches files with XMLHttpRequest, which Node lacks: the harness inlines the
// export's files as data: URIs (the same bytes); everything else is Babylon's code.
import fs from "fs";
import path from "path";
import { NullEngine } from "@babylonjs/core/Engines/nullEngine.js";
import { Scene } from "@babylonjs/core/scene.js";
import { Color3 } from "@babylonjs/core/Maths/math.color.js";
import { ShaderStore } from "@babylonjs/core/Engines/shaderStore.js";
import { Logger } from "@babylonjs/core/Misc/logger.js";
import { LoadAssetContainerAsync } from "@babylonjs/core/Loading/sceneLoader.js";
import "@babylonjs/core/Shaders/pbr.fragment.js";
import "@babylonjs/loaders/glTF/2.0/index.js";
import "./babylon_moz_lightmap.mjs";
import { bilinearSrgb, decodePng, samplePoints } from "./png.mjs";

const [file, samplesFile] = process.argv.slice(2);
const dir = path.dirname(file);
const samples = JSON.parse(fs.readFileSync(samplesFile, "utf8"));
const gltf = JSON.parse(fs.readFileSync(file, "utf8"));
const inline = (uri, mime) => `data:${mime};base64,` + fs.readFileSync(path.join(dir, decodeURIComponent(uri))).toString("base64");
for (const b of gltf.buffers) b.uri = inline(b.uri, "application/octet-stream");
// The light map every MOZ_lightmap refers to, decoded for the harness's own sampling.
const lightmapImage = gltf.images[gltf.textures[gltf.materials[0].extensions.MOZ_lightmap.index].source];
const png = decodePng(fs.readFileSync(path.join(dir, decodeURIComponent(lightmapImage.uri))));
for (const im of gltf.images) if (im.uri) im.uri = inline(im.uri, im.mimeType);

Logger.LogLevels = Logger.WarningLogLevel | Logger.ErrorLogLevel; // stdout carries the JSON
const engine = new NullEngine();
const scene = new Scene(engine);
scene.ambientColor = Color3.White();
const container = await LoadAssetContainerAsync("data:" + JSON.stringify(gltf), scene, { pluginExtension: ".gltf" });
container.addAllToScene();

const meshes = new Map();
const materials = [];
for (const mesh of container.meshes) {
  const pointer = mesh._internalMetadata?.gltf?.pointers?.find((p) => p.startsWith("/meshes/"));
  if (!pointer) continue;
  const [, , m, , p] = pointer.split("/");
  meshes.set(`${m}/${p}`, mesh);
  const mat = mesh.material;
  const t = mat.lightmapTexture;
  materials.push({
    className: mat.getClassName(),
    hasLightmap: !!t,
    coordinatesIndex: t?.coordinatesIndex,
    level: t?.level,
    // sRGB decoding: by the GPU (an sRGB texture format, where the engine supports it) or in
    // the shader (GAMMALIGHTMAP, from gammaSpace).
    gammaSpace: t?.gammaSpace,
    srgbBuffer: !!t?._texture?._useSRGBBuffer,
    pointers: t?._internalMetadata?.gltf?.pointers ?? [],
    useLightmapAsShadowmap: mat.useLightmapAsShadowmap,
    ambient: mat.ambientColor.asArray(),
    sceneAmbient: scene.ambientColor.asArray(),
    uv2: !!mesh.getVerticesData("uv2"),
  });
}
const uvs = samplePoints(samples, (m, p) => {
  const mesh = meshes.get(`${m}/${p}`);
  if (!mesh) return null;
  return { positions: mesh.getVerticesData("position"), uvs: mesh.getVerticesData("uv2"), indices: mesh.getIndices() };
});
const values = samples.map((s, i) => {
  const mesh = meshes.get(`${s.mesh}/${s.primitive}`);
  const t = mesh.material.lightmapTexture;
  return bilinearSrgb(png, uvs[i][0], uvs[i][1]).map((c) => c * t.level * Math.PI);
});
const shaders = ["pbrBlockLightmapInit", "pbrBlockFinalColorComposition", "pbrBlockFinalUnlitComponents"].map(
  (n) => ShaderStore.IncludesShadersStore[n] ?? "",
);
process.stdout.write(JSON.stringify({ shaders, materials, values }));
