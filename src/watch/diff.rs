//! [`SceneDiff`]: what changed between two loaded scenes, by content.
//!
//! Mesh instances are compared by their world-space geometry (positions, normals, uv0, uv1,
//! vertex colours, triangles: the node transform is already in the positions) and their
//! material's content (base colour, emission, sidedness, alpha mode and texture pixels; not
//! the material's name or index). Floats compare by their bits, so the diff is exact: a save that writes the same
//! numbers gives an empty diff, any other change is seen.
//!
//! Matching, in order:
//! 1. **unchanged**: a new mesh whose content equals an old one's (found by a 64-bit content
//!    hash, then confirmed element by element); among equal candidates the one of the same
//!    name, else the first. Order does not matter: a node added in front shifts every index,
//!    and the mapping says where each old mesh went.
//! 2. **changed**: the remaining old and new meshes of the same name (`node/mesh/primitive`),
//!    paired in order; then the remaining ones with the same topology (triangles, uv0, uv1),
//!    which pairs a moved mesh whose name did change (unnamed nodes are named by their
//!    index, which shifts when nodes are added).
//! 3. **removed** / **added**: whatever is left on either side.
//!
//! Lights are compared as a multiset of their content (kind, intensity, position, direction,
//! range; not names or order), the sky by value. Cameras do not affect light and are ignored.

use std::collections::HashMap;

use glam::{Vec2, Vec3};

use crate::scene::{AlphaMode, LightKind, Material, Mesh, PunctualLight, Scene, Texture, TextureRef};

/// An axis-aligned world-space box (metres). A mesh without vertices has the empty box
/// (`min = +∞`, `max = −∞`), which meets nothing.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: Vec3,
    pub max: Vec3,
}

impl Aabb {
    pub const EMPTY: Aabb = Aabb { min: Vec3::INFINITY, max: Vec3::NEG_INFINITY };

    pub fn of_points(points: &[Vec3]) -> Aabb {
        points.iter().fold(Aabb::EMPTY, |b, &p| Aabb { min: b.min.min(p), max: b.max.max(p) })
    }
}

/// A mesh present in both scenes whose content differs.
#[derive(Clone, Debug, PartialEq)]
pub struct ChangedMesh {
    /// Index in the old scene's meshes.
    pub old: usize,
    /// Index in the new scene's meshes.
    pub new: usize,
    pub old_bounds: Aabb,
    pub new_bounds: Aabb,
    /// Positions, normals, uvs or triangles differ.
    pub geometry_changed: bool,
    /// The material's content differs (a different material of equal content is no change).
    pub material_changed: bool,
}

/// A mesh present in one scene only.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshAt {
    /// Index in the new scene (added) or the old scene (removed).
    pub index: usize,
    pub bounds: Aabb,
}

/// The difference between an old and a new scene. The surroundings (sky, environment, sun)
/// are an input, like the rest: set each scene's from the configuration before diffing (a
/// loaded scene has none).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SceneDiff {
    /// `(old index, new index)` of every mesh whose content is the same, by new index.
    pub unchanged: Vec<(usize, usize)>,
    /// By new index.
    pub changed: Vec<ChangedMesh>,
    /// By new index.
    pub added: Vec<MeshAt>,
    /// By old index.
    pub removed: Vec<MeshAt>,
    pub lights_changed: bool,
    /// The uniform sky's radiance or the environment map (compared as the same map or not:
    /// maps are shared, never edited).
    pub sky_changed: bool,
    /// Some mesh kept (paired as changed) has a material of different content.
    pub materials_changed: bool,
}

impl SceneDiff {
    pub fn between(old: &Scene, new: &Scene) -> SceneDiff {
        let old_keys = MeshKeys::of(old);
        let new_keys = MeshKeys::of(new);
        let mut old_taken = vec![false; old.meshes.len()];
        let mut new_taken = vec![false; new.meshes.len()];

        // 1. Equal content.
        let mut by_content: HashMap<u64, Vec<usize>> = HashMap::new();
        for (i, &k) in old_keys.content.iter().enumerate() {
            by_content.entry(k).or_default().push(i);
        }
        let mut unchanged = Vec::new();
        for (n, mesh) in new.meshes.iter().enumerate() {
            let Some(candidates) = by_content.get(&new_keys.content[n]) else { continue };
            let equal = |o: &&usize| !old_taken[**o] && mesh_content_eq(old, &old.meshes[**o], new, mesh);
            let found = candidates
                .iter()
                .filter(equal)
                .find(|&&o| old.meshes[o].name == mesh.name)
                .or_else(|| candidates.iter().find(equal));
            if let Some(&o) = found {
                old_taken[o] = true;
                new_taken[n] = true;
                unchanged.push((o, n));
            }
        }

        // 2. Same name, then same topology.
        let mut pairs = Vec::new();
        pair_by_key(
            (&mut old_taken, &mut new_taken),
            &mut pairs,
            |o| &old.meshes[o].name,
            |n| &new.meshes[n].name,
            |_, _| true,
        );
        pair_by_key(
            (&mut old_taken, &mut new_taken),
            &mut pairs,
            |o| old_keys.topology[o],
            |n| new_keys.topology[n],
            |o, n| topology_eq(&old.meshes[o], &new.meshes[n]),
        );
        pairs.sort_by_key(|&(_, n)| n);
        let changed: Vec<ChangedMesh> = pairs
            .iter()
            .map(|&(o, n)| {
                let (om, nm) = (&old.meshes[o], &new.meshes[n]);
                ChangedMesh {
                    old: o,
                    new: n,
                    old_bounds: Aabb::of_points(&om.positions),
                    new_bounds: Aabb::of_points(&nm.positions),
                    geometry_changed: !geometry_eq(om, nm),
                    material_changed: !material_eq(old, om.material, new, nm.material),
                }
            })
            .collect();
        let materials_changed = changed.iter().any(|c| c.material_changed);

        // 3. The rest.
        let at = |meshes: &[Mesh], i: usize| MeshAt { index: i, bounds: Aabb::of_points(&meshes[i].positions) };
        let added = (0..new.meshes.len()).filter(|&n| !new_taken[n]).map(|n| at(&new.meshes, n)).collect();
        let removed = (0..old.meshes.len()).filter(|&o| !old_taken[o]).map(|o| at(&old.meshes, o)).collect();

        SceneDiff {
            unchanged,
            changed,
            added,
            removed,
            lights_changed: light_keys(&old.lights) != light_keys(&new.lights),
            sky_changed: old.sky.to_array().map(f32::to_bits) != new.sky.to_array().map(f32::to_bits)
                || match (&old.environment, &new.environment) {
                    (Some(a), Some(b)) => !std::sync::Arc::ptr_eq(a, b),
                    (a, b) => a.is_some() != b.is_some(),
                },
            materials_changed,
        }
    }

    /// Nothing that light transport sees changed.
    pub fn is_empty(&self) -> bool {
        self.changed.is_empty()
            && self.added.is_empty()
            && self.removed.is_empty()
            && !self.lights_changed
            && !self.sky_changed
            && !self.materials_changed
    }

    /// For each old mesh, its index in the new scene if it is unchanged.
    pub fn old_to_new(&self, old_meshes: usize) -> Vec<Option<usize>> {
        let mut map = vec![None; old_meshes];
        for &(o, n) in &self.unchanged {
            map[o] = Some(n);
        }
        map
    }

    /// Every box where surfaces appeared, vanished or changed: old and new bounds of changed
    /// meshes, bounds of added and removed ones. The cells meeting these (with a margin) are
    /// the ones to re-bake first.
    pub fn touched_bounds(&self) -> impl Iterator<Item = Aabb> + '_ {
        self.changed
            .iter()
            .flat_map(|c| [c.old_bounds, c.new_bounds])
            .chain(self.added.iter().chain(&self.removed).map(|m| m.bounds))
    }
}

/// Pairs every old mesh not yet taken with the first new mesh not yet taken that has the
/// same key and for which `confirm(old, new)`, in order, and marks both taken.
fn pair_by_key<K: std::hash::Hash + Eq>(
    taken: (&mut [bool], &mut [bool]),
    pairs: &mut Vec<(usize, usize)>,
    old_key: impl Fn(usize) -> K,
    new_key: impl Fn(usize) -> K,
    confirm: impl Fn(usize, usize) -> bool,
) {
    let (old_taken, new_taken) = taken;
    let mut open: HashMap<K, Vec<usize>> = HashMap::new();
    for n in (0..new_taken.len()).filter(|&n| !new_taken[n]) {
        open.entry(new_key(n)).or_default().push(n);
    }
    for (o, old_done) in old_taken.iter_mut().enumerate().filter(|(_, done)| !**done) {
        let Some(candidates) = open.get(&old_key(o)) else { continue };
        if let Some(&n) = candidates.iter().find(|&&n| !new_taken[n] && confirm(o, n)) {
            *old_done = true;
            new_taken[n] = true;
            pairs.push((o, n));
        }
    }
}

/// Per-mesh hashes of one scene: full content (geometry and material), and topology only.
struct MeshKeys {
    content: Vec<u64>,
    topology: Vec<u64>,
}

impl MeshKeys {
    fn of(scene: &Scene) -> MeshKeys {
        let textures: Vec<u64> = scene.textures.iter().map(texture_hash).collect();
        let materials: Vec<u64> = scene.materials.iter().map(|m| material_hash(m, &textures)).collect();
        let mut content = Vec::with_capacity(scene.meshes.len());
        let mut topology = Vec::with_capacity(scene.meshes.len());
        for mesh in &scene.meshes {
            let mut t = BulkHasher::default();
            hash_topology(&mut t, mesh);
            let topo = t.finish();
            let mut c = BulkHasher::default();
            c.word(topo as u32);
            c.word((topo >> 32) as u32);
            c.vec3s(&mesh.positions);
            c.vec3s(&mesh.normals);
            match &mesh.colors {
                Some(colors) => {
                    c.word(1);
                    c.words(colors.iter().flat_map(|v| v.to_array().map(f32::to_bits)));
                }
                None => c.word(0),
            }
            c.word(materials.get(mesh.material as usize).map_or(u32::MAX, |&h| h as u32));
            topology.push(topo);
            content.push(c.finish());
        }
        MeshKeys { content, topology }
    }
}

fn hash_topology(h: &mut BulkHasher, mesh: &Mesh) {
    h.word(mesh.triangles.len() as u32);
    h.words(mesh.triangles.iter().flatten().copied());
    for uv in [&mesh.uv0, &mesh.uv1] {
        match uv {
            Some(uv) => {
                h.word(1);
                h.vec2s(uv);
            }
            None => h.word(0),
        }
    }
}

fn texture_hash(t: &Texture) -> u64 {
    let mut h = BulkHasher::default();
    h.words([t.width, t.height, u32::from(t.srgb), t.wrap_s as u32, t.wrap_t as u32]);
    h.words(t.rgba8.iter().map(|&p| u32::from_le_bytes(p)));
    h.finish()
}

fn material_hash(m: &Material, textures: &[u64]) -> u64 {
    let mut h = BulkHasher::default();
    h.words(m.base_color.to_array().map(f32::to_bits));
    h.words(m.emission.to_array().map(f32::to_bits));
    h.words([u32::from(m.double_sided)]);
    match m.alpha_mode {
        AlphaMode::Opaque => h.word(0),
        AlphaMode::Mask { cutoff } => h.words([1, cutoff.to_bits()]),
        AlphaMode::Blend => h.word(2),
    }
    h.word(m.transmission.to_bits());
    for t in [m.base_color_texture, m.emissive_texture, m.transmission_texture] {
        match t.and_then(|t| Some((textures.get(t.texture)?, t.tex_coord))) {
            Some((&th, tc)) => h.words([1, th as u32, (th >> 32) as u32, tc]),
            None => h.word(0),
        }
    }
    h.finish()
}

fn mesh_content_eq(old: &Scene, a: &Mesh, new: &Scene, b: &Mesh) -> bool {
    geometry_eq(a, b) && material_eq(old, a.material, new, b.material)
}

fn geometry_eq(a: &Mesh, b: &Mesh) -> bool {
    let colors_eq = match (&a.colors, &b.colors) {
        (Some(x), Some(y)) => {
            x.len() == y.len()
                && x.iter().zip(y).all(|(p, q)| p.to_array().map(f32::to_bits) == q.to_array().map(f32::to_bits))
        }
        (None, None) => true,
        _ => false,
    };
    topology_eq(a, b) && vec3s_eq(&a.positions, &b.positions) && vec3s_eq(&a.normals, &b.normals) && colors_eq
}

fn topology_eq(a: &Mesh, b: &Mesh) -> bool {
    let uv_eq = |x: &Option<Vec<Vec2>>, y: &Option<Vec<Vec2>>| match (x, y) {
        (Some(x), Some(y)) => x.len() == y.len() && x.iter().zip(y).all(|(p, q)| bits2(*p) == bits2(*q)),
        (None, None) => true,
        _ => false,
    };
    a.triangles == b.triangles && uv_eq(&a.uv0, &b.uv0) && uv_eq(&a.uv1, &b.uv1)
}

fn vec3s_eq(a: &[Vec3], b: &[Vec3]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(p, q)| bits3(*p) == bits3(*q))
}

fn bits2(v: Vec2) -> [u32; 2] {
    v.to_array().map(f32::to_bits)
}

fn bits3(v: Vec3) -> [u32; 3] {
    v.to_array().map(f32::to_bits)
}

/// Whether material `a` of `old` and material `b` of `new` have the same content. A missing
/// material (an index past the list) equals only another missing one.
fn material_eq(old: &Scene, a: u32, new: &Scene, b: u32) -> bool {
    let (Some(ma), Some(mb)) = (old.materials.get(a as usize), new.materials.get(b as usize)) else {
        return old.materials.get(a as usize).is_none() && new.materials.get(b as usize).is_none();
    };
    let texture_eq = |x: Option<TextureRef>, y: Option<TextureRef>| match (x, y) {
        (None, None) => true,
        (Some(x), Some(y)) => {
            x.uv() == y.uv()
                && match (old.textures.get(x.texture), new.textures.get(y.texture)) {
                    (Some(tx), Some(ty)) => texture_content_eq(tx, ty),
                    (None, None) => true,
                    _ => false,
                }
        }
        _ => false,
    };
    ma.base_color.to_array().map(f32::to_bits) == mb.base_color.to_array().map(f32::to_bits)
        && bits3(ma.emission) == bits3(mb.emission)
        && ma.double_sided == mb.double_sided
        && alpha_bits(ma.alpha_mode) == alpha_bits(mb.alpha_mode)
        && texture_eq(ma.base_color_texture, mb.base_color_texture)
        && texture_eq(ma.emissive_texture, mb.emissive_texture)
        && ma.transmission.to_bits() == mb.transmission.to_bits()
        && texture_eq(ma.transmission_texture, mb.transmission_texture)
}

fn alpha_bits(a: AlphaMode) -> (u8, u32) {
    match a {
        AlphaMode::Opaque => (0, 0),
        AlphaMode::Mask { cutoff } => (1, cutoff.to_bits()),
        AlphaMode::Blend => (2, 0),
    }
}

fn texture_content_eq(a: &Texture, b: &Texture) -> bool {
    a.width == b.width
        && a.height == b.height
        && a.srgb == b.srgb
        && a.wrap_s == b.wrap_s
        && a.wrap_t == b.wrap_t
        && a.rgba8 == b.rgba8
}

/// Every light as the bits of what it does, sorted: equal lists mean the same lights.
fn light_keys(lights: &[PunctualLight]) -> Vec<Vec<u32>> {
    let mut keys: Vec<Vec<u32>> = lights
        .iter()
        .map(|l| {
            let mut k = match l.kind {
                LightKind::Directional => vec![0, 0, 0],
                LightKind::Point => vec![1, 0, 0],
                LightKind::Spot { inner_cone, outer_cone } => vec![2, inner_cone.to_bits(), outer_cone.to_bits()],
            };
            k.extend(bits3(l.intensity));
            k.extend(bits3(l.position));
            k.extend(bits3(l.direction));
            match l.range {
                Some(r) => k.extend([1, r.to_bits()]),
                None => k.extend([0, 0]),
            }
            k
        })
        .collect();
    keys.sort_unstable();
    keys
}

/// A fast streaming hash of 32-bit words (FxHash's rotate-xor-multiply step, with a
/// SplitMix64 finaliser). Weak against crafted input, which does not matter here: a hash only
/// proposes a match, and the match is confirmed element by element. What matters is speed on
/// 10⁶ triangles: one multiply per word, no buffering.
#[derive(Default)]
struct BulkHasher {
    state: u64,
}

impl BulkHasher {
    #[inline]
    fn word(&mut self, w: u32) {
        self.state = (self.state.rotate_left(5) ^ u64::from(w)).wrapping_mul(0x517c_c1b7_2722_0a95);
    }

    fn words(&mut self, words: impl IntoIterator<Item = u32>) {
        for w in words {
            self.word(w);
        }
    }

    fn vec3s(&mut self, v: &[Vec3]) {
        self.word(v.len() as u32);
        self.words(v.iter().flat_map(|p| bits3(*p)));
    }

    fn vec2s(&mut self, v: &[Vec2]) {
        self.word(v.len() as u32);
        self.words(v.iter().flat_map(|p| bits2(*p)));
    }

    fn finish(self) -> u64 {
        let mut z = self.state.wrapping_add(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scene::builder::{SceneBuilder, diffuse, white};
    use crate::scene::{Rgb, WrapMode};

    /// Three unit boxes at x = 0, 3, 6 and one light; `moves` shifts box i by the offset.
    fn boxes(moves: &[(usize, Vec3)], albedo: [f32; 3]) -> Scene {
        let mut b = SceneBuilder::new();
        let white = b.material(white());
        let grey = b.material(diffuse(Rgb::from(albedo), Rgb::ZERO, false));
        for i in 0..3 {
            let offset = moves.iter().filter(|(k, _)| *k == i).map(|(_, d)| *d).sum::<Vec3>();
            let lo = Vec3::new(3.0 * i as f32, 0.0, 0.0) + offset;
            b.cuboid(&format!("box{i}"), lo, lo + Vec3::ONE, false, if i == 1 { grey } else { white });
        }
        b.point_light(Vec3::new(0.0, 5.0, 0.0), Rgb::splat(10.0));
        b.build()
    }

    #[test]
    fn identical_scenes_differ_in_nothing() {
        let d = SceneDiff::between(&boxes(&[], [0.5; 3]), &boxes(&[], [0.5; 3]));
        assert!(d.is_empty(), "{d:?}");
        assert_eq!(d.unchanged, vec![(0, 0), (1, 1), (2, 2)]);
        assert_eq!(d.touched_bounds().count(), 0);
    }

    #[test]
    fn a_moved_box_is_the_only_change_with_its_old_and_new_bounds() {
        let d = SceneDiff::between(&boxes(&[], [0.5; 3]), &boxes(&[(2, Vec3::new(0.0, 0.0, 2.0))], [0.5; 3]));
        assert_eq!(d.unchanged, vec![(0, 0), (1, 1)]);
        assert!(d.added.is_empty() && d.removed.is_empty());
        assert!(!d.lights_changed && !d.sky_changed && !d.materials_changed);
        let [c] = d.changed.as_slice() else { panic!("{d:?}") };
        assert_eq!((c.old, c.new), (2, 2));
        assert!(c.geometry_changed && !c.material_changed);
        assert_eq!(c.old_bounds, Aabb { min: Vec3::new(6.0, 0.0, 0.0), max: Vec3::new(7.0, 1.0, 1.0) });
        assert_eq!(c.new_bounds, Aabb { min: Vec3::new(6.0, 0.0, 2.0), max: Vec3::new(7.0, 1.0, 3.0) });
        assert_eq!(d.touched_bounds().collect::<Vec<_>>(), vec![c.old_bounds, c.new_bounds]);
    }

    #[test]
    fn a_mesh_added_in_front_shifts_indices_but_changes_nothing_else() {
        let old = boxes(&[], [0.5; 3]);
        let mut new = old.clone();
        let mut extra = new.meshes[0].clone();
        extra.name = "newcomer".into();
        extra.positions.iter_mut().for_each(|p| *p += Vec3::new(0.0, 10.0, 0.0));
        new.meshes.insert(0, extra);
        let d = SceneDiff::between(&old, &new);
        assert_eq!(d.unchanged, vec![(0, 1), (1, 2), (2, 3)]);
        assert_eq!(d.old_to_new(3), vec![Some(1), Some(2), Some(3)]);
        assert!(d.changed.is_empty() && d.removed.is_empty());
        assert_eq!(
            d.added,
            vec![MeshAt { index: 0, bounds: Aabb { min: Vec3::Y * 10.0, max: Vec3::new(1.0, 11.0, 1.0) } }]
        );
        // And back: the same mesh is removed.
        let back = SceneDiff::between(&new, &old);
        assert_eq!(back.unchanged, vec![(1, 0), (2, 1), (3, 2)]);
        assert_eq!(back.removed.len(), 1);
        assert_eq!(back.removed[0].index, 0);
    }

    #[test]
    fn a_renamed_and_moved_mesh_pairs_by_topology() {
        // Unnamed glTF nodes are named by index, so a move plus a node inserted before it
        // renames the mesh; its triangles and uvs still say it is the same one.
        let old = boxes(&[], [0.5; 3]);
        let mut new = boxes(&[(0, Vec3::X * 0.5)], [0.5; 3]);
        new.meshes[0].name = "node7/box/0".into();
        let d = SceneDiff::between(&old, &new);
        assert_eq!(d.changed.len(), 1, "{d:?}");
        assert_eq!((d.changed[0].old, d.changed[0].new), (0, 0));
        assert!(d.added.is_empty() && d.removed.is_empty());
    }

    #[test]
    fn materials_compare_by_content_not_index() {
        let old = boxes(&[], [0.5; 3]);
        // Same materials in the other order, indices remapped: no change.
        let mut reordered = old.clone();
        reordered.materials.swap(0, 1);
        for m in &mut reordered.meshes {
            m.material = 1 - m.material;
        }
        assert!(SceneDiff::between(&old, &reordered).is_empty());
        // The grey box's albedo changes: that mesh changed, by material only.
        let d = SceneDiff::between(&old, &boxes(&[], [0.25, 0.5, 0.5]));
        assert!(d.materials_changed);
        let [c] = d.changed.as_slice() else { panic!("{d:?}") };
        assert_eq!(c.new, 1);
        assert!(c.material_changed && !c.geometry_changed);
        assert_eq!(c.old_bounds, c.new_bounds);
    }

    #[test]
    fn a_texture_pixel_is_material_content() {
        let texture = Texture {
            name: "t".into(),
            width: 2,
            height: 1,
            rgba8: vec![[255, 0, 0, 255], [0, 255, 0, 255]].into(),
            srgb: true,
            wrap_s: WrapMode::Repeat,
            wrap_t: WrapMode::Repeat,
        };
        let mut old = boxes(&[], [0.5; 3]);
        old.textures.push(texture);
        old.materials[1].base_color_texture = Some(TextureRef::new(0));
        let mut new = old.clone();
        assert!(SceneDiff::between(&old, &new).is_empty());
        new.textures[0].rgba8 = vec![[255, 0, 0, 255], [0, 254, 0, 255]].into();
        let d = SceneDiff::between(&old, &new);
        assert!(d.materials_changed);
        assert_eq!(d.changed.iter().map(|c| c.new).collect::<Vec<_>>(), vec![1]);
    }

    #[test]
    fn lights_compare_as_a_set_and_the_sky_by_value() {
        let mut old = boxes(&[], [0.5; 3]);
        old.lights.push(PunctualLight { name: "second".into(), position: Vec3::X, ..old.lights[0].clone() });
        let mut reordered = old.clone();
        reordered.lights.reverse();
        reordered.lights[0].name = "renamed".into();
        assert!(SceneDiff::between(&old, &reordered).is_empty());
        let mut brighter = old.clone();
        brighter.lights[1].intensity *= 2.0;
        let d = SceneDiff::between(&old, &brighter);
        assert!(d.lights_changed && d.changed.is_empty() && !d.sky_changed);
        let mut sky = old.clone();
        sky.sky = Rgb::new(0.0, 0.0, 1e-3);
        let d = SceneDiff::between(&old, &sky);
        assert!(d.sky_changed && !d.lights_changed && d.changed.is_empty());
    }

    #[test]
    fn identical_copies_keep_their_own_names() {
        // Two instances with equal content (a mesh placed twice at one spot): each unchanged
        // mesh maps to the old one of the same name, whatever the order.
        let mut old = boxes(&[], [0.5; 3]);
        let mut twin = old.meshes[0].clone();
        twin.name = "twin".into();
        old.meshes.push(twin);
        let mut new = old.clone();
        new.meshes.swap(0, 3);
        let d = SceneDiff::between(&old, &new);
        assert!(d.is_empty());
        assert_eq!(d.old_to_new(4), vec![Some(3), Some(1), Some(2), Some(0)]);
    }

    #[test]
    fn removed_mesh_and_changed_normals_are_seen() {
        let old = boxes(&[], [0.5; 3]);
        let mut new = old.clone();
        new.meshes.remove(1);
        new.meshes[0].normals[0] = -new.meshes[0].normals[0];
        let d = SceneDiff::between(&old, &new);
        assert_eq!(d.unchanged, vec![(2, 1)]);
        assert_eq!(d.removed, vec![MeshAt { index: 1, bounds: Aabb::of_points(&old.meshes[1].positions) }]);
        let [c] = d.changed.as_slice() else { panic!("{d:?}") };
        assert!(c.geometry_changed && (c.old, c.new) == (0, 0) && c.old_bounds == c.new_bounds);
    }

    /// A save that paints a mesh's vertices (COLOR_0 added, or one vertex's changed) changes
    /// its light: the diff says so; the same colours again are no change.
    #[test]
    fn painted_vertices_are_a_change() {
        let old = boxes(&[], [0.5; 3]);
        let mut new = old.clone();
        new.meshes[2].colors = Some(vec![glam::Vec4::ONE; new.meshes[2].positions.len()]);
        let mut repainted = new.clone();
        let d = SceneDiff::between(&old, &new);
        let [c] = d.changed.as_slice() else { panic!("{d:?}") };
        assert_eq!((c.old, c.new), (2, 2));
        assert!(SceneDiff::between(&new, &new.clone()).is_empty());
        if let Some(colors) = repainted.meshes[2].colors.as_mut() {
            colors[0].x = 0.5;
        }
        let d = SceneDiff::between(&new, &repainted);
        let [c] = d.changed.as_slice() else { panic!("{d:?}") };
        assert_eq!((c.old, c.new), (2, 2));
    }
}
