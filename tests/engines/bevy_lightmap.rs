// Bevy (0.15 or later): give every mesh of the exported scene the light map.
// Not compiled here (a Bevy build is too heavy for this project's CI); tests/export.rs checks
// that what it relies on holds for the exported files.
use bevy::pbr::Lightmap;
use bevy::prelude::*;
use bevy::render::camera::Exposure;

/// The export's light map. `intensity` is `MOZ_lightmap.intensity` in room.gltf (the same for
/// every material).
#[derive(Resource)]
struct LivebakeLightmap {
    image: Handle<Image>,
    intensity: f32,
}

fn setup(mut commands: Commands, assets: Res<AssetServer>) {
    commands.spawn(SceneRoot(assets.load(GltfAssetLabel::Scene(0).from_asset("room.gltf"))));
    commands.insert_resource(LivebakeLightmap {
        // PNGs load as sRGB: the GPU decodes the texels to E / intensity.
        image: assets.load("room.lightmap.png"),
        intensity: 0.889,
    });
    // livebake's numbers are radiometric; an exposure of 1 shows radiance 1 as white.
    commands.spawn((Camera3d::default(), Exposure { ev100: -(1.2f32).log2() }));
}

fn attach_lightmaps(
    mut commands: Commands,
    lightmap: Res<LivebakeLightmap>,
    meshes: Query<(Entity, &MeshMaterial3d<StandardMaterial>), Added<Mesh3d>>,
    mut materials: ResMut<Assets<StandardMaterial>>,
) {
    for (entity, material) in &meshes {
        // TEXCOORD_1 (Bevy's UV_1) spans the whole image: the full uv_rect.
        commands.entity(entity).insert(Lightmap {
            image: lightmap.image.clone(),
            uv_rect: Rect::new(0.0, 0.0, 1.0, 1.0),
            ..default()
        });
        if let Some(m) = materials.get_mut(&material.0) {
            // Bevy shades diffuse colour × texel × lightmap_exposure (no 1/π): E/π.
            m.lightmap_exposure = lightmap.intensity / std::f32::consts::PI;
        }
    }
}

fn main() {
    App::new()
        .add_plugins(DefaultPlugins)
        .add_systems(Startup, setup)
        .add_systems(Update, attach_lightmaps)
        .run();
}
