//! Stable, incremental atlas updates for hot reload: unchanged meshes keep their charts
//! exactly where they are (their texels, and pages published from them, stay valid); a
//! changed mesh is unwrapped anew and its charts go, in this order of preference:
//! 1. into the space its old charts leave: at the corner of one of its old charts' rectangles
//!    of the same size, where its footprint meets nothing kept (a moved mesh's charts take
//!    their places again);
//! 2. into the first free place of the atlas (rows top to bottom, columns left to right) for
//!    its whole rectangle;
//! 3. below the atlas, which grows taller (its width, and so every pixel index `y·width + x`,
//!    stays), up to the size limit;
//! 4. nowhere: then every chart of the scene is packed anew, as [`Atlas::build`] at the old
//!    texel size would, and the update says so.
//!
//! The texel size never changes in an update (a texel of an unchanged chart must keep its
//! meaning); a new texel budget needs a new build.

use std::time::Instant;

use super::free::{FreeMap, Rect};
use super::pack::{self, Footprint, Orient};
use super::{
    Atlas, AtlasConfig, AtlasError, AtlasStats, Chart, ChartSource, MeshCharts, NO_FACE, SceneFaces, TexelChart,
    lay_out,
};
use crate::scene::{Scene, SceneGeometry, Side, TriangleId};

/// Where a mesh of the new scene comes from, for [`Atlas::update`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshOrigin {
    /// The same mesh as this one of the old scene: same triangles, positions, material
    /// sidedness and TEXCOORD_1. Its charts are kept as they are (face UVs bit for bit).
    Unchanged(u32),
    /// Replaces this mesh of the old scene (moved, edited, re-exported): unwrapped anew, its
    /// charts preferably in the space the old mesh's charts leave.
    Changed(u32),
    /// Has no counterpart in the old scene.
    Added,
}

/// What an update did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct AtlasUpdate {
    /// Meshes of the new scene whose charts were laid out anew (changed and added meshes;
    /// every mesh with faces after a full repack), increasing.
    pub relaid: Vec<u32>,
    /// Of those, the ones all of whose charts went into the space their old charts left.
    pub reused_space: Vec<u32>,
    /// The atlas grew taller to fit them (nothing else moved).
    pub grown: bool,
    /// Nothing fitted: every chart was packed anew (every texel moved).
    pub repacked: bool,
}

impl Atlas {
    /// The atlas of `scene` (with its `geom`), changed from `old` (the atlas of the previous
    /// scene) as little as possible: `origins[m]` says where mesh `m` of `scene` comes from
    /// (see [`MeshOrigin`]; old meshes no mesh refers to are dropped, their space freed). The
    /// texel size is `old`'s; `config`'s other settings apply to the meshes laid out anew.
    ///
    /// An `Unchanged` mesh must have as many triangles, and the same faces, as the old mesh
    /// (checked: [`AtlasError::BadUpdate`] otherwise). The new atlas's `stats.uv1_rejected`
    /// lists the meshes laid out in this update only.
    pub fn update(
        old: &Atlas,
        scene: &Scene,
        geom: &SceneGeometry,
        config: &AtlasConfig,
        origins: &[MeshOrigin],
    ) -> Result<(Atlas, AtlasUpdate), AtlasError> {
        let started = Instant::now();
        let config = AtlasConfig { texel_size: Some(old.texel_size), ..config.clone() };
        config.validate()?;
        let old_meshes = old.mesh_offsets.len().saturating_sub(1);
        if origins.len() != scene.meshes.len() {
            return Err(AtlasError::BadUpdate(format!(
                "{} mesh origins for {} meshes",
                origins.len(),
                scene.meshes.len()
            )));
        }
        let mut referenced = vec![false; old_meshes];
        for o in origins {
            if let MeshOrigin::Unchanged(m) | MeshOrigin::Changed(m) = *o {
                let slot = referenced.get_mut(m as usize).ok_or_else(|| {
                    AtlasError::BadUpdate(format!("old mesh {m} does not exist (the old scene has {old_meshes})"))
                })?;
                if std::mem::replace(slot, true) {
                    return Err(AtlasError::BadUpdate(format!("old mesh {m} is the origin of two meshes")));
                }
            }
        }
        let SceneFaces { mut faces, face_of, lit_area } = SceneFaces::new(scene, geom);
        if faces.is_empty() {
            return Err(AtlasError::Empty);
        }
        let texel = old.texel_size as f64;
        let mut old_charts_of: Vec<Vec<&Chart>> = vec![Vec::new(); old_meshes];
        for c in &old.charts {
            old_charts_of[c.mesh as usize].push(c);
        }

        // Kept charts, and the space the replaced meshes leave.
        let mut kept: Vec<(u32, KeptChart)> = Vec::new();
        let mut freed: Vec<Vec<Rect>> = vec![Vec::new(); scene.meshes.len()];
        let mut relay: Vec<u32> = Vec::new();
        for (mi, origin) in origins.iter().enumerate() {
            match *origin {
                MeshOrigin::Unchanged(om) => {
                    for c in &old_charts_of[om as usize] {
                        kept.push((mi as u32, keep_chart(old, c, om, geom, &face_of, mi)?));
                    }
                    let new_faces = (geom.mesh_offsets[mi]..geom.mesh_offsets[mi + 1])
                        .map(|t| face_of[t as usize].iter().filter(|&&f| f != NO_FACE).count())
                        .sum::<usize>();
                    let old_faces: usize = old_charts_of[om as usize].iter().map(|c| c.faces.len()).sum();
                    if new_faces != old_faces {
                        return Err(AtlasError::BadUpdate(format!(
                            "mesh {mi} ({}) is said to be unchanged but has {new_faces} faces, the old mesh {old_faces}",
                            scene.meshes[mi].name
                        )));
                    }
                }
                MeshOrigin::Changed(om) => {
                    freed[mi] = old_charts_of[om as usize].iter().map(|c| rect_of(c)).collect();
                    relay.push(mi as u32);
                }
                MeshOrigin::Added => relay.push(mi as u32),
            }
        }

        // The charts of the meshes laid out anew, at the old texel size.
        let threads = crate::parallel::available_threads();
        let laid: Vec<_> = crate::parallel::par_map(relay.clone(), threads, |mi| {
            MeshCharts::new(scene, geom, &face_of, mi as usize, texel, &config)
                .map(|m| m.at(scene, geom, texel, &config))
        })
        .into_iter()
        .collect();
        let mut stats = AtlasStats { faces: faces.len(), lit_area, ..AtlasStats::default() };
        let mut fresh: Vec<TexelChart> = Vec::new();
        for (&mi, m) in relay.iter().zip(laid) {
            let Some(m) = m.transpose()? else { continue };
            if let Some(reason) = m.uv1_rejected {
                let name = &scene.meshes[mi as usize].name;
                tracing::warn!(mesh = %name, "TEXCOORD_1 not used as light-map UVs: {reason}; unwrapping instead");
                stats.uv1_rejected.push((name.clone(), reason));
            }
            fresh.extend(m.charts);
        }
        stats.unwrap_seconds = started.elapsed().as_secs_f64();

        let packing_started = Instant::now();
        let (width, mut height) = (old.width, old.height);
        let mut free = FreeMap::new(width, height);
        for (_, k) in &kept {
            free.occupy_footprint((k.rect.x, k.rect.y), &k.chart.footprint(&old.faces));
        }
        let footprints: Vec<Footprint> = fresh.iter().map(TexelChart::footprint).collect();
        let sizes: Vec<(u32, u32)> = footprints.iter().map(|f| f.size).collect();
        let area = |s: (u32, u32)| s.0 as u64 * s.1 as u64;
        let mut spot: Vec<Option<((u32, u32), Orient)>> = vec![None; fresh.len()];
        // 1. Each replaced mesh's charts at its old charts' corners, largest first.
        let mut reused_space = Vec::new();
        for (mi, rects) in freed.iter().enumerate() {
            let mut mine: Vec<usize> = (0..fresh.len()).filter(|&i| fresh[i].mesh == mi as u32).collect();
            if rects.is_empty() || mine.is_empty() {
                continue;
            }
            mine.sort_by(|&a, &b| area(sizes[b]).cmp(&area(sizes[a])).then(a.cmp(&b)));
            for &i in &mine {
                let fit = Orient::ALL.into_iter().find_map(|o| {
                    let f = footprints[i].oriented(o);
                    rects.iter().find(|r| (r.w, r.h) == f.size && free.fits((r.x, r.y), &f)).map(|r| ((r.x, r.y), o, f))
                });
                if let Some((corner, o, f)) = fit {
                    spot[i] = Some((corner, o));
                    free.occupy_footprint(corner, &f);
                }
            }
            if mine.iter().all(|&i| spot[i].is_some()) {
                reused_space.push(mi as u32);
            }
        }
        // 2. The rest into free space, largest first.
        let mut rest: Vec<usize> = (0..fresh.len()).filter(|&i| spot[i].is_none()).collect();
        rest.sort_by(|&a, &b| area(sizes[b]).cmp(&area(sizes[a])).then(a.cmp(&b)));
        let mut left = Vec::new();
        for i in rest {
            let fit = [Orient::AsIs, Orient::Quarter].into_iter().find_map(|o| {
                let (w, h) = pack::oriented(sizes[i], o);
                free.first_fit(w, h).map(|corner| (corner, o))
            });
            match fit {
                Some((corner, o)) => {
                    spot[i] = Some((corner, o));
                    free.occupy_footprint(corner, &footprints[i].oriented(o));
                }
                None => left.push(i),
            }
        }
        // 3. Whatever is left in a strip below.
        let mut grown = false;
        if !left.is_empty() {
            let strip = pack::pack_strip(&left.iter().map(|&i| footprints[i].clone()).collect::<Vec<_>>(), width)
                .filter(|p| height as u64 + p.height as u64 <= config.max_size as u64);
            match strip {
                Some(p) => {
                    for (k, &i) in left.iter().enumerate() {
                        let (x, y) = p.positions[k];
                        spot[i] = Some(((x, y + height), p.orient[k]));
                    }
                    height += p.height;
                    grown = true;
                }
                None => {
                    // 4. A full repack.
                    let atlas = Atlas::build(scene, geom, &config)?;
                    let mut relaid: Vec<u32> = atlas.charts.iter().map(|c| c.mesh).collect();
                    relaid.dedup();
                    return Ok((atlas, AtlasUpdate { relaid, reused_space: Vec::new(), grown: false, repacked: true }));
                }
            }
        }
        // Assemble: every mesh's charts in mesh order, kept ones with their old UVs.
        let mut placed: Vec<(u32, Placed)> = kept.into_iter().map(|(m, k)| (m, Placed::Kept(k))).collect();
        for (c, s) in fresh.into_iter().zip(spot) {
            let (corner, o) = s.expect("every chart has a place unless the atlas was repacked");
            placed.push((c.mesh, Placed::Fresh(c, corner, o)));
        }
        placed.sort_by_key(|(m, _)| *m);
        let mut charts: Vec<Chart> = Vec::with_capacity(placed.len());
        for (_, p) in placed {
            match p {
                Placed::Kept(k) => {
                    let id = charts.len() as u32;
                    for (&f, uv) in k.chart.faces.iter().zip(&k.uv) {
                        faces[f as usize].chart = id;
                        faces[f as usize].uv = *uv;
                    }
                    charts.push(k.chart);
                }
                Placed::Fresh(c, corner, o) => {
                    let id = charts.len() as u32;
                    charts.push(lay_out(&mut faces, &face_of, id, c, corner, o));
                }
            }
        }
        let mut per_mesh: Vec<(u32, ChartSource)> = charts.iter().map(|c| (c.mesh, c.source)).collect();
        per_mesh.dedup();
        stats.meshes_from_uv1 = per_mesh.iter().filter(|m| m.1 == ChartSource::Uv1).count();
        stats.meshes_unwrapped = per_mesh.len() - stats.meshes_from_uv1;
        stats.charts = charts.len();
        stats.pack_seconds = packing_started.elapsed().as_secs_f64();
        let mut relaid: Vec<u32> = charts
            .iter()
            .filter(|c| matches!(origins[c.mesh as usize], MeshOrigin::Changed(_) | MeshOrigin::Added))
            .map(|c| c.mesh)
            .collect();
        relaid.dedup();
        let mut atlas = Atlas {
            texel_size: old.texel_size,
            width,
            height,
            faces,
            face_of,
            charts,
            mesh_offsets: geom.mesh_offsets.clone(),
            stats,
        };
        atlas.finish_stats();
        Ok((atlas, AtlasUpdate { relaid, reused_space, grown, repacked: false }))
    }
}

/// An old chart carried over: its rectangle, and its faces (renumbered) with their UVs.
struct KeptChart {
    rect: Rect,
    chart: Chart,
    uv: Vec<[glam::Vec2; 3]>,
}

enum Placed {
    Kept(KeptChart),
    Fresh(TexelChart, (u32, u32), Orient),
}

fn rect_of(c: &Chart) -> Rect {
    Rect { x: c.rect_min.0, y: c.rect_min.1, w: c.rect_size.0, h: c.rect_size.1 }
}

/// Old chart `c` of old mesh `om`, for new mesh `mi`: the same rectangle and face UVs, faces
/// renumbered through the triangles' index within their mesh.
fn keep_chart(
    old: &Atlas,
    c: &Chart,
    om: u32,
    geom: &SceneGeometry,
    face_of: &[[u32; 2]],
    mi: usize,
) -> Result<KeptChart, AtlasError> {
    let (old_first, new_first) = (old.mesh_offsets[om as usize], geom.mesh_offsets[mi]);
    let new_count = geom.mesh_offsets[mi + 1] - new_first;
    let old_count = old.mesh_offsets[om as usize + 1] - old_first;
    if new_count != old_count {
        return Err(AtlasError::BadUpdate(format!(
            "mesh {mi} is said to be unchanged but has {new_count} triangles, the old mesh {old_count}"
        )));
    }
    let mut faces = Vec::with_capacity(c.faces.len());
    let mut uv = Vec::with_capacity(c.faces.len());
    for &f in &c.faces {
        let face = &old.faces[f as usize];
        let t: TriangleId = new_first + (face.tri - old_first);
        let nf = face_of[t as usize][face.side.index()];
        if nf == NO_FACE {
            let side = if face.side == Side::Front { "front" } else { "back" };
            return Err(AtlasError::BadUpdate(format!(
                "mesh {mi} is said to be unchanged but its triangle {} has no {side} face any more",
                t - new_first
            )));
        }
        faces.push(nf);
        uv.push(face.uv);
    }
    Ok(KeptChart {
        rect: rect_of(c),
        chart: Chart {
            mesh: mi as u32,
            side: c.side,
            source: c.source,
            rect_min: c.rect_min,
            rect_size: c.rect_size,
            faces,
        },
        uv,
    })
}

#[cfg(test)]
mod tests {
    use glam::{Affine3A, Vec3};

    use super::*;
    use crate::atlas::tests::{check_pub, config};
    use crate::scene::builder::white;
    use crate::scene::{Scene, SceneBuilder};

    /// A room, boxes (big enough never to merge) and a shelf of thin boards (whose sides
    /// merge into their faces), one mesh each; `edit(name, positions)` may move a mesh.
    fn scene(mut edit: impl FnMut(&str, &mut Vec<Vec3>)) -> Scene {
        let mut b = SceneBuilder::new();
        let m = b.material(white());
        b.cuboid("room", Vec3::ZERO, Vec3::new(6.0, 3.0, 5.0), true, m);
        for k in 0..4 {
            let o = Vec3::new(0.5 + 1.3 * k as f32, 0.0, 1.0);
            b.cuboid(&format!("box{k}"), o, o + Vec3::new(0.5 + 0.1 * k as f32, 0.7, 0.6), false, m);
        }
        for k in 0..3 {
            let o = Vec3::new(0.3, 0.4 + 0.5 * k as f32, 4.2);
            b.cuboid(&format!("board{k}"), o, o + Vec3::new(1.6, 0.03, 0.4), false, m);
        }
        b.grid_quad(
            "floor panel",
            [
                Vec3::new(2.8, 0.01, 4.0),
                Vec3::new(5.8, 0.01, 4.0),
                Vec3::new(5.8, 0.01, 1.0),
                Vec3::new(2.8, 0.01, 1.0),
            ],
            4,
            m,
        );
        let mut s = b.build();
        for mesh in &mut s.meshes {
            edit(&mesh.name.clone(), &mut mesh.positions);
        }
        s
    }

    fn transform(xf: Affine3A) -> impl Fn(&mut Vec<Vec3>) {
        move |p: &mut Vec<Vec3>| p.iter_mut().for_each(|q| *q = xf.transform_point3(*q))
    }

    fn index(s: &Scene, name: &str) -> u32 {
        s.meshes.iter().position(|m| m.name == name).expect("mesh") as u32
    }

    /// Rectangles of a mesh's charts, sorted.
    fn rects(a: &Atlas, mesh: u32) -> Vec<Rect> {
        let mut v: Vec<Rect> = a.charts.iter().filter(|c| c.mesh == mesh).map(rect_of).collect();
        v.sort_by_key(|r| (r.x, r.y, r.w, r.h));
        v
    }

    /// Every face of new mesh `new` has the UV bits, side and rectangle of the same triangle
    /// of old mesh `old`.
    fn assert_kept(old: &Atlas, a: &Atlas, old_mesh: u32, new_mesh: u32) {
        let (o0, o1) = (old.mesh_offsets[old_mesh as usize], old.mesh_offsets[old_mesh as usize + 1]);
        let n0 = a.mesh_offsets[new_mesh as usize];
        assert_eq!(o1 - o0, a.mesh_offsets[new_mesh as usize + 1] - n0);
        for k in 0..o1 - o0 {
            for side in Side::BOTH {
                let (fo, fa) =
                    (old.face_of[(o0 + k) as usize][side.index()], a.face_of[(n0 + k) as usize][side.index()]);
                assert_eq!(fo == NO_FACE, fa == NO_FACE);
                if fo == NO_FACE {
                    continue;
                }
                let (x, y) = (&old.faces[fo as usize], &a.faces[fa as usize]);
                assert_eq!(x.uv.map(|p| p.to_array().map(f32::to_bits)), y.uv.map(|p| p.to_array().map(f32::to_bits)));
                let (cx, cy) = (&old.charts[x.chart as usize], &a.charts[y.chart as usize]);
                assert_eq!((cx.rect_min, cx.rect_size, cx.side), (cy.rect_min, cy.rect_size, cy.side));
                assert_eq!(cy.mesh, new_mesh);
            }
        }
    }

    fn unchanged_all(s: &Scene) -> Vec<MeshOrigin> {
        (0..s.meshes.len() as u32).map(MeshOrigin::Unchanged).collect()
    }

    /// Meshes reordered and one dropped: every kept mesh keeps its face UVs bit for bit, the
    /// atlas its size, and nothing was laid out anew.
    #[test]
    fn unchanged_meshes_keep_their_face_uvs() {
        let s0 = scene(|_, _| {});
        let g0 = SceneGeometry::new(&s0);
        let old = Atlas::build(&s0, &g0, &config(0.05)).unwrap();
        let mut s1 = s0.clone();
        s1.meshes.reverse();
        let dropped = s1.meshes.iter().position(|m| m.name == "box2").unwrap();
        s1.meshes.remove(dropped);
        let g1 = SceneGeometry::new(&s1);
        let origins: Vec<MeshOrigin> = s1.meshes.iter().map(|m| MeshOrigin::Unchanged(index(&s0, &m.name))).collect();
        let (a, up) = Atlas::update(&old, &s1, &g1, &config(0.05), &origins).unwrap();
        assert_eq!(up, AtlasUpdate::default());
        assert_eq!((a.width, a.height, a.texel_size), (old.width, old.height, old.texel_size));
        for (mi, m) in s1.meshes.iter().enumerate() {
            assert_kept(&old, &a, index(&s0, &m.name), mi as u32);
        }
        check_pub(&s1, &a, 1, true);
        // The same scene unchanged: the same atlas.
        let (same, up) = Atlas::update(&old, &s0, &g0, &config(0.05), &unchanged_all(&s0)).unwrap();
        assert_eq!(up, AtlasUpdate::default());
        assert_eq!(same.covered_texels(0), old.covered_texels(0));
    }

    /// A box and a board moved (off the texel grid): unwrapped anew, their charts take
    /// exactly the rectangles they had; everything else keeps its UVs.
    #[test]
    fn a_moved_mesh_keeps_its_rectangles() {
        let s0 = scene(|_, _| {});
        let old = Atlas::build(&s0, &SceneGeometry::new(&s0), &config(0.05)).unwrap();
        let shift = transform(Affine3A::from_translation(Vec3::new(0.37, 0.0, -0.61)));
        let s1 = scene(|name, p| {
            if name == "box1" || name == "board2" {
                shift(p)
            }
        });
        let g1 = SceneGeometry::new(&s1);
        let moved = [index(&s1, "box1"), index(&s1, "board2")];
        let origins: Vec<MeshOrigin> = (0..s1.meshes.len() as u32)
            .map(|m| if moved.contains(&m) { MeshOrigin::Changed(m) } else { MeshOrigin::Unchanged(m) })
            .collect();
        let (a, up) = Atlas::update(&old, &s1, &g1, &config(0.05), &origins).unwrap();
        assert_eq!(
            up,
            AtlasUpdate { relaid: moved.to_vec(), reused_space: moved.to_vec(), grown: false, repacked: false }
        );
        assert!(
            old.charts.iter().filter(|c| c.mesh == moved[1]).count() < 6,
            "the board's sides merged: the test covers merges"
        );
        for m in 0..s1.meshes.len() as u32 {
            assert_eq!(rects(&a, m), rects(&old, m), "mesh {m}");
            if !moved.contains(&m) {
                assert_kept(&old, &a, m, m);
            }
        }
        assert_eq!((a.width, a.height), (old.width, old.height));
        check_pub(&s1, &a, 1, true);
    }

    /// A box grown 1.4× and the floor panel removed: the box's charts no longer fit its old
    /// space and take free space (the panel's); nothing else moves and the atlas keeps its
    /// size.
    #[test]
    fn a_grown_mesh_takes_free_space() {
        let s0 = scene(|_, _| {});
        let old = Atlas::build(&s0, &SceneGeometry::new(&s0), &config(0.05)).unwrap();
        let grow = transform(Affine3A::from_scale(Vec3::splat(1.4)));
        let mut s1 = scene(|name, p| {
            if name == "box3" {
                grow(p)
            }
        });
        s1.meshes.retain(|m| m.name != "floor panel");
        let g1 = SceneGeometry::new(&s1);
        let b3 = index(&s1, "box3");
        let origins: Vec<MeshOrigin> = s1
            .meshes
            .iter()
            .enumerate()
            .map(|(mi, m)| {
                let o = index(&s0, &m.name);
                if mi as u32 == b3 { MeshOrigin::Changed(o) } else { MeshOrigin::Unchanged(o) }
            })
            .collect();
        let (a, up) = Atlas::update(&old, &s1, &g1, &config(0.05), &origins).unwrap();
        assert_eq!(up, AtlasUpdate { relaid: vec![b3], reused_space: vec![], grown: false, repacked: false });
        assert_eq!((a.width, a.height), (old.width, old.height));
        let (old_box, new_box) = (rects(&old, index(&s0, "box3")), rects(&a, b3));
        assert!(new_box.iter().all(|r| !old_box.iter().any(|o| o.contains(r))), "{new_box:?} in {old_box:?}");
        for (mi, m) in s1.meshes.iter().enumerate() {
            if mi as u32 != b3 {
                assert_kept(&old, &a, index(&s0, &m.name), mi as u32);
            }
        }
        check_pub(&s1, &a, 1, true);
    }

    /// The floor panel grown into a wall as big as half the atlas, under a size limit the
    /// atlas cannot grow into: nothing fits, the atlas is packed anew and says so.
    #[test]
    fn an_impossible_fit_repacks_and_says_so() {
        let s0 = scene(|_, _| {});
        let old = Atlas::build(&s0, &SceneGeometry::new(&s0), &config(0.05)).unwrap();
        // The panel (3 m × 3 m) scaled so that its side is 0.7 × the atlas height.
        let k = 0.7 * old.height as f32 * 0.05 / 3.0;
        let centre = Vec3::new(4.3, 0.01, 2.5);
        let grow = transform(
            Affine3A::from_translation(centre)
                * Affine3A::from_scale(Vec3::new(k, 1.0, k))
                * Affine3A::from_translation(-centre),
        );
        let s1 = scene(|name, p| {
            if name == "floor panel" {
                grow(p)
            }
        });
        let g1 = SceneGeometry::new(&s1);
        let panel = index(&s1, "floor panel");
        let origins: Vec<MeshOrigin> = (0..s1.meshes.len() as u32)
            .map(|m| if m == panel { MeshOrigin::Changed(m) } else { MeshOrigin::Unchanged(m) })
            .collect();
        let limit = AtlasConfig { max_size: old.width.max(old.height) * 3 / 2, ..config(0.05) };
        let (a, up) = Atlas::update(&old, &s1, &g1, &limit, &origins).unwrap();
        assert!(up.repacked && !up.grown && up.reused_space.is_empty());
        assert_eq!(up.relaid, (0..s1.meshes.len() as u32).collect::<Vec<_>>());
        assert!(a.width <= limit.max_size && a.height <= limit.max_size);
        // A repack is a build at the old texel size.
        let fresh = Atlas::build(&s1, &g1, &limit).unwrap();
        assert_eq!((a.width, a.height), (fresh.width, fresh.height));
        check_pub(&s1, &a, 0, true);
        // Without the limit the atlas grows instead, keeping everything else in place.
        let (b, up) = Atlas::update(&old, &s1, &g1, &config(0.05), &origins).unwrap();
        assert!(up.grown && !up.repacked && b.width == old.width && b.height > old.height);
        for m in 0..s1.meshes.len() as u32 {
            if m != panel {
                assert_kept(&old, &b, m, m);
            }
        }
        check_pub(&s1, &b, 0, true);
    }

    #[test]
    fn bad_origins_are_refused() {
        let s0 = scene(|_, _| {});
        let g0 = SceneGeometry::new(&s0);
        let old = Atlas::build(&s0, &g0, &config(0.05)).unwrap();
        let bad = |origins: &[MeshOrigin], s: &Scene| {
            matches!(
                Atlas::update(&old, s, &SceneGeometry::new(s), &config(0.05), origins),
                Err(AtlasError::BadUpdate(_))
            )
        };
        let mut o = unchanged_all(&s0);
        assert!(bad(&o[1..], &s0), "too few origins");
        o[1] = MeshOrigin::Unchanged(0);
        assert!(bad(&o, &s0), "one old mesh for two");
        o[1] = MeshOrigin::Changed(99);
        assert!(bad(&o, &s0), "no such old mesh");
        // "Unchanged" but a triangle fewer.
        let mut s1 = s0.clone();
        s1.meshes[2].triangles.pop();
        assert!(bad(&unchanged_all(&s1), &s1));
    }
}
