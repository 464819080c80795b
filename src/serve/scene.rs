//! What the page draws, built from the runtime's world as the viewer builds its vertex
//! buffer (`gpu::scene`): one corner per triangle corner (a corner's light-map UV depends on
//! the triangle's face), grouped by material, with the light-map UV of the front and the
//! back face. The glTF alone cannot give the page this: the atlas is livebake's own unwrap.

use glam::{Vec2, Vec4};

use super::protocol::{
    BatchMessage, GEOMETRY, GridMessage, MaterialMessage, SKY, SceneMessage, StartPose, TEXTURE, TextureMessage,
    VERTEX_WORDS,
};
use crate::atlas::{Atlas, NO_FACE};
use crate::runtime::shown::{PAGE_SIDE, ShownLightmap};
use crate::scene::{AlphaMode, Scene, SceneGeometry, WrapMode};
use crate::viewer::camera::Camera;

/// A light-map UV meaning "no face on this side" (as the viewer's).
const NO_UV: [f32; 2] = [-1.0, -1.0];

/// The scene's description, geometry and texture messages.
pub struct SceneMessages {
    pub description: SceneMessage,
    /// [`GEOMETRY`]: kind, 3 bytes padding, u32 generation, then the vertices.
    pub geometry: Vec<u8>,
    /// [`TEXTURE`] messages, one a scene texture.
    pub textures: Vec<Vec<u8>>,
    /// The [`SKY`] message, unless the sky is black.
    pub sky: Option<Vec<u8>>,
}

fn wrap_name(w: WrapMode) -> &'static str {
    match w {
        WrapMode::Repeat => "repeat",
        WrapMode::MirroredRepeat => "mirrored_repeat",
        WrapMode::ClampToEdge => "clamp_to_edge",
    }
}

/// The start pose `view` uses (`pose`: `--camera` eye and target; else the glTF camera or
/// a framing view, [`Camera::initial`]).
pub fn start_pose(scene: &Scene, pose: Option<(glam::Vec3, glam::Vec3)>) -> StartPose {
    let initial = Camera::initial(scene);
    let camera = match pose {
        Some((eye, target)) => {
            let (lo, hi) = scene.bounds().unwrap_or((glam::Vec3::splat(-1.0), glam::Vec3::splat(1.0)));
            Camera::look_at(eye, target, initial.yfov, (hi - lo).length())
        }
        None => initial,
    };
    StartPose {
        eye: camera.eye.to_array(),
        target: camera.look_target().to_array(),
        yfov: camera.yfov,
        znear: camera.znear,
        zfar: camera.zfar,
        speed: camera.speed,
    }
}

/// Builds the messages for `scene` lit through `atlas`, its map shaped as `shown`.
pub fn scene_messages(
    scene: &Scene,
    atlas: &Atlas,
    shown: &ShownLightmap,
    generation: u32,
    exposure: f32,
    start: StartPose,
) -> SceneMessages {
    let geom = SceneGeometry::new(scene);
    // Per material, its vertices' bytes (VERTEX_WORDS words each).
    let mut per_material: Vec<Vec<u8>> = vec![Vec::new(); scene.materials.len()];
    for t in 0..geom.len() {
        let Some(out) = per_material.get_mut(geom.material[t] as usize) else { continue };
        let uv0: [Vec2; 3] = geom.texture_uv_corners(scene, t);
        let colors = geom.color_corners(scene, t).unwrap_or([Vec4::ONE; 3]);
        let faces = atlas.face_of.get(t).copied().unwrap_or([NO_FACE; 2]);
        let face_uv = |f: u32, i: usize| if f == NO_FACE { NO_UV } else { atlas.faces[f as usize].uv[i].to_array() };
        for (i, corner) in geom.corners[t].iter().enumerate() {
            let [fu, fv] = face_uv(faces[0], i);
            let [bu, bv] = face_uv(faces[1], i);
            for v in [corner.x, corner.y, corner.z, uv0[i].x, uv0[i].y, fu, fv, bu, bv] {
                out.extend_from_slice(&v.to_le_bytes());
            }
            for c in crate::scene::color_unorm16(colors[i]) {
                out.extend_from_slice(&c.to_le_bytes());
            }
        }
    }
    let mut geometry = vec![GEOMETRY, 0, 0, 0];
    geometry.extend_from_slice(&generation.to_le_bytes());
    let mut batches = Vec::new();
    let mut first = 0u32;
    for (material, bytes) in per_material.iter().enumerate() {
        if bytes.is_empty() {
            continue;
        }
        let count = (bytes.len() / (4 * VERTEX_WORDS)) as u32;
        batches.push(BatchMessage { material, first, count, double_sided: scene.materials[material].double_sided });
        first += count;
        geometry.extend_from_slice(bytes);
    }
    let materials = scene
        .materials
        .iter()
        .map(|m| MaterialMessage {
            base_color: m.base_color.to_array(),
            emission: m.emission.to_array(),
            base_color_texture: m.base_color_texture.map(|r| r.texture).filter(|&t| t < scene.textures.len()),
            emissive_texture: m.emissive_texture.map(|r| r.texture).filter(|&t| t < scene.textures.len()),
            alpha_cutoff: m.alpha_mode.cutoff(),
            blend: m.alpha_mode == AlphaMode::Blend,
            transmission: m.transmission,
            transmission_texture: m.transmission_texture.map(|r| r.texture).filter(|&t| t < scene.textures.len()),
        })
        .collect();
    let mut textures = Vec::new();
    let mut texture_messages = Vec::new();
    for (i, t) in scene.textures.iter().enumerate() {
        textures.push(TextureMessage {
            width: t.width,
            height: t.height,
            srgb: t.srgb,
            wrap: [wrap_name(t.wrap_s), wrap_name(t.wrap_t)],
        });
        let mut b = Vec::with_capacity(16 + t.rgba8.len() * 4);
        b.extend_from_slice(&[TEXTURE, 0, 0, 0]);
        for v in [i as u32, t.width, t.height] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        // A texture whose pixels do not fill it is sent as 0×0 (the page uses white, as the
        // viewer shows the factor alone).
        if t.rgba8.len() == (t.width as usize) * (t.height as usize) {
            b.extend(t.rgba8.iter().flatten());
        } else {
            b.truncate(8);
            b.extend_from_slice(&[0; 8]);
        }
        texture_messages.push(b);
    }
    let grid = shown.grid;
    let sky = scene.sky_picture();
    let description = SceneMessage {
        kind: "scene",
        generation,
        atlas: [shown.atlas_width, shown.atlas_height],
        lods: shown.lods(),
        page_side: PAGE_SIDE,
        page_tables: shown.layers[0].levels.iter().map(|l| [l.pages_x, l.pages_y]).collect(),
        grid: GridMessage { origin: grid.origin.to_array(), cell_size: grid.cell_size, dims: grid.dims },
        blend_band: shown.blend_band,
        exposure,
        start,
        materials,
        batches,
        textures,
        sky: sky.as_ref().map(|p| [p.width, p.height]),
        vertex_count: first,
    };
    let sky = sky.map(|p| {
        let mut b = Vec::with_capacity(12 + p.radiance.len() * 16);
        b.extend_from_slice(&[SKY, 0, 0, 0]);
        b.extend_from_slice(&p.width.to_le_bytes());
        b.extend_from_slice(&p.height.to_le_bytes());
        for l in &p.radiance {
            for v in l.extend(1.0).to_array() {
                b.extend_from_slice(&v.to_le_bytes());
            }
        }
        b
    });
    SceneMessages { description, geometry, textures: texture_messages, sky }
}
