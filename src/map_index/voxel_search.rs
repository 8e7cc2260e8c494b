//! Neighbour searches over the voxel grid, for maps too large to index whole at load: a voxel
//! gets a k-d tree over its points the first time a search reaches it, and a search merges the
//! voxels its query can touch. The answers are exact (the k nearest map points, nearest first,
//! equal distances by map index) while loading builds no tree over millions of points, and a
//! run builds trees only where its frames look.

use std::num::NonZero;

use kiddo::{ImmutableKdTree, SquaredEuclidean};
use nalgebra::{Point3, Vector3};

use super::voxels::{cell_of, key_of, Voxel, VoxelGrid};

/// Slack on a search reach derived from a found distance, so that rounding in the squared
/// distances never lets a nearer point outside the searched voxels go unnoticed.
const REACH_SLACK: f32 = 1e-4;

/// A reach just past a found point's distance (with slack for rounding).
fn reach_past(found: &Found) -> f32 {
    found.distance_sq.sqrt() * (1.0 + REACH_SLACK) + f32::EPSILON
}

/// A map point a search found.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Found {
    distance_sq: f32,
    map_index: u32,
}

/// Voxel cells in the box from `lo` to `hi` (inclusive; 0 when empty): when there are more of
/// them than occupied voxels, a search scans the occupied voxels instead of the cells.
fn cells_in(lo: &[i64; 3], hi: &[i64; 3]) -> u128 {
    (0..3).map(|a| (hi[a] - lo[a] + 1).max(0) as u128).product()
}

impl VoxelGrid {
    /// The `k` nearest map points to `q` (indices into the map), nearest first; fewer when the
    /// map holds fewer, none for a non-finite query.
    pub fn nearest_k(&self, q: &Point3<f32>, k: usize) -> Vec<usize> {
        let k = k.min(self.len());
        if k == 0 || !q.iter().all(|v| v.is_finite()) {
            return Vec::new();
        }
        // A first answer: the k nearest points of q's own voxel (when it holds k), which is the
        // answer when the sphere through the k-th of them stays in that voxel.
        let in_own = self
            .own_voxel(q)
            .filter(|&v| self.voxels.get(v).is_some_and(|voxel| voxel.len >= k))
            .map(|v| self.merged(q, k, None, &[v]));
        let mut reach = self.voxel_m;
        if let Some(kth) = in_own.as_ref().and_then(|found| found.last()) {
            reach = reach_past(kth);
            if let Some(found) = in_own.filter(|_| self.in_one_voxel(q, reach)) {
                return found.iter().map(|f| f.map_index as usize).collect();
            }
        }
        loop {
            let found = self.merged(q, k, None, &self.voxels_near(q, reach));
            let settled = found.len() == k && found.last().is_some_and(|f| f.distance_sq <= reach * reach);
            if settled || self.reaches_every_voxel(q, reach) || !reach.is_finite() {
                return found.iter().map(|f| f.map_index as usize).collect();
            }
            reach *= 2.0;
        }
    }

    /// The map point nearest to `q` if one lies within `radius` (its cost follows the voxels
    /// within `radius`).
    pub fn nearest_within(&self, q: &Point3<f32>, radius: f32) -> Option<usize> {
        if !q.iter().all(|v| v.is_finite()) || radius.is_nan() || radius < 0.0 {
            return None;
        }
        let limit = Some(radius * radius);
        // The nearest point of q's own voxel first: no other voxel can hold a nearer one when the
        // sphere through it stays in that voxel, and none beyond that sphere otherwise.
        let reach = match self.own_voxel(q) {
            Some(own) => match self.merged(q, 1, limit, &[own]).first() {
                Some(nearest) if self.in_one_voxel(q, reach_past(nearest)) => return Some(nearest.map_index as usize),
                Some(nearest) => reach_past(nearest).min(radius),
                None => radius,
            },
            None => radius,
        };
        let found = self.merged(q, 1, limit, &self.voxels_near(q, reach));
        found.first().map(|f| f.map_index as usize)
    }

    /// The `k` nearest points to `q` over `voxels` (within `max_distance_sq` when given),
    /// nearest first, equal distances by map index.
    fn merged(&self, q: &Point3<f32>, k: usize, max_distance_sq: Option<f32>, voxels: &[usize]) -> Vec<Found> {
        let Some(k_nonzero) = NonZero::new(k) else { return Vec::new() };
        let query_point = [q.x, q.y, q.z];
        let mut found = Vec::new();
        for &v in voxels {
            let (Some(tree), Some(&Voxel { start, .. })) = (self.voxel_tree(v), self.voxels.get(v)) else { continue };
            let query = tree.query(&query_point).nearest_n::<SquaredEuclidean<f32>>(k_nonzero);
            let nearest = match max_distance_sq {
                Some(limit) => query.within(limit).execute(),
                None => query.execute(),
            };
            found.extend(nearest.into_iter().filter_map(|n| {
                let map_index = *self.map_index.get(start + n.item as usize)?;
                Some(Found { distance_sq: n.distance, map_index })
            }));
        }
        found.sort_unstable_by(|a, b| a.distance_sq.total_cmp(&b.distance_sq).then(a.map_index.cmp(&b.map_index)));
        found.truncate(k);
        found
    }

    /// The k-d tree over voxel `v`'s points, built on first use.
    fn voxel_tree(&self, v: usize) -> Option<&ImmutableKdTree<f32, 3>> {
        self.trees
            .get(v)?
            .get_or_init(|| {
                let Voxel { start, len } = *self.voxels.get(v)?;
                let points: Vec<[f32; 3]> = (start..start + len).map(|i| [self.x[i], self.y[i], self.z[i]]).collect();
                if points.is_empty() {
                    return None;
                }
                ImmutableKdTree::new_from_slice(&points).ok()
            })
            .as_ref()
    }

    /// The voxel coordinates of the cube of half-side `reach` around `q`, clipped to the grid.
    fn cube_cells(&self, q: &Point3<f32>, reach: f32) -> ([i64; 3], [i64; 3]) {
        let corner = Vector3::repeat(reach);
        let (lo, hi) = (cell_of(&(q - corner), self.voxel_m), cell_of(&(q + corner), self.voxel_m));
        let [grid_lo, grid_hi] = self.cell_bounds;
        (std::array::from_fn(|a| lo[a].max(grid_lo[a])), std::array::from_fn(|a| hi[a].min(grid_hi[a])))
    }

    /// The occupied voxel holding `q`, if any.
    fn own_voxel(&self, q: &Point3<f32>) -> Option<usize> {
        self.keys.binary_search(&key_of(q, self.voxel_m)).ok()
    }

    /// Whether the cube of half-side `reach` around `q` meets one voxel cell of the grid only.
    fn in_one_voxel(&self, q: &Point3<f32>, reach: f32) -> bool {
        let (lo, hi) = self.cube_cells(q, reach);
        lo == hi
    }

    /// Whether the cube of half-side `reach` around `q` covers every voxel of the grid.
    fn reaches_every_voxel(&self, q: &Point3<f32>, reach: f32) -> bool {
        let corner = Vector3::repeat(reach);
        let (lo, hi) = (cell_of(&(q - corner), self.voxel_m), cell_of(&(q + corner), self.voxel_m));
        let [grid_lo, grid_hi] = self.cell_bounds;
        (0..3).all(|a| lo[a] <= grid_lo[a] && hi[a] >= grid_hi[a])
    }

    /// Occupied voxels (indices, ascending) that meet the cube of half-side `reach` around
    /// `q`: every point within `reach` of `q` lies in one of them.
    fn voxels_near(&self, q: &Point3<f32>, reach: f32) -> Vec<usize> {
        let (lo, hi) = self.cube_cells(q, reach);
        if cells_in(&lo, &hi) > self.keys.len() as u128 {
            let inside = |c: [i64; 3]| (0..3).all(|a| lo[a] <= c[a] && c[a] <= hi[a]);
            return (0..self.keys.len()).filter(|&v| inside(super::voxels::unpack(self.keys[v]))).collect();
        }
        let mut near = Vec::new();
        for ix in lo[0]..=hi[0] {
            for iy in lo[1]..=hi[1] {
                for iz in lo[2]..=hi[2] {
                    if let Ok(v) = self.keys.binary_search(&super::voxels::pack(ix, iy, iz)) {
                        near.push(v);
                    }
                }
            }
        }
        near.sort_unstable();
        near
    }
}

impl VoxelGrid {
    /// The distance from `p` (the map's point `map_index`) to the nearest other point of its
    /// voxel, by brute force: no tree is built for it. A point whose nearest neighbour lies
    /// across its voxel's face sees a larger gap; for the median over many samples (the map's
    /// point spacing) that is noise, as the voxels are far wider than the spacing.
    pub(super) fn gap_in_voxel(&self, map_index: usize, p: &Point3<f32>) -> Option<f32> {
        let v = self.own_voxel(p)?;
        let Voxel { start, len } = *self.voxels.get(v)?;
        let range = start..start + len;
        let (x, y, z, ids) = (
            self.x.get(range.clone())?,
            self.y.get(range.clone())?,
            self.z.get(range.clone())?,
            self.map_index.get(range)?,
        );
        let nearest_sq = (0..len)
            .filter(|&i| ids[i] as usize != map_index)
            .map(|i| (x[i] - p.x).powi(2) + (y[i] - p.y).powi(2) + (z[i] - p.z).powi(2))
            .min_by(f32::total_cmp)?;
        Some(nearest_sq.sqrt())
    }
}

impl VoxelGrid {
    /// Builds the per-voxel trees not built yet, one voxel after another (on the caller's
    /// thread), for as long as `wanted` says; returns how many it built. A node runs it beside
    /// its frames after a new map, so that the first frames do not pay for them.
    pub fn build_trees_while(&self, wanted: impl Fn() -> bool) -> usize {
        let mut built = 0;
        for (v, tree) in self.trees.iter().enumerate() {
            if !wanted() {
                break;
            }
            if tree.get().is_none() {
                self.voxel_tree(v);
                built += 1;
            }
        }
        built
    }

    /// Builds every per-voxel tree not built yet, in parallel: for a caller that indexes a map
    /// before its first frame (a replay), so that no frame pays for them.
    pub fn build_all_trees(&self) {
        use rayon::prelude::*;
        (0..self.trees.len()).into_par_iter().for_each(|v| {
            self.voxel_tree(v);
        });
    }

    /// Per-voxel trees built so far.
    pub fn built_trees(&self) -> usize {
        self.trees.iter().filter(|t| t.get().is_some()).count()
    }
}
