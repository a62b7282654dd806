//! The reward map: the scene's ground regions rasterised onto a grid of
//! `cell_size` cells, one region label per cell.
//!
//! Invariant: the label of a cell is the kind of the last region (in the scene's
//! paint order) whose polygon contains the cell's centre, or road where none does —
//! the same rule as [`Scene::region_kind_exact`], so the map and the exact
//! polygon test agree at every cell centre. The renderer's ground texture and the
//! oracle planner are built from this one grid.
//!
//! The map holds data only: which reward a region kind gets is
//! [`crate::reward`]'s rule, tabulated here once per label for fast look-ups.

use crate::region_kind::RegionKind;
use crate::scene::Scene;

/// One label per cell over the scene's extent.
#[derive(Debug, Clone)]
pub struct RegionMap {
    /// x of the grid's lower-left corner.
    pub x0: f32,
    /// y of the grid's lower-left corner.
    pub y0: f32,
    /// Cell size in metres.
    pub cell: f32,
    /// Number of cells along x.
    pub nx: usize,
    /// Number of cells along y.
    pub ny: usize,
    /// Labels, row-major with row 0 at `y0` (south).
    labels: Vec<u8>,
    /// Map reward per label, tabulated once by [`crate::reward::Rewards::map_reward_table`].
    rewards: [f32; RegionKind::ALL.len()],
}

impl RegionMap {
    /// Rasterise the scene's regions.
    pub fn new(scene: &Scene) -> RegionMap {
        let cell = scene.spec.cell_size;
        let x0 = scene.extent.min[0];
        let y0 = scene.extent.min[1];
        let nx = (scene.extent.width() / cell).ceil() as usize;
        let ny = (scene.extent.height() / cell).ceil() as usize;
        let mut labels = vec![RegionKind::Road.label(); nx * ny];
        let mut xs: Vec<f32> = Vec::new();
        for region in &scene.regions {
            let v = &region.polygon.0;
            let b = region.polygon.bounds();
            let j_lo = (((b.min[1] - y0) / cell - 0.5).floor().max(0.0)) as usize;
            let j_hi = ((((b.max[1] - y0) / cell) + 0.5).ceil() as usize).min(ny);
            for j in j_lo..j_hi {
                let yc = y0 + (j as f32 + 0.5) * cell;
                xs.clear();
                let mut k = v.len() - 1;
                for i in 0..v.len() {
                    let (a, c) = (v[i], v[k]);
                    if (a[1] > yc) != (c[1] > yc) {
                        xs.push((c[0] - a[0]) * (yc - a[1]) / (c[1] - a[1]) + a[0]);
                    }
                    k = i;
                }
                xs.sort_by(f32::total_cmp);
                for span in xs.chunks_exact(2) {
                    // Cells whose centre x satisfies span[0] < xc < span[1]... the exact
                    // test uses `x < crossing`, so a centre is inside when it lies strictly
                    // left of an odd number of crossings: xc in [span[0], span[1]).
                    let i_lo = ((span[0] - x0) / cell - 0.5).ceil().max(0.0) as usize;
                    let i_hi = (((span[1] - x0) / cell - 0.5).ceil().max(0.0) as usize).min(nx);
                    let row = &mut labels[j * nx..(j + 1) * nx];
                    for l in &mut row[i_lo.min(i_hi)..i_hi] {
                        *l = region.kind.label();
                    }
                }
            }
        }
        let rewards = scene.rewards().map_reward_table();
        RegionMap { x0, y0, cell, nx, ny, labels, rewards }
    }

    /// Cell indices of a point, clamped to the grid.
    #[inline]
    pub fn cell_of(&self, x: f32, y: f32) -> (usize, usize) {
        let i = ((x - self.x0) / self.cell).floor();
        let j = ((y - self.y0) / self.cell).floor();
        let i = (i.max(0.0) as usize).min(self.nx - 1);
        let j = (j.max(0.0) as usize).min(self.ny - 1);
        (i, j)
    }

    /// Centre of cell `(i, j)`.
    #[inline]
    pub fn cell_center(&self, i: usize, j: usize) -> (f32, f32) {
        (self.x0 + (i as f32 + 0.5) * self.cell, self.y0 + (j as f32 + 0.5) * self.cell)
    }

    /// Label of cell `(i, j)`.
    #[inline]
    pub fn label(&self, i: usize, j: usize) -> u8 {
        self.labels[j * self.nx + i]
    }

    /// All labels, row-major from the south-west corner.
    pub fn labels(&self) -> &[u8] {
        &self.labels
    }

    /// Region kind at a point (points outside the world take the nearest edge cell).
    #[inline]
    pub fn kind_at(&self, x: f32, y: f32) -> RegionKind {
        let (i, j) = self.cell_of(x, y);
        RegionKind::from_label(self.label(i, j))
    }

    /// Map reward `r_m` at a point (see [`crate::reward`]).
    #[inline]
    pub fn reward_at(&self, x: f32, y: f32) -> f32 {
        let (i, j) = self.cell_of(x, y);
        self.rewards[self.label(i, j) as usize]
    }

    /// Map reward of a region kind.
    #[inline]
    pub fn reward_of(&self, kind: RegionKind) -> f32 {
        self.rewards[kind as usize]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn map_agrees_with_exact_polygons_at_cell_centres() {
        let scene = Scene::reference();
        let map = RegionMap::new(&scene);
        let mut checked = 0;
        for j in (0..map.ny).step_by(7) {
            for i in (0..map.nx).step_by(5) {
                let (x, y) = map.cell_center(i, j);
                assert_eq!(
                    RegionKind::from_label(map.label(i, j)),
                    scene.region_kind_exact(x, y),
                    "cell ({i},{j}) at ({x},{y})"
                );
                checked += 1;
            }
        }
        assert!(checked > 10_000);
    }

    #[test]
    fn rewards_per_region_match_the_scene() {
        let scene = Scene::reference();
        let map = RegionMap::new(&scene);
        let r = scene.rewards();
        // One probe point in the middle of each kind of region of the reference scene.
        assert_eq!(map.reward_at(30.0, -2.5), r.road);
        assert_eq!(map.reward_at(25.0, -7.0), r.sidewalk);
        assert_eq!(map.reward_at(10.0, 7.0), r.goal_sidewalk);
        assert_eq!(map.reward_at(13.0, 0.0), r.zebra);
        assert_eq!(map.reward_at(20.0, 7.0), r.goal);
        assert_eq!(map.kind_at(20.0, 7.0), RegionKind::Goal);
    }
}
