//! Flat per-triangle view of a [`Scene`]: what ray tracers, rasterisers and the atlas iterate.

use glam::{Vec2, Vec3, Vec4};

use super::{MaterialId, MaterialPoint, Rgb, Scene};

/// Index of a triangle over all meshes of a scene, in mesh order.
pub type TriangleId = u32;

/// The value at barycentrics (u, v) (weights of corners 1 and 2) of one given at a
/// triangle's corners, as `a + (b − a)·u + (c − a)·v`: the order of operations every
/// interpolation of corner values follows, the GPU's twins included.
#[inline]
pub fn at_barycentrics<T>([a, b, c]: [T; 3], u: f32, v: f32) -> T
where
    T: Copy + std::ops::Add<Output = T> + std::ops::Sub<Output = T> + std::ops::Mul<f32, Output = T>,
{
    a + (b - a) * u + (c - a) * v
}

/// World-space triangles of a scene laid out flat, indexed by [`TriangleId`].
#[derive(Clone, Debug, Default)]
pub struct SceneGeometry {
    /// Corners of each triangle, counter-clockwise seen from the front.
    pub corners: Vec<[Vec3; 3]>,
    /// Unit geometric normal of the front face.
    pub normals: Vec<Vec3>,
    /// Area in m².
    pub areas: Vec<f32>,
    pub material: Vec<MaterialId>,
    /// Mesh each triangle belongs to, and its index inside that mesh.
    pub mesh: Vec<u32>,
    pub local: Vec<u32>,
    /// First global triangle of each mesh (`len = meshes + 1`).
    pub mesh_offsets: Vec<u32>,
}

impl SceneGeometry {
    pub fn new(scene: &Scene) -> Self {
        let n = scene.triangle_count();
        let mut g = SceneGeometry {
            corners: Vec::with_capacity(n),
            normals: Vec::with_capacity(n),
            areas: Vec::with_capacity(n),
            material: Vec::with_capacity(n),
            mesh: Vec::with_capacity(n),
            local: Vec::with_capacity(n),
            mesh_offsets: Vec::with_capacity(scene.meshes.len() + 1),
        };
        for (mi, mesh) in scene.meshes.iter().enumerate() {
            g.mesh_offsets.push(g.corners.len() as u32);
            for t in 0..mesh.triangles.len() {
                let c = mesh.corners(t);
                let cross = (c[1] - c[0]).cross(c[2] - c[0]);
                let len = cross.length();
                g.corners.push(c);
                g.normals.push(if len > 0.0 { cross / len } else { Vec3::Z });
                g.areas.push(0.5 * len);
                g.material.push(mesh.material);
                g.mesh.push(mi as u32);
                g.local.push(t as u32);
            }
        }
        g.mesh_offsets.push(g.corners.len() as u32);
        g
    }

    pub fn len(&self) -> usize {
        self.corners.len()
    }

    pub fn is_empty(&self) -> bool {
        self.corners.is_empty()
    }

    /// Total area of all triangles (one side), m².
    pub fn total_area(&self) -> f64 {
        self.areas.iter().map(|&a| a as f64).sum()
    }

    /// Point on triangle `t` at barycentrics (u, v) (weights of corners 1 and 2).
    #[inline]
    pub fn point(&self, t: TriangleId, u: f32, v: f32) -> Vec3 {
        at_barycentrics(self.corners[t as usize], u, v)
    }

    /// Where triangle `t`'s material reads its textures at its corners
    /// ([`Mesh::texture_uv_corners`](crate::scene::Mesh::texture_uv_corners)).
    #[inline]
    pub fn texture_uv_corners(&self, scene: &Scene, t: usize) -> [Vec2; 3] {
        let mesh = &scene.meshes[self.mesh[t] as usize];
        let uv = scene.materials.get(mesh.material as usize).map_or_else(Default::default, |m| m.texture_uv());
        mesh.texture_uv_corners(self.local[t] as usize, uv)
    }

    /// Where triangle `t`'s material reads its textures at barycentrics (u, v).
    #[inline]
    pub fn texture_uv(&self, scene: &Scene, t: TriangleId, u: f32, v: f32) -> Vec2 {
        at_barycentrics(self.texture_uv_corners(scene, t as usize), u, v)
    }

    /// Triangle `t`'s corners' vertex colours (`None`: its mesh has none).
    #[inline]
    pub fn color_corners(&self, scene: &Scene, t: usize) -> Option<[Vec4; 3]> {
        scene.meshes[self.mesh[t] as usize].color_corners(self.local[t] as usize)
    }

    /// Whether triangle `t`'s mesh has vertex colours.
    #[inline]
    pub fn has_colors(&self, scene: &Scene, t: usize) -> bool {
        scene.meshes[self.mesh[t] as usize].colors.is_some()
    }

    /// Where triangle `t`'s material is read at barycentrics (u, v): texture coordinate and
    /// vertex colour, each interpolated as the GPU's `surface_radiance.inc.wgsl` does.
    #[inline]
    pub fn material_point(&self, scene: &Scene, t: TriangleId, u: f32, v: f32) -> MaterialPoint {
        let color = self.color_corners(scene, t as usize).map(|c| at_barycentrics(c, u, v));
        MaterialPoint { uv: self.texture_uv(scene, t, u, v), color }
    }

    /// Triangle `t`'s reflectance where it is the same at every point (its material's
    /// [`Material::uniform_albedo`](crate::scene::Material::uniform_albedo), on a mesh without
    /// vertex colours), `None` where a texture or vertex colours vary it.
    #[inline]
    pub fn uniform_albedo(&self, scene: &Scene, t: usize) -> Option<Rgb> {
        if self.has_colors(scene, t) {
            return None;
        }
        scene.materials[self.material[t] as usize].uniform_albedo(&scene.textures)
    }

    /// Diffuse reflectance of triangle `t` at barycentrics (u, v)
    /// ([`Material::reflectance`](crate::scene::Material::reflectance)).
    pub fn albedo(&self, scene: &Scene, t: TriangleId, u: f32, v: f32) -> Rgb {
        let m = &scene.materials[self.material[t as usize] as usize];
        self.uniform_albedo(scene, t as usize)
            .unwrap_or_else(|| m.reflectance(&scene.textures, self.material_point(scene, t, u, v)))
    }

    /// Emitted radiance of triangle `t` at barycentrics (u, v), from its emitting side(s).
    pub fn emission(&self, scene: &Scene, t: TriangleId, u: f32, v: f32) -> Rgb {
        let m = &scene.materials[self.material[t as usize] as usize];
        if m.emissive_texture.is_none() {
            return m.emission;
        }
        m.emission_at(&scene.textures, self.texture_uv(scene, t, u, v))
    }
}
