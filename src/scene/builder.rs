//! Programmatic scene construction: analytic test scenes, benchmarks, examples.

use glam::{Vec2, Vec3, Vec4};

use super::{LightKind, Material, MaterialId, Mesh, PunctualLight, Rgb, Scene};

/// Builds a [`Scene`] from quads, boxes and lights. Every call adds one mesh.
#[derive(Default)]
pub struct SceneBuilder {
    scene: Scene,
}

/// A diffuse material with uniform albedo and emission.
pub fn diffuse(albedo: Rgb, emission: Rgb, double_sided: bool) -> Material {
    Material {
        name: format!("diffuse{albedo:?}"),
        base_color: albedo.extend(1.0),
        emission,
        double_sided,
        ..Material::default()
    }
}

impl SceneBuilder {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn material(&mut self, m: Material) -> MaterialId {
        self.scene.materials.push(m);
        (self.scene.materials.len() - 1) as MaterialId
    }

    pub fn sky(&mut self, radiance: Rgb) -> &mut Self {
        self.scene.sky = radiance;
        self
    }

    /// Radiance by direction around the scene (added to the uniform sky).
    pub fn environment(&mut self, map: super::Environment) -> &mut Self {
        self.scene.environment = Some(std::sync::Arc::new(map));
        self
    }

    /// Adds a mesh from world-space positions and CCW triangles; normals are the face normals
    /// averaged per vertex.
    pub fn mesh(
        &mut self,
        name: &str,
        positions: Vec<Vec3>,
        triangles: Vec<[u32; 3]>,
        material: MaterialId,
    ) -> &mut Self {
        let mut normals = vec![Vec3::ZERO; positions.len()];
        for t in &triangles {
            let [a, b, c] = t.map(|i| positions[i as usize]);
            let n = (b - a).cross(c - a);
            for &i in t {
                normals[i as usize] += n;
            }
        }
        let normals = normals.into_iter().map(|n| n.normalize_or(Vec3::Z)).collect();
        let uv0 = Some(vec![Vec2::ZERO; positions.len()]);
        self.scene.meshes.push(Mesh {
            name: name.to_string(),
            node: None,
            material,
            positions,
            normals,
            uv0,
            uv1: None,
            colors: None,
            triangles,
        });
        self
    }

    /// A planar quad with corners in counter-clockwise order seen from its front.
    pub fn quad(&mut self, name: &str, corners: [Vec3; 4], material: MaterialId) -> &mut Self {
        self.mesh(name, corners.to_vec(), vec![[0, 1, 2], [0, 2, 3]], material)
    }

    /// A quad split into `n × n` cells (2n² triangles), for tests that need many texels per
    /// triangle or many triangles per chart.
    pub fn grid_quad(&mut self, name: &str, corners: [Vec3; 4], n: u32, material: MaterialId) -> &mut Self {
        let n = n.max(1);
        let [a, b, _c, d] = corners;
        let (ab, ad) = (b - a, d - a);
        let mut pos = Vec::new();
        for j in 0..=n {
            for i in 0..=n {
                pos.push(a + ab * (i as f32 / n as f32) + ad * (j as f32 / n as f32));
            }
        }
        let mut tris = Vec::new();
        let idx = |i: u32, j: u32| j * (n + 1) + i;
        for j in 0..n {
            for i in 0..n {
                tris.push([idx(i, j), idx(i + 1, j), idx(i + 1, j + 1)]);
                tris.push([idx(i, j), idx(i + 1, j + 1), idx(i, j + 1)]);
            }
        }
        self.mesh(name, pos, tris, material)
    }

    /// A horizontal square of side `size` centred at `centre`, facing +Y (up).
    pub fn floor(&mut self, name: &str, centre: Vec3, size: f32, material: MaterialId) -> &mut Self {
        let h = size * 0.5;
        self.quad(
            name,
            [
                centre + Vec3::new(-h, 0.0, h),
                centre + Vec3::new(h, 0.0, h),
                centre + Vec3::new(h, 0.0, -h),
                centre + Vec3::new(-h, 0.0, -h),
            ],
            material,
        )
    }

    /// An axis-aligned box from `lo` to `hi`. With `inward` its faces look into the box
    /// (a closed room); otherwise out of it (a solid block).
    pub fn cuboid(&mut self, name: &str, lo: Vec3, hi: Vec3, inward: bool, material: MaterialId) -> &mut Self {
        let p = |x: usize, y: usize, z: usize| Vec3::new([lo.x, hi.x][x], [lo.y, hi.y][y], [lo.z, hi.z][z]);
        // Outward-facing CCW quads.
        let faces = [
            [p(0, 0, 0), p(0, 0, 1), p(0, 1, 1), p(0, 1, 0)], // -X
            [p(1, 0, 0), p(1, 1, 0), p(1, 1, 1), p(1, 0, 1)], // +X
            [p(0, 0, 0), p(1, 0, 0), p(1, 0, 1), p(0, 0, 1)], // -Y
            [p(0, 1, 0), p(0, 1, 1), p(1, 1, 1), p(1, 1, 0)], // +Y
            [p(0, 0, 0), p(0, 1, 0), p(1, 1, 0), p(1, 0, 0)], // -Z
            [p(0, 0, 1), p(1, 0, 1), p(1, 1, 1), p(0, 1, 1)], // +Z
        ];
        let mut pos = Vec::new();
        let mut tris = Vec::new();
        for f in faces {
            let base = pos.len() as u32;
            pos.extend_from_slice(&f);
            if inward {
                tris.push([base, base + 2, base + 1]);
                tris.push([base, base + 3, base + 2]);
            } else {
                tris.push([base, base + 1, base + 2]);
                tris.push([base, base + 2, base + 3]);
            }
        }
        self.mesh(name, pos, tris, material)
    }

    pub fn light(&mut self, light: PunctualLight) -> &mut Self {
        self.scene.lights.push(light);
        self
    }

    pub fn point_light(&mut self, position: Vec3, intensity: Rgb) -> &mut Self {
        self.light(PunctualLight {
            name: "point".into(),
            kind: LightKind::Point,
            intensity,
            position,
            direction: Vec3::NEG_Z,
            range: None,
        })
    }

    pub fn directional_light(&mut self, direction: Vec3, irradiance: Rgb) -> &mut Self {
        self.light(PunctualLight {
            name: "sun".into(),
            kind: LightKind::Directional,
            intensity: irradiance,
            position: Vec3::ZERO,
            direction: direction.normalize(),
            range: None,
        })
    }

    pub fn build(mut self) -> Scene {
        if self.scene.materials.is_empty() {
            self.scene.materials.push(Material::default());
        }
        self.scene.stats.triangles = self.scene.triangle_count();
        self.scene.stats.primitives = self.scene.meshes.len();
        self.scene.stats.lights = self.scene.lights.len();
        self.scene
    }
}

/// White (albedo 1) single-sided material with no emission: the glTF default.
pub fn white() -> Material {
    Material { base_color: Vec4::ONE, ..Material::default() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneGeometry;

    #[test]
    fn cuboid_faces_point_the_requested_way() {
        for inward in [true, false] {
            let mut b = SceneBuilder::new();
            let m = b.material(white());
            b.cuboid("box", Vec3::ZERO, Vec3::ONE, inward, m);
            let s = b.build();
            let g = SceneGeometry::new(&s);
            assert_eq!(g.len(), 12);
            for t in 0..g.len() {
                let c = (g.corners[t][0] + g.corners[t][1] + g.corners[t][2]) / 3.0;
                let outward = (c - Vec3::splat(0.5)).dot(g.normals[t]) > 0.0;
                assert_eq!(outward, !inward);
                assert!((g.areas[t] - 0.5).abs() < 1e-6);
            }
        }
    }

    #[test]
    fn grid_quad_covers_the_quad() {
        let mut b = SceneBuilder::new();
        let m = b.material(white());
        b.grid_quad("g", [Vec3::ZERO, Vec3::X * 2.0, Vec3::new(2.0, 0.0, -3.0), Vec3::new(0.0, 0.0, -3.0)], 4, m);
        let s = b.build();
        let g = SceneGeometry::new(&s);
        assert_eq!(g.len(), 32);
        assert!((g.total_area() - 6.0).abs() < 1e-5);
        assert!(g.normals.iter().all(|n| (*n - Vec3::Y).length() < 1e-6));
    }
}
