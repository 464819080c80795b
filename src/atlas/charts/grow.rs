//! Step 2 of the unwrapper: growing planar charts.

use glam::{DVec2, DVec3};

use super::face_grid::{FaceGrid, Visited};
use super::faces::{Frame, MeshFaces, coarse};

/// Step 2 of the [unwrapper](super): planar charts (face lists, increasing), UVs (texels) in `uv`.
pub(super) fn grow(faces: &MeshFaces, cos_max: f64, uv: &mut [[DVec2; 3]], seen: &mut Visited) -> Vec<Vec<u32>> {
    let n = faces.len();
    let mut seeds: Vec<u32> = (0..n as u32).filter(|&f| !faces.degenerate[f as usize]).collect();
    seeds.sort_unstable_by_key(|&f| (std::cmp::Reverse(coarse(faces.area[f as usize] as f64)), f));

    let mut chart_of = vec![u32::MAX; n];
    let mut tried = vec![u32::MAX; n];
    let mut grid = FaceGrid::new(faces.cell);
    let mut charts: Vec<Vec<u32>> = Vec::new();
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
        frames.push(frame);
    }

    // Degenerate faces: into the chart of their first non-degenerate edge neighbour,
    // projected onto its plane, else alone. (No overlap test: thinner than 10⁻⁷ of their
    // length, or collapsed to a segment, they have no interior to overlap with.)
    for f in 0..n as u32 {
        if !faces.degenerate[f as usize] {
            continue;
        }
        let home = faces.neighbours(f).iter().map(|&g| chart_of[g as usize]).find(|&c| c != u32::MAX);
        let c = home.unwrap_or_else(|| {
            charts.push(Vec::new());
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
    charts
}
