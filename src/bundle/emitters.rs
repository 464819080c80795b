//! Emitter groups for the light pass.
//!
//! Uniform bundle directions rarely hit a small light (a floor texel sees a 0.25 m² ceiling
//! light in under 0.5% of directions), so direct light from small emitters gets its own
//! pass: bundles clipped to each group's footprint, many directions per global direction.
//! Large emitters (a glowing wall, a furnace) are hit often by the global bundles, which
//! then carry their emission directly; each emitter is estimated by exactly one of the two.

use std::collections::HashMap;
use std::collections::hash_map::Entry;

use glam::Vec3;

use crate::scene::{Scene, SceneGeometry};

/// Connected emissive triangles of one mesh, lit into the scene by the light pass.
#[derive(Clone, Debug)]
pub struct EmitterGroup {
    pub mesh: u32,
    pub triangles: Vec<u32>,
    /// Emitting area (m², both sides of double-sided emitters).
    pub area: f32,
    pub bounds_min: Vec3,
    pub bounds_max: Vec3,
    /// Area-weighted mean geometric normal (may be ~0 for closed emitters).
    pub mean_normal: Vec3,
}

impl EmitterGroup {
    pub fn corners(&self) -> [Vec3; 8] {
        let (a, b) = (self.bounds_min, self.bounds_max);
        std::array::from_fn(|i| {
            Vec3::new(
                if i & 1 == 0 { a.x } else { b.x },
                if i & 2 == 0 { a.y } else { b.y },
                if i & 4 == 0 { a.z } else { b.z },
            )
        })
    }
}

/// How emitters are split between the light pass and the global bundles.
#[derive(Clone, Debug, Default)]
pub struct EmitterPlan {
    /// Groups handled by the light pass.
    pub small: Vec<EmitterGroup>,
    /// Per triangle: whether the global bundles carry its emission (a large emitter).
    pub carried_by_bundles: Vec<bool>,
}

/// Union-find over triangle indices.
fn find(parent: &mut [u32], mut i: u32) -> u32 {
    while parent[i as usize] != i {
        parent[i as usize] = parent[parent[i as usize] as usize];
        i = parent[i as usize];
    }
    i
}

/// Groups emissive triangles (connected through shared vertices, per mesh) and splits them:
/// groups whose emitting area is below `small_fraction` of the scene's lit area go to the
/// light pass, the rest stay with the global bundles.
pub fn plan_emitters(scene: &Scene, geom: &SceneGeometry, lit_area: f64, small_fraction: f64) -> EmitterPlan {
    let mut plan = EmitterPlan { small: Vec::new(), carried_by_bundles: vec![false; geom.len()] };
    for (mi, mesh) in scene.meshes.iter().enumerate() {
        let material = scene.material_of(mesh);
        if !material.is_emissive() {
            continue;
        }
        let first = geom.mesh_offsets[mi];
        let n = mesh.triangles.len() as u32;
        // Triangles touching at a corner position join one group. Positions, not vertex
        // indices: exporters split vertices wherever normals change (a lamp box's faces).
        let mut parent: Vec<u32> = (0..n).collect();
        let mut owner: HashMap<[u32; 3], u32> = HashMap::new();
        for (t, tri) in mesh.triangles.iter().enumerate() {
            for &v in tri {
                let key = mesh.positions[v as usize].to_array().map(f32::to_bits);
                match owner.entry(key) {
                    Entry::Vacant(e) => {
                        e.insert(t as u32);
                    }
                    Entry::Occupied(e) => {
                        let (a, b) = (find(&mut parent, *e.get()), find(&mut parent, t as u32));
                        parent[a.max(b) as usize] = a.min(b);
                    }
                }
            }
        }
        let mut groups: Vec<Vec<u32>> = Vec::new();
        let mut group_of_root = vec![u32::MAX; n as usize];
        for t in 0..n {
            let r = find(&mut parent, t) as usize;
            if group_of_root[r] == u32::MAX {
                group_of_root[r] = groups.len() as u32;
                groups.push(Vec::new());
            }
            groups[group_of_root[r] as usize].push(first + t);
        }
        let sides = if material.double_sided { 2.0 } else { 1.0 };
        for triangles in groups {
            let area: f32 = triangles.iter().map(|&t| geom.areas[t as usize]).sum::<f32>() * sides;
            if (area as f64) < small_fraction * lit_area {
                plan.small.push(group(mi as u32, triangles, area, geom));
            } else {
                for &t in &triangles {
                    plan.carried_by_bundles[t as usize] = true;
                }
            }
        }
    }
    plan
}

fn group(mesh: u32, triangles: Vec<u32>, area: f32, geom: &SceneGeometry) -> EmitterGroup {
    let mut lo = Vec3::splat(f32::MAX);
    let mut hi = Vec3::splat(f32::MIN);
    let mut normal = Vec3::ZERO;
    for &t in &triangles {
        for p in geom.corners[t as usize] {
            lo = lo.min(p);
            hi = hi.max(p);
        }
        normal += geom.normals[t as usize] * geom.areas[t as usize];
    }
    EmitterGroup { mesh, triangles, area, bounds_min: lo, bounds_max: hi, mean_normal: normal.normalize_or_zero() }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::SceneBuilder;
    use crate::scene::builder::diffuse;

    #[test]
    fn small_lamps_go_to_the_light_pass_and_glowing_rooms_stay_global() {
        let mut b = SceneBuilder::new();
        let wall = b.material(diffuse(Vec3::splat(0.5), Vec3::ZERO, false));
        let lamp = b.material(diffuse(Vec3::ZERO, Vec3::splat(10.0), false));
        let glow = b.material(diffuse(Vec3::splat(0.5), Vec3::splat(1.0), false));
        b.cuboid("room", Vec3::ZERO, Vec3::splat(4.0), true, wall);
        // Two separate lamps in one mesh: two groups.
        let y = 3.9;
        let quad = |x: f32| {
            [Vec3::new(x, y, 1.0), Vec3::new(x + 0.5, y, 1.0), Vec3::new(x + 0.5, y, 1.5), Vec3::new(x, y, 1.5)]
        };
        let (q1, q2) = (quad(1.0), quad(2.5));
        let mut pos = q1.to_vec();
        pos.extend_from_slice(&q2);
        b.mesh("lamps", pos, vec![[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], lamp);
        b.cuboid("glowing block", Vec3::splat(1.0), Vec3::splat(3.0), false, glow);
        // A lamp box with unwelded faces (cuboid gives each face its own vertices): one group.
        b.cuboid("lamp box", Vec3::new(3.0, 3.8, 3.0), Vec3::new(3.4, 3.9, 3.4), false, lamp);
        let scene = b.build();
        let geom = SceneGeometry::new(&scene);
        let lit = geom.total_area();
        let plan = plan_emitters(&scene, &geom, lit, 0.05);
        assert_eq!(plan.small.len(), 3);
        assert_eq!(plan.small[2].triangles.len(), 12);
        for g in &plan.small[..2] {
            assert_eq!(g.triangles.len(), 2);
            assert!((g.area - 0.25).abs() < 1e-5);
            assert!((g.mean_normal - Vec3::NEG_Y).length() < 1e-5, "{:?}", g.mean_normal);
        }
        // The 24 m² glowing block (of ~120 m² lit) is carried by the global bundles.
        let carried = plan.carried_by_bundles.iter().filter(|&&c| c).count();
        assert_eq!(carried, 12);
    }
}
