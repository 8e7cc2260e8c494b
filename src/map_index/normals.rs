//! Normals of map points, computed when a frame first needs them and kept: a frame uses a few
//! hundred map points, so the map's millions are never all solved (at 5 M points that took
//! ~38 s at load). The same PCA over the same k nearest neighbours as an eager pass, so a lazy
//! normal equals the eager one bit for bit.

use std::collections::HashMap;
use std::sync::Mutex;

use nalgebra::{Point3, Vector3};

use super::voxels::VoxelGrid;
use crate::geometry::{centroid, pca_normal, PointIndex};

/// Finds the map points nearest to a point: one k-d tree over the whole map, or the voxel
/// grid's per-voxel trees ([`VoxelGrid::nearest_k`]).
pub trait NearestPoints: Sync {
    /// Indices of the `k` nearest map points to `p`, nearest first.
    fn nearest_points(&self, p: &Point3<f32>, k: usize) -> Vec<usize>;
}

impl NearestPoints for PointIndex {
    fn nearest_points(&self, p: &Point3<f32>, k: usize) -> Vec<usize> {
        self.nearest(p, k)
    }
}

impl NearestPoints for VoxelGrid {
    fn nearest_points(&self, p: &Point3<f32>, k: usize) -> Vec<usize> {
        self.nearest_k(p, k)
    }
}

/// Normals at most kept; beyond it the cache starts afresh (a bound on what an hour-long run
/// over a huge map can make it hold: 4 M entries ≈ 100 MB).
const MAX_CACHED: usize = 4_000_000;

/// Lazily computed, cached normals of the points of one map.
#[derive(Debug, Default)]
pub struct LazyNormals {
    cache: Mutex<HashMap<u32, Vector3<f32>>>,
}

impl LazyNormals {
    /// The normal of each of `which` (indices into `points`), from its `k` nearest neighbours
    /// in `index`; an index out of range gets a zero vector.
    pub fn get(
        &self,
        index: &dyn NearestPoints,
        points: &[Point3<f32>],
        k: usize,
        which: &[usize],
    ) -> Vec<Vector3<f32>> {
        // A poisoned lock only means another thread panicked mid-insert: the cache stays valid.
        let mut cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        if cache.len() + which.len() > MAX_CACHED {
            cache.clear();
        }
        let mut neighbours = Vec::with_capacity(k);
        which
            .iter()
            .map(|&i| {
                let (Ok(key), Some(p)) = (u32::try_from(i), points.get(i)) else { return Vector3::zeros() };
                *cache.entry(key).or_insert_with(|| point_normal(index, points, p, k, &mut neighbours))
            })
            .collect()
    }

    /// Normals cached so far.
    pub fn cached(&self) -> usize {
        self.cache.lock().unwrap_or_else(|e| e.into_inner()).len()
    }
}

/// The unit normal at `p` from its `k` nearest points (arbitrary sign; zero when degenerate),
/// exactly as [`crate::geometry::point_cloud_normals`] computes it.
pub fn point_normal(
    index: &dyn NearestPoints,
    points: &[Point3<f32>],
    p: &Point3<f32>,
    k: usize,
    neighbours: &mut Vec<Point3<f64>>,
) -> Vector3<f32> {
    neighbours.clear();
    neighbours.extend(index.nearest_points(p, k).into_iter().filter_map(|i| points.get(i)).map(|q| q.cast::<f64>()));
    let c = centroid(neighbours);
    pca_normal(neighbours, &c).map_or_else(Vector3::zeros, |n| n.cast())
}
