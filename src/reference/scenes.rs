//! Synthetic scenes for tests and benchmarks of the reference tracer (and later of the
//! baker against it).

use std::collections::HashMap;

use glam::{Affine3A, Vec3};

use crate::scene::builder::{diffuse, white};
use crate::scene::{LightKind, MaterialId, PunctualLight, Rgb, Scene, SceneBuilder};

/// A UV sphere facing outwards: `rings` latitude bands × `segments` longitudes,
/// `2·segments·(rings − 1)` triangles (no degenerate triangles at the poles).
pub fn uv_sphere(
    b: &mut SceneBuilder,
    name: &str,
    centre: Vec3,
    radius: f32,
    rings: u32,
    segments: u32,
    material: MaterialId,
) {
    let (rings, segments) = (rings.max(2), segments.max(3));
    let mut pos = vec![centre + Vec3::Y * radius];
    for r in 1..rings {
        let theta = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let phi = std::f32::consts::TAU * s as f32 / segments as f32;
            let dir = Vec3::new(theta.sin() * phi.cos(), theta.cos(), -theta.sin() * phi.sin());
            pos.push(centre + dir * radius);
        }
    }
    pos.push(centre - Vec3::Y * radius);
    let south = pos.len() as u32 - 1;
    let ring = |r: u32, s: u32| 1 + (r - 1) * segments + s % segments;
    let mut tris = Vec::new();
    for s in 0..segments {
        tris.push([0, ring(1, s), ring(1, s + 1)]);
        tris.push([south, ring(rings - 1, s + 1), ring(rings - 1, s)]);
    }
    for r in 1..rings - 1 {
        for s in 0..segments {
            let (a, b2, c, d) = (ring(r, s), ring(r + 1, s), ring(r + 1, s + 1), ring(r, s + 1));
            tris.push([a, b2, c]);
            tris.push([a, c, d]);
        }
    }
    b.mesh(name, pos, tris, material);
}

/// The six faces of an axis-aligned room from `lo` to `hi`, facing inwards, each a grid quad:
/// the floor `n_floor²` cells, the ceiling `n_ceiling²`, each wall `n_wall²`.
#[allow(clippy::too_many_arguments)]
pub fn grid_room(
    b: &mut SceneBuilder,
    lo: Vec3,
    hi: Vec3,
    (n_floor, n_ceiling, n_wall): (u32, u32, u32),
    floor: MaterialId,
    ceiling: MaterialId,
    walls: MaterialId,
) {
    let p = |x: usize, y: usize, z: usize| Vec3::new([lo.x, hi.x][x], [lo.y, hi.y][y], [lo.z, hi.z][z]);
    // Corners a, b, c, d with (b − a) × (d − a) pointing into the room.
    b.grid_quad("floor", [p(0, 0, 1), p(1, 0, 1), p(1, 0, 0), p(0, 0, 0)], n_floor, floor);
    b.grid_quad("ceiling", [p(0, 1, 0), p(1, 1, 0), p(1, 1, 1), p(0, 1, 1)], n_ceiling, ceiling);
    b.grid_quad("wall -x", [p(0, 0, 0), p(0, 1, 0), p(0, 1, 1), p(0, 0, 1)], n_wall, walls);
    b.grid_quad("wall +x", [p(1, 0, 0), p(1, 0, 1), p(1, 1, 1), p(1, 1, 0)], n_wall, walls);
    b.grid_quad("wall -z", [p(0, 0, 0), p(1, 0, 0), p(1, 1, 0), p(0, 1, 0)], n_wall, walls);
    b.grid_quad("wall +z", [p(0, 0, 1), p(0, 1, 1), p(1, 1, 1), p(1, 0, 1)], n_wall, walls);
}

/// A box with four legs (table, stool...): top from `lo` to `hi`, legs down to y = `floor`.
fn table(b: &mut SceneBuilder, name: &str, lo: Vec3, hi: Vec3, floor: f32, leg: f32, m: MaterialId) {
    b.cuboid(name, lo, hi, false, m);
    for (x, z) in [(lo.x, lo.z), (hi.x - leg, lo.z), (lo.x, hi.z - leg), (hi.x - leg, hi.z - leg)] {
        b.cuboid(name, Vec3::new(x, floor, z), Vec3::new(x + leg, lo.y, z + leg), false, m);
    }
}

/// A closed 6 × 3 × 5 m room with furniture, ~10k triangles: grid-tessellated walls
/// (floor 40², ceiling 20², walls 16² cells), a UV sphere (28 × 48), a rug (20²), a
/// table and four chairs with legs, a bookshelf, a sofa, a double-sided painting panel,
/// two single-sided emissive ceiling panels (1 × 1 m, Le = 8) and a point light (5 W/sr).
pub fn furnished_room() -> Scene {
    let mut b = SceneBuilder::new();
    let wall = b.material(diffuse(Vec3::new(0.80, 0.78, 0.72), Vec3::ZERO, false));
    let floor = b.material(diffuse(Vec3::new(0.45, 0.32, 0.20), Vec3::ZERO, false));
    let ceiling = b.material(diffuse(Vec3::splat(0.85), Vec3::ZERO, false));
    let wood = b.material(diffuse(Vec3::new(0.55, 0.40, 0.25), Vec3::ZERO, false));
    let fabric = b.material(diffuse(Vec3::new(0.20, 0.30, 0.55), Vec3::ZERO, false));
    let rug = b.material(diffuse(Vec3::new(0.60, 0.15, 0.12), Vec3::ZERO, false));
    let ball = b.material(diffuse(Vec3::new(0.70, 0.70, 0.70), Vec3::ZERO, false));
    let painting = b.material(diffuse(Vec3::new(0.30, 0.60, 0.35), Vec3::ZERO, true));
    let lamp = b.material(diffuse(Vec3::splat(0.9), Vec3::splat(8.0), false));

    grid_room(&mut b, Vec3::ZERO, Vec3::new(6.0, 3.0, 5.0), (40, 20, 16), floor, ceiling, wall);
    uv_sphere(&mut b, "sphere", Vec3::new(4.6, 0.6, 1.2), 0.6, 28, 48, ball);
    b.grid_quad(
        "rug",
        [Vec3::new(1.5, 0.01, 4.0), Vec3::new(4.5, 0.01, 4.0), Vec3::new(4.5, 0.01, 2.0), Vec3::new(1.5, 0.01, 2.0)],
        20,
        rug,
    );
    table(&mut b, "table", Vec3::new(2.2, 0.72, 2.5), Vec3::new(3.8, 0.76, 3.5), 0.01, 0.06, wood);
    for (i, (x, z)) in [(2.5, 2.0), (3.2, 2.0), (2.5, 3.6), (3.2, 3.6)].into_iter().enumerate() {
        let name = format!("chair{i}");
        table(&mut b, &name, Vec3::new(x, 0.42, z), Vec3::new(x + 0.42, 0.46, z + 0.42), 0.01, 0.04, wood);
        let (bz0, bz1) = if z < 3.0 { (z - 0.04, z) } else { (z + 0.42, z + 0.46) };
        b.cuboid(&name, Vec3::new(x, 0.46, bz0), Vec3::new(x + 0.42, 0.95, bz1), false, wood);
    }
    // Bookshelf against the −x wall: carcass and shelves.
    b.cuboid("shelf", Vec3::new(0.0, 0.0, 0.5), Vec3::new(0.35, 2.0, 0.52), false, wood);
    b.cuboid("shelf", Vec3::new(0.0, 0.0, 1.98), Vec3::new(0.35, 2.0, 2.0), false, wood);
    for k in 0..5 {
        let y = 0.05 + 0.45 * k as f32;
        b.cuboid("shelf", Vec3::new(0.0, y, 0.52), Vec3::new(0.35, y + 0.03, 1.98), false, wood);
    }
    // Sofa against the +z wall.
    b.cuboid("sofa", Vec3::new(1.8, 0.0, 4.1), Vec3::new(4.2, 0.45, 4.95), false, fabric);
    b.cuboid("sofa", Vec3::new(1.8, 0.45, 4.7), Vec3::new(4.2, 0.95, 4.95), false, fabric);
    b.cuboid("sofa", Vec3::new(1.6, 0.0, 4.1), Vec3::new(1.8, 0.65, 4.95), false, fabric);
    b.cuboid("sofa", Vec3::new(4.2, 0.0, 4.1), Vec3::new(4.4, 0.65, 4.95), false, fabric);
    // A double-sided painting panel standing free in front of the +x wall.
    b.grid_quad(
        "painting",
        [Vec3::new(5.6, 1.0, 3.0), Vec3::new(5.6, 1.0, 4.2), Vec3::new(5.6, 2.0, 4.2), Vec3::new(5.6, 2.0, 3.0)],
        10,
        painting,
    );
    for (x, z) in [(1.5, 1.5), (3.5, 2.5)] {
        b.quad(
            "lamp",
            [
                Vec3::new(x, 2.99, z),
                Vec3::new(x + 1.0, 2.99, z),
                Vec3::new(x + 1.0, 2.99, z + 1.0),
                Vec3::new(x, 2.99, z + 1.0),
            ],
            lamp,
        );
    }
    b.light(PunctualLight {
        name: "bulb".into(),
        kind: LightKind::Point,
        intensity: Vec3::new(5.0, 4.5, 3.5),
        position: Vec3::new(1.0, 2.2, 3.8),
        direction: Vec3::NEG_Y,
        range: None,
    });
    b.build()
}

pub fn icosphere(centre: Vec3, r: f32, subdiv: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let t = (1.0 + 5f32.sqrt()) / 2.0;
    let mut p: Vec<Vec3> = [
        (-1.0, t, 0.0),
        (1.0, t, 0.0),
        (-1.0, -t, 0.0),
        (1.0, -t, 0.0),
        (0.0, -1.0, t),
        (0.0, 1.0, t),
        (0.0, -1.0, -t),
        (0.0, 1.0, -t),
        (t, 0.0, -1.0),
        (t, 0.0, 1.0),
        (-t, 0.0, -1.0),
        (-t, 0.0, 1.0),
    ]
    .iter()
    .map(|&(x, y, z)| Vec3::new(x, y, z).normalize())
    .collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..subdiv {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut m = |a: u32, b: u32, p: &mut Vec<Vec3>| {
            *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
                p.push(((p[a as usize] + p[b as usize]) * 0.5).normalize());
                (p.len() - 1) as u32
            })
        };
        let mut g = Vec::new();
        for [a, b, c] in f {
            let (ab, bc, ca) = (m(a, b, &mut p), m(b, c, &mut p), m(c, a, &mut p));
            g.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        f = g;
    }
    (p.into_iter().map(|q| centre + q * r).collect(), f)
}

pub fn torus(centre: Vec3, r0: f32, r1: f32, n0: u32, n1: u32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
    let mut p = Vec::new();
    for i in 0..n0 {
        let a = i as f32 / n0 as f32 * std::f32::consts::TAU;
        for j in 0..n1 {
            let b = j as f32 / n1 as f32 * std::f32::consts::TAU;
            let rr = r0 + r1 * b.cos();
            p.push(centre + Vec3::new(rr * a.cos(), r1 * b.sin(), rr * a.sin()));
        }
    }
    let id = |i: u32, j: u32| (i % n0) * n1 + (j % n1);
    let mut f = Vec::new();
    for i in 0..n0 {
        for j in 0..n1 {
            f.push([id(i, j), id(i, j + 1), id(i + 1, j + 1)]);
            f.push([id(i, j), id(i + 1, j + 1), id(i + 1, j)]);
        }
    }
    (p, f)
}

/// A synthetic "temple complex": a 120 m courtyard, 400 columns (box shaft, torus base,
/// icosphere capital), tiled floors. 312k triangles, 491k faces.
pub fn temple() -> Scene {
    let mut b = SceneBuilder::new();
    let m = b.material(white());
    let d = b.material(diffuse(Vec3::splat(0.7), Vec3::ZERO, true));
    // A "temple complex": 120 m courtyard, rooms, 400 columns (tori + spheres), tiled floors.
    b.cuboid("court", Vec3::new(-60.0, 0.0, -60.0), Vec3::new(60.0, 15.0, 60.0), true, m);
    temple_columns(&mut b, m, d, 0.0);
    b.build()
}

/// The temple's 400 columns (shafts and capitals in `m`, bases in `d`) on a 5.2 m grid, and
/// its eight tiled floors (in `d`) `tiles_y` above the ground.
fn temple_columns(b: &mut SceneBuilder, m: MaterialId, d: MaterialId, tiles_y: f32) {
    for i in 0..20 {
        for j in 0..20 {
            let c = Vec3::new(-50.0 + i as f32 * 5.2, 0.0, -50.0 + j as f32 * 5.2);
            let (p, f) = icosphere(c + Vec3::Y * 6.0, 0.6, 2);
            b.mesh("capital", p, f, m);
            let (p, f) = torus(c + Vec3::Y * 0.3, 0.6, 0.2, 24, 8);
            b.mesh("base", p, f, d);
            b.cuboid("shaft", c - Vec3::new(0.3, 0.0, 0.3), c + Vec3::new(0.3, 5.5, 0.3), false, m);
        }
    }
    for k in 0..8 {
        let o = Vec3::new(-55.0 + k as f32 * 14.0, tiles_y, 58.0);
        b.grid_quad("tiles", [o, o + Vec3::X * 12.0, o + Vec3::new(12.0, 0.0, -12.0), o - Vec3::Z * 12.0], 40, d);
    }
}

/// [`temple`] lit, for the runtime's large-scene bench: the courtyard open to a uniform
/// overcast sky of radiance [`TEMPLE_SKY`] (open ground receives π × that), its floor and
/// walls of albedo 0.6 and the columns and tiles of 0.7 (an albedo of 1 would bounce light
/// without loss), the tiles raised 5 cm onto a low stage rather than coplanar with the
/// ground. 312k triangles, about 31 000 m² of lit surface.
pub fn temple_courtyard() -> Scene {
    courtyard(false)
}

/// [`temple_courtyard`] on a clear day: the same sky and a sun ([`TEMPLE_SUN`]) 40° above
/// the horizon, across the column rows (azimuth 30° from +x), so that every column casts a
/// sharp shadow several metres long over the floor and its neighbours. Open ground receives
/// 20·sin 40° ≈ 12.9 W/m² from the sun beside the sky's π: about the 4:1 of direct to
/// diffuse light of a clear day. Sharp shadows are what need fine texels near the viewer,
/// the case the runtime's LOD hierarchy is for.
pub fn temple_courtyard_sunlit() -> Scene {
    courtyard(true)
}

/// The sky radiance of [`temple_courtyard`], W/(sr·m²).
pub const TEMPLE_SKY: Rgb = Vec3::new(1.0, 1.0, 1.0);

/// The sun's irradiance on a surface facing it in [`temple_courtyard_sunlit`], W/m².
pub const TEMPLE_SUN: Rgb = Vec3::new(20.0, 20.0, 20.0);

fn courtyard(sun: bool) -> Scene {
    let mut b = SceneBuilder::new();
    let ground = b.material(diffuse(Vec3::splat(0.6), Vec3::ZERO, false));
    let stone = b.material(diffuse(Vec3::splat(0.7), Vec3::ZERO, false));
    let tiles = b.material(diffuse(Vec3::splat(0.7), Vec3::ZERO, true));
    b.sky(TEMPLE_SKY);
    if sun {
        let (elevation, azimuth) = (40f32.to_radians(), 30f32.to_radians());
        let towards_sun = Vec3::new(elevation.cos() * azimuth.cos(), elevation.sin(), elevation.cos() * azimuth.sin());
        b.directional_light(-towards_sun, TEMPLE_SUN);
    }
    let (lo, hi) = (Vec3::new(-60.0, 0.0, -60.0), Vec3::new(60.0, 15.0, 60.0));
    let p = |x: f32, y: f32, z: f32| Vec3::new(x, y, z);
    b.floor("court floor", p(0.0, 0.0, 0.0), hi.x - lo.x, ground);
    // The four walls, facing into the courtyard (corners counter-clockwise seen from inside).
    b.quad("wall -z", [p(lo.x, 0.0, lo.z), p(hi.x, 0.0, lo.z), p(hi.x, hi.y, lo.z), p(lo.x, hi.y, lo.z)], ground);
    b.quad("wall +z", [p(hi.x, 0.0, hi.z), p(lo.x, 0.0, hi.z), p(lo.x, hi.y, hi.z), p(hi.x, hi.y, hi.z)], ground);
    b.quad("wall -x", [p(lo.x, 0.0, hi.z), p(lo.x, 0.0, lo.z), p(lo.x, hi.y, lo.z), p(lo.x, hi.y, hi.z)], ground);
    b.quad("wall +x", [p(hi.x, 0.0, lo.z), p(hi.x, 0.0, hi.z), p(hi.x, hi.y, hi.z), p(hi.x, hi.y, lo.z)], ground);
    temple_columns(&mut b, stone, tiles, 0.05);
    b.build()
}

/// `scene` as exporters without shared vertices write it (game assets, BIM exports): every
/// triangle has its own three vertices with its face normal as shading normal, each vertex
/// moved by up to `jitter` metres per axis (the float noise of transformed exports), and every
/// `duplicate_every`-th mesh (0: none) carries a second, overlapping copy of all its triangles
/// (coincident faces, as decals and doubled walls give), jittered independently.
/// Deterministic in `seed`.
pub fn triangle_soup(scene: &Scene, jitter: f32, duplicate_every: usize, seed: u64) -> Scene {
    let mut out = scene.clone();
    let mut rng = crate::sampling::Rng::new(seed, 0x50u64);
    let mut shake = |p: Vec3| {
        p + Vec3::new(rng.next_f32() * 2.0 - 1.0, rng.next_f32() * 2.0 - 1.0, rng.next_f32() * 2.0 - 1.0) * jitter
    };
    for (mi, mesh) in out.meshes.iter_mut().enumerate() {
        let copies = if duplicate_every > 0 && mi % duplicate_every == duplicate_every - 1 { 2 } else { 1 };
        let n = mesh.triangles.len() * 3 * copies;
        let (mut pos, mut nor) = (Vec::with_capacity(n), Vec::with_capacity(n));
        let mut uv0 = mesh.uv0.as_ref().map(|_| Vec::with_capacity(n));
        let mut uv1 = mesh.uv1.as_ref().map(|_| Vec::with_capacity(n));
        for _ in 0..copies {
            for t in &mesh.triangles {
                let c = t.map(|v| mesh.positions[v as usize]);
                let normal = (c[1] - c[0]).cross(c[2] - c[0]).normalize_or(Vec3::Z);
                for &v in t {
                    pos.push(shake(mesh.positions[v as usize]));
                    nor.push(normal);
                    if let (Some(out), Some(src)) = (uv0.as_mut(), mesh.uv0.as_ref()) {
                        out.push(src[v as usize]);
                    }
                    if let (Some(out), Some(src)) = (uv1.as_mut(), mesh.uv1.as_ref()) {
                        out.push(src[v as usize]);
                    }
                }
            }
        }
        mesh.triangles = (0..(n / 3) as u32).map(|k| [3 * k, 3 * k + 1, 3 * k + 2]).collect();
        (mesh.positions, mesh.normals, mesh.uv0, mesh.uv1) = (pos, nor, uv0, uv1);
    }
    out.stats.triangles = out.triangle_count();
    out
}

/// [`temple`] as a triangle soup ([`triangle_soup`]: 10 µm jitter, every tenth mesh
/// doubled): 343k triangles, none sharing a vertex.
pub fn temple_soup() -> Scene {
    triangle_soup(&temple(), 1e-5, 10, 1)
}

/// The meshes of several scenes, each under an affine transform, in one scene (as a glTF
/// with instanced nodes loads: one mesh per instance, in world space). Materials are copied
/// per part; lights and cameras are dropped.
pub fn instanced(parts: &[(&Scene, Affine3A)]) -> Scene {
    let mut out = Scene::default();
    for (scene, xf) in parts {
        let first_material = out.materials.len() as MaterialId;
        out.materials.extend(scene.materials.iter().cloned());
        let normal_xf = glam::Mat3::from(xf.matrix3).inverse().transpose();
        for mesh in &scene.meshes {
            let mut m = mesh.clone();
            m.material += first_material;
            for p in &mut m.positions {
                *p = xf.transform_point3(*p);
            }
            for n in &mut m.normals {
                *n = (normal_xf * *n).normalize_or(Vec3::Z);
            }
            if xf.matrix3.determinant() < 0.0 {
                // A mirror flips the winding: keep the front faces in front.
                for t in &mut m.triangles {
                    t.swap(1, 2);
                }
            }
            out.meshes.push(m);
        }
    }
    if out.materials.is_empty() {
        out.materials.push(white());
    }
    out.stats.triangles = out.triangle_count();
    out.stats.primitives = out.meshes.len();
    out
}

/// A ≥ 1 M-triangle instanced scene: three copies of [`temple_soup`] (as exported, turned
/// 30° and scaled to 60 %, and mirrored and raised 2 m) side by side, and eight
/// [`furnished_room`]s under rotations and scales between them. 1.11 M triangles.
pub fn temple_instanced() -> Scene {
    let soup = temple_soup();
    let room = furnished_room();
    let mut parts: Vec<(&Scene, Affine3A)> = vec![
        (&soup, Affine3A::IDENTITY),
        (
            &soup,
            Affine3A::from_scale_rotation_translation(
                Vec3::splat(0.6),
                glam::Quat::from_rotation_y(0.52),
                Vec3::new(140.0, 0.0, 0.0),
            ),
        ),
        (
            &soup,
            Affine3A::from_scale_rotation_translation(
                Vec3::new(-1.0, 1.0, 1.0),
                glam::Quat::IDENTITY,
                Vec3::new(0.0, 2.0, 140.0),
            ),
        ),
    ];
    for k in 0..8 {
        let a = k as f32 * 0.7;
        let s = 0.8 + 0.1 * k as f32;
        parts.push((
            &room,
            Affine3A::from_scale_rotation_translation(
                Vec3::splat(s),
                glam::Quat::from_rotation_y(a),
                Vec3::new(-90.0 - 12.0 * k as f32, 0.0, 30.0),
            ),
        ));
    }
    instanced(&parts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneGeometry;

    #[test]
    fn room_faces_inwards_and_sphere_outwards() {
        let mut b = SceneBuilder::new();
        let m = b.material(diffuse(Vec3::ONE, Vec3::ZERO, false));
        let (lo, hi) = (Vec3::ZERO, Vec3::new(6.0, 3.0, 5.0));
        grid_room(&mut b, lo, hi, (3, 2, 2), m, m, m);
        let c = Vec3::new(2.0, 1.0, 2.0);
        uv_sphere(&mut b, "s", c, 0.5, 6, 8, m);
        let s = b.build();
        let g = SceneGeometry::new(&s);
        assert_eq!(g.len(), 2 * (9 + 4 + 4 * 4) + 2 * 8 * 5);
        for t in 0..g.len() {
            let centroid = (g.corners[t][0] + g.corners[t][1] + g.corners[t][2]) / 3.0;
            let into = if g.mesh[t] < 6 { (lo + hi) * 0.5 - centroid } else { centroid - c };
            assert!(g.normals[t].dot(into) > 0.0, "triangle {t} of mesh {}", g.mesh[t]);
            assert!(g.areas[t] > 0.0);
        }
    }

    #[test]
    fn furnished_room_has_about_ten_thousand_triangles() {
        let n = furnished_room().triangle_count();
        assert!((9_000..11_000).contains(&n), "{n}");
    }
}
