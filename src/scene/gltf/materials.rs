//! glTF metallic-roughness materials seen as Lambertian [`Material`]s.

use ::gltf::json;
use glam::{Vec3, Vec4};
use json::material::AlphaMode as JsonAlphaMode;
use json::validation::Checked;

use super::diag::{Diagnostics, Kind};
use super::images::TextureCache;
use super::{Ctx, LoadError};
use crate::scene::{AlphaMode, Material, TextureRef};

/// Every material of the file, in file order (so glTF material i is scene material i).
pub(super) fn convert_all(
    ctx: &Ctx,
    textures: &mut TextureCache,
    diag: &mut Diagnostics,
) -> Result<Vec<Material>, LoadError> {
    ctx.root.materials.iter().enumerate().map(|(i, m)| convert(ctx, textures, diag, i, m)).collect()
}

fn convert(
    ctx: &Ctx,
    textures: &mut TextureCache,
    diag: &mut Diagnostics,
    index: usize,
    m: &json::Material,
) -> Result<Material, LoadError> {
    let name = m.name.clone().unwrap_or_else(|| format!("material{index}"));
    let bad = |what: &str| ctx.invalid(format!("material {index} '{name}': {what}"));
    let base_color = Vec4::from(m.pbr_metallic_roughness.base_color_factor.0);
    if !base_color.is_finite() {
        return Err(bad("baseColorFactor is not finite"));
    }
    let strength =
        m.extensions.as_ref().and_then(|e| e.emissive_strength.as_ref()).map_or(1.0, |s| s.emissive_strength.0);
    let emission = Vec3::from(m.emissive_factor.0) * strength;
    if !emission.is_finite() || emission.min_element() < 0.0 {
        return Err(bad("emissiveFactor × emissiveStrength is negative or not finite"));
    }
    let alpha_mode = match m.alpha_mode {
        Checked::Valid(JsonAlphaMode::Opaque) => AlphaMode::Opaque,
        Checked::Valid(JsonAlphaMode::Blend) => AlphaMode::Blend,
        Checked::Valid(JsonAlphaMode::Mask) => AlphaMode::Mask { cutoff: m.alpha_cutoff.map_or(0.5, |c| c.0) },
        Checked::Invalid => return Err(bad("invalid alphaMode")),
    };
    let mut texture = |info: &Option<json::texture::Info>, slot: &str| -> Result<Option<TextureRef>, LoadError> {
        let Some(info) = info else { return Ok(None) };
        if info.tex_coord != 0 {
            diag.note(Kind::TexCoordSet, 1, || format!("{name} {slot} (texCoord {})", info.tex_coord));
        }
        let texture = textures.get(ctx, info.index.value())?;
        Ok(Some(TextureRef { texture, tex_coord: info.tex_coord }))
    };
    let base_color_texture = texture(&m.pbr_metallic_roughness.base_color_texture, "baseColorTexture")?;
    let emissive_texture = texture(&m.emissive_texture, "emissiveTexture")?;
    Ok(Material {
        name,
        base_color,
        base_color_texture,
        emission,
        emissive_texture,
        double_sided: m.double_sided,
        alpha_mode,
    })
}
