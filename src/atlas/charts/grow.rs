//! Step 2 of the unwrapper: growing planar charts.

use glam::{DVec2, DVec3};

use super::face_grid::{FaceGrid, Visited};
use super::faces::{Frame, MeshFaces, coarse};

/// Where a chart stands in the mesh's chart order: charts grown from a seed in the seeds'
/// order (decreasing area, ties by face id), then degenerate faces with no neighbour to
/// join, by face id. A chart never spans two edge-connected components of the mesh, so the
/// charts of several sets of components, each grown (and merged) on its own, put in this
/// order are those of the whole mesh.
pub(super) type ChartOrder = (bool, std::cmp::Reverse<u32>, u32);

/// Step 2 of the [unwrapper](super) on `subset` (face ids, increasing: whole edge-connected
/// components of the mesh): planar charts (face lists, increasing) in their [`ChartOrder`],
/// UVs (texels) of the subset's faces in `uv`.
pub(super) fn grow(
    faces: &MeshFaces,
    subset: &[u32],
    cos_max: f64,
    uv: &mut [[DVec2; 3]],
    seen: &mut Visited,
) -> Vec<(ChartOrder, Vec<u32>)> {
    let n = faces.len();
    let seed_order = |f: u32| (std::cmp::Reverse(coarse(faces.area[f as usize] as f64)), f);
    let mut seeds: Vec<u32> = subset.iter().copied().filter(|&f| !faces.degenerate[f as usize]).collect();
    seeds.sort_unstable_by_key(|&f| seed_order(f));

    let mut chart_of = vec![u32::MAX; n];
    let mut tried = vec![u32::MAX; n];
    let mut grid = FaceGrid::new(faces.cell);
    let mut charts: Vec<Vec<u32>> = Vec::new();
    let mut order: Vec<ChartOrder> = Vec::new();
    let mut frames: Vec<Frame> = Vec::new();
    let mut queue = std::collections::VecDeque::new();

    for &seed in &seeds {
        let s = seed as usize;
        if chart_of[s] != u32::MAX {
            continue;
        }
        let id = charts.len() as u32;
        let mut members = vec![seed];
        chart_of[s] = id;
        let seed_frame = Frame { n: faces.normal[s], origin: faces.pos[s][0] };
        grid.clear();
        uv[s] = seed_frame.project(&faces.pos[s]);
        grid.insert(seed, &uv[s]);
        tried[s] = id;
        queue.clear();
        queue.push_back(seed);
        while let Some(f) = queue.pop_front() {
            for &g in faces.neighbours(f) {
                let gi = g as usize;
                if chart_of[gi] != u32::MAX || tried[gi] == id || faces.degenerate[gi] {
                    continue;
                }
                tried[gi] = id;
                if faces.normal[gi].dot(seed_frame.n) < cos_max {
                    continue;
                }
                let t = seed_frame.project(&faces.pos[gi]);
                if grid.overlaps(&t, uv, seen) {
                    continue;
                }
                uv[gi] = t;
                grid.insert(g, &t);
                chart_of[gi] = id;
                members.push(g);
                queue.push_back(g);
            }
        }

        // Final plane: area-weighted normal, unless it folds the chart.
        let mut frame = seed_frame;
        let na = members.iter().map(|&f| faces.normal[f as usize] * faces.area[f as usize] as f64).sum::<DVec3>();
        let na = na.try_normalize().unwrap_or(seed_frame.n);
        if na.dot(seed_frame.n) < 1.0 - 1e-12 {
            let candidate = Frame { n: na, origin: seed_frame.origin };
            let kept: Vec<[DVec2; 3]> = members.iter().map(|&f| uv[f as usize]).collect();
            grid.clear();
            let mut ok = true;
            for &f in &members {
                let t = candidate.project(&faces.pos[f as usize]);
                uv[f as usize] = t;
                if grid.overlaps(&t, uv, seen) {
                    ok = false;
                    break;
                }
                grid.insert(f, &t);
            }
            if ok {
                frame = candidate;
            } else {
                for (&f, t) in members.iter().zip(kept) {
                    uv[f as usize] = t;
                }
            }
        }
        charts.push(members);
        let (area, face) = seed_order(seed);
        order.push((false, area, face));
        frames.push(frame);
    }

    // Degenerate faces: into the chart of their first non-degenerate edge neighbour,
    // projected onto its plane, else alone. (No overlap test: thinner than 10⁻⁷ of their
    // length, or collapsed to a segment, they have no interior to overlap with.)
    for &f in subset {
        if !faces.degenerate[f as usize] {
            continue;
        }
        let home = faces.neighbours(f).iter().map(|&g| chart_of[g as usize]).find(|&c| c != u32::MAX);
        let c = home.unwrap_or_else(|| {
            charts.push(Vec::new());
            order.push((true, std::cmp::Reverse(0), f));
            frames.push(Frame { n: faces.normal[f as usize], origin: faces.pos[f as usize][0] });
            (charts.len() - 1) as u32
        });
        uv[f as usize] = frames[c as usize].project(&faces.pos[f as usize]);
        chart_of[f as usize] = c;
        charts[c as usize].push(f);
    }
    for c in &mut charts {
        c.sort_unstable();
    }
    order.into_iter().zip(charts).collect()
}
