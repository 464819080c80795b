//! glTF metallic-roughness (and specular-glossiness) materials seen as Lambertian
//! [`Material`]s.

use ::gltf::json;
use glam::{Vec2, Vec3, Vec4};
use json::material::AlphaMode as JsonAlphaMode;
use json::validation::Checked;

use super::diag::{Diagnostics, Kind};
use super::images::TextureCache;
use super::{Ctx, LoadError};
use crate::scene::radiometry::LightCeiling;
use crate::scene::{AlphaMode, Material, TextureRef, UvTransform};

/// Every material of the file, in file order (so glTF material i is scene material i).
/// `ceiling`: the brightest emission the scene's sums can hold.
pub(super) fn convert_all(
    ctx: &Ctx,
    textures: &mut TextureCache,
    diag: &mut Diagnostics,
    ceiling: &LightCeiling,
) -> Result<Vec<Material>, LoadError> {
    ctx.root.materials.iter().enumerate().map(|(i, m)| convert(ctx, textures, diag, ceiling, i, m)).collect()
}

fn convert(
    ctx: &Ctx,
    textures: &mut TextureCache,
    diag: &mut Diagnostics,
    ceiling: &LightCeiling,
    index: usize,
    m: &json::Material,
) -> Result<Material, LoadError> {
    let name = m.name.clone().unwrap_or_else(|| format!("material{index}"));
    let bad = |what: &str| ctx.invalid(format!("material {index} '{name}': {what}"));
    // KHR_materials_pbrSpecularGlossiness (older exporters, many downloaded models): its
    // diffuse colour is the Lambertian albedo, and it takes the place of the
    // metallic-roughness base colour (a file carries that only as a fallback for viewers
    // without the extension). Specular and glossiness are ignored, as metallic and roughness
    // are.
    let spec_gloss = m.extensions.as_ref().and_then(|e| e.pbr_specular_glossiness.as_ref());
    let (factor, factor_name) = match spec_gloss {
        Some(s) => (Vec4::from(s.diffuse_factor.0), "diffuseFactor"),
        None => (Vec4::from(m.pbr_metallic_roughness.base_color_factor.0), "baseColorFactor"),
    };
    if !factor.is_finite() {
        return Err(bad(&format!("{factor_name} is not finite")));
    }
    // An albedo above 1 reflects more light than arrives (the bounces would grow without
    // end), below 0 is meaningless; glTF allows neither.
    let base_color = factor.clamp(Vec4::ZERO, Vec4::ONE);
    if base_color != factor {
        diag.note(Kind::BaseColorClamped, 1, || {
            format!("'{name}' {:?} → {:?}", factor.to_array(), base_color.to_array())
        });
    }
    let strength =
        m.extensions.as_ref().and_then(|e| e.emissive_strength.as_ref()).map_or(1.0, |s| s.emissive_strength.0);
    let emission = Vec3::from(m.emissive_factor.0) * strength;
    if !emission.is_finite() || emission.min_element() < 0.0 {
        return Err(bad("emissiveFactor × emissiveStrength is negative or not finite"));
    }
    ceiling
        .check(
            || "emissiveFactor × emissiveStrength".into(),
            emission.max_element() as f64,
            ceiling.radiance(),
            "W/(sr·m²)",
        )
        .map_err(|e| bad(&e.to_string()))?;
    let alpha_mode = match m.alpha_mode {
        Checked::Valid(JsonAlphaMode::Opaque) => AlphaMode::Opaque,
        Checked::Valid(JsonAlphaMode::Blend) => AlphaMode::Blend,
        Checked::Valid(JsonAlphaMode::Mask) => AlphaMode::Mask { cutoff: m.alpha_cutoff.map_or(0.5, |c| c.0) },
        Checked::Invalid => return Err(bad("invalid alphaMode")),
    };
    if let AlphaMode::Mask { cutoff } = alpha_mode
        && !cutoff.is_finite()
    {
        return Err(bad("alphaCutoff is not finite"));
    }
    let mut texture =
        |info: &Option<json::texture::Info>, slot: &str, srgb: bool| -> Result<Option<TextureRef>, LoadError> {
            let Some(info) = info else { return Ok(None) };
            let khr = info.extensions.as_ref().and_then(|e| e.texture_transform.as_ref());
            let transform = khr.map_or(UvTransform::IDENTITY, |t| {
                UvTransform::new(Vec2::from(t.offset.0), t.rotation.0, Vec2::from(t.scale.0))
            });
            if !transform.is_finite() {
                return Err(bad(&format!("{slot}'s KHR_texture_transform is not finite")));
            }
            let mut tex_coord = khr.and_then(|t| t.tex_coord).unwrap_or(info.tex_coord);
            if tex_coord > 1 {
                diag.note(Kind::TexCoordSet, 1, || format!("{name} {slot} (texCoord {tex_coord})"));
                tex_coord = 0;
            }
            let Some(texture) = textures.get(ctx, diag, info.index.value(), srgb)? else { return Ok(None) };
            Ok(Some(TextureRef { texture, tex_coord, transform }))
        };
    let base_color_texture = match spec_gloss {
        Some(s) => texture(&s.diffuse_texture, "diffuseTexture", true)?,
        None => texture(&m.pbr_metallic_roughness.base_color_texture, "baseColorTexture", true)?,
    };
    let emissive_texture = texture(&m.emissive_texture, "emissiveTexture", true)?;
    // KHR_materials_transmission, thin-walled: the fraction of the light interacting with
    // the surface that passes straight through (tinted by the albedo). Its texture's red
    // channel is linear.
    let (transmission, transmission_texture) = match m.extensions.as_ref().and_then(|e| e.transmission.as_ref()) {
        None => (0.0, None),
        Some(t) => {
            let factor = t.transmission_factor.0;
            if !factor.is_finite() {
                return Err(bad("transmissionFactor is not finite"));
            }
            (factor.clamp(0.0, 1.0), texture(&t.transmission_texture, "transmissionTexture", false)?)
        }
    };
    let material = Material {
        name,
        base_color,
        base_color_texture,
        emission,
        emissive_texture,
        double_sided: m.double_sided,
        alpha_mode,
        transmission,
        transmission_texture,
    };
    // Every texture of a material is read where its first one is (`Material::texture_uv`).
    let uv = material.texture_uv();
    let differ = [material.base_color_texture, material.transmission_texture, material.emissive_texture]
        .into_iter()
        .flatten()
        .filter(|t| t.uv() != uv)
        .count();
    diag.note(Kind::TextureUvDiffers, differ, || material.name.clone());
    Ok(material)
}
