// Loads an export with three.js's GLTFLoader and docs/EXPORT.md's MozLightmap plugin
// (three_moz_lightmap.mjs), and prints as JSON what three.js then shades with: per sample
// point, lightMapIntensity × (the lightMap texel, sRGB-decoded and bilinearly filtered at the
// point's interpolated uv1), i.e. the irradiance three.js adds; plus the material settings.
//   node three_check.mjs EXPORT.gltf SAMPLES.json
// Node has no image decoder or file fetch: the test's own loaders hand GLTFLoader the files'
// bytes (PNG decoded by png.mjs); everything else is three.js's code.
import fs from "fs";
import path from "path";
import { Buffer } from "buffer";
import * as THREE from "three";
import { GLTFLoader } from "three/addons/loaders/GLTFLoader.js";
import { MozLightmap } from "./three_moz_lightmap.mjs";
import { bilinearSrgb, decodePng, samplePoints } from "./png.mjs";

// Browser globals three.js's loaders reach for.
globalThis.self = globalThis;
globalThis.ProgressEvent ??= class ProgressEvent extends Event {
  constructor(type, init) {
    super(type);
    Object.assign(this, init);
  }
};
const [file, samplesFile] = process.argv.slice(2);
const dir = path.dirname(file);
const samples = JSON.parse(fs.readFileSync(samplesFile, "utf8"));

// Relative URLs (the .bin) become data: URLs, which Node's fetch reads.
const manager = new THREE.LoadingManager();
manager.setURLModifier((url) =>
  /^(data|blob):/.test(url) ? url : "data:application/octet-stream;base64," + fs.readFileSync(path.join(dir, decodeURIComponent(url))).toString("base64"),
);
// Images: bytes from the file or the blob GLTFLoader made of a bufferView, decoded to a Texture.
class NodeImageLoader extends THREE.Loader {
  load(url, onLoad, _onProgress, onError) {
    const bytes = url.startsWith("blob:")
      ? Buffer.from([]) // embedded material textures: not needed to check the light map
      : fs.readFileSync(path.join(dir, decodeURIComponent(url.replace(/^\.\//, ""))));
    try {
      const png = decodePng(bytes);
      const texture = new THREE.Texture({ width: png.width, height: png.height, data: png.data, png });
      onLoad(texture);
      return texture;
    } catch (e) {
      onError(e);
    }
  }
}
manager.addHandler(/./, new NodeImageLoader(manager));

const loader = new GLTFLoader(manager);
loader.register((parser) => new MozLightmap(parser));
const gltf = await loader.parseAsync(fs.readFileSync(file, "utf8"), "");

const chunk = fs.readFileSync(path.join(path.dirname(new URL(import.meta.resolve("three")).pathname), "../src/renderers/shaders/ShaderChunk/lights_fragment_maps.glsl.js"), "utf8");
const meshes = new Map();
const materials = [];
gltf.scene.traverse((o) => {
  if (!o.isMesh) return;
  const a = gltf.parser.associations.get(o);
  meshes.set(`${a.meshes}/${a.primitives}`, o);
  const m = o.material;
  materials.push({
    type: m.type,
    hasLightMap: !!m.lightMap,
    channel: m.lightMap?.channel,
    colorSpace: m.lightMap?.colorSpace,
    flipY: m.lightMap?.flipY,
    lightMapIntensity: m.lightMapIntensity,
    side: m.side,
    uv1: !!o.geometry.attributes.uv1,
  });
});
const uvs = samplePoints(samples, (mesh, prim) => {
  const o = meshes.get(`${mesh}/${prim}`);
  if (!o) return null;
  const g = o.geometry;
  return { positions: g.attributes.position.array, uvs: g.attributes.uv1.array, indices: g.index.array };
});
const values = samples.map((s, i) => {
  const o = meshes.get(`${s.mesh}/${s.primitive}`);
  const m = o.material;
  return bilinearSrgb(m.lightMap.image.png, uvs[i][0], uvs[i][1]).map((c) => c * m.lightMapIntensity);
});
process.stdout.write(JSON.stringify({ revision: THREE.REVISION, shaderChunk: chunk, materials, values }));
