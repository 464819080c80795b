//! Uniform world cells over the scene.
//!
//! STAND-IN written on the `viewer` branch to the lead's specification so the viewer's GPU
//! mirror can be built and tested before the real `src/grid.rs` lands on `main`; replaced
//! by main's file at the merge.

use glam::Vec3;

#[derive(Clone, Debug, PartialEq)]
pub struct Grid {
    pub origin: Vec3,
    pub cell_size: f32,
    pub dims: [u32; 3],
}

impl Grid {
    pub fn cell_count(&self) -> usize {
        self.dims.iter().map(|&d| d as usize).product()
    }

    /// Cell coordinates of `p`: floor((p − origin)/cell_size) clamped into dims.
    pub fn cell_coords(&self, p: Vec3) -> [u32; 3] {
        let q = (p - self.origin) / self.cell_size;
        let f = |v: f32, d: u32| (v.floor().max(0.0) as u32).min(d.saturating_sub(1));
        [f(q.x, self.dims[0]), f(q.y, self.dims[1]), f(q.z, self.dims[2])]
    }

    pub fn index(&self, c: [u32; 3]) -> usize {
        c[0] as usize + self.dims[0] as usize * (c[1] as usize + self.dims[1] as usize * c[2] as usize)
    }

    pub fn cell_of(&self, p: Vec3) -> usize {
        self.index(self.cell_coords(p))
    }
}
