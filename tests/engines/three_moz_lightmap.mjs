// three.js (r151 or later): MOZ_lightmap → MeshStandardMaterial.lightMap on TEXCOORD_1.
// Register with: gltfLoader.register((parser) => new MozLightmap(parser));
import { SRGBColorSpace } from "three";

export class MozLightmap {
  constructor(parser) {
    this.parser = parser;
    this.name = "MOZ_lightmap";
  }

  async extendMaterialParams(materialIndex, params) {
    const ext = this.parser.json.materials[materialIndex].extensions?.MOZ_lightmap;
    if (!ext) return;
    const map = await this.parser.getDependency("texture", ext.index);
    map.channel = ext.texCoord; // 1: TEXCOORD_1, three's "uv1" (r151+)
    map.colorSpace = SRGBColorSpace; // the PNG holds sRGB-encoded E / intensity
    params.lightMap = map;
    // three.js adds lightMap × lightMapIntensity to the irradiance it shades with
    // (albedo/π × irradiance): the map times intensity is E in W/m².
    params.lightMapIntensity = ext.intensity;
  }
}
