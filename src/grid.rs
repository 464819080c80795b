//! The runtime's world-space grid (2017 thesis, 3.3.2): uniform cells that own light-map
//! texels. A texel of any LOD belongs to the cell holding its world position, so a cell can be
//! refined, published and evicted on its own while its neighbours stay at other LODs.
//!
//! Pure data over the scene's geometry: no baking, no GPU.

use glam::{DVec3, Vec3};

use crate::scene::SceneGeometry;

/// Uniform cells over an axis-aligned box. Cell `(x, y, z)` is the half-open box
/// `origin + [x, x+1) × [y, y+1) × [z, z+1) · cell_size`; its index is `x + dims.x·(y + dims.y·z)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Grid {
    pub origin: Vec3,
    pub cell_size: f32,
    pub dims: [u32; 3],
}

impl serde::Serialize for Grid {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeStruct;
        let mut st = s.serialize_struct("Grid", 3)?;
        st.serialize_field("origin", &self.origin.to_array())?;
        st.serialize_field("cell_size", &self.cell_size)?;
        st.serialize_field("dims", &self.dims)?;
        st.end()
    }
}

/// Index of a cell in a [`Grid`].
pub type CellId = u32;

/// Errors choosing a grid.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GridError {
    #[error("--cell-size must be a positive number of metres, got {0}")]
    BadCellSize(f32),
    #[error(
        "a cell size of {cell_size} m gives {cells} grid cells over the scene's bounds, above the limit of {max}; use a larger --cell-size"
    )]
    TooManyCells { cell_size: f32, cells: u64, max: u64 },
    #[error("the scene's bounds are not finite")]
    BadBounds,
}

/// Most cells a grid may have (its per-cell tables are dense: a few bytes each).
pub const MAX_CELLS: u64 = 1 << 22;

/// The default grid aims at about this many non-empty cells at most (DESIGN: "a few
/// thousand"): enough that refining near the camera spends little on what is far.
pub const TARGET_CELLS: f64 = 1000.0;

impl Grid {
    /// A grid of cubes of side `cell_size` covering `[lo, hi]` (the box is grown by a hair so
    /// that points on its upper faces fall inside the last cells).
    pub fn covering(lo: Vec3, hi: Vec3, cell_size: f32) -> Result<Grid, GridError> {
        if !(cell_size.is_finite() && cell_size > 0.0) {
            return Err(GridError::BadCellSize(cell_size));
        }
        if !(lo.is_finite() && hi.is_finite()) || lo.cmpgt(hi).any() {
            return Err(GridError::BadBounds);
        }
        let extent = (hi - lo).as_dvec3();
        let n = |e: f64| ((e / cell_size as f64).floor() as u64 + 1).max(1);
        let (nx, ny, nz) = (n(extent.x), n(extent.y), n(extent.z));
        let cells = nx.saturating_mul(ny).saturating_mul(nz);
        if cells > MAX_CELLS {
            return Err(GridError::TooManyCells { cell_size, cells, max: MAX_CELLS });
        }
        Ok(Grid { origin: lo, cell_size, dims: [nx as u32, ny as u32, nz as u32] })
    }

    /// The default grid of a scene: cells of side `sqrt(lit area / TARGET_CELLS)` (a surface
    /// of that area cut into that many squares), but at least `min_cell` (a cell bake's
    /// fixed costs per direction — the window's triangles, its analysis — must stay small
    /// beside its texels) and at most `max_cell` (so that a cell at the finest LOD stays a
    /// unit of work of bounded size; it wins over `min_cell`), grown until the box holds at
    /// most [`MAX_CELLS`] cells. `cell_size` overrides the size.
    pub fn for_scene(
        geom: &SceneGeometry,
        lit_area: f64,
        min_cell: f32,
        max_cell: f32,
        cell_size: Option<f32>,
    ) -> Result<Grid, GridError> {
        let (lo, hi) = bounds(geom).ok_or(GridError::BadBounds)?;
        if let Some(size) = cell_size {
            return Grid::covering(lo, hi, size);
        }
        let mut size = ((lit_area / TARGET_CELLS).sqrt() as f32).max(min_cell).min(max_cell).max(1e-4);
        loop {
            match Grid::covering(lo, hi, size) {
                Err(GridError::TooManyCells { .. }) => size *= 1.25,
                other => return other,
            }
        }
    }

    pub fn len(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Integer cell coordinates of `p`, clamped into the grid (points outside belong to the
    /// nearest border cell).
    #[inline]
    pub fn coords_of(&self, p: Vec3) -> [u32; 3] {
        let q = (p - self.origin) / self.cell_size;
        let c = |v: f32, n: u32| if v.is_nan() || v < 0.0 { 0 } else { (v as u32).min(n - 1) };
        [c(q.x, self.dims[0]), c(q.y, self.dims[1]), c(q.z, self.dims[2])]
    }

    #[inline]
    pub fn index(&self, c: [u32; 3]) -> CellId {
        c[0] + self.dims[0] * (c[1] + self.dims[1] * c[2])
    }

    #[inline]
    pub fn coords(&self, cell: CellId) -> [u32; 3] {
        let (dx, dy) = (self.dims[0], self.dims[1]);
        [cell % dx, cell / dx % dy, cell / (dx * dy)]
    }

    /// The cell holding `p` (see [`Grid::coords_of`]).
    #[inline]
    pub fn cell_of(&self, p: Vec3) -> CellId {
        self.index(self.coords_of(p))
    }

    /// World bounds `(min, max)` of a cell.
    pub fn bounds(&self, cell: CellId) -> (Vec3, Vec3) {
        let c = self.coords(cell);
        let lo = self.origin + Vec3::new(c[0] as f32, c[1] as f32, c[2] as f32) * self.cell_size;
        (lo, lo + Vec3::splat(self.cell_size))
    }

    /// Centre of a cell.
    pub fn centre(&self, cell: CellId) -> Vec3 {
        let (lo, hi) = self.bounds(cell);
        (lo + hi) * 0.5
    }

    /// The face-neighbour of `cell` along `axis` (0, 1, 2) in direction `step` (−1 or +1),
    /// if it is inside the grid.
    pub fn neighbour(&self, cell: CellId, axis: usize, step: i32) -> Option<CellId> {
        let mut c = self.coords(cell);
        let v = c[axis] as i64 + step as i64;
        if v < 0 || v >= self.dims[axis] as i64 {
            return None;
        }
        c[axis] = v as u32;
        Some(self.index(c))
    }

    /// Cells whose boxes, grown by `margin` metres on every side, meet the box `[lo, hi]`.
    pub fn cells_meeting(&self, lo: Vec3, hi: Vec3, margin: f32) -> impl Iterator<Item = CellId> + '_ {
        let a = self.coords_of(lo - Vec3::splat(margin));
        let b = self.coords_of(hi + Vec3::splat(margin));
        (a[2]..=b[2])
            .flat_map(move |z| (a[1]..=b[1]).flat_map(move |y| (a[0]..=b[0]).map(move |x| self.index([x, y, z]))))
    }
}

/// World bounds of a scene's triangles (`None` when empty or not finite).
pub fn bounds(geom: &SceneGeometry) -> Option<(Vec3, Vec3)> {
    let mut it = geom.corners.iter().flatten().copied();
    let first = it.next()?;
    let (lo, hi) = it.fold((first, first), |(lo, hi), p| (lo.min(p), hi.max(p)));
    (lo.is_finite() && hi.is_finite()).then_some((lo, hi))
}

/// Per cell, the triangles that meet it (its box grown by a margin): compressed rows
/// (`triangles[offsets[c]..offsets[c + 1]]`, ascending ids).
#[derive(Clone, Debug, Default)]
pub struct CellTriangles {
    pub offsets: Vec<u32>,
    pub triangles: Vec<u32>,
}

impl CellTriangles {
    /// Every triangle of `geom` filed under each cell whose box grown by `margin` it meets
    /// (exact triangle–box overlap, separating axes).
    pub fn build(grid: &Grid, geom: &SceneGeometry, margin: f32) -> CellTriangles {
        let mut pairs: Vec<(CellId, u32)> = Vec::new();
        for (t, c) in geom.corners.iter().enumerate() {
            if !c.iter().all(|p| p.is_finite()) {
                continue;
            }
            let lo = c[0].min(c[1]).min(c[2]);
            let hi = c[0].max(c[1]).max(c[2]);
            for cell in grid.cells_meeting(lo, hi, margin) {
                let (blo, bhi) = grid.bounds(cell);
                if triangle_meets_box(c, blo - Vec3::splat(margin), bhi + Vec3::splat(margin)) {
                    pairs.push((cell, t as u32));
                }
            }
        }
        pairs.sort_unstable();
        let mut offsets = vec![0u32; grid.len() + 1];
        for &(cell, _) in &pairs {
            offsets[cell as usize + 1] += 1;
        }
        for i in 0..grid.len() {
            offsets[i + 1] += offsets[i];
        }
        CellTriangles { offsets, triangles: pairs.into_iter().map(|(_, t)| t).collect() }
    }

    pub fn of(&self, cell: CellId) -> &[u32] {
        let c = cell as usize;
        &self.triangles[self.offsets[c] as usize..self.offsets[c + 1] as usize]
    }
}

/// Whether triangle `t` meets the closed box `[lo, hi]` (Akenine-Möller's separating-axis
/// test: the box's three axes, the triangle's normal, and the nine edge × axis cross products),
/// in f64 so thin boxes and large coordinates stay exact enough.
pub fn triangle_meets_box(t: &[Vec3; 3], lo: Vec3, hi: Vec3) -> bool {
    let c = (lo.as_dvec3() + hi.as_dvec3()) * 0.5;
    let h = (hi.as_dvec3() - lo.as_dvec3()) * 0.5;
    let v = t.map(|p| p.as_dvec3() - c);
    // Box axes.
    for a in 0..3 {
        let (mn, mx) = (v[0][a].min(v[1][a]).min(v[2][a]), v[0][a].max(v[1][a]).max(v[2][a]));
        if mn > h[a] || mx < -h[a] {
            return false;
        }
    }
    let e = [v[1] - v[0], v[2] - v[1], v[0] - v[2]];
    let separated = |axis: DVec3| {
        if axis.length_squared() < 1e-30 {
            return false;
        }
        let p = v.map(|q| q.dot(axis));
        let r = h.x * axis.x.abs() + h.y * axis.y.abs() + h.z * axis.z.abs();
        p[0].min(p[1]).min(p[2]) > r || p[0].max(p[1]).max(p[2]) < -r
    };
    if separated(e[0].cross(e[1])) {
        return false;
    }
    for edge in e {
        for axis in [DVec3::X, DVec3::Y, DVec3::Z] {
            if separated(edge.cross(axis)) {
                return false;
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::Rng;

    #[test]
    fn cells_index_round_trip_and_clamp() {
        let g = Grid::covering(Vec3::new(-1.0, 0.0, 2.0), Vec3::new(3.0, 1.0, 4.5), 0.5).unwrap();
        assert_eq!(g.dims, [9, 3, 6]);
        for cell in 0..g.len() as u32 {
            assert_eq!(g.index(g.coords(cell)), cell);
            assert_eq!(g.cell_of(g.centre(cell)), cell);
        }
        // Outside points clamp to the border cells; NaN to the first.
        assert_eq!(g.coords_of(Vec3::new(-100.0, 0.2, 100.0)), [0, 0, 5]);
        assert_eq!(g.coords_of(Vec3::NAN), [0, 0, 0]);
        // Half-open cells: a point on a shared face belongs to the upper cell.
        assert_eq!(g.coords_of(Vec3::new(-0.5, 0.0, 2.0))[0], 1);
        assert_eq!(g.neighbour(0, 0, -1), None);
        assert_eq!(g.neighbour(0, 0, 1), Some(1));
        assert!(Grid::covering(Vec3::ZERO, Vec3::splat(1e4), 1e-3).is_err());
        assert!(Grid::covering(Vec3::ZERO, Vec3::ONE, 0.0).is_err());
    }

    /// The separating-axis test against a brute-force one: sample many points of the
    /// triangle; any inside the box proves overlap. Where the brute force finds a point the
    /// exact test must say yes; where the exact test says no, no sample may be inside.
    #[test]
    fn triangle_box_overlap_agrees_with_dense_sampling() {
        let mut rng = Rng::new(5, 9);
        let (lo, hi) = (Vec3::splat(-0.5), Vec3::splat(0.5));
        let mut hits = 0;
        for _ in 0..3000 {
            let t = [0; 3].map(|_| (Vec3::new(rng.next_f32(), rng.next_f32(), rng.next_f32()) - 0.5) * 3.0);
            let exact = triangle_meets_box(&t, lo, hi);
            let mut sampled = false;
            for i in 0..=40 {
                for j in 0..=(40 - i) {
                    let (u, v) = (i as f32 / 40.0, j as f32 / 40.0);
                    let p = t[0] + (t[1] - t[0]) * u + (t[2] - t[0]) * v;
                    sampled |= p.cmpge(lo).all() && p.cmple(hi).all();
                }
            }
            if sampled {
                assert!(exact, "{t:?} has a point in the box but the test says no");
                hits += 1;
            }
        }
        assert!(hits > 300, "too few overlapping cases to mean anything: {hits}");
    }
}
