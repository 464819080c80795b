//! Stable, incremental atlas updates for hot reload: unchanged meshes keep their charts
//! exactly where they are (their texels, and pages published from them, stay valid); a
//! changed mesh is unwrapped anew and its charts go, in this order of preference:
//! 1. into the space its old charts leave (best short-side fit over those rectangles);
//! 2. into the first free place of the atlas (rows top to bottom, columns left to right);
//! 3. below the atlas, which grows taller (its width, and so every pixel index `y·width + x`,
//!    stays), up to the size limit;
//! 4. nowhere: then every chart of the scene is packed anew, as [`Atlas::build`] at the old
//!    texel size would, and the update says so.
//!
//! The texel size never changes in an update (a texel of an unchanged chart must keep its
//! meaning); a new texel budget needs a new build.

use std::time::Instant;

use super::pack::{self, FreeMap, Orient, Rect};
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
    /// (checked: [`AtlasError::BadUpdate`] otherwise).
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
            free.occupy(k.rect);
        }
        let sizes: Vec<(u32, u32)> = fresh.iter().map(|c| c.placement.rect_size()).collect();
        let mut spot: Vec<Option<((u32, u32), Orient)>> = vec![None; fresh.len()];
        // 1. Each replaced mesh's charts into its old space.
        let mut reused_space = Vec::new();
        for (mi, rects) in freed.iter().enumerate() {
            let mine: Vec<usize> = (0..fresh.len()).filter(|&i| fresh[i].mesh == mi as u32).collect();
            if rects.is_empty() || mine.is_empty() {
                continue;
            }
            let got = pack::pack_into_free(rects.clone(), &mine.iter().map(|&i| sizes[i]).collect::<Vec<_>>());
            for (&i, g) in mine.iter().zip(&got) {
                if let Some((corner, o)) = *g {
                    spot[i] = Some((corner, o));
                    free.occupy(placed_rect(corner, sizes[i], o));
                }
            }
            if got.iter().all(Option::is_some) {
                reused_space.push(mi as u32);
            }
        }
        // 2. The rest into free space, largest first.
        let mut rest: Vec<usize> = (0..fresh.len()).filter(|&i| spot[i].is_none()).collect();
        let area = |s: (u32, u32)| s.0 as u64 * s.1 as u64;
        rest.sort_by(|&a, &b| area(sizes[b]).cmp(&area(sizes[a])).then(a.cmp(&b)));
        let mut left = Vec::new();
        for i in rest {
            let fit = [Orient::AsIs, Orient::Turned].into_iter().find_map(|o| {
                let (w, h) = pack::oriented(sizes[i], o);
                free.first_fit(w, h).map(|corner| (corner, o))
            });
            match fit {
                Some((corner, o)) => {
                    spot[i] = Some((corner, o));
                    free.occupy(placed_rect(corner, sizes[i], o));
                }
                None => left.push(i),
            }
        }
        // 3. Whatever is left in a strip below.
        let mut grown = false;
        if !left.is_empty() {
            let strip = pack::pack_strip(&left.iter().map(|&i| sizes[i]).collect::<Vec<_>>(), width)
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

fn placed_rect(corner: (u32, u32), size: (u32, u32), o: Orient) -> Rect {
    let (w, h) = pack::oriented(size, o);
    Rect { x: corner.0, y: corner.1, w, h }
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
