// Babylon.js (@babylonjs/core and @babylonjs/loaders 9): MOZ_lightmap → PBRMaterial.lightmapTexture
// on TEXCOORD_1. Import this module before loading; also set scene.ambientColor = Color3.White()
// and add no lights or environment (the light map holds all the diffuse light).
import { Color3 } from "@babylonjs/core/Maths/math.color.js";
import { GLTFLoader } from "@babylonjs/loaders/glTF/2.0/glTFLoader.js";
import { registerGLTFExtension } from "@babylonjs/loaders/glTF/2.0/glTFLoaderExtensionRegistry.js";

class MozLightmap {
  constructor(loader) {
    this.name = "MOZ_lightmap";
    this.enabled = loader.isExtensionUsed(this.name);
    this.loader = loader;
  }

  dispose() {
    this.loader = null;
  }

  loadMaterialPropertiesAsync(context, material, babylonMaterial) {
    return GLTFLoader.LoadExtensionAsync(context, material, this.name, async (extContext, ext) => {
      await this.loader.loadMaterialPropertiesAsync(context, material, babylonMaterial);
      // The loader reads texCoord into coordinatesIndex (1) and decodes the PNG as sRGB.
      await this.loader.loadTextureInfoAsync(extContext, ext, (texture) => {
        // Babylon adds a light map to the final colour unless useLightmapAsShadowmap, which
        // multiplies it instead: (ambientColor × albedo) × lightmap. With white ambient, a map
        // of E/π gives albedo/π × E, the outgoing radiance of the light-mapped surface.
        texture.level = ext.intensity / Math.PI;
        babylonMaterial.lightmapTexture = texture;
        babylonMaterial.useLightmapAsShadowmap = true;
        babylonMaterial.ambientColor = Color3.White();
      });
    });
  }
}

registerGLTFExtension("MOZ_lightmap", true, (loader) => new MozLightmap(loader));
